#pragma once
/// @file
/// Synthetic input clips: a procedurally textured object moved in front of a static camera and
/// a textured background, with its pose file and a ready-to-run scene file. Used by the
/// examples and the end-to-end tests (`pbve synth`).

#include <filesystem>
#include <functional>
#include <string>
#include <vector>

#include <opencv2/core.hpp>

#include "pbve/core/camera.hpp"
#include "pbve/core/mesh.hpp"
#include "pbve/core/pose.hpp"

namespace pbve {

/// A closed box [-w/2, w/2] x [0, h] x [-t/2, t/2] (metres) with 8 vertices and 12 triangles,
/// the paper's board: its top edge lies at y = 0 (the camera's y axis points down).
Mesh make_box_mesh(double width, double height, double thickness);
/// An icosphere of `radius` about the origin, `subdivisions` times 4-split (20 * 4^s faces).
Mesh make_icosphere(double radius, int subdivisions);
/// A closed character-like figurine standing on y = 0 and extending up to y = -height (the
/// camera's y axis points down): a surface of revolution with a round belly and a head above a
/// neck, its front bulged along -z (towards a camera on -z of it). The profile is cut into
/// `rings` bands from the feet to the head: rings - 1 rings of `segments` vertices between two
/// poles, 2 + (rings - 1) x segments vertices and 2 x (rings - 1) x segments triangles. Throws
/// InputError for rings < 2 or segments < 3 (no closed surface), a height that is not positive
/// and finite, or more triangles than int indices hold.
Mesh make_figurine(double height, int rings = 48, int segments = 48);

/// Colour (BGR, 0..255) of the object's surface at a mesh-space point with a mesh-space normal.
using SurfaceTexture =
    std::function<cv::Vec3f(const Eigen::Vector3d& point, const Eigen::Vector3d& normal)>;

/// A colourful procedural texture (stripes, dots and a gradient) at the given scale (metres per
/// pattern period), distinct on every side of the object.
SurfaceTexture procedural_texture(double period);

/// A textured background (gradients, shapes and text-like marks), deterministic in `seed`.
/// Throws InputError for an empty size.
cv::Mat make_background(cv::Size size, unsigned seed = 1);

/// Renders `mesh` (mesh coordinates) at `pose` over `background` (8-bit BGR, the camera's
/// size), with Lambert shading from a light at the camera, `supersample` x `supersample` samples
/// per pixel. 8-bit BGR. Throws InputError for another background, supersample < 1
/// or no texture.
cv::Mat render_object(const Mesh& mesh, const Pose& pose, const Camera& camera,
                      const SurfaceTexture& texture, const cv::Mat& background,
                      int supersample = 3);

/// What `pbve synth` makes.
struct SynthOptions {
  std::string shape = "board";   ///< board | figurine | ball | statue (Bullet, fractured)
  std::string motion = "swing";  ///< swing | wave | stop | push | bounce | orbit | still
  /// Engine of the scene file: empty for the shape's own (mass_spring, the statue bullet), or
  /// mass_spring | bullet. With bullet, soft bodies get one control acceleration per cluster
  /// (control.clusters: 16: Bullet has no derivatives, so gradients are central differences),
  /// and the board Bullet cloth settings that follow its swing (docs/examples.md).
  std::string engine;
  int frames = 90;
  double fps = 30.0;
  /// Peak turn of the swing (yaw about the held edge, default 80) or stop (yaw during the move,
  /// default 20) motions, degrees; 0 = the motion's default.
  double amplitude_deg = 0.0;
  /// Turns per second of the swing motion (default 0.9); 0 = the default.
  double frequency_hz = 0.0;
  int width = 640;
  int height = 480;
  int supersample = 3;
  std::filesystem::path background;  ///< background image (resized), or empty for generated
  bool single_image = false;         ///< write one picture (frame 0) instead of a video
  /// A hand-like occluder passes in front of the object mid-clip, covering up to about a third
  /// of it (for tracking tests). It is not in the scene: edits would show it as texture.
  bool occluder = false;
  std::string video_name = "clip.mp4";
};

/// Files written by synthesize().
struct SynthOutput {
  std::filesystem::path video;  ///< the clip (or the picture in single-image mode)
  std::filesystem::path mesh;   ///< object.obj
  std::filesystem::path poses;  ///< poses.txt
  std::filesystem::path scene;  ///< scene.yaml (edit it, then `pbve edit` it)
  std::filesystem::path plate;  ///< the true background, plate_true.png (for checks)
  Camera camera;
  PoseTrack track;
  Mesh mesh_data;
};

/// The object mesh, the poses and the scene settings of a synthetic clip, without rendering.
struct SynthRecipe {
  Mesh mesh;
  PoseTrack track;
  Camera camera;
  std::string scene_yaml;  ///< scene file text, with file names relative to the output folder
};
SynthRecipe synth_recipe(const SynthOptions& options);

/// Writes the clip, mesh, poses, plate and scene file into `out_dir` (created if missing).
/// Throws InputError for unknown shapes or motions and unwritable folders.
SynthOutput synthesize(const SynthOptions& options, const std::filesystem::path& out_dir);

}  // namespace pbve
