#version 450
// vmgpu's mesh as its basic.vert draws it: positions and normals in two vertex buffers, the
// normal turned by its own matrix and normalized per vertex. The y flip vmgpu's shader applies
// is in the matrix here (model/geometry.py's bounds_mvp).
layout(push_constant) uniform PC { mat4 mvp; mat4 normal; } pc;
layout(location = 0) in vec3 pos;
layout(location = 1) in vec3 normal;
layout(location = 0) out vec3 out_normal;
void main() {
    gl_Position = pc.mvp * vec4(pos, 1.0);
    out_normal = normalize(mat3(pc.normal) * normal);
}
