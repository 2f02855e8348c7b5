#version 450
// Billboard vertices built by particles.comp: (pos, uv) float4 pairs.
layout(push_constant) uniform PC { mat4 mvp; } pc;
layout(location = 0) in vec4 pos;
layout(location = 1) in vec4 uv;
layout(location = 0) out vec2 out_uv;
void main() {
    out_uv = uv.xy;
    gl_Position = pc.mvp * vec4(pos.xyz, 1.0);
}
