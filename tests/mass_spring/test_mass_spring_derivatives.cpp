// Adjoint (step_vjp) gradients of pbve::mass_spring against central differences, over 1 and
// over 5 chained steps, for cloth (with moving anchors and damping), an elastic solid (interior
// lattice) and cloth resting on a ground plane with friction.

#include <algorithm>
#include <cmath>
#include <functional>
#include <memory>
#include <random>

#include <gtest/gtest.h>

#include "mass_spring/meshes.hpp"
#include "pbve/core/mesh.hpp"
#include "pbve/edit/synth.hpp"
#include "pbve/mass_spring/mass_spring.hpp"

namespace {

using Eigen::VectorXd;
using pbve::SimState;
using pbve::StepInput;
using pbve::Vertices;
using pbve::mass_spring::MassSpringSimulator;
using pbve::mass_spring::Material;
using pbve::mass_spring::Params;

// L(x) = sum_i w_i . x_i + 1/2 sum_i |x_i - c|^2 (linear plus quadratic, so both the value and
// the direction of the gradient matter).
struct Objective {
  Vertices w, c;
  double value(const Vertices& x) const {
    return (w.array() * x.array()).sum() + 0.5 * (x - c).squaredNorm();
  }
  Vertices gradient(const Vertices& x) const { return w + (x - c); }
};

struct Problem {
  std::unique_ptr<MassSpringSimulator> sim;
  std::vector<StepInput> inputs;  // one per step
  Objective objective;
};

// Runs the steps from the simulator's current state and returns L at the end.
double run(MassSpringSimulator& sim, const std::vector<StepInput>& inputs, const Objective& obj) {
  for (const StepInput& in : inputs) sim.step(in);
  return obj.value(sim.positions());
}

// Adjoint gradient w.r.t. every step's control and w.r.t. the initial state.
void adjoint(Problem& p, std::vector<VectorXd>& du, VectorXd& ds0) {
  MassSpringSimulator& sim = *p.sim;
  const SimState s0 = sim.save();
  std::vector<SimState> states;
  for (const StepInput& in : p.inputs) {
    states.push_back(sim.save());
    sim.step(in);
  }
  VectorXd g = sim.position_cotangent(p.objective.gradient(sim.positions()));
  du.assign(p.inputs.size(), VectorXd());
  for (int k = static_cast<int>(p.inputs.size()) - 1; k >= 0; --k) {
    const pbve::StepVjp r =
        sim.step_vjp(states[static_cast<size_t>(k)], p.inputs[static_cast<size_t>(k)], g);
    du[static_cast<size_t>(k)] = r.control;
    g = r.state;
  }
  ds0 = g;
  sim.restore(s0);
}

double relative_error(const VectorXd& a, const VectorXd& b) {
  return (a - b).norm() / std::max(b.norm(), 1e-300);
}

// Central differences: with step eps the truncation error is O(eps^2 L''') and the noise from
// the Newton tolerance tau (absolute position error per solve) is O(tau / eps); eps is chosen
// so that both are far below the 1e-4 relative target.
void check_controls(Problem& p, double eps) {
  std::vector<VectorXd> du;
  VectorXd ds0;
  adjoint(p, du, ds0);
  const SimState s0 = p.sim->save();
  for (size_t k = 0; k < p.inputs.size(); ++k) {
    // Control blocks of the anchored vertices (the vertices themselves, or for a single sheet
    // the nodes that carry them).
    const pbve::ControlLayout layout = p.sim->control_layout();
    std::vector<int> anchors;
    for (int a : p.sim->anchors()) anchors.push_back(layout.vertex_block[static_cast<size_t>(a)]);
    // Central differences on 24 control entries spread over the blocks (every entry would
    // cost 2 x #controls simulations); the adjoint is compared on the same entries.
    std::vector<Eigen::Index> entries;
    const Eigen::Index nc = du[k].size();
    EXPECT_EQ(nc, layout.size());
    for (int q = 0; q < 24; ++q) {
      const Eigen::Index j = (q * 7919 + 13) % nc;
      if (std::find(anchors.begin(), anchors.end(), static_cast<int>(j / 3)) == anchors.end())
        entries.push_back(j);
    }
    VectorXd fd(static_cast<Eigen::Index>(entries.size())), ad(fd.size());
    for (size_t q = 0; q < entries.size(); ++q) {
      const Eigen::Index j = entries[q];
      auto probe = [&](double delta) {
        std::vector<StepInput> in = p.inputs;
        if (in[k].control.size() == 0) in[k].control = VectorXd::Zero(nc);
        in[k].control[j] += delta;
        p.sim->restore(s0);
        return run(*p.sim, in, p.objective);
      };
      fd[static_cast<Eigen::Index>(q)] = (probe(eps) - probe(-eps)) / (2 * eps);
      ad[static_cast<Eigen::Index>(q)] = du[k][j];
    }
    p.sim->restore(s0);
    const double err = relative_error(ad, fd);
    EXPECT_LT(err, 1e-4) << "step " << k << " of " << p.inputs.size() << ": |adj| " << ad.norm()
                         << " |fd| " << fd.norm();
    // Anchored blocks are ignored, so their gradient is exactly zero.
    for (int a : anchors) EXPECT_EQ(du[k].segment<3>(3 * a).norm(), 0.0);
  }
}

// Checks dL/d(initial state) on a few state entries (positions and velocities, free nodes,
// anchors and, for solids, interior nodes).
void check_state(Problem& p, const std::vector<int>& entries, double eps_x, double eps_v) {
  std::vector<VectorXd> du;
  VectorXd ds0;
  adjoint(p, du, ds0);
  const SimState s0 = p.sim->save();
  const int n3 = p.sim->state_dim() / 2;
  VectorXd fd(static_cast<Eigen::Index>(entries.size())), ad(fd.size());
  for (size_t q = 0; q < entries.size(); ++q) {
    const int j = entries[q];
    const double eps = j < n3 ? eps_x : eps_v;
    auto probe = [&](double delta) {
      SimState s = s0;
      s.values[static_cast<size_t>(j)] += delta;
      p.sim->restore(s);
      return run(*p.sim, p.inputs, p.objective);
    };
    fd[static_cast<Eigen::Index>(q)] = (probe(eps) - probe(-eps)) / (2 * eps);
    ad[static_cast<Eigen::Index>(q)] = ds0[j];
  }
  p.sim->restore(s0);
  EXPECT_LT(relative_error(ad, fd), 1e-4)
      << "adjoint " << ad.transpose() << "\nfd " << fd.transpose();
}

Objective random_objective(const Vertices& x, unsigned seed) {
  std::mt19937 rng(seed);
  std::normal_distribution<double> n(0.0, 1.0);
  Objective o;
  o.w = Vertices::NullaryExpr(x.rows(), 3, [&] { return n(rng); });
  o.c = x + 0.05 * Vertices::NullaryExpr(x.rows(), 3, [&] { return n(rng); });
  return o;
}

std::vector<StepInput> random_inputs(const MassSpringSimulator& sim, int steps, double force,
                                     bool move_anchors, unsigned seed) {
  std::mt19937 rng(seed);
  std::normal_distribution<double> n(0.0, 1.0);
  std::vector<StepInput> out;
  Vertices targets(static_cast<Eigen::Index>(sim.anchors().size()), 3);
  for (size_t k = 0; k < sim.anchors().size(); ++k)
    targets.row(static_cast<Eigen::Index>(k)) = sim.positions().row(sim.anchors()[k]);
  for (int s = 0; s < steps; ++s) {
    StepInput in;
    in.dt = 1.0 / 30.0;
    in.control = force * VectorXd::NullaryExpr(sim.control_layout().size(), [&] { return n(rng); });
    if (move_anchors) {
      targets.col(0).array() += 0.01;
      targets.col(2).array() -= 0.005 * s;
      in.anchor_targets = targets;
    }
    out.push_back(in);
  }
  return out;
}

// An n x n cloth held at two corners, `steps` random inputs after 3 warm-up steps.
Problem cloth_problem(
    int steps, int n = 6,
    pbve::mass_spring::LinearSolver solver = pbve::mass_spring::LinearSolver::automatic) {
  Params p = Params::preset(Material::cloth);
  p.newton_tolerance = 1e-12;
  p.linear_solver = solver;
  const pbve::Mesh mesh = pbve::test::grid_mesh(n, 0.3);
  Problem pr;
  pr.sim = std::make_unique<MassSpringSimulator>(mesh, std::vector<int>{0, n - 1}, p);
  // Let it swing first so springs are stretched and velocities are non-zero.
  StepInput warm;
  for (int i = 0; i < 3; ++i) pr.sim->step(warm);
  pr.inputs = random_inputs(*pr.sim, steps, 0.01, true, 7);
  pr.objective = random_objective(pr.sim->positions(), 3);
  return pr;
}

TEST(MassSpringDerivatives, ClothControlGradientOneStep) {
  Problem p = cloth_problem(1);
  check_controls(p, 1e-5);
}

TEST(MassSpringDerivatives, ClothControlGradientFiveSteps) {
  Problem p = cloth_problem(5);
  check_controls(p, 1e-5);
}

TEST(MassSpringDerivatives, ClothStateGradientFiveSteps) {
  Problem p = cloth_problem(5);
  const int n3 = p.sim->state_dim() / 2;
  // Positions of a free vertex, of an anchor (vertex 0), and velocities.
  check_state(p, {3 * 14, 3 * 14 + 1, 3 * 20 + 2, 0, 1, n3 + 3 * 14, n3 + 3 * 30 + 1}, 1e-6, 1e-5);
}

Problem elastic_problem(int steps) {
  Params p = Params::preset(Material::elastic);
  p.newton_tolerance = 1e-12;
  p.lattice_spacing = 0.03;
  const pbve::Mesh mesh = pbve::test::icosphere(1, 0.06, Eigen::Vector3d(0, 0, 1));
  Problem pr;
  pr.sim = std::make_unique<MassSpringSimulator>(mesh, std::vector<int>{0}, p);
  StepInput warm;
  for (int i = 0; i < 2; ++i) pr.sim->step(warm);
  pr.inputs = random_inputs(*pr.sim, steps, 0.5, true, 11);
  pr.objective = random_objective(pr.sim->positions(), 5);
  return pr;
}

TEST(MassSpringDerivatives, ElasticControlGradientOneAndFiveSteps) {
  Problem p1 = elastic_problem(1);
  ASSERT_GT(p1.sim->num_nodes(), p1.sim->num_vertices());  // the lattice is there
  check_controls(p1, 1e-4);
  Problem p5 = elastic_problem(5);
  check_controls(p5, 1e-4);
  const int n3 = p5.sim->state_dim() / 2;
  const int interior = p5.sim->num_vertices();  // first lattice node
  check_state(p5, {3 * 5, 3 * interior + 1, n3 + 3 * interior, n3 + 3 * 7 + 2}, 1e-6, 1e-5);
}

TEST(MassSpringDerivatives, ClothOnGroundWithFriction) {
  // A cloth lying on a ground plane (penetrating slightly under its weight) and sliding:
  // exercises the contact Hessian and the lagged friction terms of the adjoint.
  Params p = Params::preset(Material::cloth);
  p.newton_tolerance = 1e-12;
  pbve::mass_spring::Plane ground;
  ground.point = Eigen::Vector3d(0, 0, 1.0);
  ground.normal = Eigen::Vector3d(0, 0, -1);  // free side towards the camera (-z)
  ground.friction = 0.4;
  p.planes = {ground};
  p.gravity = Eigen::Vector3d(0, 0, 9.81);  // into the plane
  const pbve::Mesh mesh = pbve::test::grid_mesh(5, 0.2, 1.0);
  Problem pr;
  pr.sim = std::make_unique<MassSpringSimulator>(mesh, std::vector<int>{}, p);
  StepInput push;
  push.control = VectorXd::Zero(3 * pr.sim->num_vertices());
  for (int i = 0; i < pr.sim->num_vertices(); ++i) push.control[3 * i] = 0.01;
  for (int i = 0; i < 3; ++i) pr.sim->step(push);
  ASSERT_GT(pr.sim->positions().col(2).maxCoeff(), 1.0);    // in contact
  ASSERT_GT(pr.sim->velocities().col(0).minCoeff(), 2e-3);  // sliding (beyond the regularization)
  pr.inputs = random_inputs(*pr.sim, 3, 0.002, false, 13);
  for (StepInput& in : pr.inputs) in.control += push.control;
  pr.objective = random_objective(pr.sim->positions(), 9);
  check_controls(pr, 1e-6);
  const int n3 = pr.sim->state_dim() / 2;
  check_state(pr, {3 * 6, 3 * 6 + 2, n3 + 3 * 6, n3 + 3 * 12 + 1}, 1e-7, 1e-5);
}

}  // namespace

namespace {

TEST(MassSpringDerivatives, IterativeSolverGradientFiveSteps) {
  // Same cloth problem with the conjugate-gradient solver: the adjoint solve is converged to a
  // relative residual of 1e-11, far below the 1e-4 target.
  Problem p = cloth_problem(5, 6, pbve::mass_spring::LinearSolver::iterative);
  check_controls(p, 1e-5);
  EXPECT_GT(p.sim->last_stats().cg_iterations, 0);
  EXPECT_EQ(p.sim->last_stats().factorizations, 0);
}

TEST(MassSpringDerivatives, MultigridSolverGradientTwoSteps) {
  // The same with multigrid-preconditioned CG (adjoint solves to a relative residual of
  // 1e-11 as well), on a 14 x 14 cloth (two levels: the hierarchy stops at 96 nodes), over
  // two steps.
  Problem p = cloth_problem(2, 14, pbve::mass_spring::LinearSolver::multigrid);
  check_controls(p, 1e-5);
  EXPECT_GT(p.sim->last_stats().cg_iterations, 0);
  EXPECT_EQ(p.sim->last_stats().factorizations, 0);
}

TEST(MassSpringDerivatives, MultigridSolverAdjointOfACompressedCloth) {
  // A cloth squeezed to 70% of its rest size in its plane: its exact Hessian is indefinite
  // (compressed springs have negative stiffness across them), so CG preconditioned by the
  // multigrid of that matrix breaks down in the adjoint solves, which then run MINRES
  // preconditioned by the multigrid of the projected Hessian, without factorizing. A buckling
  // sheet is too far from smooth for central differences (they miss the adjoint by 86% here,
  // with either solver), so the reference is the step's linearization (linearize_step), whose
  // vjp() solves the same systems along the same trajectory by sparse factorizations (LDL^T
  // when indefinite). MINRES stops at a relative residual of 1e-11 (adjoint_tolerance), so
  // the two agree to that times the systems' condition number: the 1e-8 that
  // check_linearization() asks of CG-based adjoints against the linearization.
  Params params = Params::preset(Material::cloth);
  params.newton_tolerance = 1e-12;
  params.substeps = 3;
  params.linear_solver = pbve::mass_spring::LinearSolver::multigrid;
  const pbve::Mesh mesh = pbve::test::grid_mesh(16, 0.5);
  MassSpringSimulator sim(mesh, std::vector<int>{0, 15}, params);
  SimState s0 = sim.save();
  for (int i = 0; i < mesh.num_vertices(); ++i) {
    double* x = &s0.values[3 * static_cast<size_t>(i)];
    x[0] *= 0.7;
    x[1] *= 0.7;
    x[2] += 1e-3 * std::sin(9.0 * x[0]) * std::cos(7.0 * x[1]);
  }
  sim.restore(s0);
  const StepInput in = random_inputs(sim, 1, 0.01, false, 11).front();
  sim.step(in);
  std::mt19937 rng(3);
  std::normal_distribution<double> n(0.0, 1.0);
  const VectorXd g = VectorXd::NullaryExpr(sim.state_dim(), [&] { return n(rng); });
  const int before = sim.last_stats().factorizations;
  const pbve::StepVjp sv = sim.step_vjp(s0, in, g);
  EXPECT_EQ(sim.last_stats().factorizations, before);
  const pbve::StepVjp lv = sim.linearize_step(s0, in)->vjp(g);
  EXPECT_LT(relative_error(sv.state, lv.state), 1e-8);
  EXPECT_LT(relative_error(sv.control, lv.control), 1e-8);
}

}  // namespace

namespace {

// linearize_step(): its jvp() against central differences of the whole state after one step
// along a random direction of the state before and of the control; its vjp() against
// step_vjp(); and <g, jvp(d)> = <vjp(g), d> (the two are transposes of one operator, so they
// agree to round-off).
void check_linearization(MassSpringSimulator& sim, const StepInput& in, double eps, unsigned seed) {
  std::mt19937 rng(seed);
  std::normal_distribution<double> n(0.0, 1.0);
  const SimState s0 = sim.save();
  const int ns = sim.state_dim(), n3 = ns / 2;
  const Eigen::Index nc = sim.control_layout().size();
  // Position tangents of metre scale, velocity tangents of metre-per-second scale, control
  // tangents of newton scale, each scaled so that eps moves the state by about eps metres.
  VectorXd ds = VectorXd::NullaryExpr(ns, [&] { return n(rng); });
  VectorXd du = VectorXd::NullaryExpr(nc, [&] { return n(rng); });
  const double mass = sim.node_masses().mean();
  du *= mass * 900.0;  // an acceleration of about 900 m/s^2 moves a node ~ 1 m in a frame
  const auto lin = sim.linearize_step(s0, in);
  const VectorXd jd = lin->jvp(ds, du);
  auto after = [&](double t) {
    SimState s = s0;
    for (int j = 0; j < ns; ++j) s.values[static_cast<size_t>(j)] += t * ds[j];
    sim.restore(s);
    StepInput k = in;
    if (k.control.size() == 0) k.control = VectorXd::Zero(nc);
    k.control += t * du;
    sim.step(k);
    const SimState out = sim.save();
    return Eigen::Map<const VectorXd>(out.values.data(), ns).eval();
  };
  const VectorXd fd = (after(eps) - after(-eps)) / (2 * eps);
  EXPECT_LT(relative_error(jd.head(n3), fd.head(n3)), 1e-4) << "positions";
  EXPECT_LT(relative_error(jd.tail(n3), fd.tail(n3)), 1e-4) << "velocities";

  const VectorXd g = VectorXd::NullaryExpr(ns, [&] { return n(rng); });
  const pbve::StepVjp lv = lin->vjp(g);
  const double lhs = g.dot(jd);
  const double rhs = lv.state.dot(ds) + lv.control.dot(du);
  EXPECT_LT(std::abs(lhs - rhs), 1e-10 * (std::abs(lhs) + g.norm() * jd.norm()))
      << lhs << " " << rhs;
  const pbve::StepVjp sv = sim.step_vjp(s0, in, g);
  EXPECT_LT(relative_error(lv.state, sv.state), 1e-8);
  EXPECT_LT(relative_error(lv.control, sv.control), 1e-8);
  // The control tangent of anchored blocks does not move anything.
  VectorXd da = VectorXd::Zero(nc);
  const pbve::ControlLayout layout = sim.control_layout();
  for (int a : sim.anchors()) {
    const int b = layout.vertex_block[static_cast<size_t>(a)];
    da.segment<3>(3 * b) = du.segment<3>(3 * b);
  }
  if (!sim.anchors().empty()) {
    EXPECT_EQ(lin->jvp(VectorXd(), da).norm(), 0.0);
  }
  // The linearization's position maps are the simulator's at the state after the step.
  sim.restore(s0);
  sim.step(in);
  const Vertices gx = Vertices::NullaryExpr(sim.num_vertices(), 3, [&] { return n(rng); });
  EXPECT_LT(relative_error(lin->position_cotangent(gx), sim.position_cotangent(gx)), 1e-12);
  const Vertices tx = lin->position_tangent(jd), ts = sim.position_tangent(jd);
  EXPECT_LT((tx - ts).norm(), 1e-12 * ts.norm());
  // vjp() has no empty form (unlike jvp()): a cotangent of another size, empty included, is an
  // error, not a read past its end.
  EXPECT_THROW(lin->vjp(VectorXd()), std::invalid_argument);
  EXPECT_THROW(lin->vjp(VectorXd::Zero(ns + 1)), std::invalid_argument);
  sim.restore(s0);
}

TEST(MassSpringLinearization, ClothWithMovingAnchors) {
  Problem p = cloth_problem(1);
  check_linearization(*p.sim, p.inputs[0], 1e-6, 21);
}

TEST(MassSpringLinearization, ElasticSolid) {
  Problem p = elastic_problem(1);
  check_linearization(*p.sim, p.inputs[0], 1e-6, 22);
}

TEST(MassSpringLinearization, ClothOnGroundWithFriction) {
  Params p = Params::preset(Material::cloth);
  p.newton_tolerance = 1e-12;
  pbve::mass_spring::Plane ground;
  ground.point = Eigen::Vector3d(0, 0, 1.0);
  ground.normal = Eigen::Vector3d(0, 0, -1);
  ground.friction = 0.4;
  p.planes = {ground};
  p.gravity = Eigen::Vector3d(0, 0, 9.81);
  MassSpringSimulator sim(pbve::test::grid_mesh(5, 0.2, 1.0), {}, p);
  StepInput push;
  push.control = VectorXd::Zero(3 * sim.num_vertices());
  for (int i = 0; i < sim.num_vertices(); ++i) push.control[3 * i] = 0.01;
  for (int i = 0; i < 3; ++i) sim.step(push);
  ASSERT_GT(sim.velocities().col(0).minCoeff(), 2e-3);  // sliding on the plane
  // Nodes rest about m g / contact_stiffness = 5e-7 m inside the plane, where the contact and
  // friction terms switch on: the difference step stays well inside that.
  check_linearization(sim, push, 1e-9, 23);
}

}  // namespace

namespace {

// A thin closed board (two faces 1 cm apart joined by a rim) simulated as one sheet: the other
// face and the rim follow the sheet through a nonlinear map (rest offsets in a frame turned by
// the sheet's normals), so positions(), position_cotangent() and position_tangent() depend on
// the state and the gradients exercise their derivatives.
Problem board_problem(int steps) {
  Params p = Params::preset(Material::cloth);
  p.newton_tolerance = 1e-12;
  const pbve::Mesh mesh = pbve::refine_mesh(pbve::make_box_mesh(0.2, 0.15, 0.01), 0.05);
  std::vector<int> anchors;
  for (int i = 0; i < mesh.num_vertices(); ++i)
    if (mesh.vertices(i, 1) < 1e-9 && mesh.vertices(i, 0) < -0.09) anchors.push_back(i);
  Problem pr;
  Vertices x = mesh.vertices;
  x.col(2).array() += 1.0;
  pr.sim = std::make_unique<MassSpringSimulator>(mesh, x, anchors, p);
  StepInput warm;
  for (int i = 0; i < 3; ++i) pr.sim->step(warm);
  pr.inputs = random_inputs(*pr.sim, steps, 0.01, true, 31);
  pr.objective = random_objective(pr.sim->positions(), 33);
  return pr;
}

TEST(MassSpringDerivatives, ThinBoardAsOneSheet) {
  Problem p1 = board_problem(1);
  ASSERT_TRUE(p1.sim->single_sheet());
  ASSERT_FALSE(p1.sim->anchors().empty());
  ASSERT_LT(p1.sim->num_nodes(), p1.sim->num_vertices());
  check_controls(p1, 1e-5);
  Problem p5 = board_problem(5);
  check_controls(p5, 1e-5);
  const int n3 = p5.sim->state_dim() / 2;
  check_state(p5, {3 * 4, 3 * 4 + 2, 3 * 9 + 1, n3 + 3 * 4, n3 + 3 * 7 + 2}, 1e-6, 1e-5);
}

TEST(MassSpringLinearization, ThinBoardAsOneSheet) {
  // The random state tangent bends this small sheet (5 cm springs) far more sharply than the
  // grid's: the central-difference error scales as eps^2 (3.6e-3 relative at eps = 1e-5), so
  // eps = 1e-7 puts it near 4e-7, while the Newton tolerance adds 1e-12 / 1e-7 = 1e-5 of noise.
  Problem p = board_problem(1);
  check_linearization(*p.sim, p.inputs[0], 1e-7, 23);
}

}  // namespace
