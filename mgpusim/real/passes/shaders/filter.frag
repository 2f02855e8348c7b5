#version 450
// The filter pass: a fragment loop (ITER = extra.x) that samples N = extra.y (1..4) input
// images at its own pixel and combines them: fract(last input + (other inputs + loop) / 16).
// As a temporal pass the last input is the history (the previous frame's result), so the
// output accumulates over frames: reading the wrong frame gives a different picture.
layout(push_constant) uniform PC { vec4 rect; vec4 uv; vec4 extra; } pc;
layout(set = 0, binding = 0) uniform sampler2D tex0;
layout(set = 0, binding = 1) uniform sampler2D tex1;
layout(set = 0, binding = 2) uniform sampler2D tex2;
layout(set = 0, binding = 3) uniform sampler2D tex3;
layout(location = 0) in vec2 in_uv;
layout(location = 0) out vec4 color;
void main() {
    vec2 uv = in_uv;
    int n = int(pc.extra.x);
    for (int i = 0; i < n; i++) {
        uv *= 1.00001;
        uv *= 0.999998;
    }
    ivec2 p = ivec2(gl_FragCoord.xy);
    int k = int(pc.extra.y);
    vec4 t0 = texelFetch(tex0, p, 0);
    vec4 t1 = texelFetch(tex1, p, 0);
    vec4 t2 = texelFetch(tex2, p, 0);
    vec4 t3 = texelFetch(tex3, p, 0);
    vec4 last = k == 1 ? t0 : (k == 2 ? t1 : (k == 3 ? t2 : t3));
    vec4 others = (k > 1 ? t0 : vec4(0.0)) + (k > 2 ? t1 : vec4(0.0)) + (k > 3 ? t2 : vec4(0.0));
    color = vec4(fract(last.rgb + (others.rgb + vec3(uv, 0.5)) * 0.0625), 1.0);
}
