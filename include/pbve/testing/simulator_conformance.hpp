#pragma once
/// @file
/// The adapter conformance suite: every engine behind pbve::Simulator passes it.
///
/// Instantiate it for an adapter in a test file linked with GoogleTest:
/// @code
/// #include "pbve/testing/simulator_conformance.hpp"
///
/// INSTANTIATE_TEST_SUITE_P(MyEngine, SimulatorConformance,
///     ::testing::Values(pbve::testing::ConformanceCase{
///         "cloth", [] { return std::make_unique<MySimulator>(/*...*/); }}),
///     pbve::testing::case_name);
/// @endcode
/// Include this header in exactly one source file of a test program (it defines the tests).
/// The factory must return a simulator at rest with at least one anchor and at least one free
/// block. Each property is also available as a function returning ::testing::AssertionResult
/// (check_save_restore(), ...), so a test can show that a deliberately broken adapter fails it.
///
/// Properties checked: the sizes and indices of pbve::check_simulator(), exact save/restore
/// replay, restore into a clone, clone equivalence and independence (also stepped in parallel
/// on two threads), anchors exactly at their targets after every step, f = m a (displacement
/// and velocity) for a small force on a free block, physical forces of the right size and zero
/// on anchors, determinism of two fresh instances, no NaN under a large but legal step,
/// std::invalid_argument on wrong sizes, and — when the adapter offers derivatives —
/// step_vjp() against central differences.

#include <cmath>
#include <exception>
#include <functional>
#include <memory>
#include <ostream>
#include <random>
#include <sstream>
#include <stdexcept>
#include <string>
#include <thread>

#include <gtest/gtest.h>

#include "pbve/sim/simulator.hpp"

namespace pbve::testing {

/// One configuration of an adapter under test.
struct ConformanceCase {
  std::string name;                                  ///< test-name suffix: [A-Za-z0-9_]
  std::function<std::unique_ptr<Simulator>()> make;  ///< fresh simulator at rest
  double dt = 1.0 / 30.0;                            ///< frame interval for the replay checks, s
  int steps = 6;                                     ///< steps in the replay checks
  /// f = m a probe: `fma_steps` steps of `fma_dt` seconds with a constant force on one free
  /// block; its extra displacement is compared with a T^2 / 2 (T = fma_steps * fma_dt).
  /// Choose fma_dt * fma_steps well below the block's shortest natural period so that
  /// elastic and damping forces of the displaced block stay negligible.
  double fma_dt = 1e-4;
  int fma_steps = 20;
  /// Relative tolerance of the f = m a check. A first-order integrator over N steps from rest
  /// gives N(N+1)/2 h^2 a instead of N^2 h^2 a / 2: a relative error of 1/N. The velocity,
  /// a T, gets twice this tolerance (see check_force_mass()).
  double fma_tolerance = 0.1;
  double large_dt = 0.25;       ///< a large but legal step for the NaN check, s
  double vjp_tolerance = 1e-4;  ///< relative error of step_vjp() against central differences
};

/// Prints a case by its name in test output.
inline void PrintTo(const ConformanceCase& c, std::ostream* os) {
  *os << c.name;
}

/// gtest name generator for INSTANTIATE_TEST_SUITE_P.
inline std::string case_name(const ::testing::TestParamInfo<ConformanceCase>& info) {
  return info.param.name;
}

namespace detail {

/// A deterministic step input: anchors move along a smooth path, small forces on free blocks.
inline StepInput make_input(const Simulator& sim, const Vertices& anchors_at_rest, int k, double dt,
                            unsigned seed) {
  StepInput in;
  in.dt = dt;
  const ControlLayout layout = sim.control_layout();
  in.control = Eigen::VectorXd::Zero(layout.size());
  std::mt19937 rng(seed + 7919u * static_cast<unsigned>(k));
  std::uniform_real_distribution<double> u(-1.0, 1.0);
  const int bs = layout.block_size();
  for (int b = 0; b < layout.num_blocks; ++b) {
    // About a tenth of the block's weight: small compared with gravity.
    const double scale = 0.1 * 9.81 * layout.block_mass(b);
    for (int c = 0; c < 3; ++c) in.control(b * bs + c) = scale * u(rng);
  }
  in.anchor_targets = anchors_at_rest;
  const double s = 0.01 * (k + 1);
  for (Eigen::Index r = 0; r < in.anchor_targets.rows(); ++r) {
    in.anchor_targets(r, 0) += s;
    in.anchor_targets(r, 1) += 0.5 * s * std::sin(0.7 * k);
  }
  return in;
}

inline Vertices anchor_positions(const Simulator& sim) {
  const Vertices p = sim.positions();
  const std::vector<int> a = sim.anchors();
  Vertices out(static_cast<Eigen::Index>(a.size()), 3);
  for (size_t i = 0; i < a.size(); ++i) out.row(static_cast<Eigen::Index>(i)) = p.row(a[i]);
  return out;
}

/// Runs `steps` steps from the current state with inputs k0 .. k0+steps-1.
inline Vertices run(Simulator& sim, const Vertices& anchors_at_rest, int k0, int steps, double dt) {
  for (int k = k0; k < k0 + steps; ++k) sim.step(make_input(sim, anchors_at_rest, k, dt, 1u));
  return sim.positions();
}

inline ::testing::AssertionResult bit_equal(const Vertices& a, const Vertices& b,
                                            const char* what) {
  if (a.rows() != b.rows())
    return ::testing::AssertionFailure()
           << what << ": row counts differ (" << a.rows() << " vs " << b.rows() << ")";
  for (Eigen::Index i = 0; i < a.rows(); ++i)
    for (int c = 0; c < 3; ++c)
      if (!(a(i, c) == b(i, c)))
        return ::testing::AssertionFailure()
               << what << ": vertex " << i << " coordinate " << c << " differs: " << a(i, c)
               << " vs " << b(i, c) << " (difference " << a(i, c) - b(i, c) << ")";
  return ::testing::AssertionSuccess();
}

/// First free block that moves a surface vertex; -1 when none.
inline int free_block(const Simulator& sim, int* vertex) {
  const ControlLayout layout = sim.control_layout();
  const std::vector<int> anchors = sim.anchors();
  std::vector<char> anchored(static_cast<size_t>(sim.num_vertices()), 0);
  for (int a : anchors) anchored[static_cast<size_t>(a)] = 1;
  // Prefer the block whose vertex is farthest (in index order) from anchors: the last one.
  for (int v = sim.num_vertices() - 1; v >= 0; --v) {
    const int b = layout.vertex_block[static_cast<size_t>(v)];
    if (b < 0 || anchored[static_cast<size_t>(v)]) continue;
    if (layout.space == ControlSpace::body_wrench) {
      bool body_anchored = false;
      for (int a : anchors) body_anchored |= layout.vertex_block[static_cast<size_t>(a)] == b;
      if (body_anchored) continue;
    }
    *vertex = v;
    return b;
  }
  return -1;
}

}  // namespace detail

/// Sanity of the factory's simulator: pbve::check_simulator() (sizes, sorted distinct anchors
/// in range, a consistent control layout), finite positions, positive block masses, at rest,
/// at least one anchor and one free block.
inline ::testing::AssertionResult check_layout(const ConformanceCase& c) {
  auto sim = c.make();
  const int n = sim->num_vertices();
  if (n <= 0) return ::testing::AssertionFailure() << "no surface vertices";
  try {
    check_simulator(*sim);
  } catch (const std::logic_error& e) {
    return ::testing::AssertionFailure() << e.what();
  }
  const ControlLayout layout = sim->control_layout();
  if (!sim->positions().allFinite()) return ::testing::AssertionFailure() << "non-finite positions";
  for (int b = 0; b < layout.num_blocks; ++b)
    if (!(layout.block_mass(b) > 0.0))
      return ::testing::AssertionFailure() << "block " << b << " has mass " << layout.block_mass(b);
  if (sim->anchors().empty()) return ::testing::AssertionFailure() << "the case has no anchor";
  if (sim->velocities().norm() != 0.0)
    return ::testing::AssertionFailure() << "a new simulator must be at rest";
  int v = -1;
  if (detail::free_block(*sim, &v) < 0) return ::testing::AssertionFailure() << "no free block";
  return ::testing::AssertionSuccess();
}

/// save(), more steps, restore(), the same steps again: identical positions and velocities.
inline ::testing::AssertionResult check_save_restore(const ConformanceCase& c) {
  auto sim = c.make();
  const Vertices rest = detail::anchor_positions(*sim);
  detail::run(*sim, rest, 0, c.steps / 2, c.dt);
  const SimState saved = sim->save();
  const Vertices first = detail::run(*sim, rest, 100, c.steps, c.dt);
  const Vertices first_v = sim->velocities();
  sim->restore(saved);
  const Vertices second = detail::run(*sim, rest, 100, c.steps, c.dt);
  auto r = detail::bit_equal(first, second, "positions after restore and replay");
  if (!r) return r;
  return detail::bit_equal(first_v, sim->velocities(), "velocities after restore and replay");
}

/// A state saved in one instance and restored into another (a clone) replays identically.
inline ::testing::AssertionResult check_restore_into_clone(const ConformanceCase& c) {
  auto sim = c.make();
  const Vertices rest = detail::anchor_positions(*sim);
  auto other = sim->clone();
  detail::run(*sim, rest, 0, c.steps, c.dt);
  other->restore(sim->save());
  const Vertices a = detail::run(*sim, rest, 50, c.steps, c.dt);
  const Vertices b = detail::run(*other, rest, 50, c.steps, c.dt);
  return detail::bit_equal(a, b, "positions of a clone restored from the original's state");
}

/// clone() in a mid-run state steps identically, and stepping it leaves the original alone.
inline ::testing::AssertionResult check_clone(const ConformanceCase& c) {
  auto sim = c.make();
  const Vertices rest = detail::anchor_positions(*sim);
  detail::run(*sim, rest, 0, c.steps, c.dt);
  auto copy = sim->clone();
  auto r = detail::bit_equal(sim->positions(), copy->positions(), "clone's positions");
  if (!r) return r;
  const Vertices before = sim->positions();
  detail::run(*copy, rest, 20, c.steps, c.dt);
  r = detail::bit_equal(sim->positions(), before, "original after stepping its clone");
  if (!r) return r;
  const Vertices a = detail::run(*sim, rest, 20, c.steps, c.dt);
  return detail::bit_equal(a, copy->positions(), "original vs clone after the same steps");
}

/// After every step, each anchor is exactly at its target.
inline ::testing::AssertionResult check_anchors(const ConformanceCase& c) {
  auto sim = c.make();
  const Vertices rest = detail::anchor_positions(*sim);
  const std::vector<int> anchors = sim->anchors();
  for (int k = 0; k < c.steps; ++k) {
    const StepInput in = detail::make_input(*sim, rest, k, c.dt, 3u);
    sim->step(in);
    const Vertices p = sim->positions();
    for (size_t i = 0; i < anchors.size(); ++i)
      for (int d = 0; d < 3; ++d)
        if (!(p(anchors[i], d) == in.anchor_targets(static_cast<Eigen::Index>(i), d)))
          return ::testing::AssertionFailure()
                 << "step " << k << ": anchor vertex " << anchors[i] << " coordinate " << d
                 << " is " << p(anchors[i], d) << ", target "
                 << in.anchor_targets(static_cast<Eigen::Index>(i), d);
  }
  return ::testing::AssertionSuccess();
}

/// A constant force f on one free block for T seconds displaces it by (f / m) T^2 / 2 more
/// than without the force.
inline ::testing::AssertionResult check_force_mass(const ConformanceCase& c) {
  auto with = c.make();
  auto without = c.make();
  int vertex = -1;
  const int block = detail::free_block(*with, &vertex);
  if (block < 0) return ::testing::AssertionFailure() << "no free block";
  const ControlLayout layout = with->control_layout();
  const double m = layout.block_mass(block);
  const Eigen::Vector3d accel(0.3, -0.2, 0.25);  // m/s^2, small next to gravity
  StepInput in;
  in.dt = c.fma_dt;
  in.control = Eigen::VectorXd::Zero(layout.size());
  in.control.segment<3>(block * layout.block_size()) = m * accel;
  StepInput zero = in;
  zero.control.setZero();
  for (int k = 0; k < c.fma_steps; ++k) {
    with->step(in);
    without->step(zero);
  }
  const Eigen::Vector3d d =
      (with->positions().row(vertex) - without->positions().row(vertex)).transpose();
  const double T = c.fma_dt * c.fma_steps;
  const Eigen::Vector3d expected = 0.5 * accel * T * T;
  const double err = (d - expected).norm() / expected.norm();
  if (!(err <= c.fma_tolerance))
    return ::testing::AssertionFailure()
           << "block " << block << " (vertex " << vertex << ", mass " << m << " kg): extra "
           << "displacement " << d.transpose() << " m, expected " << expected.transpose()
           << " m (relative error " << err << " > " << c.fma_tolerance << ")";
  // The extra velocity is a T: exact for symplectic and backward Euler from rest, whatever the
  // number of steps, up to the elastic forces of the displaced block. Those lower it twice as
  // much as the displacement (a block of natural frequency w pushed from rest: v = (a / w)
  // sin wT = a T (1 - (wT)^2 / 6 + ...), x = a T^2 / 2 (1 - (wT)^2 / 12 + ...)), hence twice
  // the tolerance.
  const Eigen::Vector3d dv =
      (with->velocities().row(vertex) - without->velocities().row(vertex)).transpose();
  const Eigen::Vector3d expected_v = accel * T;
  const double err_v = (dv - expected_v).norm() / expected_v.norm();
  if (!(err_v <= 2.0 * c.fma_tolerance))
    return ::testing::AssertionFailure()
           << "block " << block << " (vertex " << vertex << ", mass " << m << " kg): extra "
           << "velocity " << dv.transpose() << " m/s, expected " << expected_v.transpose()
           << " m/s (relative error " << err_v << " > " << 2.0 * c.fma_tolerance << ")";
  return ::testing::AssertionSuccess();
}

/// After each step: physical_forces() is #V by 3 and finite, physical_force_magnitudes() has
/// one finite, non-negative entry per surface vertex, and both are zero on anchored vertices.
inline ::testing::AssertionResult check_physical_forces(const ConformanceCase& c) {
  auto sim = c.make();
  const Vertices rest = detail::anchor_positions(*sim);
  const std::vector<int> anchors = sim->anchors();
  for (int k = 0; k < c.steps; ++k) {
    sim->step(detail::make_input(*sim, rest, k, c.dt, 13u));
    const Vertices f = sim->physical_forces();
    if (f.rows() != sim->num_vertices() || !f.allFinite())
      return ::testing::AssertionFailure()
             << "step " << k << ": physical_forces() has " << f.rows() << " rows for "
             << sim->num_vertices() << " vertices" << (f.allFinite() ? "" : ", not all finite");
    Eigen::VectorXd mag;
    try {
      mag = checked_force_magnitudes(*sim);
    } catch (const std::logic_error& e) {
      return ::testing::AssertionFailure() << "step " << k << ": " << e.what();
    }
    if (!mag.allFinite())
      return ::testing::AssertionFailure()
             << "step " << k << ": physical_force_magnitudes() not all finite";
    for (int a : anchors)
      if (f.row(a).norm() != 0.0 || mag[a] != 0.0)
        return ::testing::AssertionFailure()
               << "step " << k << ": anchored vertex " << a << " has physical force " << f.row(a)
               << " (magnitude " << mag[a] << "), expected zero";
  }
  return ::testing::AssertionSuccess();
}

/// A simulator's clones, stepped at the same time on two threads, give the same bits as the
/// simulator stepped alone (no mutable state shared between clones). A data race need not show
/// in every run, so a pass is evidence, not proof; a failure is a real defect.
inline ::testing::AssertionResult check_clones_in_parallel(const ConformanceCase& c) {
  auto sim = c.make();
  const Vertices rest = detail::anchor_positions(*sim);
  detail::run(*sim, rest, 0, 2, c.dt);
  auto a = sim->clone();
  auto b = sim->clone();
  const Vertices alone = detail::run(*sim, rest, 30, c.steps, c.dt);
  Vertices pa, pb;
  std::exception_ptr error_a, error_b;
  std::thread other([&] {
    try {
      pb = detail::run(*b, rest, 30, c.steps, c.dt);
    } catch (...) {
      error_b = std::current_exception();
    }
  });
  try {
    pa = detail::run(*a, rest, 30, c.steps, c.dt);
  } catch (...) {
    error_a = std::current_exception();
  }
  other.join();  // before any exception leaves: a joinable thread's destructor terminates
  if (error_a) std::rethrow_exception(error_a);
  if (error_b) std::rethrow_exception(error_b);
  auto r = detail::bit_equal(alone, pa, "a clone stepped while another clone steps on a thread");
  if (!r) return r;
  return detail::bit_equal(alone, pb, "a clone stepped on a thread while another clone steps");
}

/// Two fresh instances fed the same inputs give identical results.
inline ::testing::AssertionResult check_determinism(const ConformanceCase& c) {
  auto a = c.make();
  auto b = c.make();
  const Vertices rest = detail::anchor_positions(*a);
  return detail::bit_equal(detail::run(*a, rest, 0, c.steps, c.dt),
                           detail::run(*b, rest, 0, c.steps, c.dt), "two fresh instances");
}

/// A large but legal step (and a few more) produce finite positions and velocities.
inline ::testing::AssertionResult check_large_step(const ConformanceCase& c) {
  auto sim = c.make();
  const Vertices rest = detail::anchor_positions(*sim);
  for (int k = 0; k < 4; ++k) {
    sim->step(detail::make_input(*sim, rest, k, c.large_dt, 5u));
    if (!sim->positions().allFinite() || !sim->velocities().allFinite())
      return ::testing::AssertionFailure()
             << "non-finite state after step " << k << " of " << c.large_dt << " s";
  }
  return ::testing::AssertionSuccess();
}

/// Wrong control size, wrong anchor-target rows and dt <= 0 throw std::invalid_argument.
inline ::testing::AssertionResult check_bad_sizes(const ConformanceCase& c) {
  auto sim = c.make();
  const Vertices rest = detail::anchor_positions(*sim);
  auto expect_throw = [&](const StepInput& in, const char* what) -> ::testing::AssertionResult {
    try {
      sim->step(in);
    } catch (const std::invalid_argument& e) {
      if (std::string(e.what()).empty())
        return ::testing::AssertionFailure() << what << ": empty error message";
      return ::testing::AssertionSuccess();
    } catch (const std::exception& e) {
      return ::testing::AssertionFailure()
             << what << ": threw something else than std::invalid_argument: " << e.what();
    }
    return ::testing::AssertionFailure() << what << ": did not throw";
  };
  StepInput in = detail::make_input(*sim, rest, 0, c.dt, 1u);
  StepInput bad = in;
  bad.control = Eigen::VectorXd::Zero(in.control.size() + 1);
  auto r = expect_throw(bad, "control one entry too long");
  if (!r) return r;
  bad = in;
  bad.anchor_targets = Vertices::Zero(in.anchor_targets.rows() + 1, 3);
  r = expect_throw(bad, "one anchor target too many");
  if (!r) return r;
  bad = in;
  bad.dt = 0.0;
  r = expect_throw(bad, "dt = 0");
  if (!r) return r;
  bad = in;
  bad.dt = -c.dt;
  return expect_throw(bad, "dt < 0");
}

/// For adapters with derivatives: step_vjp() of L = <w, positions after one step> against
/// central differences in the control, and position_cotangent()/state_dim() consistent.
inline ::testing::AssertionResult check_vjp(const ConformanceCase& c) {
  auto sim = c.make();
  if (!sim->has_derivatives()) return ::testing::AssertionSuccess();
  const Vertices rest = detail::anchor_positions(*sim);
  detail::run(*sim, rest, 0, 2, c.dt);
  const SimState s0 = sim->save();
  const StepInput in = detail::make_input(*sim, rest, 7, c.dt, 11u);
  std::mt19937 rng(42);
  std::normal_distribution<double> nd;
  Vertices w(sim->num_vertices(), 3);
  for (Eigen::Index i = 0; i < w.rows(); ++i)
    for (int d = 0; d < 3; ++d) w(i, d) = nd(rng);
  auto loss = [&](const StepInput& x) {
    sim->restore(s0);
    sim->step(x);
    return (sim->positions().array() * w.array()).sum();
  };
  // dL/ds1 at the state after the step (the map from state to positions may be nonlinear).
  sim->restore(s0);
  sim->step(in);
  const Eigen::VectorXd g_state = sim->position_cotangent(w);
  if (g_state.size() != sim->state_dim())
    return ::testing::AssertionFailure() << "position_cotangent() size " << g_state.size()
                                         << " != state_dim() " << sim->state_dim();
  const StepVjp vjp = sim->step_vjp(s0, in, g_state);
  if (vjp.control.size() != in.control.size())
    return ::testing::AssertionFailure() << "step_vjp().control has the wrong size";
  // Directional derivative along a random control direction, scaled to the control size.
  Eigen::VectorXd dir(in.control.size());
  for (Eigen::Index i = 0; i < dir.size(); ++i) dir(i) = nd(rng);
  const double h = 1e-4 * std::max(1.0, in.control.norm()) / dir.norm();
  StepInput plus = in, minus = in;
  plus.control += h * dir;
  minus.control -= h * dir;
  const double fd = (loss(plus) - loss(minus)) / (2.0 * h);
  const double an = vjp.control.dot(dir);
  const double err = std::abs(fd - an) / std::max(std::abs(fd), 1e-12);
  if (!(err <= c.vjp_tolerance))
    return ::testing::AssertionFailure()
           << "directional derivative: adjoint " << an << ", central differences " << fd
           << " (relative error " << err << " > " << c.vjp_tolerance << ")";
  return ::testing::AssertionSuccess();
}

/// The value-parameterized suite.
class SimulatorConformance : public ::testing::TestWithParam<ConformanceCase> {};

TEST_P(SimulatorConformance, Layout) {
  EXPECT_TRUE(check_layout(GetParam()));
}
TEST_P(SimulatorConformance, SaveRestoreReplaysExactly) {
  EXPECT_TRUE(check_save_restore(GetParam()));
}
TEST_P(SimulatorConformance, RestoreIntoClone) {
  EXPECT_TRUE(check_restore_into_clone(GetParam()));
}
TEST_P(SimulatorConformance, CloneIsEquivalentAndIndependent) {
  EXPECT_TRUE(check_clone(GetParam()));
}
TEST_P(SimulatorConformance, AnchorsExactlyAtTargets) {
  EXPECT_TRUE(check_anchors(GetParam()));
}
TEST_P(SimulatorConformance, ForceEqualsMassTimesAcceleration) {
  EXPECT_TRUE(check_force_mass(GetParam()));
}
TEST_P(SimulatorConformance, PhysicalForcesHaveOneRowPerVertex) {
  EXPECT_TRUE(check_physical_forces(GetParam()));
}
TEST_P(SimulatorConformance, ClonesStepInParallel) {
  EXPECT_TRUE(check_clones_in_parallel(GetParam()));
}
TEST_P(SimulatorConformance, Deterministic) {
  EXPECT_TRUE(check_determinism(GetParam()));
}
TEST_P(SimulatorConformance, LargeStepStaysFinite) {
  EXPECT_TRUE(check_large_step(GetParam()));
}
TEST_P(SimulatorConformance, WrongSizesThrow) {
  EXPECT_TRUE(check_bad_sizes(GetParam()));
}
TEST_P(SimulatorConformance, VjpMatchesCentralDifferences) {
  EXPECT_TRUE(check_vjp(GetParam()));
}

}  // namespace pbve::testing

using pbve::testing::SimulatorConformance;
