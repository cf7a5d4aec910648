#version 330 core
// The CPU already tonemapped (or colour-mapped) the image to sRGB bytes: just sample it.
in vec2 v_uv;
out vec4 frag_color;
uniform sampler2D u_image;
void main() {
  frag_color = vec4(texture(u_image, v_uv).rgb, 1.0);
}
