// glTF 2.0 writer (tinygltf). See scene/write.h for what is written.
#include <tiny_gltf.h>

#include <cmath>
#include <cstring>
#include <sstream>
#include <unordered_map>

#include "scene/write.h"
#include "util/atomic_file.h"
#include "util/error.h"

namespace kdgrid {

namespace {

constexpr float kPi = 3.14159265358979f;

/// Appends raw bytes to the buffer as a new view; returns the view index.
int add_view(tinygltf::Model& model, const void* data, size_t bytes, int target) {
  auto& buf = model.buffers[0].data;
  // Every element written is 4-byte aligned; keep views aligned to 4 as glTF requires.
  while (buf.size() % 4) buf.push_back(0);
  tinygltf::BufferView view;
  view.buffer = 0;
  view.byteOffset = buf.size();
  view.byteLength = bytes;
  view.target = target;
  const auto* p = static_cast<const unsigned char*>(data);
  buf.insert(buf.end(), p, p + bytes);
  model.bufferViews.push_back(view);
  return int(model.bufferViews.size() - 1);
}

int add_accessor(tinygltf::Model& model, int view, int component, int type, size_t count) {
  tinygltf::Accessor a;
  a.bufferView = view;
  a.byteOffset = 0;
  a.componentType = component;
  a.type = type;
  a.count = count;
  model.accessors.push_back(a);
  return int(model.accessors.size() - 1);
}

int add_vec3_accessor(tinygltf::Model& model, const std::vector<Vec3>& v, bool with_bounds) {
  static_assert(sizeof(Vec3) == 12, "Vec3 must be three packed floats");
  const int view = add_view(model, v.data(), v.size() * sizeof(Vec3), TINYGLTF_TARGET_ARRAY_BUFFER);
  const int acc =
      add_accessor(model, view, TINYGLTF_COMPONENT_TYPE_FLOAT, TINYGLTF_TYPE_VEC3, v.size());
  if (with_bounds) {  // POSITION accessors must carry min and max
    Box3 b;
    for (const Vec3& p : v) b.grow(p);
    model.accessors[acc].minValues = {b.lo.x, b.lo.y, b.lo.z};
    model.accessors[acc].maxValues = {b.hi.x, b.hi.y, b.hi.z};
  }
  return acc;
}

/// Unit quaternion (x, y, z, w) of the rotation whose matrix has columns x, y, z.
std::vector<double> quaternion_from_basis(const Vec3& x, const Vec3& y, const Vec3& z) {
  const double m00 = x.x, m10 = x.y, m20 = x.z, m01 = y.x, m11 = y.y, m21 = y.z, m02 = z.x,
               m12 = z.y, m22 = z.z;
  const double trace = m00 + m11 + m22;
  double qx, qy, qz, qw;
  if (trace > 0) {
    const double s = std::sqrt(trace + 1.0) * 2;
    qw = 0.25 * s;
    qx = (m21 - m12) / s;
    qy = (m02 - m20) / s;
    qz = (m10 - m01) / s;
  } else if (m00 > m11 && m00 > m22) {
    const double s = std::sqrt(1.0 + m00 - m11 - m22) * 2;
    qw = (m21 - m12) / s;
    qx = 0.25 * s;
    qy = (m01 + m10) / s;
    qz = (m02 + m20) / s;
  } else if (m11 > m22) {
    const double s = std::sqrt(1.0 + m11 - m00 - m22) * 2;
    qw = (m02 - m20) / s;
    qx = (m01 + m10) / s;
    qy = 0.25 * s;
    qz = (m12 + m21) / s;
  } else {
    const double s = std::sqrt(1.0 + m22 - m00 - m11) * 2;
    qw = (m10 - m01) / s;
    qx = (m02 + m20) / s;
    qy = (m12 + m21) / s;
    qz = 0.25 * s;
  }
  const double n = std::sqrt(qx * qx + qy * qy + qz * qz + qw * qw);
  return {qx / n, qy / n, qz / n, qw / n};
}

/// Rotation taking the local -Z axis (glTF's view/light direction) to `dir`.
std::vector<double> rotation_looking_along(const Vec3& dir, const Vec3& up_hint) {
  const Vec3 back = -normalize(dir);
  Vec3 right = cross(up_hint, back);
  if (length(right) < 1e-6f) right = cross(Vec3(1, 0, 0), back);
  right = normalize(right);
  const Vec3 up = cross(back, right);
  return quaternion_from_basis(right, up, back);
}

void use_extension(tinygltf::Model& model, const std::string& name) {
  for (const auto& e : model.extensionsUsed)
    if (e == name) return;
  model.extensionsUsed.push_back(name);
}

tinygltf::Value object(std::initializer_list<std::pair<const std::string, tinygltf::Value>> kv) {
  return tinygltf::Value(tinygltf::Value::Object(kv));
}

}  // namespace

void write_gltf(const Scene& scene, const std::string& path) {
  const Mesh& mesh = scene.mesh;
  tinygltf::Model model;
  model.asset.version = "2.0";
  model.asset.generator = "kdgrid";
  model.buffers.emplace_back();

  // ---- materials ----
  for (const Material& m : scene.materials) {
    tinygltf::Material g;
    g.name = m.name;
    g.pbrMetallicRoughness.baseColorFactor = {m.base_color.x, m.base_color.y, m.base_color.z, 1.0};
    g.pbrMetallicRoughness.metallicFactor = m.metallic;
    g.pbrMetallicRoughness.roughnessFactor = m.roughness;
    const float e = max_component(m.emission);
    if (e > 0.0f) {
      // emissiveFactor is limited to [0, 1]; brighter emission needs the strength extension.
      const float strength = std::max(1.0f, e);
      g.emissiveFactor = {m.emission.x / strength, m.emission.y / strength,
                          m.emission.z / strength};
      if (strength > 1.0f) {
        g.extensions["KHR_materials_emissive_strength"] =
            object({{"emissiveStrength", tinygltf::Value(double(strength))}});
        use_extension(model, "KHR_materials_emissive_strength");
      }
    }
    if (m.transmission > 0.0f) {
      g.extensions["KHR_materials_transmission"] =
          object({{"transmissionFactor", tinygltf::Value(double(m.transmission))}});
      use_extension(model, "KHR_materials_transmission");
    }
    if (m.ior != 1.5f || m.transmission > 0.0f) {
      g.extensions["KHR_materials_ior"] = object({{"ior", tinygltf::Value(double(m.ior))}});
      use_extension(model, "KHR_materials_ior");
    }
    model.materials.push_back(g);
  }

  // ---- mesh: one primitive per run of consecutive triangles sharing a material ----
  tinygltf::Mesh gmesh;
  gmesh.name = scene.source.empty() ? "mesh" : scene.source;
  const bool normals = !mesh.normals.empty(), uvs = !mesh.uvs.empty();
  size_t first = 0;
  while (first < mesh.num_triangles()) {
    const uint32_t mat = mesh.material_of(first);
    size_t last = first;
    while (last < mesh.num_triangles() && mesh.material_of(last) == mat) ++last;
    // Compact the run's vertices so each primitive is self-contained.
    std::unordered_map<uint32_t, uint32_t> remap;
    std::vector<Vec3> pos, nor;
    std::vector<float> tex;
    std::vector<uint32_t> idx;
    idx.reserve((last - first) * 3);
    for (size_t t = first; t < last; ++t)
      for (uint32_t v : mesh.triangles[t]) {
        auto [it, inserted] = remap.emplace(v, uint32_t(pos.size()));
        if (inserted) {
          pos.push_back(mesh.positions[v]);
          if (normals) nor.push_back(mesh.normals[v]);
          if (uvs) {
            tex.push_back(mesh.uvs[v][0]);
            tex.push_back(mesh.uvs[v][1]);
          }
        }
        idx.push_back(it->second);
      }
    tinygltf::Primitive prim;
    prim.mode = TINYGLTF_MODE_TRIANGLES;
    prim.attributes["POSITION"] = add_vec3_accessor(model, pos, true);
    if (normals) prim.attributes["NORMAL"] = add_vec3_accessor(model, nor, false);
    if (uvs) {
      const int view =
          add_view(model, tex.data(), tex.size() * sizeof(float), TINYGLTF_TARGET_ARRAY_BUFFER);
      prim.attributes["TEXCOORD_0"] = add_accessor(model, view, TINYGLTF_COMPONENT_TYPE_FLOAT,
                                                   TINYGLTF_TYPE_VEC2, tex.size() / 2);
    }
    const int iview = add_view(model, idx.data(), idx.size() * sizeof(uint32_t),
                               TINYGLTF_TARGET_ELEMENT_ARRAY_BUFFER);
    prim.indices = add_accessor(model, iview, TINYGLTF_COMPONENT_TYPE_UNSIGNED_INT,
                                TINYGLTF_TYPE_SCALAR, idx.size());
    prim.material = mat < scene.materials.size() ? int(mat) : -1;
    gmesh.primitives.push_back(prim);
    first = last;
  }
  model.meshes.push_back(gmesh);

  tinygltf::Scene gscene;
  tinygltf::Node mesh_node;
  mesh_node.mesh = 0;
  mesh_node.name = "mesh";
  model.nodes.push_back(mesh_node);
  gscene.nodes.push_back(0);

  // ---- camera: a node at the eye whose -Z looks at the target ----
  if (scene.camera) {
    const Camera& c = *scene.camera;
    tinygltf::Camera cam;
    cam.type = "perspective";
    cam.name = c.name;
    cam.perspective.yfov = double(c.fov_deg) * kPi / 180.0;
    cam.perspective.znear = 1e-3;
    model.cameras.push_back(cam);
    tinygltf::Node node;
    node.name = c.name.empty() ? "camera" : c.name;
    node.camera = int(model.cameras.size() - 1);
    node.translation = {c.eye.x, c.eye.y, c.eye.z};
    node.rotation = rotation_looking_along(c.target - c.eye, c.up);
    model.nodes.push_back(node);
    gscene.nodes.push_back(int(model.nodes.size() - 1));
  }

  // ---- KHR_lights_punctual ----
  for (const Light& l : scene.lights) {
    tinygltf::Light gl;
    gl.name = l.name;
    gl.color = {l.color.x, l.color.y, l.color.z};
    gl.intensity = l.intensity;
    gl.type = l.type == LightType::Point  ? "point"
              : l.type == LightType::Spot ? "spot"
                                          : "directional";
    if (l.type == LightType::Spot) {
      gl.spot.innerConeAngle = l.inner_cone;
      gl.spot.outerConeAngle = l.outer_cone;
    }
    model.lights.push_back(gl);
    tinygltf::Node node;
    node.name = l.name.empty() ? "light" : l.name;
    node.translation = {l.position.x, l.position.y, l.position.z};
    if (l.type != LightType::Point)
      node.rotation = rotation_looking_along(l.direction, Vec3(0, 1, 0));
    node.extensions["KHR_lights_punctual"] =
        object({{"light", tinygltf::Value(int(model.lights.size() - 1))}});
    model.nodes.push_back(node);
    gscene.nodes.push_back(int(model.nodes.size() - 1));
  }

  model.scenes.push_back(gscene);
  model.defaultScene = 0;

  // Serialised in memory (.glb: binary container, .gltf: JSON with the buffer as a data URI),
  // then written through AtomicFile so that a failed write leaves no broken file.
  tinygltf::TinyGLTF writer;
  std::ostringstream text;
  const bool binary = lower_extension(path) == ".glb";
  if (!writer.WriteGltfSceneToStream(&model, text, /*prettyPrint=*/false, binary) || !text)
    throw Error(path + ": cannot serialise the glTF model");
  write_file_atomically(path, text.view());
}

}  // namespace kdgrid
