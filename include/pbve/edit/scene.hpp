#pragma once
/// @file
/// The scene file (YAML): what to edit and how. The format is in docs/formats.md.
///
/// Relative paths are resolved against the scene file's folder. Unknown keys are an error
/// that names the key, its line, and the nearest valid key.

#include <filesystem>
#include <map>
#include <optional>
#include <string>
#include <vector>

#include <Eigen/Core>

#include "pbve/control/optimizer.hpp"
#include "pbve/core/error.hpp"

namespace pbve {

/// `input:` — the footage.
struct SceneInput {
  std::filesystem::path video;  ///< a video file, or empty
  std::filesystem::path image;  ///< a single picture, or empty
  std::string sequence;         ///< an image-sequence pattern ("frames/%04d.png"), or empty
  int frames = 0;               ///< frame count for a single picture
  double fps = 30.0;            ///< for a single picture or a sequence
};

/// `object.anchors:` — vertices that follow the footage.
struct SceneAnchors {
  std::vector<int> vertices;               ///< mesh vertex ids
  std::optional<Eigen::Vector3d> box_min;  ///< box in mesh coordinates (with box_max)
  std::optional<Eigen::Vector3d> box_max;
};

/// `object:` — the mesh and its poses.
struct SceneObject {
  std::filesystem::path mesh;
  std::filesystem::path poses;  ///< pose file (a single pose for a single picture)
  /// `poses: track`: the poses come from pbve::track_footage() run on the footage first, from
  /// `initial_pose` (a pose file whose first pose is frame 0's) or `correspondences` (a
  /// correspondence file, pbve::pose_from_correspondence_file()); the tracked poses are written
  /// to `tracked_poses` (default: the output video's name with `.poses.txt`).
  bool track = false;
  std::filesystem::path initial_pose;
  std::filesystem::path correspondences;
  std::filesystem::path tracked_poses;
  double scale = 1.01;  ///< enlargement covering silhouette errors (paper 4.1)
  double refine = 0.0;  ///< split edges longer than this (mesh units); 0 = off
  /// `fracture: {pieces: N, seed: S}`: cut the (convex) mesh into N Voronoi pieces before
  /// refining (pbve::voronoi_fracture); 0 = off.
  int fracture_pieces = 0;
  int fracture_seed = 1;
  SceneAnchors anchors;
};

/// `background:` — the plate.
struct SceneBackground {
  std::filesystem::path plate;  ///< a given plate image; empty = automatic
  std::string remove;  ///< optional masks pattern ("masks/%04d.png") of extra regions to fill
};

/// A collision plane in camera coordinates.
struct ScenePlane {
  Eigen::Vector3d point = Eigen::Vector3d::Zero();
  Eigen::Vector3d normal = Eigen::Vector3d(0, -1, 0);
  double friction = 0.5;
};

/// `simulation.regions:` entry — a box of the object (mesh coordinates) with its own material
/// parameters, e.g. a soft belly: `{box: {min: [..], max: [..]}, volume_stiffness: 30000}`.
struct SceneRegion {
  Eigen::Vector3d box_min = Eigen::Vector3d::Zero();
  Eigen::Vector3d box_max = Eigen::Vector3d::Zero();
  /// Parameter name -> value and line, checked by the engine.
  std::map<std::string, std::pair<double, int>> parameters;
  int line = 0;  ///< line of the entry
};

/// `simulation:` — the new physics.
struct SceneSimulation {
  /// mass_spring | bullet (built in, pbve::make_engine()), or the name of a program's own
  /// adapter, which its EditCallbacks::make_simulator selects.
  std::string engine = "mass_spring";
  std::string material = "cloth";                         ///< cloth | elastic | stiff | rigid
  Eigen::Vector3d gravity = Eigen::Vector3d(0, 9.81, 0);  ///< m/s^2, camera frame
  std::optional<ScenePlane> ground;
  std::vector<ScenePlane> planes;  ///< extra collision planes
  int substeps = 10;
  std::vector<SceneRegion> regions;  ///< parts with their own material parameters
  /// Any other numeric key: a material parameter override, checked by the engine
  /// (key -> value and the line it was given on, for messages).
  std::map<std::string, std::pair<double, int>> parameters;
};

/// `control:` — the optimizer.
struct SceneControl {
  bool enabled = true;
  double weight_visibility = 1.0;
  double weight_force = 0.001;
  double weight_temporal = 0.001;
  int window = 1;
  std::string solver = "slsqp";     ///< slsqp | mma | lbfgs | cobyla | ipopt
  std::string gradient = "auto";    ///< auto | central | compressed | adjoint
  std::string active_set = "auto";  ///< auto | all
  int max_iterations = 200;         ///< objective evaluations (NLopt) / iterations (Ipopt)
  bool warm_start = false;          ///< start from the previous frame's forces (else zero)
  double margin = 0.05;             ///< facing margin of the smooth visibility term, in (0, 1)
  /// Bound on each control force component, in multiples of its vertex's (or body's) weight
  /// m g; 0 = unbounded.
  double force_bound = 0.0;
  /// Reduced control space: 0 = one force per active vertex; K > 0 = one acceleration per
  /// spatial cluster of at most K clusters (ControlOptions::clusters).
  int clusters = 0;
  /// Rings of vertex adjacency of compressed differences (ControlOptions::difference_rings).
  int difference_rings = 2;
  /// Search on the linearized dynamics (ControlOptions::linearized): on the engine's step
  /// linearizations, or on responses estimated by differences.
  bool linearized = true;
  /// Outer iterations of the linearized search (ControlOptions::max_linearizations).
  int max_linearizations = 4;
  /// Stop of the linearized search (ControlOptions::linearized_ftol_initial).
  double linearized_tolerance = 1e-3;
  /// Key -> line of every key given under `control:` (for messages about combinations).
  std::map<std::string, int> given;
};

/// `output:`.
struct SceneOutput {
  std::filesystem::path video;
  /// Empty when the scene gives none: the report is then named after the video the run writes
  /// (its name with .json; EditOptions::video's when that is set).
  std::filesystem::path report;
};

/// A parsed scene file with absolute paths.
struct Scene {
  std::filesystem::path file;  ///< the scene file itself
  SceneInput input;
  double fx = 0, fy = 0, cx = 0, cy = 0;  ///< `camera:` intrinsics, pixels
  SceneObject object;
  SceneBackground background;
  SceneSimulation simulation;
  SceneControl control;
  SceneOutput output;
  /// 1-based line of every key given in the file, by dotted name ("camera.cx",
  /// "simulation.density"), for messages about values checked after parsing.
  std::map<std::string, int> lines;

  /// Line of `key` (dotted name) in the file, or 0 when it was not given.
  int line_of(const std::string& key) const;
};

/// Parses a scene file. Throws InputError naming the file, the line and the key for YAML
/// syntax errors, unknown keys (with the nearest valid key), wrong types, missing required
/// keys (input, camera, object.mesh, object.poses, output.video) and out-of-range values
/// (for `control:`, those of control_options()).
Scene load_scene(const std::filesystem::path& path);

/// Parses scene text as if read from `path` (relative paths resolve against its folder).
Scene parse_scene(const std::string& text, const std::filesystem::path& path);

/// The control optimizer's options of the scene's `control:` section (what it does not set
/// keeps ControlOptions' defaults), checked by ControlOptions::validate(): an invalid value is
/// an InputError at the scene file's key that set it, with its line.
ControlOptions control_options(const Scene& scene);

/// An engine's InputError about this scene (its file, no line: a scene key such as
/// `simulation.material`, or a message naming `parameter NAME`) with the key's line added; any
/// other error as it is.
InputError engine_error_in_scene(const InputError& e, const Scene& scene);

/// The scene as YAML text (absolute paths), e.g. for the report's `settings`.
std::string scene_to_yaml(const Scene& scene);

/// Of `candidates`, the one nearest to `key` by edit distance (empty if none is close).
std::string nearest_key(const std::string& key, const std::vector<std::string>& candidates);

/// The keys of `simulation:` other than material parameters (engine, material, gravity,
/// ground, planes, regions, substeps).
extern const std::vector<std::string> kSimulationKeys;

}  // namespace pbve
