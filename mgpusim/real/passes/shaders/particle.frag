#version 450
// A soft round sprite, blended additively by the pipeline.
layout(location = 0) in vec2 in_uv;
layout(location = 0) out vec4 color;
void main() {
    float r = length(in_uv - 0.5) * 2.0;
    float a = clamp(1.0 - r, 0.0, 1.0);
    color = vec4(0.2 * a, 0.1 * a, 0.05 * a, a);
}
