// Control through a black-box engine: Bullet cloth at 37 x 28 = 1 036 nodes, the swung board of
// the control tests (tests/control/cloth_scene.hpp) with pbve::bullet's cloth preset (3 substeps)
// instead of mass_spring. Bullet has no derivatives, so every gradient is (compressed) central
// differences, in parallel over simulator clones.
//
// - BM_BulletFrames/mode:M/evaluations:E/rings:R: ms per frame over frames 24..29 from the same
//   state. M = 0 uncontrolled. Every evaluation simulates (ControlOptions::linearized off), plain
//   central differences: 1 one force per vertex of the default active set; 2 the same active
//   set reduced to 16 clusters (48 variables, ControlOptions::clusters). The linearized search
//   on difference responses: 3 one force per active vertex, compressed differences with the
//   default 2 rings (GradientMode::compressed); 4 16 clusters, plain central differences;
//   5 as 3 with R rings. L-BFGS with at most E objective evaluations per frame (linearized: E
//   model evaluations per linearization). Counters: ms_per_frame, violation_pct (mean),
//   force_ratio (median control / physical), evals_per_frame (simulated), model_evals_per_frame,
//   probes_per_frame, variables (per frame, mean).
// - BM_BulletGradient: one central-difference gradient over all nodes (the paper's
//   formulation), parallel; a per-evaluation frame costs about one such gradient per evaluation.
// - BM_BulletCompressedGradient/rings:R: one compressed gradient over the active set of frame
//   24, its probes and its relative error against plain central differences.
// Environment: LAST=F ends the frames of BM_BulletFrames at F instead of 29.

#include <algorithm>
#include <chrono>
#include <cstdlib>
#include <memory>
#include <span>
#include <vector>

#include <benchmark/benchmark.h>

#include "control/cloth_scene.hpp"
#include "control_frames.hpp"
#include "pbve/bullet/bullet.hpp"

namespace {

using pbve::ControlFrameInput;
using pbve::ControlOptimizer;
using pbve::ControlOptions;
using pbve::GradientMode;

constexpr int kFirst = 24;
const int kLast = std::max(kFirst, std::getenv("LAST") ? std::atoi(std::getenv("LAST")) : 29);

pbve::test::ClothScene make_scene() {
  pbve::test::ClothScene scene(36, 27);
  scene.amplitude_deg = 60.0;
  scene.period_s = 0.7;
  return scene;
}

std::unique_ptr<pbve::Simulator> start(const pbve::test::ClothScene& scene) {
  auto p = pbve::bullet::Params::preset(pbve::bullet::Material::cloth);
  p.substeps = 3;
  auto sim = std::make_unique<pbve::bullet::BulletSimulator>(scene.sheet, scene.anchors, p);
  for (int f = 1; f < kFirst; ++f) {
    pbve::StepInput in;
    in.dt = 1.0 / scene.fps;
    in.anchor_targets = scene.anchor_targets(f);
    sim->step(in);
  }
  return sim;
}

void BM_BulletFrames(benchmark::State& state) {
  const int mode = static_cast<int>(state.range(0));
  const pbve::test::ClothScene scene = make_scene();
  const auto sim0 = start(scene);
  std::vector<ControlFrameInput> inputs;
  for (int f = kFirst; f <= kLast; ++f) inputs.push_back(scene.control_input(f));
  ControlOptions o;
  o.solver = pbve::ControlSolver::lbfgs;
  o.max_evaluations = std::max(1, static_cast<int>(state.range(1)));
  o.gradient = mode == 3 || mode == 5 ? GradientMode::compressed : GradientMode::central;
  o.clusters = mode == 2 || mode == 4 ? 16 : 0;
  o.linearized = mode >= 3;
  if (mode == 5) o.difference_rings = static_cast<int>(state.range(2));
  pbve::bench::run_control_frames(state, scene, *sim0, kFirst, inputs, o, mode != 0);
}

void BM_BulletGradient(benchmark::State& state) {
  const pbve::test::ClothScene scene = make_scene();
  const auto sim = start(scene);
  const std::vector<ControlFrameInput> window{scene.control_input(kFirst)};
  ControlOptimizer opt(scene.two_sided);
  for (auto _ : state)
    benchmark::DoNotOptimize(opt.evaluate(*sim, window, {}, GradientMode::central, {}));
  state.counters["variables"] = 3.0 * scene.num_vertices();
}

// The gradient over the active set of frame kFirst, compressed with `rings` rings, against plain
// central differences (computed once, outside the timing): relative error |g_c - g| / |g| of the
// visibility part, and ms per compressed gradient.
void BM_BulletCompressedGradient(benchmark::State& state) {
  const int rings = static_cast<int>(state.range(0));
  const pbve::test::ClothScene scene = make_scene();
  const auto sim = start(scene);
  const std::vector<ControlFrameInput> window{scene.control_input(kFirst)};
  ControlOptions o;
  o.difference_rings = rings;
  ControlOptimizer opt(scene.two_sided, {}, o);
  const std::vector<int> active = opt.active_blocks(*sim, window);
  static Eigen::VectorXd reference;
  if (reference.size() == 0)
    reference = opt.evaluate(*sim, window, {}, GradientMode::central, active).gradient;
  pbve::ControlEnergyEval e;
  for (auto _ : state) e = opt.evaluate(*sim, window, {}, GradientMode::compressed, active);
  const Eigen::VectorXd& g = e.gradient;
  state.counters["probes"] = e.probes;
  // The force terms are analytic and equal in both: their gradient at zero control is zero.
  state.counters["rel_error"] = (g - reference).norm() / reference.norm();
  state.counters["variables"] = 3.0 * static_cast<double>(active.size());
}

}  // namespace

BENCHMARK(BM_BulletFrames)
    ->ArgNames({"mode", "evaluations", "rings"})
    ->Args({0, 0, 0})
    ->Args({1, 4, 0})
    ->Args({2, 4, 0})
    ->Args({2, 20, 0})
    ->Args({3, 20, 0})
    ->Args({3, 200, 0})
    ->Args({5, 200, 1})
    ->Args({5, 200, 3})
    ->Args({4, 20, 0})
    ->Args({4, 200, 0})
    ->Unit(benchmark::kMillisecond)
    ->Iterations(1);
BENCHMARK(BM_BulletGradient)->Unit(benchmark::kMillisecond)->Iterations(1);
BENCHMARK(BM_BulletCompressedGradient)
    ->ArgName("rings")
    ->DenseRange(0, 5)
    ->Unit(benchmark::kMillisecond)
    ->Iterations(1);
BENCHMARK_MAIN();
