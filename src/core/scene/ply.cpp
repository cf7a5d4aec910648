// PLY reader of kdgrid's own: ascii and binary (both byte orders), any property order and
// numeric type, unknown elements skipped. The whole file is read into memory and numbers are
// parsed with std::from_chars, because iostreams take seconds on the 33 MB dragon.
//
// Bad input of any kind ends in a LoadError naming the file and the place; the parser never
// trusts a count from the header for allocation, so a corrupt header cannot make it reserve
// more than the file could hold, and every loop consumes input, so it cannot hang.
#include <algorithm>
#include <array>
#include <bit>
#include <cctype>
#include <charconv>
#include <cmath>
#include <cstdint>
#include <cstring>
#include <limits>
#include <memory>
#include <string>
#include <string_view>
#include <vector>

#include "scene/load.h"
#include "util/error.h"
#include "util/input_file.h"
#include "util/text.h"

namespace kdgrid {

namespace {

enum class Format { Ascii, BinaryLE, BinaryBE };

enum class Type : uint8_t { Int8, UInt8, Int16, UInt16, Int32, UInt32, Float32, Float64 };

struct Property {
  std::string name;
  Type type = Type::Float32;
  bool is_list = false;
  Type count_type = Type::UInt8;  // lists only
};

struct Element {
  std::string name;
  uint64_t count = 0;
  std::vector<Property> props;
};

bool parse_type(std::string_view s, Type& t) {
  static constexpr std::pair<std::string_view, Type> kNames[] = {
      {"char", Type::Int8},      {"int8", Type::Int8},       {"uchar", Type::UInt8},
      {"uint8", Type::UInt8},    {"short", Type::Int16},     {"int16", Type::Int16},
      {"ushort", Type::UInt16},  {"uint16", Type::UInt16},   {"int", Type::Int32},
      {"int32", Type::Int32},    {"uint", Type::UInt32},     {"uint32", Type::UInt32},
      {"float", Type::Float32},  {"float32", Type::Float32}, {"double", Type::Float64},
      {"float64", Type::Float64}};
  for (const auto& [name, type] : kNames)
    if (s == name) {
      t = type;
      return true;
    }
  return false;
}

size_t type_size(Type t) {
  switch (t) {
    case Type::Int8:
    case Type::UInt8:
      return 1;
    case Type::Int16:
    case Type::UInt16:
      return 2;
    case Type::Int32:
    case Type::UInt32:
    case Type::Float32:
      return 4;
    case Type::Float64:
      return 8;
  }
  return 1;
}

bool is_integer(Type t) {
  return t != Type::Float32 && t != Type::Float64;
}

/// Reads a vertex index or list count as an integer and a coordinate as a float, from either
/// encoding. `where()` describes the current place for error messages.
class Reader {
 public:
  Reader(const char* begin, const char* end, Format fmt, const std::string& name, size_t line)
      : p_(begin), end_(end), fmt_(fmt), name_(name), line_(line) {}

  /// Context of the value being read ("face 1032 of 69451"), set by the element loop.
  void set_place(const Element& e, uint64_t index) {
    elem_ = &e;
    index_ = index;
  }

  [[noreturn]] void fail(const std::string& problem) const {
    std::string msg = name_ + ": ";
    if (elem_)
      msg += printable(elem_->name) + " " + std::to_string(index_) + " of " +
             std::to_string(elem_->count);
    if (fmt_ == Format::Ascii)
      msg += std::string(elem_ ? " (" : "(") + "line " + std::to_string(line_) + ")";
    throw LoadError(msg + ": " + problem);
  }

  [[noreturn]] void fail_eof() const {
    fail(
        "file ends early; the file is truncated or its header declares more data than it "
        "holds");
  }

  size_t remaining() const { return size_t(end_ - p_); }
  bool ascii() const { return fmt_ == Format::Ascii; }

  int64_t read_int(Type t) {
    if (ascii()) {
      const std::string_view tok = token();
      int64_t v = 0;
      const char* b = tok.data();
      if (b != tok.data() + tok.size() && *b == '+') ++b;
      auto [ptr, ec] = std::from_chars(b, tok.data() + tok.size(), v);
      if (ec != std::errc() || ptr != tok.data() + tok.size()) {
        // Some writers print integers as "3.0"; accept a float value that is integral.
        double d = 0;
        auto [p2, ec2] = std::from_chars(b, tok.data() + tok.size(), d);
        if (ec2 == std::errc() && p2 == tok.data() + tok.size() && d == double(int64_t(d)) &&
            std::abs(d) < 9.0e15)
          return int64_t(d);
        fail("malformed integer '" + printable(tok) + "'");
      }
      return v;
    }
    if (!is_integer(t)) {
      const double d = read_binary_float(t);
      if (!(d == d) || std::abs(d) > 9.0e15 || d != double(int64_t(d)))
        fail("list count or index " + std::to_string(d) + " is not an integer");
      return int64_t(d);
    }
    const uint8_t* b = take(type_size(t));
    uint64_t u = 0;
    const size_t n = type_size(t);
    if (fmt_ == Format::BinaryLE)
      for (size_t i = 0; i < n; ++i) u |= uint64_t(b[i]) << (8 * i);
    else
      for (size_t i = 0; i < n; ++i) u = (u << 8) | b[i];
    switch (t) {
      case Type::Int8:
        return int8_t(u);
      case Type::UInt8:
        return uint8_t(u);
      case Type::Int16:
        return int16_t(u);
      case Type::UInt16:
        return uint16_t(u);
      case Type::Int32:
        return int32_t(u);
      case Type::UInt32:
        return uint32_t(u);
      default:
        return 0;
    }
  }

  double read_float(Type t) {
    if (ascii()) {
      const std::string_view tok = token();
      const char* b = tok.data();
      if (b != tok.data() + tok.size() && *b == '+') ++b;
      double v = 0;
      auto [ptr, ec] = std::from_chars(b, tok.data() + tok.size(), v);
      if (ec != std::errc() || ptr != tok.data() + tok.size())
        fail("malformed number '" + printable(tok) + "'");
      return v;
    }
    if (is_integer(t)) return double(read_int(t));
    return read_binary_float(t);
  }

  /// Skips one scalar value without converting it.
  void skip(Type t) {
    if (ascii())
      token();
    else
      take(type_size(t));
  }

 private:
  const uint8_t* take(size_t n) {
    if (remaining() < n) fail_eof();
    const uint8_t* b = reinterpret_cast<const uint8_t*>(p_);
    p_ += n;
    return b;
  }

  double read_binary_float(Type t) {
    const size_t n = type_size(t);
    uint8_t bytes[8] = {};
    const uint8_t* src = take(n);
    const bool swap = (fmt_ == Format::BinaryBE) != (std::endian::native == std::endian::big);
    for (size_t i = 0; i < n && i < 8; ++i) bytes[i] = src[swap ? n - 1 - i : i];
    if (t == Type::Float32) {
      float f;
      std::memcpy(&f, bytes, 4);
      return f;
    }
    double d;
    std::memcpy(&d, bytes, 8);
    return d;
  }

  std::string_view token() {
    while (p_ < end_ && (*p_ == ' ' || *p_ == '\t' || *p_ == '\r' || *p_ == '\n')) {
      // Lines end in LF, CRLF or a lone CR (old Mac files).
      if (*p_ == '\n' || (*p_ == '\r' && (p_ + 1 == end_ || p_[1] != '\n'))) ++line_;
      ++p_;
    }
    const char* start = p_;
    while (p_ < end_ && *p_ != ' ' && *p_ != '\t' && *p_ != '\r' && *p_ != '\n') ++p_;
    if (p_ == start) fail_eof();
    return {start, size_t(p_ - start)};
  }

  const char* p_;
  const char* end_;
  Format fmt_;
  const std::string& name_;
  size_t line_;
  const Element* elem_ = nullptr;
  uint64_t index_ = 0;
};

/// Smallest number of bytes one entry of `e` can take, to cap reservations by the file size.
size_t min_entry_bytes(const Element& e, Format fmt) {
  size_t n = 0;
  for (const Property& p : e.props)
    n += fmt == Format::Ascii ? 2 : (p.is_list ? type_size(p.count_type) : type_size(p.type));
  return std::max<size_t>(n, 1);
}

void skip_property(Reader& r, const Property& p) {
  if (!p.is_list) {
    r.skip(p.type);
    return;
  }
  const int64_t n = r.read_int(p.count_type);
  if (n < 0) r.fail("list '" + p.name + "' has negative length " + std::to_string(n));
  // Each list item takes at least one byte, so a length larger than the rest of the file
  // means the data ends early, not a loop of billions of iterations.
  if (uint64_t(n) > r.remaining()) r.fail_eof();
  for (int64_t i = 0; i < n; ++i) r.skip(p.type);
}

/// A PLY header: the data's format, its elements, where the data starts and on which line.
struct Header {
  Format fmt = Format::Ascii;
  std::vector<Element> elements;
  const char* data = nullptr;
  size_t line_no = 0;  ///< the header's last line
};

/// One 'property' line's words `w` (of `line`) as a property; `error` makes the exception.
template <class Error>
Property parse_property(const std::vector<std::string_view>& w, std::string_view line,
                        const Error& error) {
  Property prop;
  if (w.size() >= 5 && w[1] == "list") {
    if (!parse_type(w[2], prop.count_type) || !parse_type(w[3], prop.type))
      throw error("unknown type in '" + printable(line, 80) + "'");
    if (!is_integer(prop.count_type))
      throw error("list count type must be an integer type in '" + printable(line, 80) + "'");
    prop.is_list = true;
    prop.name = std::string(w[4]);
  } else if (w.size() >= 3 && w[1] != "list") {
    if (!parse_type(w[1], prop.type))
      throw error("unknown property type '" + printable(w[1]) + "'");
    prop.name = std::string(w[2]);
  } else {
    throw error("malformed property line '" + printable(line, 80) + "'");
  }
  return prop;
}

/// The header: text lines from 'ply' up to "end_header".
Header parse_header(const char* data, size_t size, const std::string& name) {
  const char* const end = data + size;
  const char* p = data;
  size_t line_no = 0;
  // Header lines end in LF (CRLF too: the CR is dropped) or, in files from old Mac tools, in
  // a lone CR; which one is decided by the end of the first line, 'ply', and kept for the
  // header, so that binary data after "end_header\r" is never taken for a line end.
  const bool cr_only = size > 4 && std::memcmp(data, "ply\r", 4) == 0 && data[4] != '\n';
  auto next_line = [&](std::string_view& line) -> bool {
    if (p >= end) return false;
    const char* nl =
        static_cast<const char*>(std::memchr(p, cr_only ? '\r' : '\n', size_t(end - p)));
    const char* stop = nl ? nl : end;
    line = std::string_view(p, size_t(stop - p));
    if (!line.empty() && line.back() == '\r') line.remove_suffix(1);
    p = nl ? nl + 1 : end;
    ++line_no;
    return true;
  };
  auto header_error = [&](const std::string& problem) -> LoadError {
    return LoadError(name + ": header line " + std::to_string(line_no) + ": " + problem);
  };

  std::string_view line;
  if (size < 3 || std::memcmp(data, "ply", 3) != 0 || !next_line(line) || line != "ply")
    throw LoadError(name +
                    ": not a PLY file (it does not start with the line 'ply'); check "
                    "the file or its extension");
  bool have_format = false, have_end = false;
  Header h;
  while (next_line(line)) {
    const auto w = split_words(line);
    if (w.empty() || w[0] == "comment" || w[0] == "obj_info") continue;
    if (w[0] == "end_header") {
      have_end = true;
      break;
    }
    if (w[0] == "format") {
      if (w.size() < 2) throw header_error("'format' without a format name");
      if (w[1] == "ascii")
        h.fmt = Format::Ascii;
      else if (w[1] == "binary_little_endian")
        h.fmt = Format::BinaryLE;
      else if (w[1] == "binary_big_endian")
        h.fmt = Format::BinaryBE;
      else
        throw header_error("unknown format '" + printable(w[1]) +
                           "'; expected ascii, binary_little_endian or binary_big_endian");
      have_format = true;
    } else if (w[0] == "element") {
      if (w.size() < 3) throw header_error("'element' needs a name and a count");
      Element e;
      e.name = std::string(w[1]);
      auto [ptr, ec] = std::from_chars(w[2].data(), w[2].data() + w[2].size(), e.count);
      if (ec != std::errc() || ptr != w[2].data() + w[2].size())
        throw header_error("element '" + printable(e.name) + "' has malformed count '" +
                           printable(w[2]) + "'");
      h.elements.push_back(std::move(e));
    } else if (w[0] == "property") {
      if (h.elements.empty()) throw header_error("'property' before any 'element'");
      h.elements.back().props.push_back(parse_property(w, line, header_error));
    } else {
      // A number where a keyword belongs is the data: 'end_header' is missing.
      if (std::isdigit(static_cast<unsigned char>(w[0][0])) || w[0][0] == '-' || w[0][0] == '.')
        throw header_error("'" + printable(line) +
                           "' looks like data, but no 'end_header' line came before it; add "
                           "'end_header' after the last 'property' line");
      throw header_error("unknown keyword '" + printable(w[0]) + "'");
    }
  }
  if (!have_end)
    throw LoadError(name +
                    ": the header has no 'end_header' line; the file is truncated or not PLY");
  if (!have_format) throw LoadError(name + ": the header has no 'format' line");
  h.data = p;
  h.line_no = line_no;
  return h;
}

/// Where the vertex element's properties go: per property its slot (0-2 position, 3-5
/// normal, 6-7 uv; -1 = ignored), and whether normals and uvs are complete.
struct VertexLayout {
  std::vector<int> slot;
  bool with_normals = false, with_uvs = false;
};

VertexLayout vertex_layout(const Element& vert_elem, const std::string& name) {
  VertexLayout layout;
  layout.slot.assign(vert_elem.props.size(), -1);
  bool have[8] = {};
  for (size_t i = 0; i < vert_elem.props.size(); ++i) {
    const Property& pr = vert_elem.props[i];
    if (pr.is_list) continue;
    static constexpr std::pair<std::string_view, int> kSlots[] = {
        {"x", 0},         {"y", 1},         {"z", 2},         {"nx", 3},       {"ny", 4},
        {"nz", 5},        {"u", 6},         {"v", 7},         {"s", 6},        {"t", 7},
        {"texture_u", 6}, {"texture_v", 7}, {"texture_s", 6}, {"texture_t", 7}};
    for (const auto& [n, slot] : kSlots)
      if (pr.name == n && !have[slot]) {
        layout.slot[i] = slot;
        have[slot] = true;
      }
  }
  if (!have[0] || !have[1] || !have[2])
    throw LoadError(name + ": the vertex element lacks one of the properties x, y, z");
  layout.with_normals = have[3] && have[4] && have[5];
  layout.with_uvs = have[6] && have[7];
  return layout;
}

/// The face element's vertex index list property, or -1 (no face element, or no faces).
int face_list_property(const Element* face_elem, const std::string& name) {
  int face_list = -1;
  if (!face_elem) return face_list;
  for (size_t i = 0; i < face_elem->props.size(); ++i) {
    const Property& pr = face_elem->props[i];
    if (pr.is_list && (pr.name == "vertex_indices" || pr.name == "vertex_index")) {
      face_list = int(i);
      break;
    }
  }
  if (face_list < 0 && face_elem->count > 0)
    throw LoadError(name +
                    ": the face element has no list property 'vertex_indices' or "
                    "'vertex_index'");
  if (face_list >= 0 && !is_integer(face_elem->props[size_t(face_list)].type))
    throw LoadError(name + ": face indices must have an integer type");
  return face_list;
}

/// The vertex element's entries (at most `cap` reserved) into the mesh.
void read_vertices(Reader& r, const Element& e, const VertexLayout& layout, uint64_t cap,
                   Mesh& mesh) {
  const size_t n = size_t(std::min(e.count, cap));
  mesh.positions.reserve(n);
  if (layout.with_normals) mesh.normals.reserve(n);
  if (layout.with_uvs) mesh.uvs.reserve(n);
  for (uint64_t i = 0; i < e.count; ++i) {
    r.set_place(e, i);
    float v[8] = {0, 0, 0, 0, 0, 0, 0, 0};
    for (size_t k = 0; k < e.props.size(); ++k) {
      const Property& pr = e.props[k];
      if (pr.is_list)
        skip_property(r, pr);
      else if (layout.slot[k] >= 0)
        v[layout.slot[k]] = float(r.read_float(pr.type));
      else
        r.skip(pr.type);
    }
    mesh.positions.emplace_back(v[0], v[1], v[2]);
    if (layout.with_normals) mesh.normals.emplace_back(v[3], v[4], v[5]);
    if (layout.with_uvs) mesh.uvs.push_back({v[6], v[7]});
  }
}

/// The face element's entries as triangles (property `face_list` holds each face's indices
/// into the nv vertices).
void read_faces(Reader& r, const Element& e, int face_list, uint64_t nv, uint64_t cap, Mesh& mesh) {
  // Most files hold triangles; reserve one triangle per face, capped by the file size.
  mesh.triangles.reserve(size_t(std::min(e.count, cap)));
  for (uint64_t i = 0; i < e.count; ++i) {
    r.set_place(e, i);
    for (size_t k = 0; k < e.props.size(); ++k) {
      const Property& pr = e.props[k];
      if (int(k) != face_list) {
        skip_property(r, pr);
        continue;
      }
      const int64_t m = r.read_int(pr.count_type);
      if (m < 3) r.fail("has " + std::to_string(m) + " vertices; a face needs at least 3");
      if (uint64_t(m) > r.remaining()) r.fail_eof();
      // Fan triangulation in file order: (v0, v_{j-1}, v_j) for j = 2..m-1 (docs/RAYSETS.md).
      uint32_t first = 0, prev = 0;
      for (int64_t j = 0; j < m; ++j) {
        const int64_t idx = r.read_int(pr.type);
        if (idx < 0 || uint64_t(idx) >= nv)
          r.fail("references vertex " + std::to_string(idx) + " but the file has " +
                 std::to_string(nv) + " vertices");
        const uint32_t u = uint32_t(idx);
        if (j == 0)
          first = u;
        else if (j >= 2)
          mesh.triangles.push_back({first, prev, u});
        prev = u;
      }
    }
  }
}

}  // namespace

Scene parse_ply(const char* data, size_t size, const std::string& name) {
  // A UTF-8 byte-order mark (written by some Windows editors) before the 'ply' line.
  if (size >= 3 && std::memcmp(data, "\xEF\xBB\xBF", 3) == 0) {
    data += 3;
    size -= 3;
  }
  const Header h = parse_header(data, size, name);

  // --- Locate the vertex and face elements and map their properties. ---
  const Element* vert_elem = nullptr;
  const Element* face_elem = nullptr;
  for (const Element& e : h.elements) {
    if (e.name == "vertex" && !vert_elem) vert_elem = &e;
    if (e.name == "face" && !face_elem) face_elem = &e;
  }
  if (!vert_elem) throw LoadError(name + ": no 'vertex' element in the header");
  if (vert_elem->count > std::numeric_limits<uint32_t>::max())
    throw LoadError(name + ": the header declares " + std::to_string(vert_elem->count) +
                    " vertices, more than kdgrid's 32-bit indices allow");
  const VertexLayout layout = vertex_layout(*vert_elem, name);
  const int face_list = face_list_property(face_elem, name);

  // --- Data. ---
  Scene scene;
  Mesh& mesh = scene.mesh;
  Reader r(h.data, data + size, h.fmt, name, h.line_no + 1);
  for (const Element& e : h.elements) {
    if (e.props.empty()) continue;  // nothing stored per entry: nothing to read
    const uint64_t cap = r.remaining() / min_entry_bytes(e, h.fmt) + 1;
    if (&e == vert_elem) {
      read_vertices(r, e, layout, cap, mesh);
    } else if (&e == face_elem && face_list >= 0) {
      read_faces(r, e, face_list, vert_elem->count, cap, mesh);
    } else {
      for (uint64_t i = 0; i < e.count; ++i) {
        r.set_place(e, i);
        for (const Property& pr : e.props) skip_property(r, pr);
      }
    }
  }
  return scene;
}

Scene load_ply(const std::string& path) {
  const std::string data = read_input_file(path);
  return parse_ply(data.data(), data.size(), path);
}

}  // namespace kdgrid
