#version 450
// The particle demo's update (particles on a secondary GPU, docs/sources.md), then a camera-facing billboard (6 vertices x (pos, uv)).
layout(local_size_x = 64) in;
struct Particle { vec4 pos; vec4 dir; vec4 spawn; vec4 life; };  // dir.w = vel; life = (alive, maxLife)
layout(std430, set = 0, binding = 0) buffer Particles { Particle p[]; };
layout(std430, set = 0, binding = 1) buffer Calc { vec4 calc[]; };      // 2 per particle
layout(std430, set = 0, binding = 2) buffer Verts { vec4 verts[]; };    // 12 per particle
layout(push_constant) uniform PC { vec4 right; vec4 up; float dt; uint count; } pc;
void main() {
    uint i = gl_GlobalInvocationID.x;
    if (i >= pc.count) return;
    Particle q = p[i];
    if (pc.dt > 0.0) {
        q.life.x += pc.dt;
        if (q.life.x > q.life.y) {
            q.pos = q.spawn;
            q.life.x = 0.0;
        } else {
            q.pos.xyz += q.dir.xyz * q.dir.w * pc.dt;
        }
    }
    p[i] = q;
    calc[2 * i] = q.pos;
    calc[2 * i + 1] = vec4(q.life.x, q.life.y, 0.0, 0.0);
    float s = q.spawn.w;  // billboard half-size
    const vec2 corners[6] = vec2[](vec2(-1, -1), vec2(1, -1), vec2(-1, 1),
                                   vec2(1, -1), vec2(1, 1), vec2(-1, 1));
    for (int k = 0; k < 6; k++) {
        vec2 c = corners[k];
        vec3 v = q.pos.xyz + (c.x * pc.right.xyz + c.y * pc.up.xyz) * s;
        verts[12 * i + 2 * k] = vec4(v, 1.0);
        verts[12 * i + 2 * k + 1] = vec4(c * 0.5 + 0.5, 0.0, 0.0);
    }
}
