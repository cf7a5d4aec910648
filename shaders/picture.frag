#version 330 core
// The overlay's offscreen picture (premultiplied colour), shown pixel for pixel over the image.
out vec4 frag_color;
uniform sampler2D u_picture;
void main() {
  frag_color = texelFetch(u_picture, ivec2(gl_FragCoord.xy), 0);
}
