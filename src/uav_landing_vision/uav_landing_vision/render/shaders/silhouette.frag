#version 430
// Coverage only: 1/255 stores the byte 1 in an R8 target, so a readback is a {0,1} mask.
out float mask;

void main() {
    mask = 1.0 / 255.0;
}
