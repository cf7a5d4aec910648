#version 330 core
in vec4 v_color;
out vec4 frag_color;
uniform float u_alpha;
void main() {
  frag_color = vec4(v_color.rgb, v_color.a * u_alpha);
}
