// Fuzz target: OBJ text through pbve::parse_obj (the reader of load_obj) and validate_mesh.

#include <cstddef>
#include <cstdint>
#include <filesystem>
#include <string_view>

#include "fuzz_check.hpp"
#include "pbve/core/mesh.hpp"

extern "C" int LLVMFuzzerTestOneInput(const std::uint8_t* data, std::size_t size) {
  return pbve::fuzz::run_mesh_reader(data, size, "fuzz.obj",
                                     [](std::string_view text, const std::filesystem::path& name) {
                                       return pbve::parse_obj(text, name);
                                     });
}
