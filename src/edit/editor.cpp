#include "pbve/edit/editor.hpp"

#include <algorithm>
#include <chrono>
#include <cmath>
#include <map>
#include <optional>
#include <sstream>

#include <opencv2/imgcodecs.hpp>

#include "pbve/control/optimizer.hpp"
#include "pbve/core/camera.hpp"
#include "pbve/core/error.hpp"
#include "pbve/core/footage.hpp"
#include "pbve/core/mesh.hpp"
#include "pbve/core/pose.hpp"
#include "pbve/render/plate.hpp"
#include "pbve/render/renderer.hpp"
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

/// Same file (or the same path when one does not exist yet).
bool same_file(const fs::path& a, const fs::path& b) {
  if (a.empty() || b.empty()) return false;
  std::error_code ec;
  if (fs::exists(a, ec) && fs::exists(b, ec)) return fs::equivalent(a, b, ec);
  return fs::weakly_canonical(a, ec) == fs::weakly_canonical(b, ec);
}

void check_output_path(const fs::path& out, const Scene& scene, const char* key) {
  const std::vector<fs::path> inputs = {scene.file,         scene.input.video,
                                        scene.input.image,  scene.object.mesh,
                                        scene.object.poses, scene.background.plate};
  for (const fs::path& in : inputs)
    if (same_file(out, in))
      throw InputError("the output would overwrite the input file " + in.string(), scene.file, 0,
                       std::string("key '") + key + "'");
  const fs::path dir = out.has_parent_path() ? out.parent_path() : fs::path(".");
  std::error_code ec;
  if (!fs::is_directory(dir, ec))
    throw InputError("the output folder " + dir.string() + " does not exist", scene.file, 0,
                     std::string("key '") + key + "'");
}

Footage open_footage(const Scene& s) {
  if (!s.input.video.empty()) return Footage::open_video(s.input.video);
  if (!s.input.image.empty())
    return Footage::open_image(s.input.image, s.input.frames, s.input.fps);
  return Footage::open_sequence(s.input.sequence, s.input.fps);
}

ControlOptions control_options(const SceneControl& c) {
  ControlOptions o;
  o.weights.visibility = c.weight_visibility;
  o.weights.force = c.weight_force;
  o.weights.temporal = c.weight_temporal;
  o.window = c.window;
  o.solver = parse_control_solver(c.solver);
  o.gradient = c.gradient == "central"   ? GradientMode::central
               : c.gradient == "adjoint" ? GradientMode::adjoint
                                         : GradientMode::automatic;
  o.active_set = c.active_set == "all" ? ActiveSet::all : ActiveSet::at_risk;
  o.max_evaluations = c.max_iterations;
  o.initial_guess = c.warm_start ? InitialGuess::previous : InitialGuess::zero;
  o.barrier.margin = c.margin;
  o.force_bound = c.force_bound;
  o.clusters = c.clusters;
  return o;
}

std::vector<int> select_anchors(const Scene& s, const Mesh& mesh, int original_vertices,
                                std::vector<std::string>& warnings) {
  std::vector<int> ids;
  for (int v : s.object.anchors.vertices) {
    if (v >= original_vertices)
      throw InputError("anchor vertex " + std::to_string(v) + " is out of range (the mesh has " +
                           std::to_string(original_vertices) + " vertices)",
                       s.file, 0, "key 'object.anchors.vertices'");
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
      warnings.push_back("object.anchors.box selects no vertex: the object is not held there");
  }
  std::sort(ids.begin(), ids.end());
  ids.erase(std::unique(ids.begin(), ids.end()), ids.end());
  if (ids.empty())
    warnings.push_back(
        "no anchor vertices: the object moves freely and does not follow the footage");
  return ids;
}

}  // namespace

EditResult run_edit(const Scene& scene, const EditOptions& options, const EditCallbacks& cb) {
  if (!cb.make_simulator)
    throw std::invalid_argument("run_edit: EditCallbacks::make_simulator is required");
  EditResult result;
  Report& report = result.report;
  result.video = options.video.empty() ? scene.output.video : options.video;
  result.report_path = options.report.empty() ? scene.output.report : options.report;
  check_output_path(result.video, scene, "output.video");
  check_output_path(result.report_path, scene, "output.report");
  if (same_file(result.video, result.report_path))
    throw InputError("the video and the report would be the same file", scene.file, 0,
                     "key 'output.report'");

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
    throw InputError(e.message(), scene.file, 0, e.key());
  }

  Mesh mesh = load_mesh(scene.object.mesh);
  const MeshReport findings = validate_mesh(mesh, scene.object.mesh);
  if (!findings.ok())
    report.warnings.push_back(scene.object.mesh.string() + ": " + findings.summary());
  const int original_vertices = mesh.num_vertices();
  if (scene.object.refine > 0) mesh = refine_mesh(mesh, scene.object.refine);

  PoseTrack track = load_pose_file(scene.object.poses);
  const int frames = footage.frame_count();
  if (!scene.input.image.empty() && track.size() == 1)
    track.poses.resize(static_cast<size_t>(frames), track.poses[0]);
  if (track.size() < frames)
    throw InputError("the pose file has " + std::to_string(track.size()) +
                         " poses but the footage has " + std::to_string(frames) + " frames",
                     scene.object.poses);
  if (track.size() > frames)
    report.warnings.push_back("the pose file has " + std::to_string(track.size()) + " poses for " +
                              std::to_string(frames) + " frames: the extra poses are ignored");

  const int first = options.first_frame;
  const int end = options.end_frame < 0 ? frames : std::min(options.end_frame, frames);
  if (first < 0 || first >= end)
    throw InputError("frame range " + std::to_string(first) + ":" + std::to_string(end) +
                     " is empty or outside the footage's " + std::to_string(frames) + " frames");

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
    if (known < 0) throw InputError("every pose is 'lost': nothing to align", scene.object.poses);
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
  std::unique_ptr<Simulator> sim = cb.make_simulator(recipe);
  report.engine = sim->name();
  if (sim->num_vertices() != mesh.num_vertices())
    throw std::logic_error("the simulator has " + std::to_string(sim->num_vertices()) +
                           " surface vertices, the mesh " + std::to_string(mesh.num_vertices()));

  const bool control = options.control.value_or(scene.control.enabled);
  ControlOptimizer optimizer(mesh.triangles, mesh.interior, control_options(scene.control));
  const double dt = 1.0 / footage.fps();

  Vertices anchor_rest(static_cast<Eigen::Index>(anchors.size()), 3);
  for (size_t i = 0; i < anchors.size(); ++i)
    anchor_rest.row(static_cast<Eigen::Index>(i)) = mesh.vertices.row(anchors[i]);

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
  if (!scene.background.remove.empty()) masks.emplace(scene.background.remove, footage.size());
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

  report.settings_yaml = scene_to_yaml(scene);
  VideoWriter writer(result.video, footage.fps(), footage.size());
  RayScene sim_scene(sim->positions(), mesh.triangles);
  MetricOptions metric_options;
  cv::Mat output;

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
      }
      ControlCallbacks ccb;
      ccb.cancel = cb.cancel;
      const ControlFrameResult r = control ? optimizer.step(*sim, window, ccb)
                                           : optimizer.step_uncontrolled(*sim, window[0]);
      rec.control_force = r.control_force;
      rec.physical_force = r.physical_force;
      rec.solve_ms = r.solve_ms;
      rec.iterations = r.iterations;
      rec.status = control ? to_string(r.status) : "off";
    }
    const Vertices simulated = sim->positions();
    if (!simulated.allFinite())
      throw std::runtime_error("the simulation diverged (non-finite positions) in frame " +
                               std::to_string(t));
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
      report.stopped_reason = "cancelled after frame " + std::to_string(t);
      break;
    }
  }
  writer.close();
  for (auto& w : faithfulness_warnings(report.frames)) report.warnings.push_back(std::move(w));
  write_report(report, result.report_path);
  result.complete = report.complete;
  return result;
}

}  // namespace pbve
