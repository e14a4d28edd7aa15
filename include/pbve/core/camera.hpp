#pragma once
/// @file
/// Pinhole camera with OpenCV axes (x right, y down, z forward), camera at the origin.

#include <Eigen/Core>

namespace pbve {

/// Pinhole intrinsics and image size. Pixel centres are at integer coordinates
/// (OpenCV convention): pixel (u, v) covers [u - 0.5, u + 0.5] x [v - 0.5, v + 0.5].
struct Camera {
  double fx = 600.0;  ///< focal length, pixels
  double fy = 600.0;  ///< focal length, pixels
  double cx = 320.0;  ///< principal point, pixels
  double cy = 240.0;  ///< principal point, pixels
  int width = 640;    ///< image width, pixels
  int height = 480;   ///< image height, pixels

  /// Throws InputError when a value is not finite or not positive, the principal point
  /// lies outside the image, or a focal length is so short that the rays through the image's
  /// edges cannot be cast: the ray through pixel (u, v) has direction ((u - cx) / fx,
  /// (v - cy) / fy, 1), and ray casting (Embree, single precision) refuses components beyond
  /// 1.844e18, so fx must be at least max(cx + 0.5, width - 0.5 - cx) / 1.844e18 (a bound of at
  /// most width / 1.844e18, 3.5e-16 for 640 pixels), fy likewise with cy and height. There is no
  /// upper bound: a long focal length only makes the components small. The error's key() names
  /// the field ("camera.fx").
  void validate() const;

  /// Projects a camera-frame point (z > 0) to pixel coordinates.
  Eigen::Vector2d project(const Eigen::Vector3d& p_cam) const {
    return {fx * p_cam.x() / p_cam.z() + cx, fy * p_cam.y() / p_cam.z() + cy};
  }
  /// The camera-frame point at depth z (> 0) seen at pixel `px`.
  Eigen::Vector3d back_project(const Eigen::Vector2d& px, double z) const {
    return {(px.x() - cx) / fx * z, (px.y() - cy) / fy * z, z};
  }
  /// Unit direction of the ray through pixel `px`.
  Eigen::Vector3d ray_direction(const Eigen::Vector2d& px) const {
    return back_project(px, 1.0).normalized();
  }
  /// 3x3 intrinsic matrix K.
  Eigen::Matrix3d K() const;
};

}  // namespace pbve
