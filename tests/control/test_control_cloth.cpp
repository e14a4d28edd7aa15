// The control optimizer on the built-in mass_spring cloth (tests/control/cloth_scene.hpp).

#include <algorithm>
#include <cstdio>
#include <limits>
#include <stdexcept>
#include <string>
#include <vector>

#include <gtest/gtest.h>

#include "control/cloth_scene.hpp"

namespace pbve {
namespace {

// Steps `sim` uncontrolled through frames 1..last.
void advance(const test::ClothScene& scene, Simulator& sim, int last) {
  for (int f = 1; f <= last; ++f) {
    StepInput in;
    in.dt = 1.0 / scene.fps;
    in.anchor_targets = scene.anchor_targets(f);
    sim.step(in);
  }
}

// The 12 x 8 sheet swung by 80 degrees with soft bending, whose free edge is close to edge-on
// after frame 10 (EC > 0 in frame 11).
test::ClothScene edge_on_scene() {
  test::ClothScene scene(12, 8);
  scene.amplitude_deg = 80.0;
  scene.period_s = 1.0;
  scene.bend_stiffness = 5e-2;
  return scene;
}

TEST(ControlCloth, AdjointAndCentralGradientsOfTheFullEnergyAgree) {
  const test::ClothScene scene = edge_on_scene();
  auto sim = scene.simulator();
  advance(scene, *sim, 10);
  ControlOptions o;
  o.weights = {1.0, 0.1, 0.1};
  ControlOptimizer opt(scene.two_sided, {}, o);
  const std::vector<ControlFrameInput> window{scene.control_input(11)};
  const int size = sim->control_layout().size();
  Eigen::VectorXd u(size);
  for (int i = 0; i < size; ++i) u[i] = 1e-4 * std::sin(0.37 * i);  // ~ half a vertex weight
  const SimState before = sim->save();
  // The at-risk blocks (central differences over all ~300 components take ~20 s here).
  const std::vector<int> active = opt.active_blocks(*sim, window);
  ASSERT_GT(active.size(), 0u);
  const auto adj = opt.evaluate(*sim, window, u, GradientMode::adjoint, active);
  o.parallel = false;
  opt.set_options(o);
  const auto serial = opt.evaluate(*sim, window, u, GradientMode::central, active);
  o.parallel = true;
  opt.set_options(o);
  const auto parallel = opt.evaluate(*sim, window, u, GradientMode::central, active);
  EXPECT_GT(adj.visibility_energy, 0.0);
  EXPECT_EQ(sim->save().values, before.values);
  ASSERT_EQ(serial.gradient.size(), parallel.gradient.size());
  for (Eigen::Index i = 0; i < serial.gradient.size(); ++i)
    ASSERT_EQ(serial.gradient[i], parallel.gradient[i]) << i;
  const double rel = (adj.gradient - serial.gradient).norm() / adj.gradient.norm();
  std::printf("cloth gradient: |g| = %.4g, relative difference adjoint vs central = %.3g\n",
              adj.gradient.norm(), rel);
  EXPECT_LT(rel, 1e-4);
}

TEST(ControlCloth, CompressedDifferencesApproachTheAdjointGradientWithMoreRings) {
  const test::ClothScene scene = edge_on_scene();
  auto sim = scene.simulator();
  advance(scene, *sim, 10);
  ControlOptions o;
  ControlOptimizer opt(scene.two_sided, {}, o);
  const std::vector<ControlFrameInput> window{scene.control_input(11)};
  const std::vector<int> active = opt.active_blocks(*sim, window);
  ASSERT_GT(active.size(), 0u);
  const auto adj = opt.evaluate(*sim, window, {}, GradientMode::adjoint, active);
  ASSERT_GT(adj.gradient.norm(), 0.0);
  // The implicit step couples every vertex, but the response to a vertex force decays
  // exponentially with the graph distance (the inverse of a banded, well-conditioned Newton
  // matrix), so what compressed probes drop shrinks with every ring. Past the sheet's
  // diameter (12 + 8 edges) every colour holds one vertex and keeps its whole response: plain
  // central differences. One ring is no better than a zero gradient here (the hinge bending
  // energy couples each vertex to its neighbours' neighbours, so the response dropped past one
  // ring is not small); only the decrease from ring to ring is asserted.
  double last = std::numeric_limits<double>::infinity();
  int last_probes = 0;
  for (int rings : {1, 2, 3, 30}) {
    o.difference_rings = rings;
    opt.set_options(o);
    const auto cmp = opt.evaluate(*sim, window, {}, GradientMode::compressed, active);
    const double rel = (cmp.gradient - adj.gradient).norm() / adj.gradient.norm();
    std::printf("rings %d: %d probes, relative difference to the adjoint %.3g\n", rings, cmp.probes,
                rel);
    EXPECT_LT(rel, last) << "rings " << rings;
    EXPECT_GT(cmp.probes, last_probes);
    last = rel;
    last_probes = cmp.probes;
  }
  EXPECT_LT(last, 1e-4);  // the central-difference tolerance of the test above
  EXPECT_EQ(last_probes, 2 * 3 * static_cast<int>(active.size()));
}

struct SequenceResult {
  double violation_sum = 0.0;  // percent, summed over frames
  double ratio_median = 0.0;   // median over frames of control force / physical force
  int simulations = 0;         // window simulations of the optimizer (objective evaluations)
  int linearized_frames = 0;   // frames whose search ran on linearized dynamics
  int linearizations = 0;      // outer iterations of the linearized search, all frames
};

// Runs frames 1..frames of the swung cloth board, with control (solver) or without.
SequenceResult run_sequence(const test::ClothScene& scene, const ControlOptions* control) {
  auto sim = scene.simulator();
  ControlOptimizer opt(scene.two_sided, {}, control ? *control : ControlOptions{});
  SequenceResult out;
  std::vector<double> ratios;
  for (int f = 1; f <= scene.frames; ++f) {
    const std::vector<ControlFrameInput> window{scene.control_input(f)};
    const ControlFrameResult r =
        control ? opt.step(*sim, window) : opt.step_uncontrolled(*sim, window[0]);
    out.violation_sum += scene.violation_pct(sim->positions(), f);
    out.simulations += r.evaluations;
    out.linearized_frames += r.linearized ? 1 : 0;
    out.linearizations += r.linearizations;
    ratios.push_back(r.physical_force > 0.0 ? r.control_force / r.physical_force : 0.0);
  }
  std::sort(ratios.begin(), ratios.end());
  out.ratio_median = ratios[ratios.size() / 2];
  return out;
}

// The scene: a board anchored along one edge and swung 60 degrees back and forth in
// 0.7 s (the cloth preset's bending), 36 frames.
test::ClothScene swung_board() {
  test::ClothScene scene(12, 8);
  scene.amplitude_deg = 60.0;
  scene.period_s = 0.7;
  scene.bend_stiffness = 1e-4;
  scene.frames = 36;
  return scene;
}

class ClothEverySolver : public ::testing::TestWithParam<ControlSolver> {};

TEST_P(ClothEverySolver, ControlCutsTheViolationByNinetyPercentWithSmallForces) {
  // The scene: a board anchored along one edge and swung so that, without control,
  // its back turns to the camera. With control the violation summed over the sequence drops
  // by at least 90% while the median control / physical force ratio stays at most 0.25.
  const test::ClothScene scene = swung_board();
  const SequenceResult free = run_sequence(scene, nullptr);
  std::printf("without control: violation sum %.2f%%\n", free.violation_sum);
  ASSERT_GT(free.violation_sum / scene.frames, 2.0) << "the scene must expose the back";
  ControlOptions o;
  o.solver = GetParam();
  // COBYLA builds its linear models from evaluations alone (one simulation each).
  if (GetParam() == ControlSolver::cobyla) o.max_evaluations = 300;
  const SequenceResult controlled = run_sequence(scene, &o);
  std::printf("%s: violation sum %.2f%% -> %.2f%%, force ratio median %.3f\n",
              to_string(GetParam()), free.violation_sum, controlled.violation_sum,
              controlled.ratio_median);
  EXPECT_LE(controlled.violation_sum, 0.1 * free.violation_sum);
  EXPECT_LE(controlled.ratio_median, 0.25);
  EXPECT_GT(controlled.linearized_frames, 0);  // mass_spring offers linearize_step()
}

TEST(ControlCloth, NonlinearSearchAlsoCutsTheViolation) {
  // The same scene and criteria with linearized = false (every evaluation a simulation), the
  // path of engines with step_vjp() but no linearize_step(); the linearized search needs far
  // fewer simulations for it. And the linearized search's stop rule: with
  // linearized_ftol_initial (default 1e-3) it stops after an outer iteration that lowers the
  // energy by less than that fraction of the frame's initial energy; with 0 it runs all
  // max_linearizations unless a move fails. The early stop saves linearizations and still
  // meets the criteria.
  const test::ClothScene scene = swung_board();
  const SequenceResult free = run_sequence(scene, nullptr);
  ControlOptions o;
  o.solver = ControlSolver::lbfgs;
  o.max_evaluations = 20;
  const SequenceResult linearized = run_sequence(scene, &o);
  o.linearized_ftol_initial = 0.0;
  const SequenceResult full = run_sequence(scene, &o);
  o.linearized = false;
  const SequenceResult nonlinear = run_sequence(scene, &o);
  std::printf(
      "violation sum %.2f%%: linearized %.3f%% with %d simulations and %d linearizations "
      "(%.3f%% with %d without the stop rule), nonlinear %.3f%% with %d simulations\n",
      free.violation_sum, linearized.violation_sum, linearized.simulations,
      linearized.linearizations, full.violation_sum, full.linearizations, nonlinear.violation_sum,
      nonlinear.simulations);
  EXPECT_EQ(nonlinear.linearized_frames, 0);
  EXPECT_LE(nonlinear.violation_sum, 0.1 * free.violation_sum);
  EXPECT_LE(nonlinear.ratio_median, 0.25);
  EXPECT_LE(linearized.violation_sum, 0.1 * free.violation_sum);
  EXPECT_LE(linearized.ratio_median, 0.25);
  EXPECT_LT(linearized.simulations, nonlinear.simulations);
  EXPECT_LT(linearized.linearizations, full.linearizations);
  o.linearized_ftol_initial = 1.0;  // a fraction of the initial energy: below 1
  EXPECT_THROW(ControlOptimizer(scene.two_sided, {}, o), std::invalid_argument);
}

INSTANTIATE_TEST_SUITE_P(Solvers, ClothEverySolver,
                         ::testing::Values(ControlSolver::slsqp, ControlSolver::mma,
                                           ControlSolver::lbfgs, ControlSolver::cobyla,
                                           ControlSolver::ipopt),
                         [](const auto& info) { return std::string(to_string(info.param)); });

}  // namespace
}  // namespace pbve
