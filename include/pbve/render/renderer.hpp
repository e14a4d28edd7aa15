#pragma once
/// @file
/// Texturing the simulated mesh from the current input frame, the fail-safe fill, and
/// compositing over the background plate (paper sections 3.3 and 4.1).
///
/// Per output frame t:
///  1. The pixels of the original object — those whose centre sees the aligned mesh enlarged by
///     RenderOptions::scale about its centroid, dilated by dilate_px — and the pixels of an
///     optional extra mask are replaced by the background plate. (The enlarged mesh is not
///     cast: the aligned silhouette is dilated by the largest projected displacement that the
///     enlargement gives a vertex, plus 0.75 px, which contains the enlarged silhouette.)
///  2. Primary rays through the pixel centres find the first hit (triangle j, barycentrics) on
///     the simulated mesh. Pixels at silhouette and occlusion edges are re-sampled with
///     supersample x supersample sub-pixel rays: their matte is the fraction of sub-samples that
///     hit, their colour the mean colour of those sub-samples (so edges are antialiased without
///     a dark fringe).
///  3. A hit on an observed triangle (v_j = 1) takes its colour from the same barycentric point
///     of triangle j on the aligned mesh, projected into input frame t and bilinearly sampled.
///     With the fail-safe on, a bilinear tap is only used when the input pixel there shows that
///     very surface point (the aligned mesh's first hit through the tap's pixel centre is
///     triangle j, or lies within depth_tolerance of the point's depth) and is not in the extra
///     mask: texture never comes from the background, from a part of the object in front of
///     the point, or from a masked occluder such as the hand holding the object.
///  4. Unobserved triangles (v_j = 0), and samples whose taps were all rejected, get the
///     fail-safe colour: per-vertex colours sampled on the observed triangles and propagated
///     over the mesh graph (fill_vertex_colors), interpolated barycentrically. Interior
///     triangles (Mesh::interior) get one uniform colour.
///  5. output = matte * object colour + (1 - matte) * (input with the removed pixels taken from
///     the plate).

#include <cstdint>
#include <memory>
#include <optional>
#include <vector>

#include <opencv2/core.hpp>

#include "pbve/core/camera.hpp"
#include "pbve/core/mesh.hpp"
#include "pbve/visibility/ray_scene.hpp"
#include "pbve/visibility/visibility.hpp"

namespace pbve {

/// Settings of Renderer.
struct RenderOptions {
  /// Sub-samples per pixel along each axis at edge pixels (1..8). An odd value reuses the
  /// pixel-centre ray as the middle sub-sample.
  int supersample = 3;
  /// Enlargement of the aligned mesh about its area-weighted surface centroid when deciding
  /// which input pixels belong to the original object (paper 4.1: 1.01). Pass 1 when the
  /// aligned vertices given to render() are already enlarged.
  double scale = 1.01;
  /// Dilation of the removal mask, pixels (>= 0); at least 1 is needed to remove the pixels
  /// that the original object covers only partly (their centres miss it).
  int dilate_px = 2;
  /// Fail-safe: fill unobserved triangles from the observed surface and reject bilinear taps
  /// that do not show the sampled surface point. When false every triangle is textured from
  /// its projection, wherever that lands (for comparisons only).
  bool fail_safe = true;
  /// Relative depth tolerance of the tap test: a tap showing another triangle is accepted when
  /// |depth_tap - depth_point| <= depth_tolerance * depth_point (covers the depth change of a
  /// sloped surface over one pixel).
  double depth_tolerance = 0.02;
  /// Relative depth jump between neighbouring pixel centres above which a pixel counts as an
  /// occlusion edge and is supersampled.
  double edge_depth_jump = 0.05;
  /// Uniform colour of interior triangles, BGR 0..255. Unset: interior_shade times the mean
  /// colour of the object in the input frame.
  std::optional<cv::Vec3f> interior_color;
  /// Factor applied to the object's mean colour for the default interior colour (0..1).
  double interior_shade = 0.8;
  /// Gauss-Seidel sweeps that smooth the propagated fail-safe vertex colours (>= 0).
  int fill_smoothing_sweeps = 10;
  /// Visibility settings used by the render() overload that computes v_j itself.
  VisibilityOptions visibility = {};
};

/// What the last render() did.
struct RenderStats {
  std::int64_t covered_pixels = 0;    ///< pixels with matte > 0
  std::int64_t edge_pixels = 0;       ///< pixels that were supersampled
  std::int64_t fallback_samples = 0;  ///< samples coloured by the fail-safe fill (incl. rejected)
  std::int64_t rejected_samples = 0;  ///< samples on observed triangles whose taps were rejected
  int unobserved_triangles = 0;       ///< non-interior triangles with v_j = 0
  int filled_vertices = 0;            ///< vertices whose colour was propagated
  std::int64_t removed_pixels = 0;    ///< pixels replaced by the plate
  cv::Vec3f object_mean_color = {0, 0, 0};  ///< BGR mean of the input over the aligned object
  cv::Vec3f interior_color = {0, 0, 0};     ///< colour used for interior triangles
};

/// Renders output frames: the simulated mesh textured from the input frame over the plate.
///
/// Holds three ray scenes (aligned, enlarged aligned, simulated) that are refitted every frame,
/// and per-frame buffers that are reused, so one Renderer should serve a whole clip. Not
/// thread-safe (one render() at a time); render() itself runs in parallel (TBB).
class Renderer {
 public:
  /// @param mesh     the object's topology (triangles, interior flags); positions unused
  /// @param camera   intrinsics and image size of the footage (validated)
  /// @param options  see RenderOptions (validated; InputError for out-of-range values)
  Renderer(const Mesh& mesh, const Camera& camera, RenderOptions options = {});
  ~Renderer();
  Renderer(Renderer&&) noexcept;
  Renderer& operator=(Renderer&&) noexcept;
  Renderer(const Renderer&) = delete;
  Renderer& operator=(const Renderer&) = delete;

  /// Renders output frame t.
  ///
  /// @param input_frame        input frame t, 8-bit BGR, camera size
  /// @param aligned_cam        #V by 3, the mesh in input pose t (pose_t applied to the mesh
  ///                           vertices), camera frame, mesh units
  /// @param simulated_cam      #V by 3, the simulated mesh at frame t, camera frame
  /// @param observed_in_input  #F, v_j: 1 where triangle j is visible in input frame t (e.g.
  ///                           compute_visibility(...).visible for aligned_cam)
  /// @param plate              background plate, 8-bit BGR, camera size
  /// @param extra_mask         empty, or 8-bit single channel of camera size: non-zero pixels
  ///                           (e.g. the hand holding the object) are replaced by the plate
  ///                           and, with the fail-safe on, never used as texture
  /// @param output             the edited frame, 8-bit BGR, camera size (reallocated only when
  ///                           its size or type differ)
  /// Throws InputError on a size or type mismatch.
  void render(const cv::Mat& input_frame, const Vertices& aligned_cam,
              const Vertices& simulated_cam, const std::vector<std::uint8_t>& observed_in_input,
              const cv::Mat& plate, const cv::Mat& extra_mask, cv::Mat& output);

  /// As above, returning a new image.
  cv::Mat render(const cv::Mat& input_frame, const Vertices& aligned_cam,
                 const Vertices& simulated_cam, const std::vector<std::uint8_t>& observed_in_input,
                 const cv::Mat& plate, const cv::Mat& extra_mask = {});

  /// As above with v_j computed from aligned_cam (compute_visibility with options.visibility).
  cv::Mat render(const cv::Mat& input_frame, const Vertices& aligned_cam,
                 const Vertices& simulated_cam, const cv::Mat& plate,
                 const cv::Mat& extra_mask = {});

  /// Colour of the simulated object in the last frame, CV_32FC3 BGR 0..255 (not multiplied by
  /// the matte), camera size; meaningful where matte() > 0.
  const cv::Mat& foreground() const;
  /// Coverage of the simulated object in the last frame, CV_32F in [0, 1], camera size.
  const cv::Mat& matte() const;
  /// Pixels replaced by the plate in the last frame, CV_8U 0/255, camera size (contains
  /// silhouette_mask(aligned, scale, dilate_px) and the extra mask).
  const cv::Mat& removal_mask() const;
  /// Counters of the last frame.
  const RenderStats& stats() const;
  const RenderOptions& options() const;
  const Camera& camera() const;

 private:
  struct Impl;
  std::unique_ptr<Impl> m_impl;
};

/// Pixel rectangle [x0, x1) x [y0, y1) of the camera image that contains the projection of
/// `cam_vertices` (camera frame) grown by `margin_px` on each side; the whole image when a
/// vertex lies at or behind the camera plane (z <= 0); empty when everything projects outside.
cv::Rect projected_bounds(const Vertices& cam_vertices, const Camera& camera, int margin_px);

/// Area-weighted centroid of the surface (#V by 3 positions, same units); the vertex mean when
/// the total area is zero.
Eigen::Vector3d surface_centroid(const Vertices& vertices, const Triangles& triangles);

/// The object's pixels: CV_8U mask of camera size, 255 where the ray through the pixel centre
/// hits the mesh `cam_vertices` (camera frame) enlarged by `scale` about its surface centroid,
/// then dilated by `dilate_px` pixels (elliptic structuring element of diameter
/// 2 dilate_px + 1). `scene` must hold the mesh's triangles; it is refitted to the enlarged
/// positions. `mask` is reallocated only when its size or type differ.
void silhouette_mask(RayScene& scene, const Vertices& cam_vertices, const Camera& camera,
                     double scale, int dilate_px, cv::Mat& mask);

/// One-call form of silhouette_mask() (builds a ray scene).
cv::Mat silhouette_mask(const Triangles& triangles, const Vertices& cam_vertices,
                        const Camera& camera, double scale = 1.01, int dilate_px = 0);

}  // namespace pbve
