// The control optimizer on the built-in mass_spring cloth (tests/control/cloth_scene.hpp).

#include <algorithm>
#include <cstdio>

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

TEST(ControlCloth, AdjointAndCentralGradientsOfTheFullEnergyAgree) {
  test::ClothScene scene(12, 8);
  scene.amplitude_deg = 80.0;
  scene.period_s = 1.0;
  scene.bend_stiffness = 5e-2;
  auto sim = scene.simulator();
  advance(scene, *sim, 10);  // the free edge is close to edge-on here: EC > 0
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

}  // namespace
}  // namespace pbve
