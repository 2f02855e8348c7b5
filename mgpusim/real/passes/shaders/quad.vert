#version 450
// A screen-space rectangle (two triangles from gl_VertexIndex, no vertex buffer).
// rect = NDC (x0, y0, x1, y1); uv = texture coordinates at (x0,y0) and (x1,y1).
layout(push_constant) uniform PC { vec4 rect; vec4 uv; vec4 extra; } pc;
layout(location = 0) out vec2 out_uv;
void main() {
    const vec2 corners[6] = vec2[](vec2(0, 0), vec2(1, 0), vec2(0, 1),
                                   vec2(1, 0), vec2(1, 1), vec2(0, 1));
    vec2 c = corners[gl_VertexIndex];
    out_uv = mix(pc.uv.xy, pc.uv.zw, c);
    gl_Position = vec4(mix(pc.rect.xy, pc.rect.zw, c), 0.0, 1.0);
}
