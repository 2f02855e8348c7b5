#version 450
// Generated torus geometry: position + normal per vertex, one matrix for all.
layout(push_constant) uniform PC { mat4 mvp; } pc;
layout(location = 0) in vec3 pos;
layout(location = 1) in vec3 normal;
layout(location = 0) out vec3 out_color;
void main() {
    out_color = normal * 0.5 + 0.5;
    gl_Position = pc.mvp * vec4(pos, 1.0);
}
