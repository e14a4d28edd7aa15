#pragma once
/// @file
/// Object poses (mesh -> camera) and the pose file contract.

#include <filesystem>
#include <optional>
#include <string_view>
#include <vector>

#include <Eigen/Core>
#include <Eigen/Geometry>

#include "pbve/core/mesh.hpp"

namespace pbve {

/// Rigid transform mapping mesh coordinates to camera coordinates: p_cam = R p_mesh + t.
struct Pose {
  Eigen::Matrix3d rotation = Eigen::Matrix3d::Identity();
  Eigen::Vector3d translation = Eigen::Vector3d::Zero();

  Eigen::Vector3d apply(const Eigen::Vector3d& p) const { return rotation * p + translation; }
  /// Transforms every row of `v` (#V by 3).
  Vertices apply(const Vertices& v) const;
  /// 4x4 homogeneous matrix.
  Eigen::Matrix4d matrix() const;
  /// From a Rodrigues rotation vector (radians) and a translation.
  static Pose from_rodrigues(const Eigen::Vector3d& rvec, const Eigen::Vector3d& t);
  /// Rodrigues rotation vector (radians) of the rotation.
  Eigen::Vector3d rodrigues() const;
};

/// One pose per frame; std::nullopt for a frame whose pose is unknown ("lost").
struct PoseTrack {
  std::vector<std::optional<Pose>> poses;
  int size() const { return static_cast<int>(poses.size()); }
  int lost_count() const;
};

/// Tolerance on |R^T R - I| (max abs entry) and |det R - 1| accepted for a rotation.
inline constexpr double kRotationTolerance = 1e-4;

/// Reads a pose file: one line per frame, `#` starts a comment, blank lines ignored. A line
/// holds 16 numbers (row-major 4x4, last row 0 0 0 1), 6 numbers (rx ry rz tx ty tz,
/// Rodrigues radians) or the word `lost`. Throws InputError with file and line for
/// anything else, non-finite numbers, or a matrix whose 3x3 part is not a rotation
/// (orthonormal with determinant +1 within kRotationTolerance).
PoseTrack load_pose_file(const std::filesystem::path& path);
/// The reader of load_pose_file() on a pose file's content held in memory; `name` is the file
/// named in error messages.
PoseTrack parse_pose_file(std::string_view text, const std::filesystem::path& name = {});
/// Writes a pose file (16 numbers per line, `lost` for unknown), via a temporary name.
void save_pose_file(const PoseTrack& track, const std::filesystem::path& path);

}  // namespace pbve
