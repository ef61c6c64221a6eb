#version 430
// A full-screen triangle from gl_VertexID; no vertex buffer.
void main() {
    vec2 p = vec2(float((gl_VertexID << 1) & 2), float(gl_VertexID & 2));
    gl_Position = vec4(2.0 * p - 1.0, 1.0, 1.0);
}
