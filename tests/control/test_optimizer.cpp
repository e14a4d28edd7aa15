// The control optimizer on the reference particle adapter (exact derivatives): adjoint versus
// central-difference gradients, serial versus parallel probes, every solver, windows, the
// active set, hooks and bad input.

#include <cmath>
#include <functional>
#include <limits>
#include <numbers>
#include <string>
#include <vector>

#include <gtest/gtest.h>

#include "pbve/control/optimizer.hpp"
#include "pbve/core/error.hpp"
#include "sim/particle_simulator.hpp"

namespace pbve {
namespace {

constexpr int kN = 6;  // kN x kN particles

// A kN x kN sheet (0.25 m wide) through (0, 0, 1), bent to w = bend * u^2 (1/metres) and
// turned about the y axis by `angle` (radians; 0 = the sheet faces the camera with its
// triangles wound away from it, so they are hidden). A flat sheet turned by acos(c) has
// facing values c / |centroid|, about c.
Vertices sheet(double angle, double bend = 0.0) {
  Vertices x(kN * kN, 3);
  const double c = std::cos(angle), s = std::sin(angle);
  for (int i = 0; i < kN; ++i)
    for (int j = 0; j < kN; ++j) {
      const double u = 0.05 * i - 0.125, v = 0.05 * j - 0.125, w = bend * u * u;
      x.row(i * kN + j) << c * u - s * w, v, 1.0 + s * u + c * w;
    }
  return x;
}

Triangles sheet_triangles() {
  Triangles t(2 * (kN - 1) * (kN - 1), 3);
  int f = 0;
  for (int i = 0; i + 1 < kN; ++i)
    for (int j = 0; j + 1 < kN; ++j) {
      t.row(f++) << i * kN + j, (i + 1) * kN + j, i * kN + j + 1;
      t.row(f++) << (i + 1) * kN + j, (i + 1) * kN + j + 1, i * kN + j + 1;
    }
  return t;
}

// Every triangle of the sheet must stay hidden; anchors stay put.
std::vector<ControlFrameInput> frames(int count) {
  ControlFrameInput in;
  in.unobserved.assign(static_cast<size_t>(sheet_triangles().rows()), 1);
  return std::vector<ControlFrameInput>(static_cast<size_t>(count), in);
}

// Nearly edge-on: facing values about 0.02, inside the default margin 0.05.
const double kEdgeOn = std::acos(0.02);

// A particle adapter that hides its derivatives (a black-box engine).
class BlackBoxParticles : public test::ParticleSimulator {
 public:
  using ParticleSimulator::ParticleSimulator;
  bool has_derivatives() const override { return false; }
  std::unique_ptr<Simulator> clone() const override {
    return std::make_unique<BlackBoxParticles>(*this);
  }
};

double relative_error(const Eigen::VectorXd& a, const Eigen::VectorXd& b) {
  return (a - b).norm() / std::max(a.norm(), b.norm());
}

TEST(ControlOptimizer, ActiveBlocksOutsideTheLayoutAreErrors) {
  test::ParticleSimulator sim(sheet(kEdgeOn), {0});
  ControlOptimizer opt(sheet_triangles(), {}, ControlOptions{});
  const auto f = frames(1);
  const int blocks = sim.control_layout().num_blocks;
  for (const int b : {-1, blocks, 1000000})
    EXPECT_THROW(opt.evaluate(sim, f, {}, GradientMode::central, {b}), std::invalid_argument) << b;
  EXPECT_NO_THROW(opt.evaluate(sim, f, {}, GradientMode::central, {blocks - 1}));
}

TEST(ControlOptimizer, AdjointGradientMatchesCentralDifferences) {
  for (int window : {1, 3}) {
    test::ParticleSimulator sim(sheet(kEdgeOn), {0});
    ControlOptions o;
    o.window = window;
    o.weights = {1.0, 0.1, 0.1};
    ControlOptimizer opt(sheet_triangles(), {}, o);
    const auto f = frames(window);
    // A non-zero control so that EF and ET are away from their smoothed kinks.
    const int size = sim.control_layout().size();
    Eigen::VectorXd u = Eigen::VectorXd::Zero(window * size);
    for (int i = 0; i < u.size(); ++i) u[i] = 0.02 * std::sin(0.7 * i);
    const auto adj = opt.evaluate(sim, f, u, GradientMode::adjoint);
    const auto cen = opt.evaluate(sim, f, u, GradientMode::central);
    EXPECT_GT(adj.visibility_energy, 0.0);
    EXPECT_EQ(adj.energy, cen.energy);
    EXPECT_GT(adj.gradient.norm(), 0.0);
    EXPECT_LT(relative_error(adj.gradient, cen.gradient), 1e-4) << "window " << window;
    // Anchored block 0 carries no gradient.
    EXPECT_EQ(adj.gradient.head<3>().norm(), 0.0);
  }
}

TEST(ControlOptimizer, ParallelCentralDifferencesAreBitIdenticalToSerial) {
  test::ParticleSimulator sim(sheet(kEdgeOn), {0});
  ControlOptions o;
  o.window = 2;
  ControlOptimizer opt(sheet_triangles(), {}, o);
  const auto f = frames(2);
  const SimState before = sim.save();
  o.parallel = false;
  opt.set_options(o);
  const auto serial = opt.evaluate(sim, f, {}, GradientMode::central);
  o.parallel = true;
  opt.set_options(o);
  const auto parallel = opt.evaluate(sim, f, {}, GradientMode::central);
  ASSERT_EQ(serial.gradient.size(), parallel.gradient.size());
  for (Eigen::Index i = 0; i < serial.gradient.size(); ++i)
    ASSERT_EQ(serial.gradient[i], parallel.gradient[i]) << i;  // bit for bit
  EXPECT_GT(serial.gradient.norm(), 0.0);
  // evaluate() leaves the simulator where it was.
  EXPECT_EQ(sim.save().values, before.values);
}

class EverySolver : public ::testing::TestWithParam<ControlSolver> {};

TEST_P(EverySolver, KeepsTheSheetTurnedAway) {
  // Uncontrolled reference.
  test::ParticleSimulator free_sim(sheet(kEdgeOn), {0});
  ControlOptimizer reference(sheet_triangles());
  const auto f = frames(1);
  const ControlFrameResult base = reference.step_uncontrolled(free_sim, f[0]);
  ASSERT_GT(base.visibility_energy, 0.0);

  test::ParticleSimulator sim(sheet(kEdgeOn), {0});
  ControlOptions o;
  o.solver = GetParam();
  o.max_evaluations = GetParam() == ControlSolver::cobyla ? 2000 : 200;
  ControlOptimizer opt(sheet_triangles(), {}, o);
  const double e0 = opt.evaluate(sim, f, {}, GradientMode::automatic).energy;
  const ControlFrameResult r = opt.step(sim, f);
  // The initial energy reuses the active-set rule's uncontrolled step: the same number.
  EXPECT_EQ(r.initial_energy, e0);
  EXPECT_NE(r.status, ControlStatus::failed) << r.message;
  EXPECT_NE(r.status, ControlStatus::cancelled);
  EXPECT_GT(r.evaluations, 0);
  EXPECT_LT(r.visibility_energy, 0.05 * base.visibility_energy) << to_string(GetParam());
  EXPECT_LT(r.final_energy, r.initial_energy);
  EXPECT_GT(r.control_force, 0.0);
  EXPECT_GT(r.physical_force, 0.0);
  EXPECT_EQ(opt.previous_control(), r.control);
  // The committed step is the one the simulator took.
  test::ParticleSimulator replay(sheet(kEdgeOn), {0});
  StepInput in;
  in.control = r.control;
  replay.step(in);
  EXPECT_EQ(replay.positions(), sim.positions());
}

INSTANTIATE_TEST_SUITE_P(Solvers, EverySolver,
                         ::testing::Values(ControlSolver::slsqp, ControlSolver::mma,
                                           ControlSolver::lbfgs, ControlSolver::cobyla,
                                           ControlSolver::ipopt),
                         [](const auto& info) { return std::string(to_string(info.param)); });

TEST(ControlOptimizer, SkipsTheSolverWhenZeroControlKeepsEverythingHidden) {
  // Facing values about 0.2: inside the active band (0.3), so the blocks are optimized, but
  // beyond the margin (0.05), so EC = 0 at zero control.
  const double turned = std::acos(0.2);
  test::ParticleSimulator sim(sheet(turned), {0});
  ControlOptimizer opt(sheet_triangles());
  const ControlFrameResult r = opt.step(sim, frames(1));
  EXPECT_GT(r.active_blocks, 0);
  EXPECT_EQ(r.evaluations, 1);
  EXPECT_EQ(r.status, ControlStatus::converged);
  EXPECT_NE(r.message.find("no triangle at risk"), std::string::npos) << r.message;
  EXPECT_TRUE(r.control.isZero(0.0));
  EXPECT_EQ(r.visibility_energy, 0.0);
  EXPECT_EQ(r.energy, 0.0);

  // With lT > lF the shortcut does not apply: the solver runs, and finds nothing lower.
  test::ParticleSimulator sim2(sheet(turned), {0});
  ControlOptions o;
  o.weights.temporal = 2.0 * o.weights.force;
  ControlOptimizer solved(sheet_triangles(), {}, o);
  const ControlFrameResult r2 = solved.step(sim2, frames(1));
  EXPECT_EQ(r2.message.find("no triangle at risk"), std::string::npos) << r2.message;
  EXPECT_GE(r2.energy, r.energy);
  EXPECT_EQ(sim2.positions(), sim.positions());
}

TEST(ControlOptimizer, ClustersShareOneAccelerationAndKeepTheSheetTurnedAway) {
  // 8 clusters over the 35 free particles (24 variables instead of 105). A reduced space is
  // not always rich enough: on this sheet 3, 4 and 12 clusters leave EC at 2-15% of its
  // uncontrolled value whatever the solver, 6, 8 and 16 reach below 5%.
  test::ParticleSimulator free_sim(sheet(kEdgeOn), {0});
  ControlOptimizer reference(sheet_triangles());
  const ControlFrameResult base = reference.step_uncontrolled(free_sim, frames(1)[0]);
  ASSERT_GT(base.visibility_energy, 0.0);

  for (bool black_box : {false, true}) {
    std::unique_ptr<test::ParticleSimulator> sim =
        black_box ? std::make_unique<BlackBoxParticles>(sheet(kEdgeOn), std::vector<int>{0})
                  : std::make_unique<test::ParticleSimulator>(sheet(kEdgeOn), std::vector<int>{0});
    ControlOptions o;
    o.clusters = 8;
    o.active_set = ActiveSet::all;
    ControlOptimizer opt(sheet_triangles(), {}, o);
    const ControlFrameResult r = opt.step(*sim, frames(1));
    EXPECT_EQ(r.adjoint, !black_box);
    EXPECT_EQ(r.active_blocks, kN * kN - 1);  // every free particle
    EXPECT_LE(r.variables, 3 * o.clusters);
    EXPECT_GE(r.variables, 3);
    EXPECT_LT(r.visibility_energy, 0.05 * base.visibility_energy) << black_box;
    // Every block's force is its mass times one of at most `clusters` accelerations.
    const ControlLayout layout = sim->control_layout();
    std::vector<Eigen::Vector3d> accelerations;
    for (int b = 0; b < layout.num_blocks; ++b) {
      if (b == 0) continue;  // anchored
      const Eigen::Vector3d a = r.control.segment<3>(3 * b) / layout.block_mass[b];
      bool known = false;
      for (const auto& q : accelerations) known = known || (q - a).norm() <= 1e-12 * q.norm();
      if (!known) accelerations.push_back(a);
    }
    EXPECT_LE(static_cast<int>(accelerations.size()), o.clusters);
    EXPECT_GT(r.control_force, 0.0);
  }
}

TEST(ControlOptimizer, CentralDifferencesThroughABlackBoxEngine) {
  // Every way of searching without derivatives: (compressed) central differences, on the
  // responses (linearized) or per evaluation.
  for (GradientMode mode : {GradientMode::automatic, GradientMode::central})
    for (bool linearized : {true, false}) {
      BlackBoxParticles sim(sheet(kEdgeOn), {0});
      ControlOptions o;
      o.gradient = mode;
      o.linearized = linearized;
      o.difference_rings = 0;  // free particles: exact (see the next test)
      ControlOptimizer opt(sheet_triangles(), {}, o);
      EXPECT_THROW(opt.evaluate(sim, frames(1), {}, GradientMode::adjoint), std::invalid_argument);
      const ControlFrameResult r = opt.step(sim, frames(1));
      SCOPED_TRACE(testing::Message()
                   << "mode " << static_cast<int>(mode) << " linearized " << linearized);
      EXPECT_FALSE(r.adjoint);
      EXPECT_EQ(r.linearized, linearized);
      EXPECT_NE(r.status, ControlStatus::failed);
      EXPECT_GT(r.gradient_evaluations, 0);
      EXPECT_LT(r.final_energy, r.initial_energy);
      // A gradient or response costs 2 probes per variable, or (compressed: automatic on a
      // black box) 2 per variable of one particle and colour, here one colour.
      const int per_gradient = mode == GradientMode::central ? 2 * r.variables : 6;
      EXPECT_GE(r.probes, per_gradient);
      EXPECT_EQ(r.probes % per_gradient, 0);
      if (linearized) {
        EXPECT_LE(r.probes, o.max_linearizations * per_gradient);
      }
    }
}

TEST(ControlOptimizer, CompressedDifferencesAreExactWhenTheResponseIsLocal) {
  // Free particles: a force moves its own particle only, so probing far-apart particles
  // together loses nothing and the compressed gradient is the central one (to rounding).
  test::ParticleSimulator sim(sheet(kEdgeOn), {0});
  ControlOptions o;
  o.weights = {1.0, 0.1, 0.1};
  ControlOptimizer opt(sheet_triangles(), {}, o);
  const auto f = frames(1);
  const int size = sim.control_layout().size();
  Eigen::VectorXd u = Eigen::VectorXd::Zero(size);
  for (int i = 0; i < u.size(); ++i) u[i] = 0.02 * std::sin(0.7 * i);
  const SimState before = sim.save();
  const auto adj = opt.evaluate(sim, f, u, GradientMode::adjoint);
  const auto cen = opt.evaluate(sim, f, u, GradientMode::central);
  EXPECT_GT(adj.visibility_energy, 0.0);
  EXPECT_EQ(adj.probes, 0);
  EXPECT_EQ(cen.probes, 2 * 3 * (kN * kN - 1));  // every free particle on its own
  int previous = 0;
  for (int rings : {0, 1, 2}) {
    o.difference_rings = rings;
    for (bool parallel : {false, true}) {
      o.parallel = parallel;
      opt.set_options(o);
      const auto cmp = opt.evaluate(sim, f, u, GradientMode::compressed);
      EXPECT_EQ(cmp.energy, adj.energy);
      EXPECT_LT(relative_error(adj.gradient, cmp.gradient), 1e-4) << "rings " << rings;
      EXPECT_EQ(cmp.gradient.head<3>().norm(), 0.0);  // anchored
      // Rings 0: all particles in one probe per axis and sign. More rings: more colours, and
      // the particles of a colour are more than 2 * rings edges apart.
      if (rings == 0) {
        EXPECT_EQ(cmp.probes, 6);
      } else {
        EXPECT_GT(cmp.probes, previous);
      }
      EXPECT_LT(cmp.probes, cen.probes);
      if (parallel) previous = cmp.probes;
    }
  }
  EXPECT_EQ(sim.save().values, before.values);
  EXPECT_THROW(
      {
        o.difference_rings = -1;
        opt.set_options(o);
      },
      std::invalid_argument);
}

TEST(ControlOptimizer, WindowCommitsOnlyTheFirstFrame) {
  test::ParticleSimulator sim(sheet(kEdgeOn), {0});
  ControlOptions o;
  o.window = 3;
  o.solver = ControlSolver::lbfgs;  // SLSQP's dense subproblem is slow at 3 x 105 variables
  ControlOptimizer opt(sheet_triangles(), {}, o);
  const ControlFrameResult r = opt.step(sim, frames(5));
  EXPECT_EQ(r.variables, 3 * 3 * r.active_blocks);
  EXPECT_NE(r.status, ControlStatus::failed);
  EXPECT_LT(r.final_energy, r.initial_energy);
  EXPECT_EQ(r.control.size(), sim.control_layout().size());
  // A window longer than the frames left is cut.
  test::ParticleSimulator sim2(sheet(kEdgeOn), {0});
  EXPECT_EQ(opt.step(sim2, frames(1)).variables, 3 * opt.active_blocks(sim2, frames(1)).size());
}

TEST(ControlOptimizer, ActiveSetTakesBlocksNearTheBoundaryAndNeverAnchors) {
  // A bent sheet: facing values from about 0 to 0.8, so only part of it is near edge-on.
  test::ParticleSimulator sim(sheet(0.35 * std::numbers::pi, 2.0), {0, 1});
  ControlOptions o;
  o.active_band = 0.2;
  o.active_rings = 0;
  ControlOptimizer opt(sheet_triangles(), {}, o);
  const auto f = frames(1);
  const std::vector<int> risk = opt.active_blocks(sim, f);
  o.active_set = ActiveSet::all;
  opt.set_options(o);
  const std::vector<int> all = opt.active_blocks(sim, f);
  EXPECT_EQ(all.size(), static_cast<size_t>(kN * kN - 2));
  EXPECT_GT(risk.size(), 0u);
  EXPECT_LT(risk.size(), all.size());
  for (int b : risk) EXPECT_TRUE(b != 0 && b != 1);
  // Growing rings only adds blocks.
  o.active_set = ActiveSet::at_risk;
  o.active_rings = 1;
  opt.set_options(o);
  const std::vector<int> grown = opt.active_blocks(sim, f);
  EXPECT_GT(grown.size(), risk.size());
  EXPECT_TRUE(std::includes(grown.begin(), grown.end(), risk.begin(), risk.end()));
}

TEST(ControlOptimizer, CancelHookStopsAndStillSteps) {
  test::ParticleSimulator sim(sheet(kEdgeOn), {0});
  const Vertices x0 = sim.positions();
  ControlOptimizer opt(sheet_triangles());
  int progress_calls = 0;
  ControlCallbacks cb;
  cb.progress = [&](const ControlProgress& p) {
    ++progress_calls;
    EXPECT_LE(p.best_energy, p.energy);
  };
  cb.cancel = [&] { return progress_calls >= 2; };
  const ControlFrameResult r = opt.step(sim, frames(1), cb);
  EXPECT_EQ(r.status, ControlStatus::cancelled);
  EXPECT_EQ(progress_calls, 2);
  EXPECT_NE(sim.positions(), x0);
}

TEST(ControlOptimizer, HardConstraintModeForComparison) {
  test::ParticleSimulator free_sim(sheet(kEdgeOn), {0});
  ControlOptimizer reference(sheet_triangles());
  const double base = reference.step_uncontrolled(free_sim, frames(1)[0]).visibility_energy;
  test::ParticleSimulator sim(sheet(kEdgeOn), {0});
  ControlOptions o;
  o.constraint = ConstraintMode::hard;
  ControlOptimizer opt(sheet_triangles(), {}, o);
  const ControlFrameResult r = opt.step(sim, frames(1));
  EXPECT_NE(r.status, ControlStatus::failed) << r.message;
  EXPECT_LT(r.visibility_energy, 0.05 * base);
  o.solver = ControlSolver::lbfgs;
  EXPECT_THROW(opt.set_options(o), std::invalid_argument);
}

// Every field's invalid values are refused by name, with the value, where the optimizer takes
// options (constructor and set_options(), which then keeps the options it had).
TEST(ControlOptions, InvalidValuesNameTheFieldAndTheValue) {
  const double nan = std::numeric_limits<double>::quiet_NaN();
  const double inf = std::numeric_limits<double>::infinity();
  struct Case {
    const char* field;
    std::function<void(ControlOptions&)> set;
    const char* value;  // as the message writes it
  };
  const std::vector<Case> cases = {
      {"weights.visibility", [&](ControlOptions& o) { o.weights.visibility = -1.0; }, "-1"},
      {"weights.force", [&](ControlOptions& o) { o.weights.force = nan; }, "nan"},
      {"weights.temporal", [&](ControlOptions& o) { o.weights.temporal = inf; }, "inf"},
      {"barrier.margin", [&](ControlOptions& o) { o.barrier.margin = 0.0; }, "0"},
      {"barrier.margin", [&](ControlOptions& o) { o.barrier.margin = inf; }, "inf"},
      {"barrier.clamp", [&](ControlOptions& o) { o.barrier.clamp = 1.0; }, "1"},
      {"solver", [&](ControlOptions& o) { o.solver = static_cast<ControlSolver>(7); }, "7"},
      {"gradient", [&](ControlOptions& o) { o.gradient = static_cast<GradientMode>(-1); }, "-1"},
      {"constraint", [&](ControlOptions& o) { o.constraint = static_cast<ConstraintMode>(2); },
       "2"},
      {"initial_guess", [&](ControlOptions& o) { o.initial_guess = static_cast<InitialGuess>(5); },
       "5"},
      {"window", [&](ControlOptions& o) { o.window = 0; }, "0"},
      {"active_set", [&](ControlOptions& o) { o.active_set = static_cast<ActiveSet>(3); }, "3"},
      {"active_band", [&](ControlOptions& o) { o.active_band = nan; }, "nan"},
      {"active_rings", [&](ControlOptions& o) { o.active_rings = -1; }, "-1"},
      {"clusters", [&](ControlOptions& o) { o.clusters = -4; }, "-4"},
      {"occlusion_margin", [&](ControlOptions& o) { o.occlusion_margin = 1.0; }, "1"},
      {"force_bound", [&](ControlOptions& o) { o.force_bound = nan; }, "nan"},
      {"force_bound", [&](ControlOptions& o) { o.force_bound = -0.5; }, "-0.5"},
      {"torque_arm", [&](ControlOptions& o) { o.torque_arm = 0.0; }, "0"},
      {"torque_arm", [&](ControlOptions& o) { o.torque_arm = -0.1; }, "-0.1"},
      {"force_smoothing", [&](ControlOptions& o) { o.force_smoothing = inf; }, "inf"},
      {"fd_step", [&](ControlOptions& o) { o.fd_step = inf; }, "inf"},
      {"fd_step", [&](ControlOptions& o) { o.fd_step = 0.0; }, "0"},
      {"difference_rings", [&](ControlOptions& o) { o.difference_rings = -2; }, "-2"},
      {"max_linearizations", [&](ControlOptions& o) { o.max_linearizations = 0; }, "0"},
      {"linearized_ftol_initial", [&](ControlOptions& o) { o.linearized_ftol_initial = nan; },
       "nan"},
      {"model_ftol_rel", [&](ControlOptions& o) { o.model_ftol_rel = -1e-4; }, "-0.0001"},
      {"max_evaluations", [&](ControlOptions& o) { o.max_evaluations = 0; }, "0"},
      {"ftol_rel", [&](ControlOptions& o) { o.ftol_rel = nan; }, "nan"},
      {"xtol_abs", [&](ControlOptions& o) { o.xtol_abs = -1.0; }, "-1"},
      {"time_limit_s", [&](ControlOptions& o) { o.time_limit_s = -1.0; }, "-1"},
      {"time_limit_s", [&](ControlOptions& o) { o.time_limit_s = inf; }, "inf"},
      {"solver",
       [&](ControlOptions& o) {
         o.constraint = ConstraintMode::hard;
         o.solver = ControlSolver::lbfgs;
       },
       "lbfgs"},
  };
  ControlOptimizer opt(sheet_triangles());
  ControlOptions kept;
  kept.max_evaluations = 17;
  opt.set_options(kept);
  for (const Case& c : cases) {
    ControlOptions o;
    c.set(o);
    const std::string key = std::string("ControlOptions::") + c.field;
    try {
      o.validate();
      ADD_FAILURE() << key << " = " << c.value << " accepted";
    } catch (const InputError& e) {
      const std::string m = e.what();
      EXPECT_EQ(e.key(), key) << m;
      EXPECT_NE(m.find(key + ": "), std::string::npos) << m;
      EXPECT_NE(m.find(c.value), std::string::npos) << m;
    }
    EXPECT_THROW(ControlOptimizer(sheet_triangles(), {}, o), InputError) << key;
    EXPECT_THROW(opt.set_options(o), InputError) << key;
    EXPECT_EQ(opt.options().max_evaluations, 17) << key;  // the options it had are kept
  }
}

// Values at the edges of the documented ranges are taken, and the optimizer runs with them.
TEST(ControlOptions, DocumentedEdgeValuesAreAccepted) {
  ControlOptions o;
  o.weights = {0.0, 0.0, 0.0};
  o.active_band = -2.0;  // no triangle at risk
  o.active_rings = 0;
  o.occlusion_margin = 0.0;
  o.force_bound = 0.0;
  o.linearized_ftol_initial = 0.0;
  o.model_ftol_rel = 0.0;
  o.ftol_rel = 0.0;
  o.xtol_abs = 0.0;
  o.time_limit_s = 0.0;
  o.difference_rings = 0;
  EXPECT_NO_THROW(o.validate());
  o.active_band = 2.0;  // every must-stay-hidden triangle at risk
  o.weights.visibility = 1.0;
  EXPECT_NO_THROW(o.validate());
  test::ParticleSimulator sim(sheet(kEdgeOn), {0});
  ControlOptimizer opt(sheet_triangles(), {}, o);
  EXPECT_NE(opt.step(sim, frames(1)).status, ControlStatus::failed);
}

// More rings than the mesh has reach stop growing: every free block, at once.
TEST(ControlOptimizer, RingCountsBeyondTheMeshStopGrowing) {
  test::ParticleSimulator sim(sheet(kEdgeOn), {0});
  ControlOptions o;
  o.active_rings = std::numeric_limits<int>::max();
  o.difference_rings = std::numeric_limits<int>::max();
  o.gradient = GradientMode::compressed;
  ControlOptimizer opt(sheet_triangles(), {}, o);
  EXPECT_EQ(opt.active_blocks(sim, frames(1)).size(), static_cast<size_t>(kN * kN - 1));
  const ControlEnergyEval e = opt.evaluate(sim, frames(1), {}, GradientMode::compressed);
  EXPECT_TRUE(e.gradient.allFinite());
}

// ControlFrameInput::observed is one flag per triangle or empty (no occlusion term); another
// size is an error naming both sizes, whether or not the occlusion term is on.
TEST(ControlOptimizer, ObservedFlagsOfAnotherSizeAreErrors) {
  const auto nf = static_cast<size_t>(sheet_triangles().rows());
  for (const double occlusion_margin : {0.5, 0.0}) {
    ControlOptions o;
    o.occlusion_margin = occlusion_margin;
    for (const size_t size : {size_t{3}, nf + 1}) {
      std::vector<ControlFrameInput> in = frames(2);
      in[1].observed.assign(size, 0);
      auto expect_refused = [&](int frame, auto call) {
        const std::string expected = "ControlFrameInput::observed of frame " +
                                     std::to_string(frame) + " has " + std::to_string(size) +
                                     " entries, expected " + std::to_string(nf);
        try {
          call();
          ADD_FAILURE() << size << " observed flags accepted";
        } catch (const std::invalid_argument& e) {
          EXPECT_NE(std::string(e.what()).find(expected), std::string::npos) << e.what();
        }
      };
      o.window = 2;
      test::ParticleSimulator sim(sheet(kEdgeOn), {0});
      ControlOptimizer opt(sheet_triangles(), {}, o);
      const Vertices x0 = sim.positions();
      expect_refused(1, [&] { opt.step(sim, in); });
      expect_refused(1, [&] { opt.evaluate(sim, in, {}, GradientMode::central); });
      EXPECT_EQ(sim.positions(), x0);  // refused before any step
      in[0] = in[1];
      expect_refused(0, [&] { opt.step_uncontrolled(sim, in[0]); });
    }
    // Empty (no occlusion term) and one per triangle are taken.
    std::vector<ControlFrameInput> in = frames(1);
    test::ParticleSimulator sim(sheet(kEdgeOn), {0});
    ControlOptimizer opt(sheet_triangles(), {}, o);
    EXPECT_NO_THROW(opt.step(sim, in));
    in[0].observed.assign(nf, 0);
    EXPECT_NO_THROW(opt.step(sim, in));
  }
}

TEST(ControlOptimizer, RejectsBadInput) {
  test::ParticleSimulator sim(sheet(kEdgeOn), {0});
  ControlOptimizer opt(sheet_triangles());
  EXPECT_THROW(opt.step(sim, {}), std::invalid_argument);
  std::vector<ControlFrameInput> wrong(1);
  wrong[0].unobserved.assign(3, 1);
  EXPECT_THROW(opt.step(sim, wrong), std::invalid_argument);
  ControlOptions o;
  o.window = 0;
  EXPECT_THROW(opt.set_options(o), std::invalid_argument);
  EXPECT_THROW(ControlOptimizer(sheet_triangles(), {1, 0}), std::invalid_argument);
  EXPECT_THROW(parse_control_solver("knitro"), std::invalid_argument);
  EXPECT_EQ(parse_control_solver("ipopt"), ControlSolver::ipopt);
}

}  // namespace
}  // namespace pbve
