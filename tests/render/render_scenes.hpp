#pragma once
// Synthetic scenes for the render tests: procedural meshes, a procedurally coloured object
// rendered (supersampled) over a background image, and image statistics.

#include <array>
#include <cmath>
#include <functional>
#include <map>
#include <numbers>
#include <vector>

#include <Eigen/Geometry>
#include <opencv2/core.hpp>

#include "pbve/core/camera.hpp"
#include "pbve/core/mesh.hpp"
#include "pbve/edit/synth.hpp"
#include "pbve/visibility/ray_scene.hpp"

namespace pbve::test {

/// Fills the per-triangle arrays of a mesh made of one part.
inline Mesh finish_mesh(Vertices v, Triangles t) {
  Mesh mesh;
  mesh.vertices = std::move(v);
  mesh.triangles = std::move(t);
  mesh.triangle_part.assign(static_cast<size_t>(mesh.triangles.rows()), 0);
  mesh.part_names = {"default"};
  mesh.interior.assign(static_cast<size_t>(mesh.triangles.rows()), 0);
  return mesh;
}

/// Icosphere of `radius` about the origin, 20 * 4^levels triangles, outward counter-clockwise.
inline Mesh icosphere(int levels, double radius) {
  return pbve::make_icosphere(radius, levels);
}

/// Torus about the z axis (major radius R, minor r), nu x nv quads, outward counter-clockwise.
inline Mesh torus(double R, double r, int nu, int nv) {
  Vertices v(nu * nv, 3);
  for (int i = 0; i < nu; ++i)
    for (int j = 0; j < nv; ++j) {
      const double a = 2 * std::numbers::pi * i / nu, b = 2 * std::numbers::pi * j / nv;
      v.row(i * nv + j) << (R + r * std::cos(b)) * std::cos(a), (R + r * std::cos(b)) * std::sin(a),
          r * std::sin(b);
    }
  Triangles t(2 * nu * nv, 3);
  int k = 0;
  for (int i = 0; i < nu; ++i)
    for (int j = 0; j < nv; ++j) {
      const int a = i * nv + j, b = ((i + 1) % nu) * nv + j;
      const int c = ((i + 1) % nu) * nv + (j + 1) % nv, d = i * nv + (j + 1) % nv;
      t.row(k++) << a, b, c;
      t.row(k++) << a, c, d;
    }
  return finish_mesh(std::move(v), std::move(t));
}

/// Axis-aligned box [-h, h]^3 with every face split into n x n quads (12 n^2 triangles),
/// outward counter-clockwise. Triangles [2 n^2 f, 2 n^2 (f + 1)) belong to face f in the order
/// +x, -x, +y, -y, +z, -z.
inline Mesh box(double h, int n) {
  std::vector<Eigen::Vector3d> v;
  std::vector<std::array<int, 3>> f;
  for (int axis = 0; axis < 3; ++axis)
    for (int sign : {1, -1}) {
      Eigen::Vector3d normal = Eigen::Vector3d::Zero();
      normal[axis] = sign;
      Eigen::Vector3d u = Eigen::Vector3d::Zero(), w;
      u[(axis + 1) % 3] = 1;
      w = normal.cross(u);  // (u, w, normal) right-handed: quads counter-clockwise seen outside
      const int base = static_cast<int>(v.size());
      for (int j = 0; j <= n; ++j)
        for (int i = 0; i <= n; ++i)
          v.push_back(h * (normal + (2.0 * i / n - 1) * u + (2.0 * j / n - 1) * w));
      for (int j = 0; j < n; ++j)
        for (int i = 0; i < n; ++i) {
          const int a = base + j * (n + 1) + i, b = a + 1, c = a + n + 2, d = a + n + 1;
          f.push_back({a, b, c});
          f.push_back({a, c, d});
        }
    }
  Vertices vertices(static_cast<Eigen::Index>(v.size()), 3);
  for (size_t i = 0; i < v.size(); ++i) vertices.row(i) = v[i].transpose();
  Triangles triangles(static_cast<Eigen::Index>(f.size()), 3);
  for (size_t j = 0; j < f.size(); ++j) triangles.row(j) << f[j][0], f[j][1], f[j][2];
  return finish_mesh(std::move(vertices), std::move(triangles));
}

/// Rigid transform of mesh coordinates into the camera frame.
inline Vertices transform(const Vertices& v, const Eigen::Matrix3d& R, const Eigen::Vector3d& t) {
  return ((v * R.transpose()).rowwise() + t.transpose()).eval();
}

/// Colour (BGR 0..255) of a surface point as a function of its mesh coordinates.
using SurfaceColor = std::function<cv::Vec3f(const Eigen::Vector3d& p_mesh)>;

/// Result of render_object().
struct SyntheticFrame {
  cv::Mat image;     ///< CV_8UC3
  cv::Mat coverage;  ///< CV_32F, fraction of the ss x ss sub-samples that hit the object
};

/// Renders the mesh (mesh coordinates `mesh_v`, camera coordinates `cam_v`) over `background`
/// with ss x ss samples per pixel: every sub-sample takes the colour of its surface point, or
/// the background pixel's colour when it misses, and the pixel is their mean (rounded).
inline SyntheticFrame render_object(const Triangles& triangles, const Vertices& mesh_v,
                                    const Vertices& cam_v, const Camera& camera,
                                    const cv::Mat& background, const SurfaceColor& color,
                                    int ss = 4) {
  RayScene scene(cam_v, triangles);
  const PrimaryHits hits = scene.cast_primary(camera, ss);
  SyntheticFrame out;
  out.image.create(camera.height, camera.width, CV_8UC3);
  out.coverage.create(camera.height, camera.width, CV_32F);
  for (int y = 0; y < camera.height; ++y)
    for (int x = 0; x < camera.width; ++x) {
      cv::Vec3f sum(0, 0, 0);
      int hit = 0;
      for (int sy = 0; sy < ss; ++sy)
        for (int sx = 0; sx < ss; ++sx) {
          const size_t i = static_cast<size_t>(y * ss + sy) * hits.width + (x * ss + sx);
          const int tri = hits.triangle[i];
          if (tri < 0) {
            const cv::Vec3b b = background.at<cv::Vec3b>(y, x);
            sum += cv::Vec3f(b[0], b[1], b[2]);
            continue;
          }
          const float u = hits.u[i], v = hits.v[i];
          const Eigen::Vector3d p = (1 - u - v) * mesh_v.row(triangles(tri, 0)).transpose() +
                                    u * mesh_v.row(triangles(tri, 1)).transpose() +
                                    v * mesh_v.row(triangles(tri, 2)).transpose();
          sum += color(p);
          ++hit;
        }
      sum *= 1.0f / (ss * ss);
      out.image.at<cv::Vec3b>(y, x) =
          cv::Vec3b(cv::saturate_cast<uchar>(sum[0]), cv::saturate_cast<uchar>(sum[1]),
                    cv::saturate_cast<uchar>(sum[2]));
      out.coverage.at<float>(y, x) = static_cast<float>(hit) / (ss * ss);
    }
  return out;
}

/// A smooth textured background: sums of sines per channel, values in [30, 225].
inline cv::Mat smooth_background(cv::Size size) {
  cv::Mat bg(size, CV_8UC3);
  for (int y = 0; y < size.height; ++y)
    for (int x = 0; x < size.width; ++x)
      bg.at<cv::Vec3b>(y, x) = cv::Vec3b(
          cv::saturate_cast<uchar>(128 + 60 * std::sin(0.05 * x) + 35 * std::cos(0.07 * y)),
          cv::saturate_cast<uchar>(128 + 50 * std::sin(0.03 * x + 0.04 * y) +
                                   40 * std::cos(0.11 * x)),
          cv::saturate_cast<uchar>(128 + 70 * std::cos(0.045 * y + 0.02 * x) +
                                   25 * std::sin(0.09 * y)));
  return bg;
}

/// Mean absolute difference per channel value (0..255 scale) over the pixels where mask != 0;
/// -1 when the mask is empty.
inline double mean_abs_diff(const cv::Mat& a, const cv::Mat& b, const cv::Mat& mask) {
  double sum = 0.0;
  std::int64_t n = 0;
  for (int y = 0; y < a.rows; ++y)
    for (int x = 0; x < a.cols; ++x) {
      if (!mask.at<uchar>(y, x)) continue;
      const cv::Vec3b p = a.at<cv::Vec3b>(y, x), q = b.at<cv::Vec3b>(y, x);
      for (int c = 0; c < 3; ++c) sum += std::abs(int(p[c]) - int(q[c]));
      n += 3;
    }
  return n ? sum / n : -1.0;
}

/// PSNR in dB (peak 255) over the pixels where mask != 0; +infinity for identical images.
inline double psnr(const cv::Mat& a, const cv::Mat& b, const cv::Mat& mask) {
  double sum = 0.0;
  std::int64_t n = 0;
  for (int y = 0; y < a.rows; ++y)
    for (int x = 0; x < a.cols; ++x) {
      if (!mask.at<uchar>(y, x)) continue;
      const cv::Vec3b p = a.at<cv::Vec3b>(y, x), q = b.at<cv::Vec3b>(y, x);
      for (int c = 0; c < 3; ++c) sum += std::pow(double(p[c]) - double(q[c]), 2);
      n += 3;
    }
  if (n == 0 || sum == 0.0) return std::numeric_limits<double>::infinity();
  return 10.0 * std::log10(255.0 * 255.0 / (sum / n));
}

}  // namespace pbve::test
