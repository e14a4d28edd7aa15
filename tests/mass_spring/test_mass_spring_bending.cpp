// Bending of pbve::mass_spring: the quadratic energy of hinges that are flat at rest, measured
// on the model's isotropic couplings against the continuum energy 1/2 B (k1 + k2)^2 of known
// surfaces, and the rest shape's equilibrium.

#include <cmath>
#include <numbers>

#include <gtest/gtest.h>

#include "../../adapters/mass_spring/src/model.hpp"
#include "meshes.hpp"
#include "pbve/mass_spring/mass_spring.hpp"

namespace {

using Eigen::Vector3d;
using Eigen::VectorXd;
using pbve::Vertices;
using pbve::mass_spring::MassSpringSimulator;
using pbve::mass_spring::Material;
using pbve::mass_spring::Params;
using pbve::mass_spring::detail::build_model;
using pbve::mass_spring::detail::Model;
using pbve::mass_spring::detail::Spring;

constexpr int n = 21;         // vertices per side
constexpr double side = 0.4;  // m
constexpr double cell = side / (n - 1);
constexpr double B = 2e-4;  // N m

Params cloth() {
  Params p = Params::preset(Material::cloth);
  p.bend_stiffness = B;
  return p;
}

// The quadratic bending energy of the model at x (surface nodes only: a cloth).
double bending_energy(const Model& m, const Vertices& x) {
  double e = 0.0;
  for (const Spring& sp : m.springs) e += 0.5 * sp.iso * (x.row(sp.b) - x.row(sp.a)).squaredNorm();
  for (Eigen::Index i = 0; i < m.bend_rest_force.size() / 3; ++i)
    e += m.bend_rest_force.segment<3>(3 * i).dot(x.row(i).transpose());
  return e;
}

// The flat sheet in the z = 0 plane.
pbve::Mesh flat_sheet() {
  return pbve::test::grid_mesh(n, side, 0.0);
}

// Hinges sit on interior edges: the boundary edges along the folds carry none, a strip of half
// a cell on either side, so the discrete energy covers (1 - 1 / cells) of the sheet.
constexpr double covered = 1.0 - 1.0 / (n - 1);

TEST(MassSpringBending, FlatHingesCarryTheQuadraticEnergy) {
  const pbve::Mesh sheet = flat_sheet();
  const Model m = build_model(sheet, sheet.vertices, {}, cloth());
  // Every interior edge of the flat grid is a flat hinge.
  const int interior_edges = 3 * (n - 1) * (n - 1) - 2 * (n - 1);
  EXPECT_EQ(m.flat_hinges, interior_edges);
  // The rest shape is flat: no rest force beyond rounding.
  ASSERT_EQ(m.bend_rest_force.size(), 3 * n * n);
  EXPECT_LT(m.bend_rest_force.cwiseAbs().maxCoeff(), 1e-12 * B / cell);
}

TEST(MassSpringBending, CylinderEnergyIsHalfBKappaSquaredArea) {
  const pbve::Mesh sheet = flat_sheet();
  const Model m = build_model(sheet, sheet.vertices, {}, cloth());
  // Roll the sheet isometrically around the y axis onto cylinders of several radii.
  for (double radius : {0.2, 0.5, 2.0}) {
    Vertices x = sheet.vertices;
    for (Eigen::Index i = 0; i < x.rows(); ++i) {
      const double s = sheet.vertices(i, 0);
      x(i, 0) = radius * std::sin(s / radius);
      x(i, 2) = radius * (1.0 - std::cos(s / radius));
    }
    const double expected = 0.5 * B * side * side * covered / (radius * radius);
    // The discrete curvature of a chord polygon is 1/R to O((cell / R)^2).
    const double tol = (cell / radius) * (cell / radius);
    EXPECT_NEAR(bending_energy(m, x) / expected, 1.0, tol) << "R = " << radius;
  }
}

TEST(MassSpringBending, GridScaleZigzagIsNotFree) {
  // A fold at every column line, of amplitude a: second differences of +-4 a / cell^2. Springs
  // across the hinges stretch only to O(a^2) here, so spring-based bending leaves this mode
  // with no stiffness at all; the quadratic energy charges it the curvature it has.
  const pbve::Mesh sheet = flat_sheet();
  const Model m = build_model(sheet, sheet.vertices, {}, cloth());
  for (double a : {1e-5, 1e-4}) {
    Vertices x = sheet.vertices;
    for (int j = 0; j < n; ++j)
      for (int i = 0; i < n; ++i) x(j * n + i, 2) = (i % 2 == 0 ? a : -a);
    const double kappa = 4.0 * a / (cell * cell);
    const double expected = 0.5 * B * kappa * kappa * side * side * covered;
    EXPECT_NEAR(bending_energy(m, x) / expected, 1.0, 1e-6) << "a = " << a;
  }
}

TEST(MassSpringBending, RigidMotionsOfTheFlatSheetCostNothing) {
  const pbve::Mesh sheet = flat_sheet();
  const Model m = build_model(sheet, sheet.vertices, {}, cloth());
  const Eigen::Matrix3d R =
      Eigen::AngleAxisd(1.1, Vector3d(0.3, -0.8, 0.5).normalized()).toRotationMatrix();
  Vertices x = (sheet.vertices * R.transpose()).rowwise() + Eigen::RowVector3d(0.1, -2.0, 3.0);
  // Against the energy of a gentle bend (R = 2 m) of the same sheet.
  const double scale = 0.5 * B * side * side / 4.0;
  EXPECT_LT(std::abs(bending_energy(m, x)), 1e-10 * scale);
}

TEST(MassSpringBending, NearlyFlatRestShapeIsAtEquilibrium) {
  // A sheet with a bump of 50 um (hinge angles up to about 3e-4 rad): its hinges are within the
  // flat tolerance, so they get the quadratic energy, whose rest force is subtracted. Without
  // gravity it stays where it is.
  pbve::Mesh sheet = flat_sheet();
  for (Eigen::Index i = 0; i < sheet.vertices.rows(); ++i) {
    const double u = sheet.vertices(i, 0) / side, v = sheet.vertices(i, 1) / side;
    sheet.vertices(i, 2) = 5e-5 * std::exp(-20.0 * (u * u + v * v));
  }
  Params p = cloth();
  p.gravity.setZero();
  const Model m = build_model(sheet, sheet.vertices, {}, p);
  EXPECT_EQ(m.flat_hinges, 3 * (n - 1) * (n - 1) - 2 * (n - 1));
  // The rest force is not negligible: alone it would move the nodes by far more than the
  // tolerance below within the run (1/2 a t^2).
  const double run = 5.0 / 30.0;  // s
  const double drift =
      0.5 * m.bend_rest_force.cwiseAbs().maxCoeff() / m.mass.maxCoeff() * run * run;
  EXPECT_GT(drift, 1e-6);
  MassSpringSimulator sim(sheet, {}, p);
  for (int f = 0; f < 5; ++f) sim.step(pbve::StepInput{});
  // Newton stops at the first iterate within its tolerance of the (rest) solution.
  EXPECT_LT((sim.positions() - sheet.vertices).cwiseAbs().maxCoeff(), 1e-12);
}

TEST(MassSpringBending, CreasedHingesKeepTheSpring) {
  // A sheet folded by 90 degrees along its middle column: the hinges on the fold are creased
  // and bend by the spring across them; all others are flat.
  pbve::Mesh sheet = flat_sheet();
  const int mid = n / 2;
  for (int j = 0; j < n; ++j)
    for (int i = mid; i < n; ++i) {
      const Eigen::Index k = j * n + i;
      const double s = (i - mid) * cell;
      sheet.vertices(k, 0) = sheet.vertices(j * n + mid, 0);
      sheet.vertices(k, 2) = s;
    }
  const Model m = build_model(sheet, sheet.vertices, {}, cloth());
  EXPECT_EQ(m.flat_hinges, 3 * (n - 1) * (n - 1) - 2 * (n - 1) - (n - 1));
}

}  // namespace
