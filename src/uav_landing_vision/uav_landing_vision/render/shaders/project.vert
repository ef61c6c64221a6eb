#version 430
// Pinhole projection of the body-frame mesh into a destination rectangle of the framebuffer.
// Per instance: rows of [R|t] (body -> camera optical frame), the image-space box the
// rectangle covers (x0, y0, x1, y1; box edges in OpenCV pixel coordinates, integer = pixel
// centre) and the rectangle in framebuffer NDC. Image rows go to framebuffer rows directly
// (v down = window y up), which mirrors the image: front faces are clockwise.
in vec3 in_pos;
in vec4 in_row0;
in vec4 in_row1;
in vec4 in_row2;
in vec4 in_box;
in vec4 in_dst;

uniform vec4 intrinsics;  // fx, fy, cx, cy
uniform float skew;
uniform float near;

out vec3 v_cam;
out float gl_ClipDistance[4];

void main() {
    vec4 p = vec4(in_pos, 1.0);
    vec3 c = vec3(dot(in_row0, p), dot(in_row1, p), dot(in_row2, p));
    float w = c.z;
    float uw = intrinsics.x * c.x + skew * c.y + intrinsics.z * w;
    float vw = intrinsics.y * c.y + intrinsics.w * w;
    // Box-local NDC times w: the box edges map to -w and +w.
    float lx = 2.0 * (uw - in_box.x * w) / (in_box.z - in_box.x) - w;
    float ly = 2.0 * (vw - in_box.y * w) / (in_box.w - in_box.y) - w;
    gl_ClipDistance[0] = w + lx;
    gl_ClipDistance[1] = w - lx;
    gl_ClipDistance[2] = w + ly;
    gl_ClipDistance[3] = w - ly;
    float x = in_dst.x * w + 0.5 * (lx + w) * (in_dst.z - in_dst.x);
    float y = in_dst.y * w + 0.5 * (ly + w) * (in_dst.w - in_dst.y);
    // Depth 1 - 2 near / z: the near plane at -1, infinity at +1.
    gl_Position = vec4(x, y, w - 2.0 * near, w);
    v_cam = c;
}
