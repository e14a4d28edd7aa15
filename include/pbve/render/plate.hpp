#pragma once
/// @file
/// The background plate: what the scene looks like without the object (paper section 4.1).
///
/// For a static camera the plate is estimated automatically: for every pixel, the temporal
/// median of its colour over the frames in which neither the object (the aligned mesh enlarged
/// by `scale` and dilated) nor an extra mask covers it; pixels that are never uncovered are
/// inpainted (cv::inpaint, Telea). A single image is the special case where nothing is ever
/// uncovered: the plate is the image with the object inpainted.
///
/// Memory: frames are read one at a time (sequentially). For the median every pixel keeps a
/// uniform random subset (reservoir sample) of at most samples_per_pixel of its background
/// colours, i.e. samples_per_pixel x width x height x 3 bytes (24 samples at 1280x720: 66 MB),
/// whatever the clip length. At most max_frames frames are read, evenly spread over the clip.

#include <filesystem>
#include <functional>
#include <optional>
#include <string>

#include <opencv2/core.hpp>

#include "pbve/core/camera.hpp"
#include "pbve/core/footage.hpp"
#include "pbve/core/mesh.hpp"
#include "pbve/core/pose.hpp"

namespace pbve {

/// Settings of estimate_plate().
struct PlateOptions {
  /// Enlargement of the mesh about its surface centroid (as RenderOptions::scale).
  double scale = 1.01;
  /// Dilation of the object's silhouette, pixels (>= 0): covers motion blur, the partly covered
  /// edge pixels and small pose errors.
  int dilate_px = 4;
  /// Background colours kept per pixel for the median (1..255).
  int samples_per_pixel = 24;
  /// Frames read at most (>= 1); with more frames in the clip every k-th frame is read,
  /// k = ceil(frame_count / max_frames).
  int max_frames = 150;
  /// Radius of the inpainting neighbourhood, pixels.
  double inpaint_radius_px = 5.0;
  /// Optional extra mask per frame index (CV_8U of camera size, non-zero = not background,
  /// e.g. the hand holding the object); an empty Mat means no extra mask for that frame.
  std::function<cv::Mat(int frame)> extra_mask;
};

/// An estimated background plate.
struct BackgroundPlate {
  cv::Mat image;        ///< CV_8UC3 BGR, camera size
  cv::Mat observed;     ///< CV_8U, 255 where at least one read frame showed the background
  cv::Mat inpainted;    ///< CV_8U, 255 where the plate was inpainted (never uncovered)
  int frames_used = 0;  ///< frames read (frames with a lost pose are skipped)
};

/// Estimates the plate of a static-camera clip.
///
/// @param frame_count  number of frames
/// @param frame        returns frame i (CV_8UC3 BGR, camera size); called with increasing i
/// @param poses        one pose per frame (mesh -> camera); frames whose pose is lost are
///                     skipped (where the object is there is unknown)
/// @param mesh         the object (triangles and vertices in mesh coordinates)
/// @param camera       intrinsics and image size
/// Throws InputError when the pose track is shorter than the clip, a frame or mask has the
/// wrong size or type, or no frame has a pose.
BackgroundPlate estimate_plate(int frame_count, const std::function<cv::Mat(int)>& frame,
                               const PoseTrack& poses, const Mesh& mesh, const Camera& camera,
                               const PlateOptions& options = {});

/// estimate_plate() over footage (read in frame order).
BackgroundPlate estimate_plate(Footage& footage, const PoseTrack& poses, const Mesh& mesh,
                               const Camera& camera, const PlateOptions& options = {});

/// A plate for a single image: `image` with the pixels where `remove` is non-zero inpainted.
BackgroundPlate inpaint_plate(const cv::Mat& image, const cv::Mat& remove,
                              double inpaint_radius_px = 5.0);

/// A plate given as an image file. Throws InputError naming the file when it cannot be read
/// or its size differs from `size`.
cv::Mat load_plate(const std::filesystem::path& path, cv::Size size);

/// Per-frame masks stored as images named by a printf pattern (`background.remove`, e.g.
/// "masks/%04d.png"): non-zero = remove. Frame i reads the file of index first_index + i.
class MaskSequence {
 public:
  /// @param pattern      printf pattern with one integer conversion
  /// @param size         expected mask size (the camera's)
  /// @param first_index  index of frame 0's file; -1: the first existing of 0 and 1
  /// Throws InputError when the pattern is malformed or (first_index = -1) neither file exists.
  MaskSequence(std::string pattern, cv::Size size, int first_index = -1);
  /// The mask of frame `frame` as CV_8U 0/255; an empty Mat when the file does not exist.
  /// Throws InputError naming the file when it exists but cannot be read or has another size.
  cv::Mat mask(int frame) const;
  /// The file name of frame `frame`.
  std::string path(int frame) const;
  int first_index() const { return m_first; }

 private:
  std::string m_pattern;
  cv::Size m_size;
  int m_first = 0;
};

}  // namespace pbve
