#pragma once
/// @file
/// What every fuzz target checks: bad input is a pbve::InputError naming the file, and what a
/// reader accepts satisfies the contract of its result. A broken expectation aborts (a
/// finding), whatever the build type.

#include <cstddef>
#include <cstdint>
#include <cstdio>
#include <cstdlib>
#include <filesystem>
#include <string>
#include <string_view>

#include "pbve/core/error.hpp"
#include "pbve/core/mesh.hpp"

namespace pbve::fuzz {

/// Aborts with `what` when `ok` is false.
inline void expect(bool ok, const char* what) {
  if (ok) return;
  std::fprintf(stderr, "fuzz expectation failed: %s\n", what);
  std::abort();
}

/// An InputError from reading `file` names that file first in its message.
inline void check_error(const InputError& e, const std::filesystem::path& file) {
  expect(e.file() == file, "the error names the file read");
  expect(!e.message().empty(), "the error says what is wrong");
  expect(std::string(e.what()).rfind(file.string(), 0) == 0, "the message starts with the file");
}

/// A mesh a reader returned: consistent arrays, finite coordinates, indices in range, part
/// ids with names.
inline void check_mesh(const Mesh& m) {
  const auto nf = static_cast<std::size_t>(m.num_triangles());
  expect(m.num_vertices() > 0 && nf > 0, "a mesh that was read is not empty");
  expect(m.vertices.allFinite(), "coordinates are finite");
  expect(m.triangle_part.size() == nf && m.interior.size() == nf, "one part and flag per face");
  expect(m.num_parts() > 0, "a mesh that was read has a part name");
  for (Eigen::Index f = 0; f < m.triangles.rows(); ++f)
    for (int k = 0; k < 3; ++k)
      expect(m.triangles(f, k) >= 0 && m.triangles(f, k) < m.num_vertices(),
             "triangle indices are in range");
  for (const int p : m.triangle_part) expect(p >= 0 && p < m.num_parts(), "part ids have names");
  for (const auto in : m.interior) expect(in == 0 || in == 1, "interior flags are 0 or 1");
}

/// The body of a mesh reader's target: `parse(text, name)` either throws an InputError that
/// names the file, or returns a mesh that check_mesh() and validate_mesh() accept.
template <class Parse>
int run_mesh_reader(const std::uint8_t* data, std::size_t size, const std::filesystem::path& name,
                    Parse parse) {
  const std::string_view text(reinterpret_cast<const char*>(data), size);
  Mesh mesh;
  try {
    mesh = parse(text, name);
  } catch (const InputError& e) {
    check_error(e, name);
    return 0;
  }
  check_mesh(mesh);
  // What the reader accepts, validation accepts too (it only reports non-fatal findings).
  const MeshReport report = validate_mesh(mesh, name);
  expect(report.ok() == report.summary().empty(), "a summary exactly when not ok");
  return 0;
}

}  // namespace pbve::fuzz
