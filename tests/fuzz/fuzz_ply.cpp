// Fuzz target: PLY data (ascii or binary) through pbve::parse_ply (the reader of load_ply) and
// validate_mesh.

#include <cstddef>
#include <cstdint>
#include <filesystem>
#include <string_view>

#include "fuzz_check.hpp"
#include "pbve/core/mesh.hpp"

extern "C" int LLVMFuzzerTestOneInput(const std::uint8_t* data, std::size_t size) {
  return pbve::fuzz::run_mesh_reader(data, size, "fuzz.ply",
                                     [](std::string_view text, const std::filesystem::path& name) {
                                       return pbve::parse_ply(text, name);
                                     });
}
