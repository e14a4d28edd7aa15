// Pose tracking speed: pbve synth's clips of the issue at 640 x 480 (moved and turned around
// the frame for 150 frames, a hand passing in front), the figurine and the board, each tracked
// with its surface refined to at least 5 000 triangles (edges split: the same surface, so the
// true poses still hold). Frames are decoded before timing; the counters give the tracking time
// per frame, the frames per second and the reprojection error against the true poses (median
// and maximum over frames of the mean over vertices).

#include <algorithm>
#include <chrono>
#include <filesystem>
#include <string>
#include <vector>

#include <benchmark/benchmark.h>

#include "pbve/edit/synth.hpp"
#include "pbve/track/tracker.hpp"

namespace {

struct Clip {
  std::vector<cv::Mat> frames;
  pbve::Mesh mesh;
  pbve::Camera camera;
  pbve::PoseTrack truth;
};

Clip make_clip(const std::string& shape) {
  const auto dir = std::filesystem::temp_directory_path() / ("pbve_bench_track_" + shape);
  pbve::SynthOptions o;
  o.shape = shape;
  o.motion = "orbit";
  o.frames = 150;
  o.supersample = 2;
  o.occluder = true;
  const pbve::SynthOutput out = pbve::synthesize(o, dir);
  Clip c;
  pbve::Footage f = pbve::Footage::open_video(out.video);
  for (int i = 0; i < f.frame_count(); ++i) c.frames.push_back(f.frame(i));
  // Split edges until the mesh has at least 5 000 triangles.
  double edge = 0.1;
  do {
    c.mesh = pbve::refine_mesh(out.mesh_data, edge);
    edge *= 0.95;
  } while (c.mesh.num_triangles() < 5000);
  c.camera = out.camera;
  c.truth = out.track;
  std::filesystem::remove_all(dir);
  return c;
}

const Clip& clip(int which) {
  static const Clip figurine = make_clip("figurine");
  static const Clip board = make_clip("board");
  return which == 0 ? figurine : board;
}

void BM_TrackClip(benchmark::State& state) {
  const Clip& c = clip(static_cast<int>(state.range(0)));
  state.SetLabel(state.range(0) == 0 ? "figurine" : "board");
  const int n = static_cast<int>(c.frames.size());
  double ms = 0.0;
  std::vector<double> errors;
  int lost = 0;
  for (auto _ : state) {
    pbve::PoseTracker tracker(c.mesh, c.camera);
    errors.clear();
    lost = 0;
    const auto t0 = std::chrono::steady_clock::now();
    tracker.start(c.frames[0], *c.truth.poses[0]);
    std::vector<std::optional<pbve::Pose>> poses{c.truth.poses[0]};
    for (int t = 1; t < n; ++t) poses.push_back(tracker.track(c.frames[static_cast<size_t>(t)]));
    ms = std::chrono::duration<double, std::milli>(std::chrono::steady_clock::now() - t0).count();
    for (int t = 0; t < n; ++t) {
      lost += !poses[static_cast<size_t>(t)];
      errors.push_back(poses[static_cast<size_t>(t)]
                           ? pbve::reprojection_error_px(c.mesh, c.camera,
                                                         *poses[static_cast<size_t>(t)],
                                                         *c.truth.poses[static_cast<size_t>(t)])
                           : 1e9);
    }
  }
  std::sort(errors.begin(), errors.end());
  state.counters["triangles"] = c.mesh.num_triangles();
  state.counters["ms_per_frame"] = ms / n;
  state.counters["fps"] = 1000.0 * n / ms;
  state.counters["error_median_px"] = errors[errors.size() / 2];
  state.counters["error_max_px"] = errors.back();
  state.counters["lost"] = lost;
}

}  // namespace

BENCHMARK(BM_TrackClip)->Arg(0)->Arg(1)->Unit(benchmark::kMillisecond)->Iterations(1);
BENCHMARK_MAIN();
