#version 450
// The thesis's fragment-loop benchmark: ITER (= extra.x) dependent multiplies per fragment.
layout(push_constant) uniform PC { vec4 rect; vec4 uv; vec4 extra; } pc;
layout(location = 0) in vec2 in_uv;
layout(location = 0) out vec4 color;
void main() {
    vec2 uv = in_uv;
    int n = int(pc.extra.x);
    for (int i = 0; i < n; i++) {
        uv *= 1.00001;
        uv *= 0.999998;
    }
    color = vec4(uv, 0.5, 1.0);
}
