// Control of rigid Bullet bodies: torques are weighed as forces at each body's lever arm.

#include <cmath>

#include <gtest/gtest.h>

#include "pbve/bullet/bullet.hpp"
#include "pbve/control/optimizer.hpp"
#include "pbve/edit/synth.hpp"

namespace {

using pbve::bullet::BulletSimulator;
using pbve::bullet::Material;
using pbve::bullet::Params;

// A cube of side a has I = m a^2 / 6 about each axis, so its radius of gyration
// sqrt(trace(I) / (2 m)) is a / 2; a torque tau then costs what a force |tau| / (a / 2) costs.
TEST(BulletRigidControl, TorqueCostsTheForceAtTheRadiusOfGyration) {
  pbve::Mesh cube = pbve::make_box_mesh(0.1, 0.1, 0.1);
  cube.vertices.rowwise() += Eigen::RowVector3d(0, 0, 1.0);
  Params p = Params::preset(Material::rigid);
  p.gravity.setZero();
  BulletSimulator sim(cube, {}, p);
  const pbve::ControlLayout layout = sim.control_layout();
  ASSERT_EQ(layout.space, pbve::ControlSpace::body_wrench);
  ASSERT_EQ(layout.block_arm.size(), 1);
  EXPECT_NEAR(layout.block_arm[0], 0.05, 1e-12);
  EXPECT_NEAR(layout.block_mass[0], 1.0, 1e-12);  // 1000 kg/m^3 * 1 litre

  pbve::ControlOptions o;
  o.torque_arm = 1.0;  // the simulator's own arm takes precedence
  pbve::ControlOptimizer opt(cube.triangles, {}, o);
  pbve::ControlFrameInput frame;
  frame.unobserved.assign(static_cast<size_t>(cube.num_triangles()), 0);
  const std::vector<pbve::ControlFrameInput> window{frame};
  Eigen::VectorXd torque = Eigen::VectorXd::Zero(6), force = Eigen::VectorXd::Zero(6);
  torque(5) = 0.5;  // N m about z
  force(0) = 10.0;  // N, = 0.5 N m / 0.05 m
  const auto a = opt.evaluate(sim, window, torque, pbve::GradientMode::central);
  const auto b = opt.evaluate(sim, window, force, pbve::GradientMode::central);
  EXPECT_GT(a.force_energy, 0.5);  // about 10 N / (1 kg g0) = 1.02
  EXPECT_NEAR(a.force_energy, b.force_energy, 1e-12);
  EXPECT_NEAR(a.temporal_energy, b.temporal_energy, 1e-12);
}

}  // namespace
