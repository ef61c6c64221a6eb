#version 430
// Image row r is framebuffer row r (see project.vert); alpha 0 marks background coverage.
uniform sampler2D background;

out vec4 color;

void main() {
    color = vec4(texelFetch(background, ivec2(gl_FragCoord.xy), 0).rgb, 0.0);
}
