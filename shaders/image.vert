#version 330 core
// Full-screen triangle pair for the ray-traced image; no vertex buffer needed.
out vec2 v_uv;
void main() {
  // Two triangles covering clip space, generated from the vertex index.
  const vec2 corners[6] = vec2[6](vec2(-1, -1), vec2(1, -1), vec2(1, 1),
                                  vec2(-1, -1), vec2(1, 1), vec2(-1, 1));
  vec2 p = corners[gl_VertexID];
  // The image's row 0 is the top row (docs/RAYSETS.md) and is uploaded first, i.e. at texture
  // t = 0, which GL places at the bottom: flip t so the image is upright.
  v_uv = vec2(p.x * 0.5 + 0.5, 0.5 - p.y * 0.5);
  gl_Position = vec4(p, 0.0, 1.0);
}
