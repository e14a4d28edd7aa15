#pragma once
// Region-based (silhouette) cues for the pose tracker: the mesh's outer contour at a pose,
// foreground/background colour statistics, and the position of the image contour along
// correspondence lines normal to the projected one (after Stoiber et al.'s sparse
// correspondence lines: the posterior of the contour's offset along a line given the pixels'
// colours under a smoothed step model). Implementation detail of src/track.

#include <vector>

#include <Eigen/Core>
#include <opencv2/core.hpp>

#include "pbve/core/camera.hpp"
#include "pbve/core/mesh.hpp"
#include "pbve/core/pose.hpp"
#include "pbve/visibility/ray_scene.hpp"

namespace pbve::track_detail {

/// A mesh edge with its two faces and the vertex of each face opposite to it (-1 for a
/// boundary edge's missing face).
struct MeshEdge {
  int a = 0, b = 0;
  int face[2] = {-1, -1};
  int opposite[2] = {-1, -1};
};
std::vector<MeshEdge> mesh_edges(const Mesh& mesh);

/// A point of the object's outer contour: `point` in mesh coordinates, `pixel` its projection,
/// `normal` the unit image normal pointing out of the object.
struct ContourPoint {
  Eigen::Vector3d point;
  Eigen::Vector2d pixel;
  Eigen::Vector2d normal;
};

/// Points on the outer contour of `mesh` at `pose`, every `spacing_px` pixels along it (at most
/// `max_points`, spaced wider when the contour is longer), on the edges between faces turned
/// towards and away from the camera, without those whose outer side is covered by the object
/// itself (a ray `probe_px` outside hits the mesh). `scene` holds the mesh in mesh coordinates.
/// Points whose line of `reach_px` pixels either way leaves the image are dropped.
std::vector<ContourPoint> sample_contour(const Mesh& mesh, const std::vector<MeshEdge>& edges,
                                         const RayScene& scene, const Camera& camera,
                                         const Pose& pose, double spacing_px, int max_points,
                                         double reach_px, double probe_px = 1.5);

/// Colour histograms (32 bins per BGR channel) of the object and of its surroundings.
class ColourModel {
 public:
  bool empty() const { return m_fg.empty(); }
  /// P(foreground | colour) under equal priors: 0.5 where neither histogram has seen it.
  float foreground(const cv::Vec3b& c) const {
    const int i = index(c);
    const float f = m_fg[static_cast<size_t>(i)] + kPrior,
                b = m_bg[static_cast<size_t>(i)] + kPrior;
    return f / (f + b);
  }
  /// Blends in new normalized histograms of `fg` and `bg` pixels with weight `rate` (1: replace).
  void update(const std::vector<cv::Vec3b>& fg, const std::vector<cv::Vec3b>& bg, double rate);

 private:
  static int index(const cv::Vec3b& c) {
    return (c[0] >> 3) << 10 | (c[1] >> 3) << 5 | (c[2] >> 3);
  }
  static constexpr float kPrior = 2e-5f;
  std::vector<float> m_fg, m_bg;
};

/// Settings of one correspondence line.
struct LineOptions {
  int scale = 1;            ///< pixels per line segment (coarse-to-fine: 4, 2, 1)
  int range = 5;            ///< offsets considered, in segments either way
  int context = 5;          ///< further segments either way seen by every offset
  double slope = 0.6;       ///< slope of the smoothed step, in segments
  double amplitude = 0.43;  ///< of the smoothed step (below 0.5: a wrong pixel never zeroes it)
};

/// The contour's offset along one line: posterior mean and variance (pixels, along `normal`
/// from `pixel`), and how much the inner side looks like the object.
struct LineEstimate {
  double mean_px = 0.0;
  double variance_px2 = 0.0;
  /// Mean foreground probability of the line's pixels more than 2 pixels inside the projected
  /// contour: low where something else (an occluder) covers the object there.
  double inner_foreground = 0.0;
  /// Mean background probability of its pixels more than 2 pixels outside the projected one.
  double outer_background = 0.0;
  bool valid = false;  ///< false when the line leaves the image
};
LineEstimate estimate_line(const cv::Mat& bgr, const ColourModel& model, const ContourPoint& c,
                           const LineOptions& options);

/// Pixels `from_px` to `to_px` along the line (negative: inside), for histogram updates.
void line_pixels(const cv::Mat& bgr, const ContourPoint& c, int from_px, int to_px,
                 std::vector<cv::Vec3b>& out);

/// Fraction of the pixels `from_px` to `to_px` along the line that are non-zero in `mask`
/// (8-bit, the image's size).
double line_fraction(const cv::Mat& mask, const ContourPoint& c, int from_px, int to_px);

}  // namespace pbve::track_detail
