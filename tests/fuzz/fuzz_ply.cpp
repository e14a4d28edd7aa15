// Fuzz target: PLY data (ascii or binary) through pbve::parse_ply (the reader of load_ply) and
// validate_mesh.

#include <cstddef>
#include <cstdint>
#include <string_view>

#include "fuzz_check.hpp"
#include "pbve/core/error.hpp"
#include "pbve/core/mesh.hpp"

extern "C" int LLVMFuzzerTestOneInput(const std::uint8_t* data, std::size_t size) {
  const std::filesystem::path name = "fuzz.ply";
  const std::string_view text(reinterpret_cast<const char*>(data), size);
  pbve::Mesh mesh;
  try {
    mesh = pbve::parse_ply(text, name);
  } catch (const pbve::InputError& e) {
    pbve::fuzz::check_error(e, name);
    return 0;
  }
  pbve::fuzz::check_mesh(mesh);
  // What the reader accepts, validation accepts too (it only reports non-fatal findings).
  const pbve::MeshReport report = pbve::validate_mesh(mesh, name);
  pbve::fuzz::expect(report.ok() == report.summary().empty(), "a summary exactly when not ok");
  return 0;
}
