// Fuzz target: pose-file text through pbve::parse_pose_file (the reader of load_pose_file).

#include <cmath>
#include <cstddef>
#include <cstdint>
#include <string_view>

#include "fuzz_check.hpp"
#include "pbve/core/error.hpp"
#include "pbve/core/pose.hpp"

extern "C" int LLVMFuzzerTestOneInput(const std::uint8_t* data, std::size_t size) {
  const std::filesystem::path name = "fuzz_poses.txt";
  const std::string_view text(reinterpret_cast<const char*>(data), size);
  pbve::PoseTrack track;
  try {
    track = pbve::parse_pose_file(text, name);
  } catch (const pbve::InputError& e) {
    pbve::fuzz::check_error(e, name);
    return 0;
  }
  pbve::fuzz::expect(track.size() > 0, "a pose file that was read has a pose");
  for (const auto& pose : track.poses) {
    if (!pose) continue;
    // Every accepted pose is a finite rigid motion (16-number lines are checked against
    // kRotationTolerance; Rodrigues vectors give rotations up to rounding).
    pbve::fuzz::expect(pose->rotation.allFinite() && pose->translation.allFinite(),
                       "poses are finite");
    const double orth = (pose->rotation.transpose() * pose->rotation - Eigen::Matrix3d::Identity())
                            .cwiseAbs()
                            .maxCoeff();
    pbve::fuzz::expect(orth <= 2 * pbve::kRotationTolerance, "rotations are orthonormal");
    pbve::fuzz::expect(std::abs(pose->rotation.determinant() - 1.0) <= 2 * pbve::kRotationTolerance,
                       "rotations have determinant 1");
  }
  return 0;
}
