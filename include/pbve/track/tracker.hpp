#pragma once
/// @file
/// Model-based pose tracking (the preprocessing the paper assumes): the pose of a known mesh
/// in every frame of footage from a static camera, given its pose in the first frame.
///
/// Each frame's pose minimizes a joint cost, by Gauss-Newton from the corners' RANSAC pose,
/// coarse to fine (docs/tracking.md has the details and the measured accuracy):
/// - corners: keyframe corners with their 3-D points on the mesh (a ray cast through the pose
///   that found them), followed by pyramidal Lucas-Kanade from the keyframe's view warped to
///   the predicted pose (constant velocity) through the mesh, kept when tracking back lands
///   within a pixel; their reprojection errors (Huber);
/// - silhouette: along correspondence lines normal to the projected outer contour, the
///   posterior of where the image contour lies from foreground/background colour histograms
///   (region-based, after PWP3D / RBOT / SRT3D), each line weighted by its inverse variance.
///
/// Occluders (a hand): pixels where the frame differs from the warped keyframe view, and lines
/// whose inner side does not look like the object, are left out; the colour statistics learn
/// only colours the other side does not claim; no keyframe is taken while the silhouette
/// agrees poorly. A frame whose silhouette agreement is too low is `lost`; ORB descriptors of
/// the keyframes then search the frame near the last pose (re-detection). Keyframes are kept,
/// and a view seen before is followed from the one nearest to the first keyframe.

#include <filesystem>
#include <functional>
#include <memory>
#include <optional>
#include <vector>

#include <Eigen/Core>
#include <opencv2/core.hpp>

#include "pbve/core/camera.hpp"
#include "pbve/core/footage.hpp"
#include "pbve/core/mesh.hpp"
#include "pbve/core/pose.hpp"

namespace pbve {

/// Tracker settings (pixels refer to the footage's resolution).
struct TrackOptions {
  int max_corners = 300;           ///< corners detected per keyframe / frame
  double corner_quality = 0.01;    ///< Shi-Tomasi quality level, relative to the best corner
  double corner_distance = 7.0;    ///< minimum distance between corners, pixels
  int window = 15;                 ///< Lucas-Kanade window, pixels (corners stay half a window
                                   ///< inside the silhouette)
  int pyramid_levels = 3;          ///< Lucas-Kanade pyramid levels above the full image
  double back_track_px = 1.0;      ///< forward-backward check tolerance, pixels
  double ransac_px = 2.0;          ///< RANSAC inlier reprojection threshold, pixels
  int min_inliers = 12;            ///< fewer inliers: the frame is lost
  double keyframe_angle_deg = 20;  ///< rotation since the keyframe that triggers a new one
  double keyframe_keep = 0.5;      ///< new keyframe when fewer than this fraction survive
  /// Follow keyframe corners from the keyframe's view warped to the predicted pose through the
  /// mesh (else from the keyframe image itself).
  bool warp_keyframe = true;

  // Silhouette (region) term.
  bool region = true;  ///< refine every pose with the silhouette term (else corners only)
  /// Pixels per correspondence-line segment, coarse to fine; each scale searches the contour
  /// within 5 segments either way.
  std::vector<int> region_scales = {4, 2, 1};
  int region_iterations = 2;        ///< Gauss-Newton iterations per scale
  int contour_points = 200;         ///< at most this many correspondence lines
  double contour_spacing_px = 3.0;  ///< at least this far apart along the contour
  double region_weight = 0.5;       ///< of a line (inverse variance, pixels^-2) vs. a corner
  double feature_sigma_px = 1.0;    ///< corner reprojection noise, pixels
  int colour_band_px = 15;          ///< colour statistics from this far either side of the contour
  double colour_rate = 0.1;         ///< weight of a frame's colours in the running statistics
  /// A line whose pixels inside the contour look less like the object than this (mean
  /// foreground probability) is covered by something else and left out.
  double occlusion_threshold = 0.5;
  double colour_update_threshold = 0.65;  ///< object colours only from lines above this
  /// Occlusion map: the sum over B, G, R of the difference between the frame and the
  /// keyframe's view of the object warped to the predicted pose (both blurred) above which a
  /// pixel is covered by something else (0: no map). Corners landing there and lines whose
  /// inner half lies there by more than occluded_line_fraction are left out.
  double occlusion_colour_difference = 90.0;
  double occluded_line_fraction = 0.3;
  double colour_update_agreement = 0.5;  ///< statistics updated only at this agreement or more
  double keyframe_agreement = 0.65;      ///< new keyframes only at this agreement or more
  /// The frame is lost below this silhouette agreement, or below region_only_agreement when
  /// the corners give no pose.
  double lost_agreement = 0.2;
  double region_only_agreement = 0.5;
  bool redetect = true;  ///< after a loss, search the whole frame for keyframe descriptors (ORB)
  /// track_footage() tracks frames [0, end_frame) only (the frames an edit needs); -1: the
  /// whole clip.
  int end_frame = -1;
};

/// What happened in one frame.
struct TrackFrameInfo {
  bool lost = false;          ///< no pose could be trusted
  int correspondences = 0;    ///< 2-D/3-D pairs offered to PnP
  int inliers = 0;            ///< RANSAC inliers
  double rms_px = 0.0;        ///< RMS reprojection error of the inliers, pixels
  bool new_keyframe = false;  ///< this frame became the keyframe
  bool in_view = true;        ///< the predicted object overlaps the image
  /// Silhouette agreement: the fraction of the contour's correspondence lines (in the image)
  /// whose colours show the object inside and the background outside within 2 pixels of the
  /// projected contour (1 without the region term).
  double agreement = 0.0;
  bool relocalized = false;  ///< found again by re-detection after a loss
};

/// Frame-by-frame pose tracker. Not thread-safe; one instance per clip.
class PoseTracker {
 public:
  /// `mesh` in its own coordinates (same length unit as the poses), `camera` the footage's
  /// intrinsics (width and height included). Throws InputError for an empty mesh or an invalid
  /// camera.
  PoseTracker(const Mesh& mesh, const Camera& camera, TrackOptions options = {});
  ~PoseTracker();
  PoseTracker(const PoseTracker&) = delete;
  PoseTracker& operator=(const PoseTracker&) = delete;

  /// Starts on `frame` (8-bit grey, BGR or BGRA, the camera's size) where the object has `pose`:
  /// it becomes the first keyframe. Throws InputError for a frame of another size or type, a
  /// pose that is not finite, or when the object shows too few trackable corners there.
  void start(const cv::Mat& frame, const Pose& pose);
  /// The pose in the next frame, or std::nullopt when lost. start() first. Throws InputError
  /// for a frame of another size or type than start() takes.
  std::optional<Pose> track(const cv::Mat& frame, TrackFrameInfo* info = nullptr);

 private:
  struct Impl;
  std::unique_ptr<Impl> m_impl;
  void start_checked(const cv::Mat& frame, const Pose& pose);
  std::optional<Pose> track_checked(const cv::Mat& frame, TrackFrameInfo* info);
};

/// Poses of a whole clip.
struct TrackResult {
  PoseTrack track;                     ///< one per frame, std::nullopt where lost
  std::vector<TrackFrameInfo> frames;  ///< one per frame (frame 0: the initial pose)
  double track_ms_per_frame = 0.0;     ///< mean tracking time per frame, without decoding
  /// First frame of a final run of lost frames in which the object was predicted outside the
  /// image (it left the view for good); -1 when it did not.
  int left_view_at = -1;
};

/// Called after every frame with its index, the frame, its pose (or nullopt) and its info.
using TrackFrameCallback =
    std::function<void(int, const cv::Mat&, const std::optional<Pose>&, const TrackFrameInfo&)>;

/// Tracks `mesh` through every frame of `footage` (up to options.end_frame) from `initial`, the
/// pose in frame 0.
TrackResult track_footage(Footage& footage, const Mesh& mesh, const Camera& camera,
                          const Pose& initial, const TrackOptions& options = {},
                          const TrackFrameCallback& on_frame = {});

/// The pose that maps `mesh_points` (mesh coordinates) onto `pixels` with `camera`
/// (perspective-n-point, at least 4 pairs, iterative refinement). Throws InputError for fewer
/// than 4 pairs, mismatched sizes, an invalid camera, a coordinate that is not finite (naming
/// the pair), mesh points that are all one point or on one line (the rotation about it is
/// undetermined), a configuration the solver refuses, or a solution with RMS reprojection error
/// above `max_rms_px` (the message gives it) or with the object behind the camera.
Pose pose_from_correspondences(const std::vector<Eigen::Vector3d>& mesh_points,
                               const std::vector<Eigen::Vector2d>& pixels, const Camera& camera,
                               double max_rms_px = 5.0);

/// The pose in frame 0 from a correspondence file: one pair per line, `VERTEX u v` (a mesh
/// vertex index and the pixel where it appears) or `x y z u v` (a point in mesh coordinates and
/// its pixel); `#` starts a comment. Solved by pose_from_correspondences(). Throws InputError
/// naming the file (and the line, for a bad line).
Pose pose_from_correspondence_file(const std::filesystem::path& path, const Mesh& mesh,
                                   const Camera& camera, double max_rms_px = 5.0);

/// Draws the mesh's silhouette and crease edges (dihedral angle above `crease_deg`) of the
/// faces turned towards the camera, projected with `pose`, on `image` (BGR, the camera's size).
void draw_mesh_edges(cv::Mat& image, const Mesh& mesh, const Camera& camera, const Pose& pose,
                     const cv::Scalar& color = cv::Scalar(0, 255, 0), double crease_deg = 30.0);

/// Reprojection error between two poses of `mesh` in one frame: the mean over vertices of the
/// pixel distance between their projections (vertices behind the camera are skipped;
/// +infinity when none is in front of it).
double reprojection_error_px(const Mesh& mesh, const Camera& camera, const Pose& a, const Pose& b);

}  // namespace pbve
