// OBJ + MTL through tinyobjloader. tinyobjloader is asked not to triangulate so that polygons
// are fan-triangulated here, in file order, exactly as docs/RAYSETS.md numbers triangles.
#include <tiny_obj_loader.h>

#include <algorithm>
#include <array>
#include <charconv>
#include <cmath>
#include <cstdint>
#include <cstdio>
#include <filesystem>
#include <map>
#include <sstream>
#include <string_view>
#include <unordered_map>

#include "image/image_io.h"
#include "scene/load.h"
#include "util/error.h"
#include "util/format.h"
#include "util/input_file.h"
#include "util/memory.h"
#include "util/text.h"

namespace kdgrid {

namespace {

/// Prints warnings once each, prefixed with the file name, each line made printable and cut
/// to a few hundred bytes (a warning may quote a name from the file), at most ten.
/// tinyobjloader's warnings that kdgrid replaces with its own, which carry the line number,
/// are dropped: "Degenerated face found" (with a stray "." line) and "material [ 'x' ] not
/// found in .mtl".
void print_warnings(const std::string& path, const std::string& text) {
  std::istringstream lines(text);
  std::string line;
  std::map<std::string, int> seen;
  int printed = 0;
  while (std::getline(lines, line)) {
    if (line.empty() || line == "." || line == "Degenerated face found" ||
        (line.rfind("material [ ", 0) == 0 && line.find(" ] not found in .mtl") != line.npos) ||
        seen[line]++)
      continue;
    if (++printed > 10) {
      std::fprintf(stderr, "%s: warning: (further warnings suppressed)\n", path.c_str());
      return;
    }
    std::fprintf(stderr, "%s: warning: %s\n", path.c_str(), printable(line, 300).c_str());
  }
}

/// The UTF-8 byte-order mark some Windows tools write at the start of a text file; a reader
/// that does not skip it misreads the first line.
std::string_view without_bom(std::string_view text) {
  if (text.substr(0, 3) == "\xEF\xBB\xBF") text.remove_prefix(3);
  return text;
}

/// A read-only stream over text already in memory (std::istringstream would copy it).
class ViewBuf : public std::streambuf {
 public:
  explicit ViewBuf(std::string_view text) {
    char* p = const_cast<char*>(text.data());
    setg(p, p, p + text.size());
  }
};

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

/// Reads the .mtl files an OBJ names (mtllib) through read_input_file, so that a FIFO or a
/// device given as a material library is refused instead of blocking or growing memory; a
/// library that cannot be read is a warning, as a missing one is.
class CheckedMaterialReader : public tinyobj::MaterialReader {
 public:
  explicit CheckedMaterialReader(std::string base_dir) : base_dir_(std::move(base_dir)) {}
  bool operator()(const std::string& name, std::vector<tinyobj::material_t>* materials,
                  std::map<std::string, int>* names, std::string* warn, std::string* err) override {
    const std::string path =
        base_dir_.empty() ? name : (std::filesystem::path(base_dir_) / name).string();
    std::string text;
    try {
      text = read_input_file(path, "material library");
    } catch (const LoadError& e) {
      if (warn) *warn += std::string(e.what()) + "; materials left grey\n";
      return false;
    }
    ViewBuf buf(without_bom(text));
    std::istream in(&buf);
    tinyobj::LoadMtl(names, materials, &in, warn, err);
    return true;
  }

 private:
  std::string base_dir_;
};

/// What validate_obj_text learns about a file on its way: the counts the memory estimate
/// needs, the faces tinyobjloader cannot hold as they are, the materials used.
struct ObjScan {
  size_t vertices = 0, texcoords = 0, normals = 0;  // v, vt, vn lines
  size_t faces = 0, corners = 0;                    // f lines and their corners
  size_t longest_line = 0;
  bool long_faces = false;  // a face of more than kMaxTinyObjCorners corners
  std::vector<std::string> warnings;
  std::map<std::string, size_t, std::less<>> usemtl;  // material name -> first line using it
};

/// tinyobjloader stores a face's corner count in a byte (it wraps at 256): longer faces are
/// split before parsing (split_long_faces) into fans of at most this many corners.
constexpr size_t kMaxTinyObjCorners = 255;

/// Checks what tinyobjloader reads leniently, with the line number: every number of a v, vt
/// or vn line must be finite (it reads "nan" and "abc" as 0), every face index an integer
/// that is not 0 and fits an int (it wraps 99999999999999999999), and a negative (relative)
/// index must count back to an existing element (-1 is the last one defined above the line).
ObjScan validate_obj_text(std::string_view text, const std::string& path) {
  ObjScan scan;
  struct Kind {
    const char* name;
    const char* plural;
    size_t defined = 0;     // elements defined so far
    int64_t max_index = 0;  // largest positive index used, checked at the end
    size_t max_line = 0;
  };
  Kind kinds[3] = {
      {"vertex", "vertices"}, {"texture coordinate", "texture coordinates"}, {"normal", "normals"}};
  size_t line_no = 0, pos = 0;
  auto fail = [&](const std::string& problem) {
    throw LoadError(path + ": line " + std::to_string(line_no) + ": " + problem);
  };
  while (pos < text.size()) {
    // Lines end in LF, CRLF or a lone CR, as tinyobjloader reads them.
    size_t end = pos;
    while (end < text.size() && text[end] != '\n' && text[end] != '\r') ++end;
    const std::string_view line = text.substr(pos, end - pos);
    pos = end + (end + 1 < text.size() && text[end] == '\r' && text[end + 1] == '\n' ? 2 : 1);
    ++line_no;
    scan.longest_line = std::max(scan.longest_line, line.size());
    const auto w = split_words(line);
    if (w.empty()) continue;
    if (w[0] == "usemtl" && w.size() > 1) scan.usemtl.try_emplace(std::string(w[1]), line_no);
    const int vk = w[0] == "v" ? 0 : w[0] == "vt" ? 1 : w[0] == "vn" ? 2 : -1;
    if (vk >= 0) {
      const size_t need = vk == 1 ? 1 : 3;
      if (w.size() < need + 1) {
        std::string msg = kinds[vk].name;  // built stepwise: GCC 12 warns falsely on "'" + ...
        msg += " line '" + printable(line, 80);
        msg +=
            "' has " + std::to_string(w.size() - 1) + " numbers; it needs " + std::to_string(need);
        fail(msg);
      }
      for (size_t i = 1; i < w.size(); ++i) {
        std::string_view t = w[i];
        if (!t.empty() && t[0] == '+') t.remove_prefix(1);
        double v = 0;
        const auto [ptr, ec] = std::from_chars(t.data(), t.data() + t.size(), v);
        if (ec != std::errc() || ptr != t.data() + t.size() || !std::isfinite(v))
          fail(std::string(kinds[vk].name) + " '" + printable(line, 80) + "': '" + printable(w[i]) +
               "' is not a finite number; fix or remove the line");
      }
      ++kinds[vk].defined;
      (vk == 0 ? scan.vertices : vk == 1 ? scan.texcoords : scan.normals)++;
    } else if (w[0] == "f") {
      const size_t corners = w.size() - 1;
      if (corners < 3) {
        // tinyobjloader skips it; a line or a point is not a surface to render.
        if (scan.warnings.size() < 10)
          scan.warnings.push_back(
              "line " + std::to_string(line_no) + ": face with " + std::to_string(corners) +
              (corners == 1 ? " vertex" : " vertices") + " skipped; a face needs at least 3");
      } else {
        ++scan.faces;
        scan.corners += corners;
        if (corners > kMaxTinyObjCorners) scan.long_faces = true;
      }
      for (size_t i = 1; i < w.size(); ++i) {
        std::string_view corner = w[i];
        for (int k = 0; k < 3 && !corner.empty(); ++k) {
          const size_t slash = corner.find('/');
          const std::string_view part = corner.substr(0, slash);
          corner = slash == std::string_view::npos ? std::string_view() : corner.substr(slash + 1);
          if (part.empty()) continue;  // "1//3": no texture coordinate
          int64_t idx = 0;
          const auto [ptr, ec] = std::from_chars(part.data(), part.data() + part.size(), idx);
          if (ec != std::errc() || ptr != part.data() + part.size() || idx > INT32_MAX ||
              idx < -int64_t(INT32_MAX))
            fail(std::string("face ") + kinds[k].name + " index '" + printable(part) +
                 "' is not a whole number between -2147483647 and 2147483647");
          if (idx == 0)
            fail(std::string("face ") + kinds[k].name +
                 " index 0: OBJ indices count from 1 (or back from -1, the last one defined)");
          Kind& kd = kinds[k];
          if (idx < 0 && uint64_t(-idx) > kd.defined)
            fail(std::string("face ") + kinds[k].name + " index " + std::to_string(idx) +
                 " counts back past the first " + kd.name + ": only " + std::to_string(kd.defined) +
                 " are defined above this line (-1 is the last)");
          if (idx > kd.max_index) {
            kd.max_index = idx;
            kd.max_line = line_no;
          }
        }
      }
    }
  }
  for (const Kind& kd : kinds)
    if (uint64_t(kd.max_index) > kd.defined) {
      line_no = kd.max_line;
      fail(std::string("face references ") + kd.name + " " + std::to_string(kd.max_index) +
           " but the file has " + std::to_string(kd.defined) + " " + kd.plural +
           " (OBJ indices count from 1)");
    }
  return scan;
}

/// `text` with every face of more than kMaxTinyObjCorners corners written as several faces
/// that share its first corner: (c0 c1 .. c254), (c0 c254 c255 .. c507), ... Their fan
/// triangles are the long face's own, (c0, c_{j-1}, c_j) in file order.
std::string split_long_faces(std::string_view text) {
  std::string out;
  out.reserve(text.size() + text.size() / 64);
  size_t pos = 0;
  while (pos < text.size()) {
    size_t end = pos;
    while (end < text.size() && text[end] != '\n' && text[end] != '\r') ++end;
    const std::string_view line = text.substr(pos, end - pos);
    const auto w = split_words(line);
    if (w.size() > kMaxTinyObjCorners + 1 && w[0] == "f") {
      // w[1] is c0; a piece is c0 and w[from..to], at most kMaxTinyObjCorners corners.
      for (size_t from = 2; from + 1 < w.size();) {
        const size_t to = std::min(w.size() - 1, from + kMaxTinyObjCorners - 2);
        out += "f ";
        out += w[1];
        for (size_t i = from; i <= to; ++i) {
          out += ' ';
          out += w[i];
        }
        out += '\n';
        from = to;  // the next piece starts with this piece's last corner
      }
    } else {
      out += line;
      out += '\n';
    }
    pos = end + (end + 1 < text.size() && text[end] == '\r' && text[end + 1] == '\n' ? 2 : 1);
  }
  return out;
}

/// Bytes loading an OBJ holds at its peak, from the counts of its lines: the file's text (and
/// its rewritten copy), tinyobjloader's line buffer, its attribute arrays (it keeps a colour
/// per vertex too), its faces (a vector of corners each) and the shapes made from them
/// (copied once), then the mesh built here. Vectors grown by push_back are counted at 1.5
/// times their size (their capacity on average).
double obj_peak_bytes(const ObjScan& s, size_t text_bytes) {
  const double v = double(s.vertices), t = double(s.texcoords), n = double(s.normals);
  const double f = double(s.faces), c = double(s.corners), tris = c - 2 * f;
  const double attributes = 1.5 * (24 * v + 8 * t + 12 * n);
  const double face_group = f * (1.5 * 32 + 16) + c * 16;
  const double shapes = 2 * 1.5 * (f * 9 + c * 12);
  // Shared indices: the arrays as they are; otherwise a vertex (and a hash entry) per corner.
  const double mesh_vertices = (t > 0 || n > 0) ? c * 96 : v * 32;
  return double(text_bytes) * (s.long_faces ? 2.0 : 1.0) + double(s.longest_line) + attributes +
         face_group + shapes + tris * 16 + mesh_vertices;
}

/// What tinyobjloader made of the file, with the scan's warnings (and usemtl lines naming no
/// material) and tinyobjloader's own (warn, err: non-fatal once the parse succeeded).
struct ParsedObj {
  tinyobj::attrib_t attrib;
  std::vector<tinyobj::shape_t> shapes;
  std::vector<tinyobj::material_t> mats;
  std::string warn, err;
  ObjScan scan;
};

/// Reads, checks and parses the file: refused before tinyobjloader holds several bytes for
/// each byte of the file when that would pass the memory budget.
void parse_obj(const std::string& path, const std::string& base_dir, const LoadOptions& options,
               ParsedObj& o) {
  const std::string file = read_input_file(path);
  std::string_view text = without_bom(file);
  o.scan = validate_obj_text(text, path);
  const double peak = obj_peak_bytes(o.scan, file.size());
  const uint64_t budget =
      options.memory_budget ? options.memory_budget : default_memory_budget_bytes();
  if (peak > double(budget))
    throw LoadError(path + ": loading it would take about " + format_bytes_iec(peak) + " (" +
                    std::to_string(o.scan.vertices) + " vertices, " + std::to_string(o.scan.faces) +
                    " faces), above the memory budget of " + format_bytes_iec(double(budget)) +
                    (options.memory_budget ? "" : " (half of the memory available)") +
                    "; convert it to PLY or glTF, which load with far less, or run with more "
                    "memory");
  std::string split;
  if (o.scan.long_faces) {
    split = split_long_faces(text);
    text = split;
  }
  ViewBuf buf(text);
  std::istream in(&buf);
  CheckedMaterialReader materials(base_dir);
  const bool ok = tinyobj::LoadObj(&o.attrib, &o.shapes, &o.mats, &o.warn, &o.err, &in, &materials,
                                   /*triangulate=*/false, /*default_vcols_fallback=*/false);
  if (!ok) {
    std::string e = o.err.empty() ? o.warn : o.err;
    while (!e.empty() && (e.back() == '\n' || e.back() == ' ')) e.pop_back();
    std::replace(e.begin(), e.end(), '\n', ' ');
    throw LoadError(path + ": cannot parse OBJ: " + printable(e, 300));
  }
  split = std::string();
  for (const auto& [name, line] : o.scan.usemtl) {
    bool found = false;
    for (const auto& m : o.mats) found = found || m.name == name;
    if (!found && o.scan.warnings.size() < 10)
      o.scan.warnings.push_back("line " + std::to_string(line) + ": usemtl '" +
                                printable(name, 80) +
                                "': no material of that name in the material libraries; its "
                                "faces are rendered grey");
  }
}

/// The faces' corners as the first pass over them found them.
struct FaceSurvey {
  size_t num_tris = 0;
  bool all_normals = true, any_uvs = false;
  bool shared_index = true;  ///< every corner has one index for position, normal and uv
};

/// First pass: validates indices, counts triangles and sees whether every corner shares one
/// index for position, normal and uv (then the arrays can be used as they are).
FaceSurvey survey_faces(const ParsedObj& o, const std::string& path) {
  const size_t nv = o.attrib.vertices.size() / 3;
  const size_t nn = o.attrib.normals.size() / 3;
  const size_t nt = o.attrib.texcoords.size() / 2;
  FaceSurvey s;
  size_t face_no = 0;
  for (const auto& sh : o.shapes) {
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
        if (ix.normal_index < 0) s.all_normals = false;
        if (ix.texcoord_index >= 0) s.any_uvs = true;
        if ((ix.normal_index >= 0 && ix.normal_index != ix.vertex_index) ||
            (ix.texcoord_index >= 0 && ix.texcoord_index != ix.vertex_index))
          s.shared_index = false;
      }
      k += m;
      s.num_tris += m - 2;
    }
  }
  return s;
}

/// The mesh's vertices: either the file's vertex arrays as they are (shared indices), or one
/// vertex per distinct (v, vn, vt), made as the faces meet them.
class ObjVertices {
 public:
  ObjVertices(const tinyobj::attrib_t& attrib, bool shared_index, bool use_normals, bool use_uvs,
              Mesh& mesh)
      : attrib_(attrib),
        shared_index_(shared_index),
        use_normals_(use_normals),
        use_uvs_(use_uvs),
        mesh_(mesh) {
    if (!shared_index) return;
    const size_t nv = attrib.vertices.size() / 3;
    const size_t nn = attrib.normals.size() / 3;
    const size_t nt = attrib.texcoords.size() / 2;
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

  /// The mesh vertex of corner ix.
  uint32_t operator()(const tinyobj::index_t& ix) {
    if (shared_index_) return uint32_t(ix.vertex_index);
    const std::array<int, 3> key{ix.vertex_index, use_normals_ ? ix.normal_index : -1,
                                 use_uvs_ ? ix.texcoord_index : -1};
    const auto [it, inserted] = remap_.try_emplace(key, uint32_t(mesh_.positions.size()));
    if (inserted) {
      mesh_.positions.push_back(vec3(&attrib_.vertices[3 * size_t(ix.vertex_index)]));
      if (use_normals_)
        mesh_.normals.push_back(vec3(&attrib_.normals[3 * size_t(ix.normal_index)]));
      if (use_uvs_)
        mesh_.uvs.push_back(
            ix.texcoord_index >= 0
                ? std::array<float, 2>{float(attrib_.texcoords[2 * size_t(ix.texcoord_index)]),
                                       float(attrib_.texcoords[2 * size_t(ix.texcoord_index) + 1])}
                : std::array<float, 2>{0.f, 0.f});
    }
    return it->second;
  }

 private:
  struct CornerHash {
    size_t operator()(const std::array<int, 3>& c) const {
      uint64_t h = uint64_t(uint32_t(c[0])) * 0x9E3779B97F4A7C15ull;
      h ^= (uint64_t(uint32_t(c[1])) + 0x7F4A7C159E3779B9ull + (h << 6) + (h >> 2));
      h ^= (uint64_t(uint32_t(c[2])) + 0x94D049BB133111EBull + (h << 6) + (h >> 2));
      return size_t(h);
    }
  };
  const tinyobj::attrib_t& attrib_;
  const bool shared_index_, use_normals_, use_uvs_;
  Mesh& mesh_;
  std::unordered_map<std::array<int, 3>, uint32_t, CornerHash> remap_;
};

/// The faces fan-triangulated into the mesh, with their materials (a face without one gets
/// the default material, index mats.size()); returns whether any face did.
bool add_faces(const ParsedObj& o, const FaceSurvey& s, Mesh& mesh) {
  // Normals are used only when every corner has one (the renderer falls back to the
  // geometric normal otherwise); missing uvs read as (0, 0).
  const bool use_normals = s.all_normals && o.attrib.normals.size() / 3 > 0;
  const bool use_uvs = s.any_uvs;
  mesh.triangles.reserve(s.num_tris);
  ObjVertices add_vertex(o.attrib, s.shared_index, use_normals, use_uvs, mesh);
  const bool any_material = !o.mats.empty();
  bool uses_default = false;
  if (any_material) mesh.material_ids.reserve(s.num_tris);
  for (const auto& sh : o.shapes) {
    size_t k = 0;
    for (size_t f = 0; f < sh.mesh.num_face_vertices.size(); ++f) {
      const size_t m = sh.mesh.num_face_vertices[f];
      int mat = f < sh.mesh.material_ids.size() ? sh.mesh.material_ids[f] : -1;
      if (mat < 0 || size_t(mat) >= o.mats.size()) {
        mat = int(o.mats.size());  // the default material appended below
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
  return uses_default;
}

/// The materials, and the diffuse textures they name (loaded once each), into the scene.
void add_materials(const std::vector<tinyobj::material_t>& mats, const std::string& base_dir,
                   const std::string& path, const LoadOptions& options, Scene& scene) {
  namespace fs = std::filesystem;
  std::map<std::string, int> texture_of;
  for (const auto& m : mats) {
    Material out = convert_material(m);
    if (!m.diffuse_texname.empty()) {
      const std::string tex_path = (fs::path(base_dir) / m.diffuse_texname).string();
      auto it = texture_of.find(tex_path);
      if (it == texture_of.end()) {
        std::string why;
        int index = -1;
        if (auto tex = read_texture_file(tex_path, why, options.decode_textures)) {
          index = int(scene.textures.size());
          scene.textures.push_back(std::move(*tex));
        } else {
          std::fprintf(stderr,
                       "%s: warning: material '%s': cannot read texture %s (%s); "
                       "rendering it untextured\n",
                       path.c_str(), printable(m.name, 80).c_str(),
                       printable(tex_path, 300).c_str(), printable(why, 400).c_str());
        }
        it = texture_of.emplace(tex_path, index).first;
      }
      out.base_color_texture = it->second;
      // map_Kd multiplies Kd; a black Kd with a texture would hide the texture.
      if (it->second >= 0 && max_component(out.base_color) <= 0.0f) out.base_color = Vec3(1.0f);
    }
    scene.materials.push_back(std::move(out));
  }
}

}  // namespace

Scene load_obj(const std::string& path, const LoadOptions& options) {
  const std::string base_dir = std::filesystem::path(path).parent_path().string();
  ParsedObj o;
  parse_obj(path, base_dir, options, o);
  Scene scene;
  const FaceSurvey survey = survey_faces(o, path);
  // With a successful parse, err holds non-fatal problems (e.g. a missing .mtl file); they
  // are printed only once the faces are known to be valid, so a fatal error stands alone.
  std::string own;
  for (const std::string& w : o.scan.warnings) own += w + "\n";
  print_warnings(path, own + o.warn + o.err);

  const bool uses_default = add_faces(o, survey, scene.mesh);
  add_materials(o.mats, base_dir, path, options, scene);
  if (!o.mats.empty() && uses_default) {
    Material grey;
    grey.name = "default grey diffuse";
    scene.materials.push_back(grey);
  }
  return scene;
}

}  // namespace kdgrid
