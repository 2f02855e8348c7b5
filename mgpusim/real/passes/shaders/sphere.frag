#version 450
// vmgpu's basic.frag: one directional light, an ambient term, white.
layout(location = 0) in vec3 in_normal;
layout(location = 0) out vec4 color;
void main() {
    float intensity = clamp(dot(normalize(vec3(-1.0, 1.0, 1.0)), in_normal), 0.0, 1.0) * 0.85;
    color = vec4(vec3(0.15 + intensity), 1.0);
}
