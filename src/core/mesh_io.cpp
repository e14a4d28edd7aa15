// Mesh file formats: OBJ and PLY readers (hand-written scanners over the whole file in
// memory) and writers (to a temporary name, renamed on success).

#include <algorithm>
#include <bit>
#include <cerrno>
#include <charconv>
#include <cmath>
#include <cstdint>
#include <cstdio>
#include <cstring>
#include <limits>
#include <string>
#include <string_view>
#include <system_error>
#include <unordered_map>
#include <vector>

#include <fcntl.h>
#include <sys/mman.h>
#include <sys/stat.h>
#include <unistd.h>

#include "pbve/core/error.hpp"
#include "pbve/core/files.hpp"
#include "pbve/core/mesh.hpp"

namespace pbve {
namespace {

namespace fs = std::filesystem;

static_assert(std::endian::native == std::endian::little,
              "binary PLY reading and writing assume a little-endian host");

// ---------------------------------------------------------------------------------------
// Shared helpers

/// The whole content of a file, memory-mapped when possible (no copy, no zero-fill).
class FileData {
 public:
  explicit FileData(const fs::path& path) {
    const int fd = ::open(path.c_str(), O_RDONLY | O_CLOEXEC);
    if (fd < 0) {
      const int err = errno;
      throw InputError("cannot open mesh file: " + std::generic_category().message(err), path);
    }
    struct stat st {};
    if (::fstat(fd, &st) == 0 && S_ISREG(st.st_mode) && st.st_size > 0) {
      void* p = ::mmap(nullptr, static_cast<std::size_t>(st.st_size), PROT_READ,
                       MAP_PRIVATE | MAP_POPULATE, fd, 0);
      if (p != MAP_FAILED) {
        m_map = p;
        m_size = static_cast<std::size_t>(st.st_size);
        ::close(fd);
        return;
      }
    }
    // Not mappable (empty file, pipe, ...): read it.
    char chunk[1 << 16];
    for (;;) {
      const ssize_t n = ::read(fd, chunk, sizeof chunk);
      if (n < 0 && errno == EINTR) continue;
      if (n < 0) {
        ::close(fd);
        throw InputError("cannot read mesh file", path);
      }
      if (n == 0) break;
      m_copy.append(chunk, static_cast<std::size_t>(n));
    }
    ::close(fd);
  }
  ~FileData() {
    if (m_map) ::munmap(m_map, m_size);
  }
  FileData(const FileData&) = delete;
  FileData& operator=(const FileData&) = delete;

  std::string_view view() const {
    return m_map ? std::string_view(static_cast<const char*>(m_map), m_size)
                 : std::string_view(m_copy);
  }

 private:
  void* m_map = nullptr;
  std::size_t m_size = 0;
  std::string m_copy;
};

/// Writes `bytes` to `path` through a temporary file (write_atomically()).
void write_file_atomically(const fs::path& path, std::string_view bytes) {
  write_atomically(path, [&](const fs::path& tmp) {
    std::FILE* f = std::fopen(tmp.c_str(), "wb");
    if (!f) {
      const int err = errno;
      throw InputError("cannot create file: " + std::generic_category().message(err), tmp);
    }
    const bool ok = std::fwrite(bytes.data(), 1, bytes.size(), f) == bytes.size();
    const bool closed = std::fclose(f) == 0;
    if (!ok || !closed) throw InputError("cannot write file (disk full?)", tmp);
  });
}

bool is_blank(char c) {
  return c == ' ' || c == '\t' || c == '\r' || c == '\v' || c == '\f';
}

bool starts_with_nocase(std::string_view s, std::string_view prefix) {
  if (s.size() < prefix.size()) return false;
  for (std::size_t i = 0; i < prefix.size(); ++i) {
    char c = s[i];
    if (c >= 'A' && c <= 'Z') c = static_cast<char>(c - 'A' + 'a');
    if (c != prefix[i]) return false;
  }
  return true;
}

/// Shortens a token for an error message.
std::string quote_token(std::string_view token) {
  std::string s(token.substr(0, 40));
  if (token.size() > 40) s += "...";
  return "'" + s + "'";
}

std::string_view trim(std::string_view s) {
  while (!s.empty() && is_blank(s.front())) s.remove_prefix(1);
  while (!s.empty() && is_blank(s.back())) s.remove_suffix(1);
  return s;
}

/// Parses a floating-point token completely (a leading '+' is accepted).
bool parse_double(std::string_view token, double& value) {
  const char* b = token.data();
  const char* e = b + token.size();
  if (b != e && *b == '+') ++b;
  auto [ptr, ec] = std::from_chars(b, e, value);
  return ec == std::errc() && ptr == e && b != e;
}

template <class Int>
bool parse_int(std::string_view token, Int& value) {
  const char* b = token.data();
  const char* e = b + token.size();
  if (b != e && *b == '+') ++b;
  auto [ptr, ec] = std::from_chars(b, e, value);
  return ec == std::errc() && ptr == e && b != e;
}

/// Vertices and triangles accumulated by a reader, written straight into Eigen storage
/// (grown geometrically when the expected counts are exceeded).
class MeshBuilder {
 public:
  /// Allocates storage for the expected counts; call before adding anything.
  void reserve(std::size_t vertices, std::size_t triangles) {
    m_mesh.vertices.resize(static_cast<Eigen::Index>(std::max<std::size_t>(vertices, 16)), 3);
    reserve_triangles(triangles);
  }
  void reserve_vertices(std::size_t vertices) {
    m_mesh.vertices.resize(static_cast<Eigen::Index>(std::max<std::size_t>(vertices, 16)), 3);
  }
  void reserve_triangles(std::size_t triangles) {
    m_mesh.triangles.resize(static_cast<Eigen::Index>(std::max<std::size_t>(triangles, 16)), 3);
    m_mesh.triangle_part.reserve(triangles);
    m_mesh.interior.reserve(triangles);
  }
  int num_vertices() const { return m_nv; }
  std::vector<int>& parts() { return m_mesh.triangle_part; }

  /// Pointer to the 3 coordinates of a new vertex.
  double* add_vertex() {
    if (m_nv == m_mesh.vertices.rows())
      m_mesh.vertices.conservativeResize(std::max<Eigen::Index>(16, 2 * m_nv), 3);
    return m_mesh.vertices.data() + 3 * static_cast<std::size_t>(m_nv++);
  }

  void add_triangle(int a, int b, int c, int p, std::uint8_t in) {
    if (m_nf == m_mesh.triangles.rows())
      m_mesh.triangles.conservativeResize(std::max<Eigen::Index>(16, 2 * m_nf), 3);
    int* t = m_mesh.triangles.data() + 3 * static_cast<std::size_t>(m_nf++);
    t[0] = a;
    t[1] = b;
    t[2] = c;
    m_mesh.triangle_part.push_back(p);
    m_mesh.interior.push_back(in);
  }

  Mesh finish(std::vector<std::string> part_names, const fs::path& path) && {
    if (m_nv == 0) throw InputError("empty mesh: the file has no vertices", path);
    if (m_nf == 0) throw InputError("empty mesh: the file has no faces", path);
    // Shrinking a row-major matrix keeps its prefix in place (a realloc, no copy).
    if (m_mesh.vertices.rows() != m_nv) m_mesh.vertices.conservativeResize(m_nv, 3);
    if (m_mesh.triangles.rows() != m_nf) m_mesh.triangles.conservativeResize(m_nf, 3);
    m_mesh.part_names = std::move(part_names);
    return std::move(m_mesh);
  }

 private:
  Mesh m_mesh;
  int m_nv = 0;
  int m_nf = 0;
};

// ---------------------------------------------------------------------------------------
// OBJ

class ObjReader {
 public:
  ObjReader(const fs::path& path, std::string_view text) : m_path(path), m_text(text) {}

  Mesh read() {
    const char* p = m_text.data();
    const char* const end = p + m_text.size();
    // Rough capacity guesses from the file size avoid most reallocations.
    reserve_from_line_counts();
    while (p < end) {
      ++m_line;
      const char* eol = static_cast<const char*>(std::memchr(p, '\n', end - p));
      if (!eol) eol = end;
      parse_line(p, eol);
      p = eol + 1;
    }
    check_forward_references();
    return std::move(m_mesh).finish(used_parts(), m_path);
  }

 private:
  [[noreturn]] void fail(const std::string& message) const {
    throw InputError(message, m_path, m_line);
  }

  /// Counts `v` and `f` lines in a quick first pass so storage is allocated once.
  void reserve_from_line_counts() {
    std::size_t nv = 0, nf = 0;
    const char* p = m_text.data();
    const char* const end = p + m_text.size();
    while (p < end) {
      while (p < end && is_blank(*p)) ++p;
      if (end - p >= 2 && is_blank(p[1])) {
        nv += p[0] == 'v';
        nf += p[0] == 'f';
      }
      const char* eol = static_cast<const char*>(std::memchr(p, '\n', end - p));
      if (!eol) break;
      p = eol + 1;
    }
    m_mesh.reserve(nv, nf);
  }

  static const char* skip_blanks(const char* p, const char* end) {
    while (p < end && is_blank(*p)) ++p;
    return p;
  }
  static const char* token_end(const char* p, const char* end) {
    while (p < end && !is_blank(*p)) ++p;
    return p;
  }

  void parse_line(const char* p, const char* end) {
    p = skip_blanks(p, end);
    if (p == end || *p == '#') return;
    const char* kw_end = token_end(p, end);
    const std::string_view kw(p, kw_end - p);
    if (kw == "v") {
      parse_vertex(kw_end, end);
    } else if (kw == "f") {
      parse_face(kw_end, end);
    } else if (kw == "g" || kw == "o") {
      start_part(trim(std::string_view(kw_end, end - kw_end)));
    } else if (kw == "usemtl") {
      m_material_interior =
          starts_with_nocase(trim(std::string_view(kw_end, end - kw_end)), "interior");
    }
    // Everything else (vt, vn, vp, s, l, p, mtllib, ...) does not affect the mesh.
  }

  void parse_vertex(const char* p, const char* end) {
    double c[3];
    for (int k = 0; k < 3; ++k) {
      p = skip_blanks(p, end);
      if (p == end) fail("vertex needs 3 coordinates, found " + std::to_string(k));
      const char* te = token_end(p, end);
      const std::string_view tok(p, te - p);
      if (!parse_double(tok, c[k])) fail("malformed number " + quote_token(tok));
      if (!std::isfinite(c[k]))
        fail("non-finite coordinate " + quote_token(tok) + " in vertex " +
             std::to_string(m_mesh.num_vertices() + 1));
      p = te;
    }
    // An optional w and vertex colours may follow; they do not matter here.
    std::copy(c, c + 3, m_mesh.add_vertex());
  }

  /// Parses one `v`, `v/vt`, `v//vn` or `v/vt/vn` reference and returns the 0-based vertex.
  int parse_reference(const char*& p, const char* end) {
    const char* te = token_end(p, end);
    const char* slash = static_cast<const char*>(std::memchr(p, '/', te - p));
    const char* ie = slash ? slash : te;
    long long idx = 0;
    const char* b = p;
    if (b != ie && *b == '+') ++b;
    auto [ptr, ec] = std::from_chars(b, ie, idx);
    if (ec != std::errc() || ptr != ie || b == ie)
      fail("malformed vertex index " + quote_token(std::string_view(p, te - p)));
    // Texture and normal indices are not used; check only that they are integers.
    for (const char* q = ie; q < te; ++q)
      if (!(*q == '/' || *q == '-' || *q == '+' || (*q >= '0' && *q <= '9')))
        fail("malformed vertex reference " + quote_token(std::string_view(p, te - p)));
    p = te;
    const long long defined = static_cast<long long>(m_mesh.num_vertices());
    if (idx == 0) fail("vertex index 0 is invalid (OBJ indices start at 1)");
    if (idx < 0) {
      if (idx < -defined)  // not -idx > defined: -LLONG_MIN overflows
        fail("vertex index " + std::to_string(idx) + " out of range: " + std::to_string(defined) +
             " vertices defined before this line");
      return static_cast<int>(defined + idx);
    }
    if (idx > std::numeric_limits<int>::max())
      fail("vertex index " + std::to_string(idx) + " out of range");
    // A face may refer to vertices defined further down; checked at the end of the file.
    if (idx > defined && (m_forward.empty() || m_forward.back().first != m_line))
      m_forward.emplace_back(m_line, static_cast<int>(idx));
    else if (idx > defined && m_forward.back().second < idx)
      m_forward.back().second = static_cast<int>(idx);
    return static_cast<int>(idx - 1);
  }

  void parse_face(const char* p, const char* end) {
    if (m_part < 0) m_part = part_id("default");
    const std::uint8_t in = (m_part_interior[m_part] || m_material_interior) ? 1 : 0;
    int first = -1, prev = -1, count = 0;
    for (;;) {
      p = skip_blanks(p, end);
      if (p == end || *p == '#') break;  // end of line or a trailing comment
      const int v = parse_reference(p, end);
      if (count == 0)
        first = v;
      else if (count >= 2)
        m_mesh.add_triangle(first, prev, v, m_part, in);
      prev = v;
      ++count;
    }
    if (count < 3) fail("face has " + std::to_string(count) + " vertices, needs at least 3");
  }

  void check_forward_references() {
    const long long total = static_cast<long long>(m_mesh.num_vertices());
    for (const auto& [line, idx] : m_forward)
      if (idx > total)
        throw InputError("vertex index " + std::to_string(idx) + " out of range: the file has " +
                             std::to_string(total) + " vertices",
                         m_path, line);
  }

  int part_id(std::string_view name) {
    auto it = m_part_ids.find(std::string(name));
    if (it != m_part_ids.end()) return it->second;
    const int id = static_cast<int>(m_part_names.size());
    m_part_names.emplace_back(name);
    m_part_interior.push_back(starts_with_nocase(name, "interior"));
    m_part_ids.emplace(std::string(name), id);
    return id;
  }

  void start_part(std::string_view name) { m_part = part_id(name.empty() ? "default" : name); }

  /// Part names in order of declaration, without parts that received no face; remaps ids.
  std::vector<std::string> used_parts() {
    std::vector<int> used(m_part_names.size(), 0);
    for (int p : m_mesh.parts()) used[p] = 1;
    std::vector<int> remap(m_part_names.size(), -1);
    std::vector<std::string> names;
    for (std::size_t i = 0; i < m_part_names.size(); ++i)
      if (used[i]) {
        remap[i] = static_cast<int>(names.size());
        names.push_back(m_part_names[i]);
      }
    for (int& p : m_mesh.parts()) p = remap[p];
    return names;
  }

  const fs::path& m_path;
  std::string_view m_text;
  int m_line = 0;
  MeshBuilder m_mesh;
  std::vector<std::string> m_part_names;
  std::vector<char> m_part_interior;
  std::unordered_map<std::string, int> m_part_ids;
  int m_part = -1;
  bool m_material_interior = false;
  std::vector<std::pair<int, int>> m_forward;  // (line, largest index) of forward references
};

// ---------------------------------------------------------------------------------------
// PLY

enum class PlyType { Int8, UInt8, Int16, UInt16, Int32, UInt32, Float32, Float64 };

bool ply_type_from_name(std::string_view s, PlyType& t) {
  static constexpr std::pair<std::string_view, PlyType> names[] = {
      {"char", PlyType::Int8},      {"int8", PlyType::Int8},       {"uchar", PlyType::UInt8},
      {"uint8", PlyType::UInt8},    {"short", PlyType::Int16},     {"int16", PlyType::Int16},
      {"ushort", PlyType::UInt16},  {"uint16", PlyType::UInt16},   {"int", PlyType::Int32},
      {"int32", PlyType::Int32},    {"uint", PlyType::UInt32},     {"uint32", PlyType::UInt32},
      {"float", PlyType::Float32},  {"float32", PlyType::Float32}, {"double", PlyType::Float64},
      {"float64", PlyType::Float64}};
  for (const auto& [n, v] : names)
    if (n == s) {
      t = v;
      return true;
    }
  return false;
}

std::size_t ply_type_size(PlyType t) {
  switch (t) {
    case PlyType::Int8:
    case PlyType::UInt8:
      return 1;
    case PlyType::Int16:
    case PlyType::UInt16:
      return 2;
    case PlyType::Int32:
    case PlyType::UInt32:
    case PlyType::Float32:
      return 4;
    case PlyType::Float64:
      return 8;
  }
  return 0;
}

bool ply_type_is_integer(PlyType t) {
  return t != PlyType::Float32 && t != PlyType::Float64;
}

const char* ply_type_name(PlyType t) {
  switch (t) {
    case PlyType::Int8:
      return "char";
    case PlyType::UInt8:
      return "uchar";
    case PlyType::Int16:
      return "short";
    case PlyType::UInt16:
      return "ushort";
    case PlyType::Int32:
      return "int";
    case PlyType::UInt32:
      return "uint";
    case PlyType::Float32:
      return "float";
    case PlyType::Float64:
      return "double";
  }
  return "?";
}

/// Whether the integer `v` is representable in the integer type `t`.
bool ply_integer_in_range(PlyType t, long long v) {
  switch (t) {
    case PlyType::Int8:
      return v >= INT8_MIN && v <= INT8_MAX;
    case PlyType::UInt8:
      return v >= 0 && v <= UINT8_MAX;
    case PlyType::Int16:
      return v >= INT16_MIN && v <= INT16_MAX;
    case PlyType::UInt16:
      return v >= 0 && v <= UINT16_MAX;
    case PlyType::Int32:
      return v >= INT32_MIN && v <= INT32_MAX;
    case PlyType::UInt32:
      return v >= 0 && v <= UINT32_MAX;
    default:
      return true;
  }
}

/// A value read from a PLY file, for messages: integers in full, others as %g (never converted
/// to an integer type, which is undefined for NaN or huge values).
std::string format_value(double v) {
  char buf[32];
  if (v == std::floor(v) && std::abs(v) < 9007199254740992.0)
    std::snprintf(buf, sizeof buf, "%.0f", v);
  else
    std::snprintf(buf, sizeof buf, "%g", v);
  return buf;
}

struct PlyProperty {
  std::string name;
  PlyType type = PlyType::Float32;  // the item type for lists
  bool is_list = false;
  PlyType count_type = PlyType::UInt8;
};

struct PlyElement {
  std::string name;
  long long count = 0;
  std::vector<PlyProperty> properties;
  int line = 0;  // of the `element` line in the header
};

class PlyReader {
 public:
  PlyReader(const fs::path& path, std::string_view data) : m_path(path), m_data(data) {}

  Mesh read() {
    parse_header();
    if (m_binary)
      read_body<true>();
    else
      read_body<false>();
    std::vector<std::string> names;
    if (!m_has_part) {
      names.push_back("default");
    } else {
      int max_part = 0;
      for (int p : m_mesh.parts()) max_part = std::max(max_part, p);
      for (int k = 0; k <= max_part; ++k) {
        auto it = m_comment_parts.find(k);
        names.push_back(it != m_comment_parts.end() ? it->second : "part" + std::to_string(k));
      }
    }
    return std::move(m_mesh).finish(std::move(names), m_path);
  }

 private:
  [[noreturn]] void fail(const std::string& message, int line = 0,
                         const std::string& element = {}) const {
    throw InputError(message, m_path, line, element);
  }

  // ---- header

  void parse_header() {
    std::size_t pos = 0;
    int line = 0;
    bool have_format = false;
    auto next_line = [&](std::string_view& out) {
      if (pos >= m_data.size()) return false;
      std::size_t eol = m_data.find('\n', pos);
      if (eol == std::string_view::npos) eol = m_data.size();
      out = m_data.substr(pos, eol - pos);
      if (!out.empty() && out.back() == '\r') out.remove_suffix(1);
      // The body starts after the newline, or at the end when the last line has none.
      pos = std::min(eol + 1, m_data.size());
      ++line;
      return true;
    };
    std::string_view l;
    if (!next_line(l) || trim(l) != "ply") fail("not a PLY file: the first line must be 'ply'", 1);
    for (;;) {
      if (!next_line(l)) fail("unexpected end of file in the PLY header (no 'end_header')", line);
      std::vector<std::string_view> tok = split(l);
      if (tok.empty()) continue;
      const std::string_view kw = tok[0];
      if (kw == "end_header") break;
      if (kw == "comment") {
        parse_comment(tok);
      } else if (kw == "obj_info") {
        continue;
      } else if (kw == "format") {
        if (tok.size() != 3) fail("malformed format line, expected 'format <type> 1.0'", line);
        if (tok[1] == "ascii")
          m_binary = false;
        else if (tok[1] == "binary_little_endian")
          m_binary = true;
        else if (tok[1] == "binary_big_endian")
          fail(
              "unsupported PLY format 'binary_big_endian' (ascii and binary_little_endian "
              "are supported)",
              line);
        else
          fail("unknown PLY format " + quote_token(tok[1]), line);
        if (tok[2] != "1.0") fail("unsupported PLY version " + quote_token(tok[2]), line);
        have_format = true;
      } else if (kw == "element") {
        if (tok.size() != 3)
          fail("malformed element line, expected 'element <name> <count>'", line);
        PlyElement e;
        e.name = std::string(tok[1]);
        e.line = line;
        if ((e.name == "vertex" || e.name == "face") &&
            std::any_of(m_elements.begin(), m_elements.end(),
                        [&](const PlyElement& o) { return o.name == e.name; }))
          fail("a second '" + e.name + "' element (a PLY mesh has one)", line);
        if (!parse_int(tok[2], e.count) || e.count < 0 || e.count > std::numeric_limits<int>::max())
          fail("malformed element count " + quote_token(tok[2]), line);
        m_elements.push_back(std::move(e));
      } else if (kw == "property") {
        if (m_elements.empty()) fail("property before any element", line);
        PlyProperty prop;
        if (tok.size() == 5 && tok[1] == "list") {
          prop.is_list = true;
          if (!ply_type_from_name(tok[2], prop.count_type) || !ply_type_is_integer(prop.count_type))
            fail("bad list count type " + quote_token(tok[2]), line);
          if (!ply_type_from_name(tok[3], prop.type))
            fail("unknown property type " + quote_token(tok[3]), line);
          prop.name = std::string(tok[4]);
        } else if (tok.size() == 3) {
          if (!ply_type_from_name(tok[1], prop.type))
            fail("unknown property type " + quote_token(tok[1]), line);
          prop.name = std::string(tok[2]);
        } else {
          fail("malformed property line " + quote_token(l), line);
        }
        m_elements.back().properties.push_back(std::move(prop));
      } else {
        fail("unexpected header line " + quote_token(l), line);
      }
    }
    if (!have_format) fail("the PLY header has no 'format' line", line);
    m_body = pos;
    m_body_line = line + 1;
    check_elements();
  }

  static std::vector<std::string_view> split(std::string_view l) {
    std::vector<std::string_view> out;
    std::size_t i = 0;
    while (i < l.size()) {
      while (i < l.size() && is_blank(l[i])) ++i;
      std::size_t j = i;
      while (j < l.size() && !is_blank(l[j])) ++j;
      if (j > i) out.push_back(l.substr(i, j - i));
      i = j;
    }
    return out;
  }

  /// Part names written by save_ply: "comment pbve part <id> <name>".
  void parse_comment(const std::vector<std::string_view>& tok) {
    if (tok.size() >= 5 && tok[1] == "pbve" && tok[2] == "part") {
      int id = 0;
      if (!parse_int(tok[3], id) || id < 0) return;
      const char* b = tok[4].data();
      const char* e = tok.back().data() + tok.back().size();
      m_comment_parts[id] = std::string(b, e);
    }
  }

  void check_elements() {
    for (std::size_t i = 0; i < m_elements.size(); ++i) {
      const PlyElement& e = m_elements[i];
      if (e.name == "vertex") {
        m_vertex_count = e.count;
        for (const char* c : {"x", "y", "z"})
          if (std::count_if(e.properties.begin(), e.properties.end(),
                            [&](const PlyProperty& p) { return !p.is_list && p.name == c; }) != 1)
            fail("the vertex element needs properties x, y and z, once each");
      } else if (e.name == "face") {
        int lists = 0;
        for (const auto& p : e.properties)
          if (p.is_list && (p.name == "vertex_indices" || p.name == "vertex_index")) {
            ++lists;
            if (!ply_type_is_integer(p.type))
              fail("face property '" + p.name + "' must have an integer item type");
          }
        if (lists != 1) fail("the face element needs one list property 'vertex_indices'");
      }
    }
  }

  // ---- body

  /// Reads values either from binary data or from whitespace-separated ASCII tokens.
  template <bool Binary>
  struct Source {
    const char* p;
    const char* end;
    int line;  // ASCII only

    [[noreturn]] void truncated(const PlyReader& r, const std::string& element) const {
      if (Binary) r.fail("truncated binary data: file ends inside " + element, 0, element);
      // A final newline does not start a new line of content.
      const int last = (p > r.m_data.data() && p[-1] == '\n') ? line - 1 : line;
      r.fail("unexpected end of file inside " + element, last, element);
    }

    /// Reads one value of type `t` as a double (exact for every PLY type).
    double read(PlyType t, const PlyReader& r, const std::string_view element_name, long long i) {
      if constexpr (Binary) {
        const std::size_t n = ply_type_size(t);
        if (static_cast<std::size_t>(end - p) < n) truncated(r, key(element_name, i));
        double v = 0;
        switch (t) {
          case PlyType::Int8:
            v = load<std::int8_t>();
            break;
          case PlyType::UInt8:
            v = load<std::uint8_t>();
            break;
          case PlyType::Int16:
            v = load<std::int16_t>();
            break;
          case PlyType::UInt16:
            v = load<std::uint16_t>();
            break;
          case PlyType::Int32:
            v = load<std::int32_t>();
            break;
          case PlyType::UInt32:
            v = load<std::uint32_t>();
            break;
          case PlyType::Float32:
            v = load<float>();
            break;
          case PlyType::Float64:
            v = load<double>();
            break;
        }
        return v;
      } else {
        while (p < end && (is_blank(*p) || *p == '\n')) {
          if (*p == '\n') ++line;
          ++p;
        }
        if (p == end) truncated(r, key(element_name, i));
        const char* te = p;
        while (te < end && !is_blank(*te) && *te != '\n') ++te;
        const std::string_view tok(p, te - p);
        double v = 0;
        bool ok;
        if (ply_type_is_integer(t)) {
          long long iv = 0;
          ok = parse_int(tok, iv);
          // ASCII values keep to their declared type, as binary ones do by construction.
          if (ok && !ply_integer_in_range(t, iv))
            r.fail("value " + std::string(tok) + " out of range for type " + ply_type_name(t), line,
                   key(element_name, i));
          v = static_cast<double>(iv);
        } else {
          ok = parse_double(tok, v);
        }
        if (!ok) r.fail("malformed number " + quote_token(tok), line, key(element_name, i));
        p = te;
        return v;
      }
    }

    template <class T>
    T load() {
      T v;
      std::memcpy(&v, p, sizeof(T));
      p += sizeof(T);
      return v;
    }
  };

  static std::string key(std::string_view element, long long i) {
    return std::string(element) + " " + std::to_string(i);
  }

  template <bool Binary>
  void read_body() {
    Source<Binary> src{m_data.data() + m_body, m_data.data() + m_data.size(), m_body_line};
    for (const PlyElement& e : m_elements) {
      if (e.name == "vertex")
        read_vertices(e, src);
      else if (e.name == "face")
        read_faces(e, src);
      else
        skip_element(e, src);
    }
  }

  /// The line of the token just read (ASCII), 0 for binary data.
  template <class Src>
  int line_of(const Src& src) const {
    return m_binary ? 0 : src.line;
  }

  /// How many entries of `e` the rest of the data can hold at most (at least one byte per ASCII
  /// value; the value and list-count sizes in binary), so that storage for the declared count
  /// is not allocated before the data is there.
  template <class Src>
  std::size_t entries_that_fit(const PlyElement& e, const Src& src) const {
    std::size_t entry = 0;
    for (const PlyProperty& p : e.properties)
      entry += m_binary ? ply_type_size(p.is_list ? p.count_type : p.type) : 1;
    const auto left = static_cast<std::size_t>(src.end - src.p);
    return std::min(static_cast<std::size_t>(e.count), entry == 0 ? 0 : left / entry);
  }

  template <class Src>
  void read_vertices(const PlyElement& e, Src& src) {
    // Which slot (0, 1, 2 for x, y, z; -1 for anything else) each property fills.
    std::vector<int> slot;
    for (const auto& p : e.properties)
      slot.push_back(p.is_list       ? -1
                     : p.name == "x" ? 0
                     : p.name == "y" ? 1
                     : p.name == "z" ? 2
                                     : -1);
    m_mesh.reserve_vertices(entries_that_fit(e, src));
    for (long long i = 0; i < e.count; ++i) {
      double* xyz = m_mesh.add_vertex();
      for (std::size_t k = 0; k < e.properties.size(); ++k) {
        const PlyProperty& p = e.properties[k];
        if (p.is_list) {
          skip_list(p, src, e.name, i);
          continue;
        }
        const double v = src.read(p.type, *this, e.name, i);
        if (slot[k] >= 0) {
          if (!std::isfinite(v))
            fail("non-finite coordinate " + std::to_string(v), line_of(src), key(e.name, i));
          xyz[slot[k]] = v;
        }
      }
    }
  }

  template <class Src>
  void read_faces(const PlyElement& e, Src& src) {
    m_mesh.reserve_triangles(entries_that_fit(e, src));
    std::vector<int> face;
    for (const auto& p : e.properties) m_has_part = m_has_part || (!p.is_list && p.name == "part");
    for (long long i = 0; i < e.count; ++i) {
      face.clear();
      int part = 0;
      std::uint8_t interior = 0;
      for (const PlyProperty& p : e.properties) {
        if (p.is_list && (p.name == "vertex_indices" || p.name == "vertex_index")) {
          const double n = src.read(p.count_type, *this, e.name, i);
          if (n < 3)
            fail("face has " + format_value(n) + " vertices, needs at least 3", line_of(src),
                 key(e.name, i));
          for (long long k = 0; k < static_cast<long long>(n); ++k) {
            const double idx = src.read(p.type, *this, e.name, i);
            if (idx < 0 || idx >= static_cast<double>(m_vertex_count))
              fail("vertex index " + format_value(idx) + " out of range: the file has " +
                       std::to_string(m_vertex_count) + " vertices",
                   line_of(src), key(e.name, i));
            face.push_back(static_cast<int>(idx));
          }
        } else if (p.is_list) {
          skip_list(p, src, e.name, i);
        } else {
          const double v = src.read(p.type, *this, e.name, i);
          if (p.name == "part") {
            // Ids may be sparse, but not beyond one part per face (plus named parts), and
            // they are ints.
            const double max_part = std::min(static_cast<double>(e.count + m_comment_parts.size()),
                                             static_cast<double>(std::numeric_limits<int>::max()));
            if (v < 0 || v >= max_part || v != std::floor(v))
              fail("invalid part id " + format_value(v) + ": expected 0 to " +
                       std::to_string(static_cast<long long>(max_part) - 1),
                   line_of(src), key(e.name, i));
            part = static_cast<int>(v);
          } else if (p.name == "interior") {
            interior = v != 0 ? 1 : 0;
          }
        }
      }
      for (std::size_t k = 2; k < face.size(); ++k)
        m_mesh.add_triangle(face[0], face[k - 1], face[k], part, interior);
    }
  }

  template <class Src>
  void skip_list(const PlyProperty& p, Src& src, std::string_view element, long long i) {
    const double n = src.read(p.count_type, *this, element, i);
    if (n < 0) fail("negative list length", line_of(src), key(element, i));
    for (long long k = 0; k < static_cast<long long>(n); ++k) src.read(p.type, *this, element, i);
  }

  template <class Src>
  void skip_element(const PlyElement& e, Src& src) {
    if (e.properties.empty()) return;  // nothing to read, however many entries
    for (long long i = 0; i < e.count; ++i)
      for (const PlyProperty& p : e.properties) {
        if (p.is_list)
          skip_list(p, src, e.name, i);
        else
          src.read(p.type, *this, e.name, i);
      }
  }

  const fs::path& m_path;
  std::string_view m_data;
  bool m_binary = false;
  std::vector<PlyElement> m_elements;
  std::size_t m_body = 0;
  int m_body_line = 0;
  long long m_vertex_count = 0;
  bool m_has_part = false;
  std::unordered_map<int, std::string> m_comment_parts;
  MeshBuilder m_mesh;
};

// ---------------------------------------------------------------------------------------
// Writers

void append_double(std::string& out, double v) {
  char buf[32];
  auto [ptr, ec] = std::to_chars(buf, buf + sizeof buf, v);
  out.append(buf, ptr);
}

void append_int(std::string& out, long long v) {
  char buf[24];
  auto [ptr, ec] = std::to_chars(buf, buf + sizeof buf, v);
  out.append(buf, ptr);
}

/// Checks what the writers rely on; throws InputError naming the target file.
void check_writable(const Mesh& mesh, const fs::path& path) {
  const std::size_t nf = static_cast<std::size_t>(mesh.num_triangles());
  if (mesh.num_vertices() == 0 || nf == 0) throw InputError("cannot write an empty mesh", path);
  try {
    check_triangle_indices(mesh.triangles, mesh.num_vertices(), "cannot write the mesh");
  } catch (const std::invalid_argument& e) {
    throw InputError(e.what(), path);
  }
  if (!mesh.triangle_part.empty() && mesh.triangle_part.size() != nf)
    throw InputError("triangle_part has " + std::to_string(mesh.triangle_part.size()) +
                         " entries for " + std::to_string(nf) + " triangles",
                     path);
  if (!mesh.interior.empty() && mesh.interior.size() != nf)
    throw InputError("interior has " + std::to_string(mesh.interior.size()) + " entries for " +
                         std::to_string(nf) + " triangles",
                     path);
  for (std::size_t f = 0; f < mesh.triangle_part.size(); ++f)
    if (mesh.triangle_part[f] < 0 ||
        (mesh.triangle_part[f] > 0 && mesh.triangle_part[f] >= mesh.num_parts()))
      throw InputError("part id " + std::to_string(mesh.triangle_part[f]) + " has no name", path, 0,
                       "triangle " + std::to_string(f));
}

std::string part_name_of(const Mesh& mesh, int part) {
  if (part < mesh.num_parts() && !mesh.part_names[part].empty()) return mesh.part_names[part];
  return part == 0 ? "default" : "part" + std::to_string(part);
}

}  // namespace

Mesh parse_obj(std::string_view text, const std::filesystem::path& name) {
  return ObjReader(name, text).read();
}

Mesh parse_ply(std::string_view data, const std::filesystem::path& name) {
  return PlyReader(name, data).read();
}

Mesh load_obj(const std::filesystem::path& path) {
  const FileData file(path);
  return parse_obj(file.view(), path);
}

Mesh load_ply(const std::filesystem::path& path) {
  const FileData file(path);
  return parse_ply(file.view(), path);
}

Mesh load_mesh(const std::filesystem::path& path) {
  const std::string ext = path.extension().string();
  if (starts_with_nocase(ext, ".obj") && ext.size() == 4) return load_obj(path);
  if (starts_with_nocase(ext, ".ply") && ext.size() == 4) return load_ply(path);
  throw InputError("unsupported mesh format " + quote_token(ext) + " (expected .obj or .ply)",
                   path);
}

void save_obj(const Mesh& mesh, const std::filesystem::path& path) {
  check_writable(mesh, path);
  std::string out;
  out.reserve(static_cast<std::size_t>(mesh.num_vertices()) * 64 +
              static_cast<std::size_t>(mesh.num_triangles()) * 32);
  out += "# pbve mesh: ";
  append_int(out, mesh.num_vertices());
  out += " vertices, ";
  append_int(out, mesh.num_triangles());
  out += " triangles\n";
  // Declare every part first so that part ids survive a round trip.
  for (int p = 0; p < std::max(1, mesh.num_parts()); ++p)
    out += "g " + part_name_of(mesh, p) + "\n";
  for (int v = 0; v < mesh.num_vertices(); ++v) {
    out += "v ";
    append_double(out, mesh.vertices(v, 0));
    out += ' ';
    append_double(out, mesh.vertices(v, 1));
    out += ' ';
    append_double(out, mesh.vertices(v, 2));
    out += '\n';
  }
  int part = -1;
  bool material_interior = false;
  for (int f = 0; f < mesh.num_triangles(); ++f) {
    const int p = mesh.triangle_part.empty() ? 0 : mesh.triangle_part[f];
    if (p != part) {
      out += "g " + part_name_of(mesh, p) + "\n";
      part = p;
    }
    // Interior faces outside "interior*" parts are marked with a material.
    const bool want = !mesh.interior.empty() && mesh.interior[f] != 0;
    const bool named_interior = starts_with_nocase(part_name_of(mesh, part), "interior");
    if (!named_interior && want != material_interior) {
      out += want ? "usemtl interior\n" : "usemtl surface\n";
      material_interior = want;
    }
    out += "f ";
    append_int(out, mesh.triangles(f, 0) + 1);
    out += ' ';
    append_int(out, mesh.triangles(f, 1) + 1);
    out += ' ';
    append_int(out, mesh.triangles(f, 2) + 1);
    out += '\n';
  }
  write_file_atomically(path, out);
}

void save_ply(const Mesh& mesh, const std::filesystem::path& path) {
  check_writable(mesh, path);
  std::string out;
  out += "ply\nformat binary_little_endian 1.0\ncomment written by pbve\n";
  for (int p = 0; p < mesh.num_parts(); ++p)
    out += "comment pbve part " + std::to_string(p) + " " + part_name_of(mesh, p) + "\n";
  out += "element vertex " + std::to_string(mesh.num_vertices()) + "\n";
  out += "property double x\nproperty double y\nproperty double z\n";
  out += "element face " + std::to_string(mesh.num_triangles()) + "\n";
  out += "property list uchar int vertex_indices\nproperty int part\nproperty uchar interior\n";
  out += "end_header\n";
  const std::size_t header = out.size();
  out.resize(header + static_cast<std::size_t>(mesh.num_vertices()) * 24 +
             static_cast<std::size_t>(mesh.num_triangles()) * 18);
  char* w = out.data() + header;
  std::memcpy(w, mesh.vertices.data(), static_cast<std::size_t>(mesh.num_vertices()) * 24);
  w += static_cast<std::size_t>(mesh.num_vertices()) * 24;
  for (int f = 0; f < mesh.num_triangles(); ++f) {
    *w++ = 3;
    std::memcpy(w, mesh.triangles.row(f).data(), 12);
    w += 12;
    const std::int32_t part = mesh.triangle_part.empty() ? 0 : mesh.triangle_part[f];
    std::memcpy(w, &part, 4);
    w += 4;
    *w++ = static_cast<char>(mesh.interior.empty() ? 0 : (mesh.interior[f] ? 1 : 0));
  }
  write_file_atomically(path, out);
}

}  // namespace pbve
