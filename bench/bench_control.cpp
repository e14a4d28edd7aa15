// The control optimizer on one scene, all in one run: the swung cloth board of the control
// tests (tests/control/cloth_scene.hpp) at 33 x 25 = 825 vertices.
//
// - BM_Frames/<mode>: ms per frame over frames 24..35 (where the cloth turns its back without
//   control), from the same saved state, for the uncontrolled simulation and for control
//   (L-BFGS, default active set): `linearized` is the default search on the linearized
//   dynamics (at most <evaluations> model evaluations per linearization), `adjoint` the search
//   whose every evaluation simulates the frame and takes a step_vjp (at most <evaluations>).
//   BM_OneFrame/<mode>: frame 24 alone in every mode, including central differences over the
//   active set (parallel over clones, and serial), at most 4 evaluations each. Counters:
//   `violation_pct` = mean violation over those frames (the paper's Figure 7 measure),
//   `force_ratio` = median control / physical force, `ms_per_frame`, `evals_per_frame`
//   (simulations of the frame by the optimizer).
// - BM_Gradient/<mode>: one gradient of the full energy over *all* vertices (the paper's
//   formulation: 2 x 3 x #V simulations by central differences, serial or in parallel over
//   clones) against the adjoint.

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

// adjoint: every evaluation a simulation and a step_vjp (ControlOptions::linearized = false);
// linearized: the default search on the linearized dynamics (adjoint gradients).
enum Mode {
  uncontrolled = 0,
  adjoint = 1,
  central_parallel = 2,
  central_serial = 3,
  linearized = 4
};

// Frames first..last in `mode` with at most `evaluations` per frame.
void run_frames(benchmark::State& state, int first, int last) {
  const auto mode = static_cast<Mode>(state.range(0));
  const pbve::test::ClothScene scene = make_scene();
  const auto sim0 = start(scene);
  std::vector<ControlFrameInput> inputs;
  for (int f = first; f <= last; ++f) inputs.push_back(scene.control_input(f));
  ControlOptions o;
  o.solver = pbve::ControlSolver::lbfgs;
  o.max_evaluations = std::max(1, static_cast<int>(state.range(1)));
  o.gradient =
      mode == adjoint || mode == linearized ? GradientMode::adjoint : GradientMode::central;
  o.linearized = mode == linearized;
  o.parallel = mode != central_serial;
  pbve::bench::run_control_frames(state, scene, *sim0, first, inputs, o, mode != uncontrolled);
}

void BM_Frames(benchmark::State& state) {
  run_frames(state, kFirst, kLast);
}

// Frame kFirst alone, in every mode: central differences over the active set cost minutes
// per frame, so they are compared with the adjoint and the uncontrolled step on one frame.
void BM_OneFrame(benchmark::State& state) {
  run_frames(state, kFirst, kFirst);
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
  static const char* names[] = {"uncontrolled", "adjoint", "central_parallel", "central_serial",
                                "linearized"};
  return names[m];
}

void frame_modes(benchmark::internal::Benchmark* b) {
  b->ArgNames({"mode", "evaluations"});
  b->Args({uncontrolled, 0});
  b->Args({linearized, 20});
  b->Args({linearized, 5});
  b->Args({adjoint, 20});
  b->Args({adjoint, 4});
}

void one_frame_modes(benchmark::internal::Benchmark* b) {
  b->ArgNames({"mode", "evaluations"});
  for (int m : {uncontrolled, linearized, adjoint, central_parallel, central_serial})
    b->Args({m, m == uncontrolled ? 0 : 4});
}

}  // namespace

BENCHMARK(BM_Frames)->Apply(frame_modes)->Unit(benchmark::kMillisecond)->Iterations(1);
BENCHMARK(BM_OneFrame)->Apply(one_frame_modes)->Unit(benchmark::kMillisecond)->Iterations(1);
BENCHMARK(BM_Gradient)
    ->ArgName("mode")
    ->Arg(adjoint)
    ->Arg(central_parallel)
    ->Arg(central_serial)
    ->Unit(benchmark::kMillisecond)
    ->Iterations(1);

int main(int argc, char** argv) {
  benchmark::Initialize(&argc, argv);
  for (int m = 0; m < 5; ++m) benchmark::AddCustomContext(std::to_string(m), mode_name(m));
  benchmark::RunSpecifiedBenchmarks();
  benchmark::Shutdown();
  return 0;
}
