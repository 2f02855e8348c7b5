#version 450
// Sort-last composite: one contribution's colour and depth; the depth test keeps the nearest.
layout(set = 0, binding = 0) uniform sampler2D tex;
layout(set = 0, binding = 1) uniform sampler2D depth_tex;
layout(location = 0) in vec2 in_uv;
layout(location = 0) out vec4 color;
void main() {
    color = texture(tex, in_uv);
    gl_FragDepth = texture(depth_tex, in_uv).r;
}
