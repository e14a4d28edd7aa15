#include "pbve/edit/editor.hpp"

#include <algorithm>
#include <array>
#include <chrono>
#include <cmath>
#include <cstdio>
#include <map>
#include <optional>
#include <sstream>

#include <unistd.h>

#include <opencv2/imgcodecs.hpp>

#include "pbve/control/optimizer.hpp"
#include "pbve/core/camera.hpp"
#include "pbve/core/error.hpp"
#include "pbve/core/files.hpp"
#include "pbve/core/footage.hpp"
#include "pbve/core/fracture.hpp"
#include "pbve/core/mesh.hpp"
#include "pbve/core/pose.hpp"
#include "pbve/render/plate.hpp"
#include "pbve/render/renderer.hpp"
#include "pbve/track/tracker.hpp"
#include "pbve/visibility/metric.hpp"
#include "pbve/visibility/ray_scene.hpp"
#include "pbve/visibility/visibility.hpp"

namespace pbve {

namespace fs = std::filesystem;

namespace {

using Clock = std::chrono::steady_clock;

double ms_since(Clock::time_point t0) {
  return std::chrono::duration<double, std::milli>(Clock::now() - t0).count();
}

// A refinement beyond this many vertices is refused (about 60x example 1's finest benchmark
// mesh: hours per frame).
constexpr int kMaxRefinedVertices = 2000000;

std::string format_length(double metres) {
  char buf[64];
  std::snprintf(buf, sizeof buf, "%.3g m", metres);
  return buf;
}

double longest_edge(const Mesh& mesh, Eigen::Index t) {
  double longest = 0.0;
  for (int c = 0; c < 3; ++c)
    longest = std::max(longest, (mesh.vertices.row(mesh.triangles(t, c)) -
                                 mesh.vertices.row(mesh.triangles(t, (c + 1) % 3)))
                                    .norm());
  return longest;
}

/// An error about the scene key `key` (dotted name), at its line in the scene file.
InputError scene_error(const Scene& s, const std::string& key, const std::string& message) {
  return InputError(message, s.file, s.line_of(key), "key '" + key + "'");
}

/// Checks that an input file given by scene key `key` exists and can be read.
void check_input_file(const Scene& s, const fs::path& path, const std::string& key,
                      const std::string& what) {
  if (path.empty()) return;
  std::error_code ec;
  const fs::file_status st = fs::status(path, ec);
  if (!fs::exists(st)) throw scene_error(s, key, what + " not found: " + path.string());
  if (fs::is_directory(st))
    throw scene_error(s, key, what + " is a folder, not a file: " + path.string());
  if (::access(path.c_str(), R_OK) != 0)
    throw scene_error(s, key, what + " is not readable: " + path.string());
}

/// Checks that `out` (given by key `key` or the command line) is not an input and that its
/// folder exists and accepts new files (probed by creating the temporary name).
void check_output_path(const fs::path& out, const Scene& scene, const std::string& key,
                       bool from_scene) {
  auto fail = [&](const std::string& message) {
    if (from_scene) throw scene_error(scene, key, message);
    throw InputError(message, out);
  };
  const std::vector<fs::path> inputs = {scene.file,
                                        scene.input.video,
                                        scene.input.image,
                                        scene.object.mesh,
                                        scene.background.plate,
                                        scene.object.initial_pose,
                                        scene.object.correspondences};
  for (const fs::path& in : inputs)
    if (same_file(out, in)) fail("the output would overwrite the input file " + in.string());
  if (!scene.object.track && same_file(out, scene.object.poses))
    fail("the output would overwrite the input file " + scene.object.poses.string());
  for (const std::string& pattern : {scene.input.sequence, scene.background.remove})
    if (in_image_sequence(out, pattern))
      fail("the output would overwrite a file of the input sequence " + pattern);
  try {
    check_writable(out);
  } catch (const InputError& e) {
    fail(e.message());
  }
}

/// An error reading the file of scene key `key`, at the key's line, the file kept in the text.
InputError scene_error(const Scene& s, const std::string& key, const InputError& e) {
  return scene_error(s, key, (e.file().empty() ? "" : e.file().string() + ": ") + e.message());
}

/// The scene's footage; an error opening it names the input's key and line too.
Footage open_footage(const Scene& s) {
  const char* key = !s.input.video.empty()   ? "input.video"
                    : !s.input.image.empty() ? "input.image"
                                             : "input.sequence";
  try {
    if (!s.input.video.empty()) return Footage::open_video(s.input.video);
    if (!s.input.image.empty())
      return Footage::open_image(s.input.image, s.input.frames, s.input.fps);
    return Footage::open_sequence(s.input.sequence, s.input.fps);
  } catch (const InputError& e) {
    throw scene_error(s, key, e);
  }
}

std::vector<int> select_anchors(const Scene& s, const Mesh& mesh, int original_vertices,
                                std::vector<std::string>& warnings) {
  std::vector<int> ids;
  for (int v : s.object.anchors.vertices) {
    if (v >= original_vertices)
      throw scene_error(s, "object.anchors.vertices",
                        "anchor vertex " + std::to_string(v) + " is out of range (the mesh has " +
                            std::to_string(original_vertices) + " vertices, 0 to " +
                            std::to_string(original_vertices - 1) + ")");
    ids.push_back(v);
  }
  if (s.object.anchors.box_min) {
    const Eigen::RowVector3d lo = s.object.anchors.box_min->transpose();
    const Eigen::RowVector3d hi = s.object.anchors.box_max->transpose();
    int selected = 0;
    for (int v = 0; v < mesh.num_vertices(); ++v) {
      const Eigen::RowVector3d p = mesh.vertices.row(v);
      if ((p.array() >= lo.array()).all() && (p.array() <= hi.array()).all()) {
        ids.push_back(v);
        ++selected;
      }
    }
    if (selected == 0)
      warnings.push_back(
          format_location(s.file, s.line_of("object.anchors.box"), "key 'object.anchors.box'") +
          "selects no vertex of the mesh: the object is not held there");
  }
  std::sort(ids.begin(), ids.end());
  ids.erase(std::unique(ids.begin(), ids.end()), ids.end());
  if (ids.empty())
    warnings.push_back(
        "no anchor vertices: the object moves freely and does not follow the footage");
  return ids;
}

/// Factors of the scene's substeps a diverging frame is retried with, in order.
constexpr std::array<int, 2> kRetryFactors = {2, 4};

/// Detects a diverged simulation: non-finite positions or velocities, or a vertex that flew
/// away (farther from the rest shape's centre than 1000 times its size plus 1000 m).
class DivergenceCheck {
 public:
  explicit DivergenceCheck(const Vertices& rest)
      : m_centre(rest.colwise().mean()),
        m_limit(1000.0 * ((rest.colwise().maxCoeff() - rest.colwise().minCoeff()).norm() + 1.0)) {}
  /// Empty when the state is sound, else what is wrong.
  std::string operator()(const Simulator& sim) const {
    const Vertices x = sim.positions();
    if (!x.allFinite()) return "non-finite positions";
    if (!sim.velocities().allFinite()) return "non-finite velocities";
    if (x.rows() > 0 && ((x.rowwise() - m_centre).rowwise().norm().maxCoeff() > m_limit))
      return "a vertex flew away";
    return {};
  }

 private:
  Eigen::RowVector3d m_centre;
  double m_limit;
};

/// Steps `sim` over one frame in `factor` equal steps with `control` held constant and the
/// anchors interpolated linearly to the frame's targets (the equivalent of `factor` times the
/// substeps). Returns the physical force of the frame (mean over the steps of the sum over
/// free vertices), as the report counts it.
double step_subdivided(Simulator& sim, const Eigen::VectorXd& control,
                       const ControlFrameInput& frame, int factor) {
  const std::vector<int> anchors = sim.anchors();
  const Vertices x0 = sim.positions();
  Vertices a0(static_cast<Eigen::Index>(anchors.size()), 3);
  for (size_t i = 0; i < anchors.size(); ++i)
    a0.row(static_cast<Eigen::Index>(i)) = x0.row(anchors[i]);
  const bool move_anchors = frame.anchor_targets.rows() == a0.rows() && a0.rows() > 0;
  std::vector<char> anchored(static_cast<size_t>(sim.num_vertices()), 0);
  for (int a : anchors) anchored[static_cast<size_t>(a)] = 1;
  double physical = 0.0;
  for (int k = 1; k <= factor; ++k) {
    StepInput in;
    in.dt = frame.dt / factor;
    in.control = control;
    if (move_anchors) {
      const double s = static_cast<double>(k) / factor;
      in.anchor_targets = (1.0 - s) * a0 + s * frame.anchor_targets;
    }
    sim.step(in);
    const Eigen::VectorXd f = checked_force_magnitudes(sim);
    for (Eigen::Index v = 0; v < f.size(); ++v)
      if (!anchored[static_cast<size_t>(v)]) physical += f[v];
  }
  return physical / factor;
}

}  // namespace

EditResult run_edit(const Scene& scene, const EditOptions& options, const EditCallbacks& cb) {
  if (!cb.make_simulator)
    throw std::invalid_argument("run_edit: EditCallbacks::make_simulator is required");
  EditResult result;
  Report& report = result.report;
  result.video = options.video.empty() ? scene.output.video : options.video;
  // The report: as given on the command line, else as the scene gives it, else named after the
  // video written (the command line's, when given; errors about that name are not the scene's).
  const bool report_from_option_video =
      options.report.empty() && scene.output.report.empty() && !options.video.empty();
  result.report_path = !options.report.empty() ? options.report
                       : !scene.output.report.empty()
                           ? scene.output.report
                           : fs::path(result.video).replace_extension(".json");
  // ---- checks before any work: inputs readable, outputs writable and not inputs ----------
  check_input_file(scene, scene.input.video, "input.video", "video file");
  check_input_file(scene, scene.input.image, "input.image", "image file");
  check_input_file(scene, scene.object.mesh, "object.mesh", "mesh file");
  fs::path tracked_poses;  // with `poses: track`: where the tracked poses go
  if (scene.object.track) {
    check_input_file(scene, scene.object.initial_pose, "object.initial_pose", "initial pose file");
    check_input_file(scene, scene.object.correspondences, "object.correspondences",
                     "correspondence file");
    if (!scene.input.image.empty())
      throw scene_error(scene, "object.poses",
                        "'poses: track' needs a video or an image sequence, not a single picture");
    tracked_poses = scene.object.tracked_poses.empty()
                        ? fs::path(result.video).replace_extension(".poses.txt")
                        : scene.object.tracked_poses;
    check_output_path(tracked_poses, scene, "object.tracked_poses", true);
  } else {
    check_input_file(scene, scene.object.poses, "object.poses", "pose file");
  }
  check_input_file(scene, scene.background.plate, "background.plate", "background plate");
  check_output_path(result.video, scene, "output.video", options.video.empty());
  try {
    VideoWriter::check_extension(result.video);
  } catch (const InputError& e) {
    if (options.video.empty()) throw scene_error(scene, "output.video", e);
    throw;
  }
  check_output_path(result.report_path, scene, "output.report",
                    options.report.empty() && !report_from_option_video);
  if (same_file(result.video, result.report_path)) {
    const std::string message = "the video and the report would be the same file";
    if (options.video.empty() && options.report.empty())
      throw scene_error(scene, "output.report", message);
    throw InputError(message, result.report_path);  // (given on the command line)
  }
  for (const fs::path& out : {result.video, result.report_path})
    if (same_file(tracked_poses, out))
      throw scene_error(scene, "object.tracked_poses",
                        "the tracked poses and " + out.string() + " would be the same file");

  // ---- inputs -----------------------------------------------------------------------------
  Footage footage = open_footage(scene);
  Camera camera;
  camera.fx = scene.fx;
  camera.fy = scene.fy;
  camera.cx = scene.cx;
  camera.cy = scene.cy;
  camera.width = footage.size().width;
  camera.height = footage.size().height;
  try {
    camera.validate();
  } catch (const InputError& e) {
    throw scene_error(scene, e.key(), e.message());
  }
  const int frames = footage.frame_count();
  const int first = options.first_frame;
  const int end = options.end_frame < 0 ? frames : options.end_frame;
  if (first < 0 || first >= end || end > frames)
    throw InputError(
        "frames " + std::to_string(first) + ":" +
            (options.end_frame < 0 ? std::string() : std::to_string(options.end_frame)) +
            " requested, but the footage has " + std::to_string(frames) +
            " frames (0:" + std::to_string(frames) + ")",
        footage.source());

  Mesh mesh = load_mesh(scene.object.mesh);
  const MeshReport findings = validate_mesh(mesh, scene.object.mesh);
  if (findings.degenerate_count == mesh.num_triangles())
    throw InputError("every triangle of the mesh is degenerate (zero area): nothing to simulate",
                     scene.object.mesh);
  if (!findings.ok())
    report.warnings.push_back(scene.object.mesh.string() + ": " + findings.summary() +
                              " They are simulated as given: check the edited video there.");
  // Fracture and refinement before tracking, so that their errors come before any tracking
  // work; tracking follows the mesh as given.
  const Mesh given = scene.object.track ? mesh : Mesh{};
  if (scene.object.fracture_pieces > 0) {
    FractureOptions fo;
    fo.pieces = scene.object.fracture_pieces;
    fo.seed = static_cast<std::uint64_t>(scene.object.fracture_seed);
    try {
      mesh = voronoi_fracture(mesh, fo);
    } catch (const InputError& e) {
      throw scene_error(scene, "object.fracture", scene.object.mesh.string() + ": " + e.message());
    }
  }
  const int original_vertices = mesh.num_vertices();
  if (scene.object.refine > 0) {
    // A refinement that cannot be edited (a length in the wrong unit) is refused before it
    // fills the memory.
    try {
      mesh = refine_mesh(mesh, scene.object.refine, kMaxRefinedVertices);
    } catch (const std::length_error&) {
      double longest = 0.0;
      for (Eigen::Index t = 0; t < mesh.triangles.rows(); ++t)
        longest = std::max(longest, longest_edge(mesh, t));
      throw scene_error(scene, "object.refine",
                        "refining to edges of " + format_length(scene.object.refine) +
                            " would make more than " + std::to_string(kMaxRefinedVertices) +
                            " vertices (the mesh's longest edge is " + format_length(longest) +
                            "; lengths are in the mesh's units, metres)");
    }
  }

  PoseTrack track;
  if (scene.object.track) {
    const Pose initial = [&] {
      if (!scene.object.correspondences.empty())
        return pose_from_correspondence_file(scene.object.correspondences, given, camera);
      const PoseTrack start = load_pose_file(scene.object.initial_pose);
      if (start.size() == 0 || !start.poses[0])
        throw InputError("the first line must be a pose (not `lost`) for frame 0",
                         scene.object.initial_pose, 1);
      return *start.poses[0];
    }();
    // Only the frames the edit needs: 0 (the initial pose) to the end of the edited range.
    Footage clip = open_footage(scene);
    TrackOptions to;
    to.end_frame = end;
    TrackResult tracked;
    try {
      tracked = track_footage(
          clip, given, camera, initial, to,
          [&](int t, const cv::Mat&, const std::optional<Pose>&, const TrackFrameInfo&) {
            if (cb.cancel && cb.cancel())
              throw EditCancelled("cancelled while tracking, at frame " + std::to_string(t) +
                                  ": nothing written");
          });
    } catch (const InputError& e) {
      if (!e.file().empty()) throw;
      throw scene_error(
          scene,
          scene.object.correspondences.empty() ? "object.initial_pose" : "object.correspondences",
          "tracking: " + e.message());
    }
    save_pose_file(tracked.track, tracked_poses);
    track = tracked.track;
    ReportTracking& rt = report.tracking.emplace();
    rt.poses = fs::absolute(tracked_poses);
    rt.ms_per_frame = tracked.track_ms_per_frame;
    rt.left_view_at = tracked.left_view_at;
    for (int t = 0; t < tracked.track.size(); ++t)
      if (!tracked.track.poses[static_cast<size_t>(t)]) rt.lost.push_back(t);
    if (tracked.left_view_at >= 0)
      report.warnings.push_back("tracking: the object left the view at frame " +
                                std::to_string(tracked.left_view_at) + " and was not found again");
  } else {
    track = load_pose_file(scene.object.poses);
  }
  const fs::path& pose_source = scene.object.track ? tracked_poses : scene.object.poses;

  if (!scene.input.image.empty() && track.size() == 1)
    track.poses.resize(static_cast<size_t>(frames), track.poses[0]);
  // Poses are needed up to the end of the edited range (a tracked file, or one cut to the
  // range, stops there); later frames count as lost for the background plate.
  if (track.size() < end)
    throw InputError(
        "the pose file has " + std::to_string(track.size()) + " poses but the footage has " +
            std::to_string(frames) + " frames" +
            (end < frames ? " (the edited frames need " + std::to_string(end) + ")" : ""),
        pose_source);
  if (track.size() < frames) track.poses.resize(static_cast<size_t>(frames));
  if (track.size() > frames)
    report.warnings.push_back("the pose file has " + std::to_string(track.size()) + " poses for " +
                              std::to_string(frames) + " frames: the extra poses are ignored");

  // Poses of the edited range; `lost` frames hold the last known pose (and its frame's texture).
  std::vector<Pose> pose(static_cast<size_t>(end));
  std::vector<int> texture_frame(static_cast<size_t>(end));
  std::vector<char> lost(static_cast<size_t>(end), 0);
  {
    int known = -1;
    for (int t = 0; t < end; ++t)
      if (track.poses[static_cast<size_t>(t)]) {
        known = t;
        break;
      }
    if (known < 0) throw InputError("every pose is 'lost': nothing to align", pose_source);
    int last = known;
    for (int t = 0; t < end; ++t) {
      if (track.poses[static_cast<size_t>(t)])
        last = t;
      else
        lost[static_cast<size_t>(t)] = 1;
      const int from = t < known ? known : last;
      pose[static_cast<size_t>(t)] = *track.poses[static_cast<size_t>(from)];
      texture_frame[static_cast<size_t>(t)] = from;
    }
    // Behind the camera in every edited frame (no vertex in front): nothing of the object is
    // seen, the output would be the footage unchanged. The usual cause is another camera
    // convention.
    bool seen = false;
    for (int t = first; t < end && !seen; ++t)
      seen = (pose[static_cast<size_t>(t)].apply(mesh.vertices).col(2).array() > 0.0).any();
    const Eigen::Vector3d centre = mesh.vertices.colwise().mean().transpose();
    if (!seen)
      throw InputError("the object is behind the camera in every edited frame (its centre at z = " +
                           format_length(pose[static_cast<size_t>(first)].apply(centre).z()) +
                           " in frame " + std::to_string(first) +
                           "): poses are in OpenCV camera axes, x right, y down, z forward (a "
                           "pose for an OpenGL camera, which looks along -z, needs its y and z "
                           "rows negated)",
                       pose_source);
    int lost_in_range = 0;
    for (int t = first; t < end; ++t) lost_in_range += lost[static_cast<size_t>(t)];
    if (lost_in_range > 0)
      report.warnings.push_back(std::to_string(lost_in_range) +
                                " frames have a 'lost' pose: the anchors hold the last known pose "
                                "and the texture comes from the last frame with a pose");
  }

  const std::vector<int> anchors = select_anchors(scene, mesh, original_vertices, report.warnings);

  // ---- simulator, optimizer, renderer -----------------------------------------------------
  EngineRecipe recipe;
  recipe.simulation = scene.simulation;
  recipe.mesh = mesh;
  recipe.rest_positions = pose[static_cast<size_t>(first)].apply(mesh.vertices);
  recipe.anchors = anchors;
  recipe.scene_file = scene.file;
  std::unique_ptr<Simulator> sim;
  try {
    sim = cb.make_simulator(recipe);
  } catch (const InputError& e) {
    throw engine_error_in_scene(e, scene);
  }
  if (!sim)
    throw scene_error(scene, "simulation.engine",
                      "the simulator factory (EditCallbacks::make_simulator) made no simulator "
                      "for engine '" +
                          scene.simulation.engine + "'");
  report.engine = sim->name();
  check_simulator(*sim);
  if (sim->num_vertices() != mesh.num_vertices())
    throw std::logic_error("the simulator has " + std::to_string(sim->num_vertices()) +
                           " surface vertices, the mesh " + std::to_string(mesh.num_vertices()));

  const bool control = options.control.value_or(scene.control.enabled);
  const ControlOptions control_settings = control_options(scene);
  if (control) {
    try {
      resolve_gradient(*sim, control_settings.gradient);  // before any output, not per frame
    } catch (const std::invalid_argument& e) {
      throw scene_error(scene, "control.gradient",
                        std::string(e.what()) + " (use auto, compressed or central)");
    }
  }
  ControlOptimizer optimizer(mesh.triangles, mesh.interior, control_settings);
  const double dt = 1.0 / footage.fps();

  // The vertices the engine holds (it may hold others than those selected, e.g. the sheet
  // nodes under selected vertices of a thin board's other face); they follow the input poses.
  const std::vector<int> held = sim->anchors();
  Vertices anchor_rest(static_cast<Eigen::Index>(held.size()), 3);
  for (size_t i = 0; i < held.size(); ++i)
    anchor_rest.row(static_cast<Eigen::Index>(i)) = mesh.vertices.row(held[i]);

  // Which triangles each input frame observes (cached: windows look ahead).
  RayScene input_scene(pose[static_cast<size_t>(first)].apply(mesh.vertices), mesh.triangles);
  VisibilityOptions vis;
  // Per input frame: v_j (observed) and the triangles the optimizer keeps hidden. Only
  // triangles that face away by more than the barrier margin in the input are penalized: an
  // unobserved triangle that is edge-on there (0 < s_j < margin) would make even the input's own
  // rigid motion violate the margin, and one hidden only by occlusion (s_j < 0) cannot be kept
  // hidden by turning it away. The metric still counts every unobserved triangle.
  struct InputVisibility {
    std::vector<std::uint8_t> observed, keep_hidden;
  };
  std::map<int, InputVisibility> input_cache;
  const double margin = scene.control.margin;
  auto input_visibility = [&](int t) -> const InputVisibility& {
    auto it = input_cache.find(t);
    if (it != input_cache.end()) return it->second;
    if (input_cache.size() > 64) input_cache.erase(input_cache.begin());
    const Vertices aligned = pose[static_cast<size_t>(t)].apply(mesh.vertices);
    const TriangleVisibility v = compute_visibility(input_scene, aligned, camera, vis);
    InputVisibility out;
    out.observed = v.visible;
    out.keep_hidden.resize(v.visible.size());
    for (size_t j = 0; j < v.visible.size(); ++j)
      out.keep_hidden[j] = !v.visible[j] && v.facing(static_cast<Eigen::Index>(j)) > margin;
    return input_cache[t] = std::move(out);
  };
  auto observed = [&](int t) -> const std::vector<std::uint8_t>& {
    return input_visibility(t).observed;
  };

  RenderOptions render_options;
  render_options.scale = scene.object.scale;
  Renderer renderer(mesh, camera, render_options);
  std::optional<MaskSequence> masks;
  if (!scene.background.remove.empty()) {
    try {
      masks.emplace(scene.background.remove, footage.size());
      // Every mask the run will read, read once now, so that one that cannot be read or has
      // another size stops the run before any output (a missing file is an empty mask): all
      // frames when the plate is estimated from the footage, frame 0 for a single picture's
      // inpainted plate, and the frames edited.
      const bool estimated = scene.background.plate.empty() && scene.input.image.empty();
      const bool picture = !scene.input.image.empty();
      for (int t = estimated || picture ? 0 : first; t < (estimated ? frames : end); ++t)
        masks->mask(t);
    } catch (const InputError& e) {
      throw scene_error(scene, "background.remove", e);
    }
  }
  auto extra_mask = [&](int t) { return masks ? masks->mask(t) : cv::Mat(); };
  cv::Mat plate;
  if (!scene.background.plate.empty()) {
    plate = load_plate(scene.background.plate, footage.size());
  } else if (!scene.input.image.empty()) {
    // A single picture: the object never uncovers the background, inpaint it.
    cv::Mat remove =
        silhouette_mask(mesh.triangles, pose[static_cast<size_t>(first)].apply(mesh.vertices),
                        camera, scene.object.scale, 4);
    const cv::Mat extra = extra_mask(0);
    if (!extra.empty()) cv::max(remove, extra, remove);
    plate = inpaint_plate(footage.frame(0), remove).image;
  } else {
    PlateOptions po;
    po.scale = scene.object.scale;
    if (masks) po.extra_mask = extra_mask;
    PoseTrack plate_track = track;
    plate_track.poses.resize(static_cast<size_t>(frames));
    plate = estimate_plate(footage, plate_track, mesh, camera, po).image;
  }

  // The settings of the run as done: the command line's outputs and control, the tracked poses.
  Scene done = scene;
  done.output.video = fs::absolute(result.video);
  done.output.report = fs::absolute(result.report_path);
  done.control.enabled = control;
  if (scene.object.track) done.object.tracked_poses = fs::absolute(tracked_poses);
  report.settings_yaml = scene_to_yaml(done);
  VideoWriter writer(result.video, footage.fps(), footage.size());
  RayScene sim_scene(sim->positions(), mesh.triangles);
  MetricOptions metric_options;
  cv::Mat output;
  const DivergenceCheck diverged(recipe.rest_positions);

  const int total = end - first;
  for (int t = first; t < end; ++t) {
    const auto t0 = Clock::now();
    FrameRecord rec;
    rec.index = t;
    rec.pose_lost = lost[static_cast<size_t>(t)] != 0;
    if (t == first) {
      rec.status = "rest";  // the simulation starts at rest in this frame's pose (paper 3.4)
    } else {
      const int w = std::min(scene.control.window, end - t);
      std::vector<ControlFrameInput> window(static_cast<size_t>(control ? w : 1));
      for (size_t k = 0; k < window.size(); ++k) {
        const int tk = t + static_cast<int>(k);
        window[k].dt = dt;
        window[k].anchor_targets = pose[static_cast<size_t>(tk)].apply(anchor_rest);
        window[k].unobserved = input_visibility(tk).keep_hidden;
        window[k].observed = input_visibility(tk).observed;
      }
      const SimState before = sim->save();
      ControlFrameResult r;
      std::string failure;  // why the simulation of this frame failed, empty if it did not
      if (control) {
        ControlCallbacks ccb;
        ccb.cancel = cb.cancel;
        std::string fallback;
        try {
          r = optimizer.step(*sim, window, ccb);
          if (!r.control.allFinite() || !std::isfinite(r.energy))
            fallback = "non-finite energy or forces";
        } catch (const std::exception& e) {
          fallback = e.what();
        }
        if (!fallback.empty()) {
          report.warnings.push_back("frame " + std::to_string(t) +
                                    ": the control optimizer failed (" + fallback +
                                    "); the frame was simulated without control forces");
          sim->restore(before);
          try {
            r = optimizer.step_uncontrolled(*sim, window[0]);
          } catch (const std::exception& e) {
            failure = e.what();
          }
          r.status = ControlStatus::failed;
        }
      } else {
        try {
          r = optimizer.step_uncontrolled(*sim, window[0]);
        } catch (const std::exception& e) {
          failure = e.what();
        }
      }
      if (failure.empty()) failure = diverged(*sim);
      if (!failure.empty()) {
        // Retry the frame with 2x, then 4x the substeps (the frame interval split into equal
        // steps, anchors interpolated), keeping the committed control forces.
        const std::string first_failure = failure;
        for (const int factor : kRetryFactors) {
          sim->restore(before);
          try {
            r.physical_force = step_subdivided(*sim, r.control, window[0], factor);
            failure = diverged(*sim);
          } catch (const std::exception& e) {
            failure = e.what();
          }
          if (failure.empty()) {
            rec.substep_factor = factor;
            report.warnings.push_back("the simulation diverged in frame " + std::to_string(t) +
                                      " (" + first_failure + "); the frame was recomputed with " +
                                      std::to_string(factor) + "x the substeps");
            break;
          }
        }
      }
      if (!failure.empty()) {
        report.complete = false;
        report.stopped_at = t;
        report.stopped_reason = "the simulation diverged in frame " + std::to_string(t) + " (" +
                                failure + ") even with " + std::to_string(kRetryFactors.back()) +
                                "x the substeps; try more simulation.substeps or a softer material";
        result.status = EditStatus::diverged;
        break;
      }
      rec.control_force = r.control_force;
      rec.physical_force = r.physical_force;
      rec.solve_ms = r.solve_ms;
      rec.iterations = r.iterations;
      rec.status = control ? to_string(r.status) : "off";
    }
    const Vertices simulated = sim->positions();
    sim_scene.update(simulated);
    const auto& obs = observed(t);
    const ViolationMetric m =
        violation_metric(sim_scene, camera, obs, mesh.interior, metric_options);
    rec.violation_pct = m.violation_pct;
    rec.visible_area_px = m.object_area_px;

    const int tf = texture_frame[static_cast<size_t>(t)];
    const cv::Mat input = footage.frame(tf);
    const Vertices aligned = pose[static_cast<size_t>(t)].apply(mesh.vertices);
    renderer.render(input, aligned, simulated, obs, plate, extra_mask(t), output);
    writer.write(output);
    rec.frame_ms = ms_since(t0);
    report.frames.push_back(rec);
    if (cb.progress) cb.progress({t - first + 1, total, rec});
    if (cb.cancel && cb.cancel() && t + 1 < end) {
      report.complete = false;
      report.stopped_at = t + 1;
      report.stopped_reason = "cancelled after frame " + std::to_string(t);
      result.status = EditStatus::cancelled;
      break;
    }
  }
  for (auto& w : faithfulness_warnings(report.frames)) report.warnings.push_back(std::move(w));
  // The report is written under its temporary name first, so that a failure leaves neither
  // output under its final name; then both are moved into place.
  const fs::path staged_report = reserve_partial(result.report_path);
  try {
    write_report(report, staged_report);
    writer.close();
    commit_partial(staged_report, result.report_path);
  } catch (...) {
    std::error_code ec;
    fs::remove(staged_report, ec);
    throw;
  }
  result.complete = report.complete;
  return result;
}

}  // namespace pbve
