// The control optimizer on one scene, all in one run: the swung cloth board of the control
// tests (tests/control/cloth_scene.hpp) at 33 x 25 = 825 vertices.
//
// - BM_Frames/<mode>: ms per frame over frames 24..35 (where the cloth turns its back without
//   control), from the same saved state, for the uncontrolled simulation and for control
//   (L-BFGS with at most <evaluations> objective evaluations per frame, 20 or 4, adjoint
//   gradients, default active set). Counters:
//   `violation_pct` = mean violation over those frames (the paper's Figure 7 measure),
//   `force_ratio` = median control / physical force, `ms_per_frame`, `evals_per_frame`.
// - BM_Gradient/<mode>: one gradient of the full energy over *all* vertices (the paper's
//   formulation: 2 x 3 x #V simulations by central differences, serial or in parallel over
//   clones) against the adjoint. A whole frame with central differences costs about 20 such
//   gradients, too long to run here; the frame cost follows from this ratio.

#include <algorithm>
#include <chrono>
#include <memory>
#include <span>
#include <string>
#include <vector>

#include <benchmark/benchmark.h>

#include "control/cloth_scene.hpp"
#include "control_frames.hpp"

namespace {

using pbve::ControlFrameInput;
using pbve::ControlOptimizer;
using pbve::ControlOptions;
using pbve::GradientMode;

constexpr int kFirst = 24, kLast = 35;

pbve::test::ClothScene make_scene() {
  pbve::test::ClothScene scene(32, 24);
  scene.amplitude_deg = 60.0;
  scene.period_s = 0.7;
  scene.bend_stiffness = 1e-4;
  scene.substeps = 3;
  scene.linear_solver = pbve::mass_spring::LinearSolver::direct;
  return scene;
}

// The simulator advanced without control to the state before frame kFirst.
std::unique_ptr<pbve::Simulator> start(const pbve::test::ClothScene& scene) {
  auto sim = scene.simulator();
  for (int f = 1; f < kFirst; ++f) {
    pbve::StepInput in;
    in.dt = 1.0 / scene.fps;
    in.anchor_targets = scene.anchor_targets(f);
    sim->step(in);
  }
  return sim;
}

enum Mode { uncontrolled = 0, adjoint = 1, central_parallel = 2, central_serial = 3 };

void BM_Frames(benchmark::State& state) {
  const auto mode = static_cast<Mode>(state.range(0));
  const pbve::test::ClothScene scene = make_scene();
  const auto sim0 = start(scene);
  std::vector<ControlFrameInput> inputs;
  for (int f = kFirst; f <= kLast; ++f) inputs.push_back(scene.control_input(f));
  ControlOptions o;
  o.solver = pbve::ControlSolver::lbfgs;
  o.max_evaluations = std::max(1, static_cast<int>(state.range(1)));
  o.gradient = GradientMode::adjoint;
  pbve::bench::run_control_frames(state, scene, *sim0, kFirst, inputs, o, mode != uncontrolled);
}

void BM_Gradient(benchmark::State& state) {
  const auto mode = static_cast<Mode>(state.range(0));
  const pbve::test::ClothScene scene = make_scene();
  const auto sim = start(scene);
  const std::vector<ControlFrameInput> window{scene.control_input(kFirst)};
  ControlOptions o;
  o.parallel = mode != central_serial;
  ControlOptimizer opt(scene.two_sided, {}, o);
  const GradientMode g = mode == adjoint ? GradientMode::adjoint : GradientMode::central;
  for (auto _ : state) benchmark::DoNotOptimize(opt.evaluate(*sim, window, {}, g, {}));
  state.counters["variables"] = 3.0 * scene.num_vertices();
}

const char* mode_name(int m) {
  static const char* names[] = {"uncontrolled", "adjoint", "central_parallel", "central_serial"};
  return names[m];
}

void frame_modes(benchmark::internal::Benchmark* b) {
  b->ArgNames({"mode", "evaluations"});
  b->Args({uncontrolled, 0});
  b->Args({adjoint, 20});
  b->Args({adjoint, 4});
  b->Args({adjoint, 3});
  b->Args({adjoint, 2});
}

}  // namespace

BENCHMARK(BM_Frames)->Apply(frame_modes)->Unit(benchmark::kMillisecond)->Iterations(1);
BENCHMARK(BM_Gradient)
    ->ArgName("mode")
    ->Arg(adjoint)
    ->Arg(central_parallel)
    ->Arg(central_serial)
    ->Unit(benchmark::kMillisecond)
    ->Iterations(1);

int main(int argc, char** argv) {
  benchmark::Initialize(&argc, argv);
  for (int m = 0; m < 4; ++m) benchmark::AddCustomContext(std::to_string(m), mode_name(m));
  benchmark::RunSpecifiedBenchmarks();
  benchmark::Shutdown();
  return 0;
}
