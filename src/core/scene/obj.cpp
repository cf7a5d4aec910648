// OBJ + MTL through tinyobjloader. tinyobjloader is asked not to triangulate so that polygons
// are fan-triangulated here, in file order, exactly as docs/RAYSETS.md numbers triangles.
#include <tiny_obj_loader.h>

#include <algorithm>
#include <array>
#include <cstdio>
#include <filesystem>
#include <map>
#include <sstream>
#include <unordered_map>

#include "scene/image_io.h"
#include "scene/load.h"
#include "util/error.h"

namespace kdgrid {

namespace {

/// Prints tinyobjloader's warnings once each, prefixed with the file name.
void print_warnings(const std::string& path, const std::string& text) {
  std::istringstream lines(text);
  std::string line;
  std::map<std::string, int> seen;
  int printed = 0;
  while (std::getline(lines, line)) {
    if (line.empty() || seen[line]++) continue;
    if (++printed > 10) {
      std::fprintf(stderr, "%s: warning: (further warnings suppressed)\n", path.c_str());
      return;
    }
    std::fprintf(stderr, "%s: warning: %s\n", path.c_str(), line.c_str());
  }
}

Vec3 vec3(const tinyobj::real_t* v) {
  return {float(v[0]), float(v[1]), float(v[2])};
}

Material convert_material(const tinyobj::material_t& m) {
  Material out;
  out.name = m.name;
  out.base_color = vec3(m.diffuse);
  out.specular = vec3(m.specular);
  out.shininess = float(m.shininess);
  out.emission = vec3(m.emission);
  // illum 3, 5 and 7 ask for ray-traced reflection: the mirror colour is Ks.
  if (m.illum == 3 || m.illum == 5 || m.illum == 7) out.mirror = out.specular;
  // Dissolve d < 1 makes the surface partly transparent; illum 4, 6, 7, 9 are glass models.
  if (m.dissolve < 1.0f) out.transmission = std::clamp(1.0f - float(m.dissolve), 0.0f, 1.0f);
  if ((m.illum == 4 || m.illum == 6 || m.illum == 7 || m.illum == 9) && out.transmission == 0.0f)
    out.transmission = 1.0f;
  // tinyobjloader reports Ni 1 when the file has none; keep the glass default 1.5 then.
  if (m.ior > 0.0f && m.ior != 1.0f) out.ior = float(m.ior);
  out.metallic = std::clamp(float(m.metallic), 0.0f, 1.0f);
  return out;
}

}  // namespace

Scene load_obj(const std::string& path) {
  namespace fs = std::filesystem;
  tinyobj::attrib_t attrib;
  std::vector<tinyobj::shape_t> shapes;
  std::vector<tinyobj::material_t> mats;
  std::string warn, err;
  const std::string base_dir = fs::path(path).parent_path().string();
  const bool ok = tinyobj::LoadObj(&attrib, &shapes, &mats, &warn, &err, path.c_str(),
                                   base_dir.empty() ? nullptr : base_dir.c_str(),
                                   /*triangulate=*/false, /*default_vcols_fallback=*/false);
  if (!ok) {
    std::string e = err.empty() ? warn : err;
    while (!e.empty() && (e.back() == '\n' || e.back() == ' ')) e.pop_back();
    throw LoadError(path + ": cannot parse OBJ: " + e);
  }

  Scene scene;
  const size_t nv = attrib.vertices.size() / 3;
  const size_t nn = attrib.normals.size() / 3;
  const size_t nt = attrib.texcoords.size() / 2;

  // First pass: validate indices, count triangles and see whether every corner shares one
  // index for position, normal and uv (then the arrays can be used as they are).
  size_t num_tris = 0;
  bool all_normals = true, any_uvs = false, shared_index = true;
  size_t face_no = 0;
  for (const auto& sh : shapes) {
    size_t k = 0;
    for (size_t f = 0; f < sh.mesh.num_face_vertices.size(); ++f, ++face_no) {
      const size_t m = sh.mesh.num_face_vertices[f];
      if (m < 3)
        throw LoadError(path + ": face " + std::to_string(face_no) + " has " + std::to_string(m) +
                        " vertices; a face needs at least 3");
      if (k + m > sh.mesh.indices.size())
        throw LoadError(path + ": face " + std::to_string(face_no) + " is incomplete");
      for (size_t j = 0; j < m; ++j) {
        const tinyobj::index_t& ix = sh.mesh.indices[k + j];
        if (ix.vertex_index < 0 || size_t(ix.vertex_index) >= nv)
          throw LoadError(path + ": face " + std::to_string(face_no) + " references vertex " +
                          std::to_string(ix.vertex_index + 1) + " but the file has " +
                          std::to_string(nv) + " vertices (OBJ indices count from 1)");
        if (ix.normal_index >= 0 && size_t(ix.normal_index) >= nn)
          throw LoadError(path + ": face " + std::to_string(face_no) + " references normal " +
                          std::to_string(ix.normal_index + 1) + " but the file has " +
                          std::to_string(nn) + " normals");
        if (ix.texcoord_index >= 0 && size_t(ix.texcoord_index) >= nt)
          throw LoadError(path + ": face " + std::to_string(face_no) +
                          " references texture coordinate " +
                          std::to_string(ix.texcoord_index + 1) + " but the file has " +
                          std::to_string(nt) + " texture coordinates");
        if (ix.normal_index < 0) all_normals = false;
        if (ix.texcoord_index >= 0) any_uvs = true;
        if ((ix.normal_index >= 0 && ix.normal_index != ix.vertex_index) ||
            (ix.texcoord_index >= 0 && ix.texcoord_index != ix.vertex_index))
          shared_index = false;
      }
      k += m;
      num_tris += m - 2;
    }
  }
  // With a successful parse, err holds non-fatal problems (e.g. a missing .mtl file); they
  // are printed only once the faces are known to be valid, so a fatal error stands alone.
  print_warnings(path, warn + err);

  // Normals are used only when every corner has one (the renderer falls back to the
  // geometric normal otherwise); missing uvs read as (0, 0).
  const bool use_normals = all_normals && nn > 0;
  const bool use_uvs = any_uvs;

  Mesh& mesh = scene.mesh;
  mesh.triangles.reserve(num_tris);
  // Either the file's vertex arrays as they are, or one vertex per distinct (v, vn, vt).
  struct CornerHash {
    size_t operator()(const std::array<int, 3>& c) const {
      uint64_t h = uint64_t(uint32_t(c[0])) * 0x9E3779B97F4A7C15ull;
      h ^= (uint64_t(uint32_t(c[1])) + 0x7F4A7C159E3779B9ull + (h << 6) + (h >> 2));
      h ^= (uint64_t(uint32_t(c[2])) + 0x94D049BB133111EBull + (h << 6) + (h >> 2));
      return size_t(h);
    }
  };
  std::unordered_map<std::array<int, 3>, uint32_t, CornerHash> remap;
  auto corner_key = [&](const tinyobj::index_t& ix) {
    return std::array<int, 3>{ix.vertex_index, use_normals ? ix.normal_index : -1,
                              use_uvs ? ix.texcoord_index : -1};
  };
  auto add_vertex = [&](const tinyobj::index_t& ix) -> uint32_t {
    if (shared_index) return uint32_t(ix.vertex_index);
    const auto [it, inserted] = remap.try_emplace(corner_key(ix), uint32_t(mesh.positions.size()));
    if (inserted) {
      mesh.positions.push_back(vec3(&attrib.vertices[3 * size_t(ix.vertex_index)]));
      if (use_normals) mesh.normals.push_back(vec3(&attrib.normals[3 * size_t(ix.normal_index)]));
      if (use_uvs)
        mesh.uvs.push_back(
            ix.texcoord_index >= 0
                ? std::array<float, 2>{float(attrib.texcoords[2 * size_t(ix.texcoord_index)]),
                                       float(attrib.texcoords[2 * size_t(ix.texcoord_index) + 1])}
                : std::array<float, 2>{0.f, 0.f});
    }
    return it->second;
  };
  if (shared_index) {
    mesh.positions.reserve(nv);
    for (size_t i = 0; i < nv; ++i) mesh.positions.push_back(vec3(&attrib.vertices[3 * i]));
    if (use_normals) {
      mesh.normals.resize(nv, Vec3(0.0f));
      for (size_t i = 0; i < std::min(nv, nn); ++i) mesh.normals[i] = vec3(&attrib.normals[3 * i]);
    }
    if (use_uvs) {
      mesh.uvs.resize(nv, {0.f, 0.f});
      for (size_t i = 0; i < std::min(nv, nt); ++i)
        mesh.uvs[i] = {float(attrib.texcoords[2 * i]), float(attrib.texcoords[2 * i + 1])};
    }
  }

  const bool any_material = !mats.empty();
  bool uses_default = false;
  if (any_material) mesh.material_ids.reserve(num_tris);
  for (const auto& sh : shapes) {
    size_t k = 0;
    for (size_t f = 0; f < sh.mesh.num_face_vertices.size(); ++f) {
      const size_t m = sh.mesh.num_face_vertices[f];
      int mat = f < sh.mesh.material_ids.size() ? sh.mesh.material_ids[f] : -1;
      if (mat < 0 || size_t(mat) >= mats.size()) {
        mat = int(mats.size());  // the default material appended below
        uses_default = true;
      }
      // Fan triangulation in file order: (v0, v_{j-1}, v_j) for j = 2..m-1 (docs/RAYSETS.md).
      const uint32_t v0 = add_vertex(sh.mesh.indices[k]);
      uint32_t prev = add_vertex(sh.mesh.indices[k + 1]);
      for (size_t j = 2; j < m; ++j) {
        const uint32_t cur = add_vertex(sh.mesh.indices[k + j]);
        mesh.triangles.push_back({v0, prev, cur});
        if (any_material) mesh.material_ids.push_back(uint32_t(mat));
        prev = cur;
      }
      k += m;
    }
  }

  // Materials, and the diffuse textures they name (loaded once each).
  std::map<std::string, int> texture_of;
  for (const auto& m : mats) {
    Material out = convert_material(m);
    if (!m.diffuse_texname.empty()) {
      const std::string tex_path = (fs::path(base_dir) / m.diffuse_texname).string();
      auto it = texture_of.find(tex_path);
      if (it == texture_of.end()) {
        std::string why;
        int index = -1;
        if (auto tex = read_texture_file(tex_path, why)) {
          index = int(scene.textures.size());
          scene.textures.push_back(std::move(*tex));
        } else {
          std::fprintf(stderr,
                       "%s: warning: material '%s': cannot read texture %s (%s); "
                       "rendering it untextured\n",
                       path.c_str(), m.name.c_str(), tex_path.c_str(), why.c_str());
        }
        it = texture_of.emplace(tex_path, index).first;
      }
      out.base_color_texture = it->second;
      // map_Kd multiplies Kd; a black Kd with a texture would hide the texture.
      if (it->second >= 0 && max_component(out.base_color) <= 0.0f) out.base_color = Vec3(1.0f);
    }
    scene.materials.push_back(std::move(out));
  }
  if (any_material && uses_default) {
    Material grey;
    grey.name = "default grey diffuse";
    scene.materials.push_back(grey);
  }
  return scene;
}

}  // namespace kdgrid
