// glTF 2.0 scenes: the parsed model's default scene, its node tree flattened into one world-space
// mesh, with its materials, textures, lights and camera (gltf_to_scene). tinygltf parses JSON and
// decodes images but does not check that accessors stay inside their buffers, so every accessor
// is bounds-checked here before it is read. gltf_file.cpp reads the file.
#include <tiny_gltf.h>

#include <algorithm>
#include <array>
#include <cfloat>
#include <cmath>
#include <cstdio>
#include <cstring>
#include <map>

#include "image/image_io.h"
#include "scene/gltf_scene.h"
#include "scene/load.h"
#include "util/error.h"
#include "util/format.h"
#include "util/input_file.h"
#include "util/memory.h"

namespace kdgrid {

namespace {

/// Column-major 4x4 matrix, as glTF stores them.
struct Mat4 {
  std::array<double, 16> m{1, 0, 0, 0, 0, 1, 0, 0, 0, 0, 1, 0, 0, 0, 0, 1};
  double& at(int row, int col) { return m[size_t(col * 4 + row)]; }
  double at(int row, int col) const { return m[size_t(col * 4 + row)]; }
  Mat4 operator*(const Mat4& o) const {
    Mat4 r;
    for (int i = 0; i < 4; ++i)
      for (int j = 0; j < 4; ++j) {
        double s = 0;
        for (int k = 0; k < 4; ++k) s += at(i, k) * o.at(k, j);
        r.at(i, j) = s;
      }
    return r;
  }
  Vec3 point(const Vec3& p) const {
    return {float(at(0, 0) * p.x + at(0, 1) * p.y + at(0, 2) * p.z + at(0, 3)),
            float(at(1, 0) * p.x + at(1, 1) * p.y + at(1, 2) * p.z + at(1, 3)),
            float(at(2, 0) * p.x + at(2, 1) * p.y + at(2, 2) * p.z + at(2, 3))};
  }
  Vec3 vector(const Vec3& v) const {
    return {float(at(0, 0) * v.x + at(0, 1) * v.y + at(0, 2) * v.z),
            float(at(1, 0) * v.x + at(1, 1) * v.y + at(1, 2) * v.z),
            float(at(2, 0) * v.x + at(2, 1) * v.y + at(2, 2) * v.z)};
  }
  double det3() const {
    return at(0, 0) * (at(1, 1) * at(2, 2) - at(1, 2) * at(2, 1)) -
           at(0, 1) * (at(1, 0) * at(2, 2) - at(1, 2) * at(2, 0)) +
           at(0, 2) * (at(1, 0) * at(2, 1) - at(1, 1) * at(2, 0));
  }
  /// Inverse transpose of the upper 3x3 (the cofactor matrix / det), for normals.
  Mat4 normal_matrix() const {
    Mat4 r;
    const double d = det3();
    const double inv = std::abs(d) > 1e-300 ? 1.0 / d : 0.0;
    for (int i = 0; i < 3; ++i)
      for (int j = 0; j < 3; ++j) {
        const int i1 = (i + 1) % 3, i2 = (i + 2) % 3, j1 = (j + 1) % 3, j2 = (j + 2) % 3;
        r.at(i, j) = (at(i1, j1) * at(i2, j2) - at(i1, j2) * at(i2, j1)) * inv;
      }
    r.at(0, 3) = r.at(1, 3) = r.at(2, 3) = 0;
    return r;
  }
};

Mat4 local_transform(const tinygltf::Node& n) {
  Mat4 out;
  if (n.matrix.size() == 16) {
    std::copy(n.matrix.begin(), n.matrix.end(), out.m.begin());
    return out;
  }
  Mat4 t, r, s;
  if (n.translation.size() == 3)
    for (int i = 0; i < 3; ++i) t.at(i, 3) = n.translation[size_t(i)];
  if (n.rotation.size() == 4) {
    double x = n.rotation[0], y = n.rotation[1], z = n.rotation[2], w = n.rotation[3];
    const double len = std::sqrt(x * x + y * y + z * z + w * w);
    if (len > 0) x /= len, y /= len, z /= len, w /= len;
    r.at(0, 0) = 1 - 2 * (y * y + z * z);
    r.at(0, 1) = 2 * (x * y - z * w);
    r.at(0, 2) = 2 * (x * z + y * w);
    r.at(1, 0) = 2 * (x * y + z * w);
    r.at(1, 1) = 1 - 2 * (x * x + z * z);
    r.at(1, 2) = 2 * (y * z - x * w);
    r.at(2, 0) = 2 * (x * z - y * w);
    r.at(2, 1) = 2 * (y * z + x * w);
    r.at(2, 2) = 1 - 2 * (x * x + y * y);
  }
  if (n.scale.size() == 3)
    for (int i = 0; i < 3; ++i) s.at(i, i) = n.scale[size_t(i)];
  return t * r * s;
}

/// Reads the elements of one accessor as floats (or integers), after checking that every
/// element lies inside its buffer view and buffer.
class AccessorReader {
 public:
  AccessorReader(const tinygltf::Model& model, const std::string& path)
      : model_(model), path_(path) {}

  [[noreturn]] void fail(const std::string& what) const { throw LoadError(path_ + ": " + what); }

  /// Checks accessor `index` and returns it; `what` names its use in messages.
  const tinygltf::Accessor& check(int index, const std::string& what, int want_type) const {
    if (index < 0 || size_t(index) >= model_.accessors.size())
      fail(what + " refers to accessor " + std::to_string(index) + " but the file has " +
           std::to_string(model_.accessors.size()));
    const tinygltf::Accessor& a = model_.accessors[size_t(index)];
    const std::string name = "accessor " + std::to_string(index) + " (" + what + ")";
    if (a.sparse.isSparse)
      fail(name +
           " uses sparse storage, which kdgrid does not read; re-export the file "
           "without sparse accessors");
    if (want_type >= 0 && a.type != want_type)
      fail(name + " has the wrong element type " + std::to_string(a.type));
    const int csize = tinygltf::GetComponentSizeInBytes(uint32_t(a.componentType));
    const int ncomp = tinygltf::GetNumComponentsInType(uint32_t(a.type));
    if (csize <= 0 || ncomp <= 0 || csize > 4)
      fail(name + " has an unknown component type " + std::to_string(a.componentType));
    if (a.bufferView < 0) return a;  // all zeros (glTF: no buffer view means zeros)
    if (size_t(a.bufferView) >= model_.bufferViews.size())
      fail(name + " refers to buffer view " + std::to_string(a.bufferView) + " but the file has " +
           std::to_string(model_.bufferViews.size()));
    const tinygltf::BufferView& bv = model_.bufferViews[size_t(a.bufferView)];
    if (bv.buffer < 0 || size_t(bv.buffer) >= model_.buffers.size())
      fail("buffer view " + std::to_string(a.bufferView) + " refers to buffer " +
           std::to_string(bv.buffer) + " but the file has " +
           std::to_string(model_.buffers.size()));
    const size_t buf_size = model_.buffers[size_t(bv.buffer)].data.size();
    if (bv.byteOffset > buf_size || bv.byteLength > buf_size - bv.byteOffset)
      fail("buffer view " + std::to_string(a.bufferView) + " (bytes " +
           std::to_string(bv.byteOffset) + "+" + std::to_string(bv.byteLength) +
           ") lies outside buffer " + std::to_string(bv.buffer) + " of " +
           std::to_string(buf_size) + " bytes; the file is truncated or corrupt");
    const size_t elem = size_t(csize) * size_t(ncomp);
    const size_t stride = bv.byteStride ? bv.byteStride : elem;
    if (stride < elem)
      fail(name + ": byteStride " + std::to_string(stride) + " is smaller than an element");
    if (a.count > 0) {
      // offset + (count-1)*stride + elem <= byteLength, written so that nothing overflows.
      const size_t len = bv.byteLength;
      bool ok = a.byteOffset <= len && elem <= len - a.byteOffset;
      if (ok) ok = (a.count - 1) <= (len - a.byteOffset - elem) / stride;
      if (!ok)
        fail(name + " (" + std::to_string(a.count) + " elements at offset " +
             std::to_string(a.byteOffset) + ", stride " + std::to_string(stride) +
             ") reads past the end of buffer view " + std::to_string(a.bufferView) + " of " +
             std::to_string(bv.byteLength) + " bytes; the file is truncated or corrupt");
    }
    return a;
  }

  /// Component c of element i, converted to float (normalized integers to [0,1] / [-1,1]).
  static double component(const tinygltf::Model& model, const tinygltf::Accessor& a, size_t i,
                          int c) {
    if (a.bufferView < 0) return 0.0;
    const tinygltf::BufferView& bv = model.bufferViews[size_t(a.bufferView)];
    const int csize = tinygltf::GetComponentSizeInBytes(uint32_t(a.componentType));
    const int ncomp = tinygltf::GetNumComponentsInType(uint32_t(a.type));
    const size_t stride = bv.byteStride ? bv.byteStride : size_t(csize) * size_t(ncomp);
    const uint8_t* p = model.buffers[size_t(bv.buffer)].data.data() + bv.byteOffset + a.byteOffset +
                       i * stride + size_t(c) * size_t(csize);
    switch (a.componentType) {
      case TINYGLTF_COMPONENT_TYPE_FLOAT: {
        float f;
        std::memcpy(&f, p, 4);
        return f;
      }
      case TINYGLTF_COMPONENT_TYPE_BYTE: {
        const int8_t v = int8_t(p[0]);
        return a.normalized ? std::max(v / 127.0, -1.0) : v;
      }
      case TINYGLTF_COMPONENT_TYPE_UNSIGNED_BYTE:
        return a.normalized ? p[0] / 255.0 : p[0];
      case TINYGLTF_COMPONENT_TYPE_SHORT: {
        int16_t v;
        std::memcpy(&v, p, 2);
        return a.normalized ? std::max(v / 32767.0, -1.0) : v;
      }
      case TINYGLTF_COMPONENT_TYPE_UNSIGNED_SHORT: {
        uint16_t v;
        std::memcpy(&v, p, 2);
        return a.normalized ? v / 65535.0 : v;
      }
      case TINYGLTF_COMPONENT_TYPE_INT: {
        int32_t v;
        std::memcpy(&v, p, 4);
        return v;
      }
      case TINYGLTF_COMPONENT_TYPE_UNSIGNED_INT: {
        uint32_t v;
        std::memcpy(&v, p, 4);
        return a.normalized ? v / 4294967295.0 : double(v);
      }
      default:
        return 0.0;
    }
  }

  double get(const tinygltf::Accessor& a, size_t i, int c) const {
    return component(model_, a, i, c);
  }

 private:
  const tinygltf::Model& model_;
  const std::string& path_;
};

Vec3 factor3(const std::vector<double>& f, Vec3 fallback) {
  return f.size() >= 3 ? Vec3(float(f[0]), float(f[1]), float(f[2])) : fallback;
}

/// A number inside a material extension object, e.g. KHR_materials_ior.ior.
bool extension_number(const tinygltf::ExtensionMap& ext, const char* name, const char* key,
                      double& out) {
  const auto it = ext.find(name);
  if (it == ext.end() || !it->second.IsObject() || !it->second.Has(key)) return false;
  const tinygltf::Value& v = it->second.Get(key);
  if (!v.IsNumber()) return false;
  out = v.GetNumberAsDouble();
  return true;
}

/// Deepest node hierarchy read (levels below a scene's root nodes): the builder recurses.
constexpr int kMaxNodeDepth = 1000;
/// Most node instances after expanding the hierarchy: far above real scenes (Sponza has a few
/// hundred), far below what a hostile file can declare with nodes that list a child twice.
/// Each instance costs a matrix product and a few lookups, so at this count a file without a
/// single triangle still loads in well under a second (about 0.7 s under AddressSanitizer).
constexpr double kMaxNodeInstances = double(1 << 20);
/// Bytes per triangle of the expanded mesh for the memory check: positions, normals and uvs
/// of three unshared vertices plus indices and material ids (3*32 + 12 + 4).
constexpr double kMeshBytesPerTriangle = 112;

std::string number_text(double v) {
  char buf[32];
  std::snprintf(buf, sizeof buf, "%g", v);
  return buf;
}

class GltfBuilder {
 public:
  GltfBuilder(const tinygltf::Model& model, const std::string& path, Scene& scene, bool decode)
      : model_(model), path_(path), scene_(scene), acc_(model, path), decode_(decode) {}

  void build() {
    convert_materials();
    std::vector<int> roots;
    int scene_index = model_.defaultScene >= 0 ? model_.defaultScene : 0;
    if (!model_.scenes.empty()) {
      if (size_t(scene_index) >= model_.scenes.size())
        throw LoadError(path_ + ": default scene " + std::to_string(scene_index) +
                        " does not exist (the file has " + std::to_string(model_.scenes.size()) +
                        " scenes)");
      roots = model_.scenes[size_t(scene_index)].nodes;
    } else {
      // No scenes: take every node that is nobody's child.
      std::vector<bool> is_child(model_.nodes.size(), false);
      for (const auto& n : model_.nodes)
        for (int c : n.children)
          if (c >= 0 && size_t(c) < is_child.size()) is_child[size_t(c)] = true;
      for (size_t i = 0; i < model_.nodes.size(); ++i)
        if (!is_child[i]) roots.push_back(int(i));
    }
    check_expansion(roots);
    on_path_.assign(model_.nodes.size(), false);
    for (int r : roots) visit(r, Mat4(), 0);
    if (!undecoded_.empty()) {
      // One line for all of them: the reasons, one per image, were the parser's warnings.
      std::string list;
      for (size_t i = 0; i < undecoded_.size() && i < 8; ++i)
        list += (i ? ", " : "") + std::to_string(undecoded_[i]);
      if (undecoded_.size() > 8) list += ", ...";
      std::fprintf(stderr,
                   "%s: warning: %zu image(s) not decoded (%s); their materials are left "
                   "untextured\n",
                   path_.c_str(), undecoded_.size(), list.c_str());
    }
    if (skipped_prims_ > 0)
      std::fprintf(stderr,
                   "%s: note: skipped %zu point/line primitives (kdgrid renders triangles)\n",
                   path_.c_str(), skipped_prims_);
  }

 private:
  /// A colour factor (or strength) of material `mi` must be a finite number >= 0: a negative
  /// one subtracts light (negative EXR values), as a negative light intensity would.
  void check_factor(size_t mi, const tinygltf::Material& gm, const std::string& field,
                    const std::vector<double>& values) const {
    for (size_t i = 0; i < values.size(); ++i)
      if (!(values[i] >= 0.0 && values[i] <= double(FLT_MAX)))
        throw LoadError(
            path_ + ": material " + std::to_string(mi) + " '" + printable(gm.name, 80) + "' has " +
            field + (values.size() > 1 ? "[" + std::to_string(i) + "]" : "") + " " +
            number_text(values[i]) + "; give finite numbers >= 0 (colours usually 0 to 1)");
  }

  void convert_materials() {
    for (size_t mi = 0; mi < model_.materials.size(); ++mi) {
      const tinygltf::Material& gm = model_.materials[mi];
      Material m;
      m.name = gm.name;
      const auto& pbr = gm.pbrMetallicRoughness;
      check_factor(mi, gm, "pbrMetallicRoughness.baseColorFactor", pbr.baseColorFactor);
      check_factor(mi, gm, "emissiveFactor", gm.emissiveFactor);
      m.base_color = factor3(pbr.baseColorFactor, Vec3(1.0f));
      m.metallic = std::clamp(float(pbr.metallicFactor), 0.0f, 1.0f);
      m.roughness = std::clamp(float(pbr.roughnessFactor), 0.0f, 1.0f);
      m.emission = factor3(gm.emissiveFactor, Vec3(0.0f));
      double v = 0;
      if (extension_number(gm.extensions, "KHR_materials_emissive_strength", "emissiveStrength",
                           v)) {
        check_factor(mi, gm, "KHR_materials_emissive_strength.emissiveStrength", {v});
        m.emission *= float(v);
      }
      if (extension_number(gm.extensions, "KHR_materials_transmission", "transmissionFactor", v))
        m.transmission = std::clamp(float(v), 0.0f, 1.0f);
      if (extension_number(gm.extensions, "KHR_materials_ior", "ior", v) && v > 0) m.ior = float(v);
      if (pbr.baseColorTexture.index >= 0)
        m.base_color_texture = texture(pbr.baseColorTexture.index);
      scene_.materials.push_back(std::move(m));
    }
  }

  /// Index into Scene::textures of glTF texture `index`, decoding its image once; -1 if unusable.
  int texture(int index) {
    if (size_t(index) >= model_.textures.size()) {
      std::fprintf(stderr, "%s: warning: texture %d does not exist; material left untextured\n",
                   path_.c_str(), index);
      return -1;
    }
    const int src = model_.textures[size_t(index)].source;
    if (src < 0 || size_t(src) >= model_.images.size()) return -1;
    const auto found = image_texture_.find(src);
    if (found != image_texture_.end()) return found->second;
    const tinygltf::Image& img = model_.images[size_t(src)];
    int result = -1;
    // decode_image leaves RGB8 pixels, or none with the size when textures are not decoded.
    const size_t px = img.width > 0 && img.height > 0 ? size_t(img.width) * size_t(img.height) : 0;
    if (px == 0 || img.component != 3 || img.bits != 8 || (decode_ && img.image.size() != px * 3)) {
      undecoded_.push_back(src);
    } else {
      Texture t;
      t.width = img.width;
      t.height = img.height;
      t.channels = 3;
      t.pixels.assign(img.image.begin(), img.image.end());
      t.srgb = true;  // glTF base colour textures are sRGB
      t.name = img.name.empty() ? img.uri : img.name;
      result = int(scene_.textures.size());
      scene_.textures.push_back(std::move(t));
    }
    image_texture_[src] = result;
    return result;
  }

  void visit(int index, const Mat4& parent, int depth) {
    if (index < 0 || size_t(index) >= model_.nodes.size())
      throw LoadError(path_ + ": the scene refers to node " + std::to_string(index) +
                      " but the file has " + std::to_string(model_.nodes.size()) + " nodes");
    if (on_path_[size_t(index)])
      throw LoadError(path_ + ": node " + std::to_string(index) +
                      " is its own ancestor; the node hierarchy must be a tree");
    if (depth > kMaxNodeDepth) throw too_deep(index);
    on_path_[size_t(index)] = true;
    const tinygltf::Node& node = model_.nodes[size_t(index)];
    const Mat4 world = parent * local_transform(node);
    if (node.mesh >= 0) {
      if (size_t(node.mesh) >= model_.meshes.size())
        throw LoadError(path_ + ": node " + std::to_string(index) + " refers to mesh " +
                        std::to_string(node.mesh) + " but the file has " +
                        std::to_string(model_.meshes.size()) + " meshes");
      add_mesh(node.mesh, world);
    }
    if (node.camera >= 0 && !scene_.camera) add_camera(node, world);
    add_light(node, world);
    for (int c : node.children) visit(c, world, depth + 1);
    on_path_[size_t(index)] = false;
  }

  LoadError too_deep(int index) const {
    return LoadError(path_ + ": the node hierarchy is more than " + std::to_string(kMaxNodeDepth) +
                     " levels deep (node " + std::to_string(index) + "); kdgrid reads at most " +
                     std::to_string(kMaxNodeDepth) + " levels: flatten the hierarchy");
  }

  /// Triangles of one instance of mesh `m`, from its accessors' counts (0 for what add_mesh
  /// will report as broken).
  double mesh_triangles(int m) const {
    if (m < 0 || size_t(m) >= model_.meshes.size()) return 0;
    double tris = 0;
    for (const tinygltf::Primitive& prim : model_.meshes[size_t(m)].primitives) {
      int acc = prim.indices;
      if (acc < 0) {
        const auto it = prim.attributes.find("POSITION");
        acc = it == prim.attributes.end() ? -1 : it->second;
      }
      if (acc < 0 || size_t(acc) >= model_.accessors.size()) continue;
      const double n = double(model_.accessors[size_t(acc)].count);
      const int mode = prim.mode < 0 ? TINYGLTF_MODE_TRIANGLES : prim.mode;
      if (mode == TINYGLTF_MODE_TRIANGLES)
        tris += std::floor(n / 3);
      else if (mode == TINYGLTF_MODE_TRIANGLE_STRIP || mode == TINYGLTF_MODE_TRIANGLE_FAN)
        tris += std::max(0.0, n - 2);
    }
    return tris;
  }

  struct Expansion {
    double instances = 0, triangles = 0;
  };

  /// Node instances and triangles under node `index` once the hierarchy is expanded (a node
  /// listed twice by its parent is expanded twice), memoised per node, so that a small file
  /// whose nodes each list the next one twice is refused before 2^40 instances are built.
  Expansion expand(int index, int depth, std::vector<int>& state, std::vector<Expansion>& memo) {
    if (index < 0 || size_t(index) >= model_.nodes.size()) return {};  // visit() reports it
    if (depth > kMaxNodeDepth) throw too_deep(index);
    int& st = state[size_t(index)];
    if (st == 1)
      throw LoadError(path_ + ": node " + std::to_string(index) +
                      " is its own ancestor; the node hierarchy must be a tree");
    if (st == 2) return memo[size_t(index)];
    st = 1;
    const tinygltf::Node& node = model_.nodes[size_t(index)];
    Expansion e{1, mesh_triangles(node.mesh)};
    for (int c : node.children) {
      const Expansion ce = expand(c, depth + 1, state, memo);
      e.instances += ce.instances;
      e.triangles += ce.triangles;
    }
    st = 2;
    memo[size_t(index)] = e;
    return e;
  }

  void check_expansion(const std::vector<int>& roots) {
    std::vector<int> state(model_.nodes.size(), 0);
    std::vector<Expansion> memo(model_.nodes.size());
    Expansion total;
    for (int r : roots) {
      const Expansion e = expand(r, 0, state, memo);
      total.instances += e.instances;
      total.triangles += e.triangles;
    }
    char buf[64];
    if (total.instances > double(kMaxNodeInstances)) {
      std::snprintf(buf, sizeof buf, "%.4g", total.instances);
      throw LoadError(path_ + ": the node hierarchy expands to " + buf +
                      " node instances (nodes listed more than once are expanded once per "
                      "listing), above the limit of " +
                      std::to_string(uint64_t(kMaxNodeInstances)) +
                      "; list each child once or use fewer instances");
    }
    const double bytes = total.triangles * kMeshBytesPerTriangle;
    const uint64_t budget = default_memory_budget_bytes();
    if (bytes > double(budget)) {
      std::snprintf(buf, sizeof buf, "%.4g", total.triangles);
      throw LoadError(path_ + ": the node hierarchy expands to " + buf + " triangles, about " +
                      format_bytes_iec(bytes) + " as a mesh, above the memory budget of " +
                      format_bytes_iec(double(budget)) +
                      " (half of the memory available); use fewer instances or a smaller mesh");
    }
  }

  void add_camera(const tinygltf::Node& node, const Mat4& world) {
    if (size_t(node.camera) >= model_.cameras.size()) return;
    const tinygltf::Camera& gc = model_.cameras[size_t(node.camera)];
    if (gc.type != "perspective") return;
    Camera c;
    c.eye = world.point(Vec3(0.0f));
    const Vec3 fwd = normalize(world.vector(Vec3(0, 0, -1)));
    c.target = c.eye + fwd;
    c.up = normalize(world.vector(Vec3(0, 1, 0)));
    c.fov_deg = float(gc.perspective.yfov * 180.0 / 3.14159265358979323846);
    c.name = gc.name.empty() ? "glTF camera " + std::to_string(node.camera) : gc.name;
    if (!is_finite(c.eye) || !is_finite(fwd) || !(c.fov_deg > 0.0f && c.fov_deg < 180.0f)) {
      std::fprintf(stderr, "%s: warning: camera '%s' is degenerate; ignoring it\n", path_.c_str(),
                   printable(c.name, 80).c_str());
      return;
    }
    scene_.camera = c;
  }

  void add_light(const tinygltf::Node& node, const Mat4& world) {
    const auto it = node.extensions.find("KHR_lights_punctual");
    if (it == node.extensions.end() || !it->second.IsObject() || !it->second.Has("light")) return;
    const tinygltf::Value& idx = it->second.Get("light");
    if (!idx.IsNumber()) return;
    const int li = idx.GetNumberAsInt();
    if (li < 0 || size_t(li) >= model_.lights.size()) {
      std::fprintf(stderr, "%s: warning: node refers to light %d which does not exist\n",
                   path_.c_str(), li);
      return;
    }
    const tinygltf::Light& gl = model_.lights[size_t(li)];
    const std::optional<LightType> type = enum_value(gl.type, kLightTypeNames);
    if (!type) return;
    Light l;
    l.type = *type;
    l.position = world.point(Vec3(0.0f));
    l.direction = normalize(world.vector(Vec3(0, 0, -1)));
    l.color = factor3(gl.color, Vec3(1.0f));
    // A value outside a float's range would become infinite (a black image), a negative one
    // would subtract light (negative EXR values): both are refused, naming the light.
    const std::string which = "light " + std::to_string(li) + " '" + printable(gl.name, 80) + "'";
    if (!(gl.intensity >= 0.0 && gl.intensity <= double(FLT_MAX)))
      throw LoadError(path_ + ": " + which + " has intensity " + number_text(gl.intensity) +
                      "; give a finite number between 0 and 3.4e38 (candela or lux)");
    for (double c : gl.color)
      if (!(c >= 0.0 && c <= double(FLT_MAX)))
        throw LoadError(path_ + ": " + which + " has colour component " + number_text(c) +
                        "; give finite numbers >= 0 (usually 0 to 1)");
    l.intensity = float(gl.intensity);
    l.inner_cone = float(gl.spot.innerConeAngle);
    l.outer_cone = float(gl.spot.outerConeAngle);
    l.name = gl.name.empty() ? "glTF light " + std::to_string(li) : gl.name;
    scene_.lights.push_back(l);
  }

  uint32_t material_index(int gltf_material) {
    if (gltf_material >= 0 && size_t(gltf_material) < model_.materials.size())
      return uint32_t(gltf_material);
    if (default_material_ < 0) {
      // glTF's own default (metallic 1) would render as a mirror; a grey diffuse reads better.
      Material grey;
      grey.name = "default grey diffuse";
      default_material_ = int(scene_.materials.size());
      scene_.materials.push_back(grey);
    }
    return uint32_t(default_material_);
  }

  /// The accessor of the primitive's vertex attribute `name`, checked to hold `type` elements,
  /// one per vertex (`nv`, POSITION's count); nullptr where the primitive has no such attribute.
  const tinygltf::Accessor* vertex_attribute(const tinygltf::Primitive& prim, const char* name,
                                             int type, size_t nv, const std::string& where) const {
    const auto it = prim.attributes.find(name);
    if (it == prim.attributes.end()) return nullptr;
    const tinygltf::Accessor& a = acc_.check(it->second, where + " " + name, type);
    if (a.count != nv)
      throw LoadError(path_ + ": " + where + ": " + name + " count differs from POSITION count");
    return &a;
  }

  void add_mesh(int mesh_index, const Mat4& world) {
    const tinygltf::Mesh& gm = model_.meshes[size_t(mesh_index)];
    const Mat4 nmat = world.normal_matrix();
    const bool flip = world.det3() < 0;  // mirroring transforms reverse the winding
    for (size_t pi = 0; pi < gm.primitives.size(); ++pi) {
      const tinygltf::Primitive& prim = gm.primitives[pi];
      const std::string where =
          "mesh " + std::to_string(mesh_index) + " primitive " + std::to_string(pi);
      const int mode = prim.mode < 0 ? TINYGLTF_MODE_TRIANGLES : prim.mode;
      if (mode != TINYGLTF_MODE_TRIANGLES && mode != TINYGLTF_MODE_TRIANGLE_STRIP &&
          mode != TINYGLTF_MODE_TRIANGLE_FAN) {
        ++skipped_prims_;
        continue;
      }
      const auto pos_it = prim.attributes.find("POSITION");
      if (pos_it == prim.attributes.end()) {
        std::fprintf(stderr, "%s: warning: %s has no POSITION; skipped\n", path_.c_str(),
                     where.c_str());
        continue;
      }
      const tinygltf::Accessor& pos =
          acc_.check(pos_it->second, where + " POSITION", TINYGLTF_TYPE_VEC3);
      const size_t nv = pos.count;
      if (nv > std::numeric_limits<uint32_t>::max() - scene_.mesh.positions.size())
        throw LoadError(path_ + ": " + where + " has too many vertices for 32-bit indices");
      Mesh part;
      part.positions.resize(nv);
      for (size_t i = 0; i < nv; ++i)
        part.positions[i] = world.point(Vec3(float(acc_.get(pos, i, 0)), float(acc_.get(pos, i, 1)),
                                             float(acc_.get(pos, i, 2))));
      if (const auto* nrm = vertex_attribute(prim, "NORMAL", TINYGLTF_TYPE_VEC3, nv, where)) {
        part.normals.resize(nv);
        for (size_t i = 0; i < nv; ++i) {
          const Vec3 n = nmat.vector(Vec3(float(acc_.get(*nrm, i, 0)), float(acc_.get(*nrm, i, 1)),
                                          float(acc_.get(*nrm, i, 2))));
          const float len = length(n);
          part.normals[i] = len > 0 ? n / len : n;
        }
      }
      if (const auto* uv = vertex_attribute(prim, "TEXCOORD_0", TINYGLTF_TYPE_VEC2, nv, where)) {
        part.uvs.resize(nv);
        for (size_t i = 0; i < nv; ++i)
          part.uvs[i] = {float(acc_.get(*uv, i, 0)), float(acc_.get(*uv, i, 1))};
      }

      // Vertex order of the primitive: the index accessor, or 0..n-1.
      std::vector<uint32_t> order;
      if (prim.indices >= 0) {
        const tinygltf::Accessor& ia =
            acc_.check(prim.indices, where + " indices", TINYGLTF_TYPE_SCALAR);
        if (ia.componentType != TINYGLTF_COMPONENT_TYPE_UNSIGNED_BYTE &&
            ia.componentType != TINYGLTF_COMPONENT_TYPE_UNSIGNED_SHORT &&
            ia.componentType != TINYGLTF_COMPONENT_TYPE_UNSIGNED_INT)
          throw LoadError(path_ + ": " + where + ": indices must be unsigned byte, short or int");
        order.resize(ia.count);
        for (size_t i = 0; i < ia.count; ++i) {
          const double v = acc_.get(ia, i, 0);
          if (v >= double(nv))
            throw LoadError(path_ + ": " + where + ": index " + std::to_string(i) +
                            " references vertex " + std::to_string(uint64_t(v)) +
                            " but the primitive has " + std::to_string(nv) + " vertices");
          order[i] = uint32_t(v);
        }
      } else {
        order.resize(nv);
        for (size_t i = 0; i < nv; ++i) order[i] = uint32_t(i);
      }
      auto tri = [&](uint32_t a, uint32_t b, uint32_t c) {
        if (flip) std::swap(b, c);
        part.triangles.push_back({a, b, c});
      };
      const size_t n = order.size();
      if (mode == TINYGLTF_MODE_TRIANGLES) {
        if (n % 3 != 0)
          std::fprintf(stderr,
                       "%s: warning: %s has %zu indices, not a multiple of 3; ignoring the rest\n",
                       path_.c_str(), where.c_str(), n);
        for (size_t i = 0; i + 2 < n; i += 3) tri(order[i], order[i + 1], order[i + 2]);
      } else if (mode == TINYGLTF_MODE_TRIANGLE_STRIP) {
        // glTF: triangle i is (v_i, v_{i+1+i%2}, v_{i+2-i%2}), keeping a consistent winding.
        for (size_t i = 0; i + 2 < n; ++i)
          tri(order[i], order[i + 1 + i % 2], order[i + 2 - i % 2]);
      } else {
        for (size_t i = 1; i + 1 < n; ++i) tri(order[0], order[i], order[i + 1]);
      }
      const uint32_t mat = material_index(prim.material);
      part.material_ids.assign(part.triangles.size(), mat);
      scene_.mesh.append(part);
    }
  }

  const tinygltf::Model& model_;
  const std::string& path_;
  Scene& scene_;
  AccessorReader acc_;
  std::map<int, int> image_texture_;
  std::vector<bool> on_path_;
  bool decode_;
  std::vector<int> undecoded_;  // images that could not be used as textures
  int default_material_ = -1;
  size_t skipped_prims_ = 0;
};

}  // namespace

void gltf_to_scene(const tinygltf::Model& model, const std::string& path, bool decode_textures,
                   Scene& scene) {
  GltfBuilder(model, path, scene, decode_textures).build();
}

}  // namespace kdgrid
