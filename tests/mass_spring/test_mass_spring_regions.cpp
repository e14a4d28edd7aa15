// Stiffness regions of pbve::mass_spring solids (Params::regions): a box of the body with its
// own lattice stiffness, given in mesh coordinates.

#include <cmath>
#include <stdexcept>
#include <string>
#include <vector>

#include <Eigen/Geometry>

#include <gtest/gtest.h>

#include "mass_spring/meshes.hpp"
#include "pbve/core/mesh.hpp"
#include "pbve/mass_spring/mass_spring.hpp"

namespace {

using pbve::StepInput;
using pbve::Vertices;
using pbve::mass_spring::MassSpringSimulator;
using pbve::mass_spring::Material;
using pbve::mass_spring::Params;
using pbve::mass_spring::StiffnessRegion;

// An elastic ball of 5 cm radius at the origin, the vertices of its bottom cap (y > 3.5 cm,
// +y is down) anchored, sagging under gravity for `frames` frames.
struct Ball {
  pbve::Mesh mesh = pbve::test::icosphere(2, 0.05, Eigen::Vector3d::Zero());
  std::vector<int> anchors;
  Ball() {
    for (int i = 0; i < mesh.num_vertices(); ++i)
      if (mesh.vertices(i, 1) > 0.035) anchors.push_back(i);
  }
  static Params params() {
    Params p = Params::preset(Material::elastic);
    p.volume_stiffness = 2e4;
    p.newton_tolerance = 1e-12;
    return p;
  }
  // Node positions after `frames` frames from rest positions `rest` (mesh when empty).
  Vertices run(const Params& p, int frames, const Vertices* rest = nullptr) const {
    MassSpringSimulator sim(mesh, rest ? *rest : mesh.vertices, anchors, p);
    for (int f = 0; f < frames; ++f) sim.step(StepInput{});
    return sim.positions();
  }
  // Mean drop of the top half of the surface (y < 0), metres.
  double sag(const Vertices& x) const {
    double sum = 0.0;
    int n = 0;
    for (int i = 0; i < mesh.num_vertices(); ++i)
      if (mesh.vertices(i, 1) < 0.0) {
        sum += x(i, 1) - mesh.vertices(i, 1);
        ++n;
      }
    return sum / n;
  }
};

StiffnessRegion box(Eigen::Vector3d lo, Eigen::Vector3d hi, double stiffness) {
  StiffnessRegion r;
  r.min = lo;
  r.max = hi;
  r.volume_stiffness = stiffness;
  return r;
}

TEST(MassSpringRegions, ARegionOverTheWholeBodyIsTheSameAsItsStiffnessEverywhere) {
  // Spring constants come from the same expression with the region's modulus in place of
  // volume_stiffness, so the trajectories agree bit for bit.
  const Ball ball;
  const Eigen::Vector3d big(1, 1, 1);
  Params with_region = Ball::params();
  with_region.regions = {box(-big, big, 5e3)};
  Params uniform = Ball::params();
  uniform.volume_stiffness = 5e3;
  EXPECT_EQ(ball.run(with_region, 10), ball.run(uniform, 10));
  // A region of the base stiffness changes nothing; one outside the body neither.
  Params same = Ball::params();
  same.regions = {box(-big, big, same.volume_stiffness)};
  Params outside = Ball::params();
  outside.regions = {box(Eigen::Vector3d(0.5, 0.5, 0.5), big, 10.0)};
  const Vertices base = ball.run(Ball::params(), 10);
  EXPECT_EQ(ball.run(same, 10), base);
  EXPECT_EQ(ball.run(outside, 10), base);
}

TEST(MassSpringRegions, ASoftUpperHalfSagsBetweenTheStiffAndTheSoftBody) {
  // After 30 frames (1 s) the anchored ball has nearly settled; softening the upper half
  // (y < 0) by 4x lets the top sag more than the uniform ball but less than a ball softened
  // everywhere (its lower half still carries the load stiffly). The sag of the stiff ball is
  // about rho g h^2 / E ~ 1000 * 9.81 * 0.1^2 / 2e4 ~ 5 mm, well above the Newton tolerance.
  const Ball ball;
  const double stiff = ball.sag(ball.run(Ball::params(), 30));
  Params soft_all = Ball::params();
  soft_all.volume_stiffness /= 4;
  const double soft = ball.sag(ball.run(soft_all, 30));
  Params soft_top = Ball::params();
  soft_top.regions = {box(Eigen::Vector3d(-1, -1, -1), Eigen::Vector3d(1, 0, 1), 5e3)};
  const double mixed = ball.sag(ball.run(soft_top, 30));
  EXPECT_GT(stiff, 1e-4);
  EXPECT_GT(mixed, 1.2 * stiff);
  EXPECT_LT(mixed, soft / 1.2);
}

TEST(MassSpringRegions, RegionsAreInMeshCoordinatesWhateverTheRestPose) {
  // The ball's rest positions are its mesh posed by a quarter turn about z and a translation.
  // A region given in mesh coordinates (y < 1.3 mm there) must soften the same springs as the
  // posed box given to a simulator whose mesh coordinates are the rest positions themselves
  // (x > t.x + 1.3 mm after the turn). The lattice and its ties are built from the rest
  // positions alone, so both models are the same but for the region test, and the trajectories
  // agree to rounding (far below the 1e-9 m asserted).
  const Ball ball;
  const Eigen::Matrix3d R =
      Eigen::AngleAxisd(std::acos(-1.0) / 2, Eigen::Vector3d::UnitZ()).toRotationMatrix();
  const Eigen::Vector3d t(0.2, -0.1, 1.3);
  const Vertices rest = ((ball.mesh.vertices * R.transpose()).rowwise() + t.transpose()).eval();
  Params in_mesh = Ball::params();
  in_mesh.regions = {box(Eigen::Vector3d(-1, -1, -1), Eigen::Vector3d(1, 0.0013, 1), 5e3)};
  Params in_rest = Ball::params();
  in_rest.regions = {box(t + Eigen::Vector3d(-0.0013, -1, -1), t + Eigen::Vector3d(1, 1, 1), 5e3)};
  const auto run = [&](const pbve::Mesh& mesh, const Params& p) {
    MassSpringSimulator sim(mesh, rest, ball.anchors, p);
    for (int f = 0; f < 5; ++f) sim.step(StepInput{});
    return sim.positions();
  };
  pbve::Mesh posed_mesh = ball.mesh;
  posed_mesh.vertices = rest;
  const Vertices a = run(ball.mesh, in_mesh);
  const Vertices b = run(posed_mesh, in_rest);
  EXPECT_LT((a - b).cwiseAbs().maxCoeff(), 1e-9);
  // And the region matters: without it the ball moves differently.
  Params plain = Ball::params();
  const Vertices c = run(ball.mesh, plain);
  EXPECT_GT((c - a).cwiseAbs().maxCoeff(), 1e-5);
}

TEST(MassSpringRegions, BadRegionsAreRefusedWithTheirName) {
  const Ball ball;
  auto message = [&](const Params& p, const Vertices* rest = nullptr) -> std::string {
    try {
      MassSpringSimulator sim(ball.mesh, rest ? *rest : ball.mesh.vertices, ball.anchors, p);
    } catch (const std::invalid_argument& e) {
      return e.what();
    }
    return "";
  };
  Params inverted = Ball::params();
  inverted.regions = {box(Eigen::Vector3d(0, 0, 0), Eigen::Vector3d(1, -1, 1), 5e3)};
  EXPECT_NE(message(inverted).find("regions[0]"), std::string::npos);
  Params zero = Ball::params();
  zero.regions = {box(Eigen::Vector3d::Zero(), Eigen::Vector3d::Ones(), 5e3),
                  box(Eigen::Vector3d::Zero(), Eigen::Vector3d::Ones(), 0.0)};
  EXPECT_NE(message(zero).find("regions[1].volume_stiffness"), std::string::npos);
  Params cloth = Params::preset(Material::cloth);
  cloth.regions = {box(Eigen::Vector3d::Zero(), Eigen::Vector3d::Ones(), 5e3)};
  EXPECT_NE(message(cloth).find("solids"), std::string::npos);
  // Rest positions that are no rigid copy of the mesh (stretched along x): mesh coordinates
  // cannot be placed in them.
  Params ok = Ball::params();
  ok.regions = {box(Eigen::Vector3d::Zero(), Eigen::Vector3d::Ones(), 5e3)};
  Vertices stretched = ball.mesh.vertices;
  stretched.col(0) *= 1.5;
  EXPECT_NE(message(ok, &stretched).find("not a rigid or similar copy"), std::string::npos);
  EXPECT_EQ(message(ok), "");
}

}  // namespace
