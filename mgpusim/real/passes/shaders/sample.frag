#version 450
// Sort-first composite: copy one contribution's colour texture into its rectangle.
layout(set = 0, binding = 0) uniform sampler2D tex;
layout(location = 0) in vec2 in_uv;
layout(location = 0) out vec4 color;
void main() { color = texture(tex, in_uv); }
