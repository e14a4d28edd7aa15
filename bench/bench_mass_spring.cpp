// pbve::mass_spring: one step (dt 1/30 s, default substeps) of an anchored cloth at 484, ~1k,
// 4k and 16k vertices (and at 33k and 65k, to follow the growth further), and one step_vjp
// relative to one step; the same for the thin two-layer board of example 1 (cloth with layer
// ties, 3 substeps, swung by its held edge) at 494, ~1k, 4k and 16k vertices, plus its
// linearization (linearize_step, jvp, vjp); and the multigrid solver alone on a flat sheet's
// Newton matrix at 1k to 65k vertices, with and without bending (BM_MultigridSheet). For
// comparisons, environment variables override parameters: SUBS (substeps), NTOL (newton_tolerance),
// SOLVER (direct, iterative or multigrid instead of the automatic linear solver choice), FRAMES
// (steps before the timed cloth step), BEND (the cloth's bend_stiffness, N m).

#include <cmath>
#include <cstdlib>
#include <memory>
#include <random>
#include <string>
#include <vector>

#include <Eigen/Geometry>

#include <benchmark/benchmark.h>

#include "../adapters/mass_spring/src/multigrid.hpp"
#include "../tests/support/pcg.hpp"
#include "pbve/core/mesh.hpp"
#include "pbve/edit/synth.hpp"
#include "pbve/mass_spring/mass_spring.hpp"

namespace {

using pbve::mass_spring::MassSpringSimulator;
using pbve::mass_spring::Material;
using pbve::mass_spring::Params;

void set_solver(Params& prm) {
  if (const char* s = std::getenv("SOLVER")) {
    const std::string name = s;
    if (name == "direct") prm.linear_solver = pbve::mass_spring::LinearSolver::direct;
    if (name == "iterative") prm.linear_solver = pbve::mass_spring::LinearSolver::iterative;
    if (name == "multigrid") prm.linear_solver = pbve::mass_spring::LinearSolver::multigrid;
  }
}

// n x n cloth of 1 m x 1 m, horizontal (x-z plane), held at two corners; gravity +y.
MassSpringSimulator make_cloth(int n) {
  pbve::Mesh m;
  m.vertices.resize(n * n, 3);
  for (int j = 0; j < n; ++j)
    for (int i = 0; i < n; ++i)
      m.vertices.row(j * n + i) << 1.0 * i / (n - 1) - 0.5, 0.0, 1.5 + 1.0 * j / (n - 1);
  m.triangles.resize(2 * (n - 1) * (n - 1), 3);
  int f = 0;
  for (int j = 0; j + 1 < n; ++j)
    for (int i = 0; i + 1 < n; ++i) {
      const int a = j * n + i, b = a + 1, c = a + n, d = c + 1;
      m.triangles.row(f++) << a, c, b;
      m.triangles.row(f++) << b, c, d;
    }
  Params prm = Params::preset(Material::cloth);
  if (std::getenv("NTOL")) prm.newton_tolerance = std::atof(std::getenv("NTOL"));
  if (std::getenv("SUBS")) prm.substeps = std::atoi(std::getenv("SUBS"));
  if (std::getenv("BEND")) prm.bend_stiffness = std::atof(std::getenv("BEND"));
  set_solver(prm);
  MassSpringSimulator sim(m, {0, n - 1}, prm);
  // Start from a swinging state, not from rest: after 5 steps (FRAMES overrides).
  const int frames = std::getenv("FRAMES") ? std::atoi(std::getenv("FRAMES")) : 5;
  for (int s = 0; s < frames; ++s) sim.step(pbve::StepInput{});
  return sim;
}

void BM_ClothStep(benchmark::State& state) {
  MassSpringSimulator sim = make_cloth(static_cast<int>(state.range(0)));
  const pbve::SimState s0 = sim.save();
  pbve::StepInput in;
  in.control = Eigen::VectorXd::Constant(3 * sim.num_vertices(), 1e-5);
  double cg = 0, newton = 0, fact = 0, curvature = 0, unconverged = 0;
  for (auto _ : state) {
    sim.restore(s0);
    sim.step(in);
    cg += sim.last_stats().cg_iterations;
    newton += sim.last_stats().newton_iterations;
    fact += sim.last_stats().factorizations;
    curvature += sim.last_stats().curvature_steps;
    unconverged += sim.last_stats().converged ? 0 : 1;
  }
  state.counters["vertices"] = sim.num_vertices();
  state.counters["cg_iters"] = benchmark::Counter(cg, benchmark::Counter::kAvgIterations);
  state.counters["newton_iters"] = benchmark::Counter(newton, benchmark::Counter::kAvgIterations);
  state.counters["factorizations"] = benchmark::Counter(fact, benchmark::Counter::kAvgIterations);
  state.counters["curvature_steps"] =
      benchmark::Counter(curvature, benchmark::Counter::kAvgIterations);
  // 1 when the timed step left a substep short of the Newton tolerance.
  state.counters["unconverged"] =
      benchmark::Counter(unconverged, benchmark::Counter::kAvgIterations);
}

// step_vjp right after the step it differentiates (the recorded trajectory is reused: the
// usual pattern of an optimizer that evaluates, then asks for the gradient).
void BM_ClothVjp(benchmark::State& state) {
  MassSpringSimulator sim = make_cloth(static_cast<int>(state.range(0)));
  const pbve::SimState s0 = sim.save();
  pbve::StepInput in;
  in.control = Eigen::VectorXd::Constant(3 * sim.num_vertices(), 1e-5);
  sim.step(in);
  const Eigen::VectorXd g = sim.position_cotangent(pbve::Vertices::Ones(sim.num_vertices(), 3));
  double cg = 0, fact = 0;
  for (auto _ : state) {
    const pbve::mass_spring::StepStats before = sim.last_stats();
    benchmark::DoNotOptimize(sim.step_vjp(s0, in, g));
    cg += sim.last_stats().cg_iterations - before.cg_iterations;
    fact += sim.last_stats().factorizations - before.factorizations;
  }
  state.counters["vertices"] = sim.num_vertices();
  state.counters["cg_iters"] = benchmark::Counter(cg, benchmark::Counter::kAvgIterations);
  state.counters["factorizations"] = benchmark::Counter(fact, benchmark::Counter::kAvgIterations);
}

// step_vjp from a state this simulator did not just step from (forward replay + backward).
void BM_ClothVjpReplay(benchmark::State& state) {
  MassSpringSimulator sim = make_cloth(static_cast<int>(state.range(0)));
  const pbve::SimState s0 = sim.save();
  pbve::StepInput in;
  in.control = Eigen::VectorXd::Constant(3 * sim.num_vertices(), 1e-5);
  pbve::StepInput other = in;
  other.control *= 2.0;
  const Eigen::VectorXd g = sim.position_cotangent(pbve::Vertices::Ones(sim.num_vertices(), 3));
  for (auto _ : state) {
    state.PauseTiming();
    sim.restore(s0);
    sim.step(other);  // invalidates the recorded trajectory
    state.ResumeTiming();
    benchmark::DoNotOptimize(sim.step_vjp(s0, in, g));
  }
  state.counters["vertices"] = sim.num_vertices();
}

// The multigrid-preconditioned CG alone, on one family of linear systems at growing
// resolution: the Newton matrix of a flat n x n cloth at rest (1 m, the cloth preset's density
// and stretch and shear moduli, springs k = modulus area / L0^2; substep h = 1/300 s, Rayleigh
// alpha 0.5, beta 0.01, so J = (1 + h alpha) M + (h^2 + h beta) K), held at two corners, with a
// small transverse stiffness (a tension of 1e-3 of the stretch modulus) and a bending term
// B (h^2 + h beta) / L^2 (D^T D) on the normal component, D the grid's graph Laplacian and L the
// grid spacing (the discrete 1/2 B integral of (laplacian w)^2). Arguments: n, and B in 1e-5 N m
// (0, 10 = the cloth preset's 1e-4, 100). One iteration: the multigrid setup for J and CG to a
// 1e-8 residual reduction from a fixed pseudo-random right side (the hierarchy is built once,
// outside). Counters: CG iterations and multigrid levels. It isolates the solver's growth with
// the resolution from the stepped cloth's changing state, and the bending term's share in it.
// Its bending is not the engine's hinge energy: linear interpolation on coarse triangles costs it
// iterations that the cloth's own systems do not lose (docs/benchmarks.md, "The sheet benchmark
// and the cloth step part ways"), so a solver change it favours needs checking on BM_ClothStep.
namespace sheet {

using Eigen::SparseMatrix;

struct System {
  SparseMatrix<double> J, strength;
  Eigen::MatrixX3d rest;
};

System make(int n, double bend) {
  const double L = 1.0 / (n - 1), h = 1.0 / 300.0, alpha = 0.5, beta = 0.01;
  const double w = h * h + h * beta, density = 0.3, stretch = 2000.0, shear = 100.0;
  auto node = [n](int i, int j) { return j * n + i; };
  // The anchors (the corners 0 and n - 1) are not unknowns.
  std::vector<int> free_index(static_cast<size_t>(n * n));
  int nf = 0;
  for (int v = 0; v < n * n; ++v)
    free_index[static_cast<size_t>(v)] = v == 0 || v == n - 1 ? -1 : nf++;
  System s;
  s.rest.resize(nf, 3);
  std::vector<double> mass(static_cast<size_t>(n * n), 0.0);
  for (int j = 0; j < n; ++j)
    for (int i = 0; i < n; ++i) {
      const int f = free_index[static_cast<size_t>(node(i, j))];
      if (f >= 0) s.rest.row(f) << i * L, 0.0, j * L;
    }
  std::vector<Eigen::Triplet<double>> t, st;
  auto add = [&](int a, int b, const Eigen::Matrix3d& B) {
    const int fa = free_index[static_cast<size_t>(a)], fb = free_index[static_cast<size_t>(b)];
    if (fa < 0 || fb < 0) return;
    for (int c = 0; c < 3; ++c)
      for (int r = 0; r < 3; ++r) t.emplace_back(3 * fa + r, 3 * fb + c, B(r, c));
  };
  // k = modulus * A / L0^2, A a third of each adjacent triangle's area (L^2 / 2 each).
  auto spring = [&](int a, int b, double modulus, double area) {
    const Eigen::Vector3d d = (Eigen::Vector3d((b % n) - (a % n), 0.0, (b / n) - (a / n)) * L);
    const double k = modulus * area / d.squaredNorm();
    const Eigen::Vector3d u = d.normalized();
    const Eigen::Matrix3d P = u * u.transpose();
    const Eigen::Matrix3d B = w * k * (P + 1e-3 * (Eigen::Matrix3d::Identity() - P));
    add(a, a, B);
    add(b, b, B);
    add(a, b, -B);
    add(b, a, -B);
    const int fa = free_index[static_cast<size_t>(a)], fb = free_index[static_cast<size_t>(b)];
    if (fa >= 0 && fb >= 0) {
      st.emplace_back(fa, fb, k);
      st.emplace_back(fb, fa, k);
    }
  };
  const double third = L * L / 6.0;  // a third of one triangle
  for (int j = 0; j < n; ++j)
    for (int i = 0; i < n; ++i) {
      // Triangles (a, c, b) and (b, c, d) of each cell, as make_cloth() builds them.
      const bool right = i + 1 < n, up = j + 1 < n;
      if (right) spring(node(i, j), node(i + 1, j), stretch, third * ((j > 0) + up));
      if (up) spring(node(i, j), node(i, j + 1), stretch, third * ((i > 0) + right));
      if (right && up) {
        spring(node(i + 1, j), node(i, j + 1), stretch, 2.0 * third);  // the cell's diagonal
        spring(node(i, j), node(i + 1, j + 1), shear, 2.0 * third);    // across it
        for (const int v : {node(i, j), node(i + 1, j), node(i, j + 1), node(i + 1, j + 1)})
          mass[static_cast<size_t>(v)] +=
              density * third * (v == node(i, j) || v == node(i + 1, j + 1) ? 1.0 : 2.0);
      }
    }
  for (int v = 0; v < n * n; ++v)
    add(v, v, (1.0 + h * alpha) * mass[static_cast<size_t>(v)] * Eigen::Matrix3d::Identity());
  if (bend > 0.0) {
    std::vector<Eigen::Triplet<double>> lt;
    auto link = [&lt](int a, int b) {
      lt.emplace_back(a, a, 1.0);
      lt.emplace_back(b, b, 1.0);
      lt.emplace_back(a, b, -1.0);
      lt.emplace_back(b, a, -1.0);
    };
    for (int j = 0; j < n; ++j)
      for (int i = 0; i < n; ++i) {
        if (i + 1 < n) link(node(i, j), node(i + 1, j));
        if (j + 1 < n) link(node(i, j), node(i, j + 1));
      }
    SparseMatrix<double> D(n * n, n * n);
    D.setFromTriplets(lt.begin(), lt.end());
    const SparseMatrix<double> K = (bend * w / (L * L)) * SparseMatrix<double>(D.transpose() * D);
    for (int c = 0; c < K.outerSize(); ++c)
      for (SparseMatrix<double>::InnerIterator it(K, c); it; ++it) {
        Eigen::Matrix3d B = Eigen::Matrix3d::Zero();  // full 3x3 blocks, as the engine's pattern
        B(1, 1) = it.value();
        add(static_cast<int>(it.row()), c, B);
      }
  }
  s.J.resize(3 * nf, 3 * nf);
  s.J.setFromTriplets(t.begin(), t.end());
  s.J.makeCompressed();
  s.strength.resize(nf, nf);
  s.strength.setFromTriplets(st.begin(), st.end());
  return s;
}

}  // namespace sheet

void BM_MultigridSheet(benchmark::State& state) {
  using pbve::mass_spring::detail::Multigrid;
  using pbve::mass_spring::detail::MultigridHierarchy;
  const int n = static_cast<int>(state.range(0));
  const sheet::System s = sheet::make(n, 1e-5 * static_cast<double>(state.range(1)));
  const auto hierarchy = std::make_shared<const MultigridHierarchy>(s.J, s.strength, s.rest);
  Multigrid mg(hierarchy);
  Eigen::VectorXd b(s.J.rows());
  std::mt19937 gen(1);
  std::normal_distribution<double> normal;
  for (Eigen::Index q = 0; q < b.size(); ++q) b[q] = normal(gen);
  double iterations = 0;
  for (auto _ : state) {
    if (!mg.setup(s.J)) {
      state.SkipWithError("the sheet's matrix is not positive definite");
      return;
    }
    Eigen::VectorXd x;
    const int it = pbve::test::pcg_iterations(
        [&](const Eigen::VectorXd& p, Eigen::VectorXd& Ap) { mg.multiply(p, Ap); }, b, 1e-8,
        [&](const Eigen::VectorXd& r, Eigen::VectorXd& z) { mg.apply(r, z); }, x);
    if (it < 0) {
      state.SkipWithError("CG did not converge in 1000 iterations");
      return;
    }
    iterations += it;
    benchmark::DoNotOptimize(x.data());
  }
  state.counters["vertices"] = n * n;
  state.counters["levels"] = static_cast<double>(hierarchy->levels().size());
  state.counters["cg_iters"] = benchmark::Counter(iterations, benchmark::Counter::kAvgIterations);
}

// Example 1's board: 40 x 30 x 1 cm, refined like `pbve bench` does (edge lengths shrinking by
// 2^(1/8) from the longest edge; the one whose vertex count is closest to the target), the
// middle 10 cm of its top edge held and turned about the vertical axis.
struct Board {
  std::unique_ptr<MassSpringSimulator> sim;
  std::vector<int> anchors;
  pbve::Mesh mesh;
  int frame = 0;

  pbve::StepInput input(int f) const {
    pbve::StepInput in;
    in.anchor_targets.resize(static_cast<Eigen::Index>(anchors.size()), 3);
    const double yaw = 1.4 * std::sin(2 * 3.14159265358979 * 0.9 * f / 30.0);
    const Eigen::Matrix3d R = Eigen::AngleAxisd(yaw, Eigen::Vector3d::UnitY()).toRotationMatrix();
    for (size_t k = 0; k < anchors.size(); ++k)
      in.anchor_targets.row(static_cast<Eigen::Index>(k)) =
          (R * mesh.vertices.row(anchors[k]).transpose()).transpose();
    in.control = Eigen::VectorXd::Constant(sim->control_layout().size(), 1e-5);
    return in;
  }
};

Board make_board(int target) {
  const pbve::Mesh box = pbve::make_box_mesh(0.4, 0.3, 0.01);
  double best = 0.05, len = pbve::max_edge_length(box);
  int best_count = pbve::refine_mesh(box, best).num_vertices();
  if (target > 0) {
    best_count = box.num_vertices();
    for (int k = 0; k < 200; ++k) {
      len /= std::pow(2.0, 1.0 / 8.0);
      const int count = pbve::refine_mesh(box, len).num_vertices();
      if (std::abs(count - target) < std::abs(best_count - target)) {
        best_count = count;
        best = len;
      }
      if (count > 2 * target) break;
    }
  }
  Board b;
  b.mesh = pbve::refine_mesh(box, best);
  for (int i = 0; i < b.mesh.num_vertices(); ++i)
    if (std::abs(b.mesh.vertices(i, 1)) < 1e-9 && std::abs(b.mesh.vertices(i, 0)) <= 0.05)
      b.anchors.push_back(i);
  Params prm = Params::preset(Material::cloth);
  prm.substeps = 3;
  if (std::getenv("NTOL")) prm.newton_tolerance = std::atof(std::getenv("NTOL"));
  if (std::getenv("SUBS")) prm.substeps = std::atoi(std::getenv("SUBS"));
  set_solver(prm);
  b.sim = std::make_unique<MassSpringSimulator>(b.mesh, b.anchors, prm);
  b.anchors = b.sim->anchors();  // a single sheet holds the nodes carrying the held vertices
  // Swing it for a few frames first (the turn is fastest at the start).
  for (b.frame = 1; b.frame <= 4; ++b.frame) b.sim->step(b.input(b.frame));
  return b;
}

void BM_BoardStep(benchmark::State& state) {
  Board b = make_board(static_cast<int>(state.range(0)));
  const pbve::SimState s0 = b.sim->save();
  const pbve::StepInput in = b.input(b.frame);
  double cg = 0, newton = 0, fact = 0, curvature = 0, unconverged = 0;
  for (auto _ : state) {
    b.sim->restore(s0);
    b.sim->step(in);
    cg += b.sim->last_stats().cg_iterations;
    newton += b.sim->last_stats().newton_iterations;
    fact += b.sim->last_stats().factorizations;
    curvature += b.sim->last_stats().curvature_steps;
    unconverged += b.sim->last_stats().converged ? 0 : 1;
  }
  state.counters["vertices"] = b.sim->num_vertices();
  state.counters["nodes"] = b.sim->num_nodes();  // one face's vertices when a single sheet
  state.counters["cg_iters"] = benchmark::Counter(cg, benchmark::Counter::kAvgIterations);
  state.counters["newton_iters"] = benchmark::Counter(newton, benchmark::Counter::kAvgIterations);
  state.counters["factorizations"] = benchmark::Counter(fact, benchmark::Counter::kAvgIterations);
  state.counters["curvature_steps"] =
      benchmark::Counter(curvature, benchmark::Counter::kAvgIterations);
  // 1 when the timed step left a substep short of the Newton tolerance.
  state.counters["unconverged"] =
      benchmark::Counter(unconverged, benchmark::Counter::kAvgIterations);
}

// step_vjp right after the step (trajectory reused).
void BM_BoardVjp(benchmark::State& state) {
  Board b = make_board(static_cast<int>(state.range(0)));
  const pbve::SimState s0 = b.sim->save();
  const pbve::StepInput in = b.input(b.frame);
  b.sim->step(in);
  const Eigen::VectorXd g =
      b.sim->position_cotangent(pbve::Vertices::Ones(b.sim->num_vertices(), 3));
  for (auto _ : state) benchmark::DoNotOptimize(b.sim->step_vjp(s0, in, g));
  state.counters["vertices"] = b.sim->num_vertices();
}

// step_vjp from a state this simulator did not just step from (forward replay + backward).
void BM_BoardVjpReplay(benchmark::State& state) {
  Board b = make_board(static_cast<int>(state.range(0)));
  const pbve::SimState s0 = b.sim->save();
  const pbve::StepInput in = b.input(b.frame);
  pbve::StepInput other = in;
  other.control *= 2.0;
  const Eigen::VectorXd g =
      b.sim->position_cotangent(pbve::Vertices::Ones(b.sim->num_vertices(), 3));
  for (auto _ : state) {
    state.PauseTiming();
    b.sim->restore(s0);
    b.sim->step(other);  // invalidates the recorded trajectory
    state.ResumeTiming();
    benchmark::DoNotOptimize(b.sim->step_vjp(s0, in, g));
  }
  state.counters["vertices"] = b.sim->num_vertices();
}

// linearize_step right after the step (trajectory reused), without its products.
void BM_BoardLinearize(benchmark::State& state) {
  Board b = make_board(static_cast<int>(state.range(0)));
  const pbve::SimState s0 = b.sim->save();
  const pbve::StepInput in = b.input(b.frame);
  b.sim->step(in);
  for (auto _ : state) benchmark::DoNotOptimize(b.sim->linearize_step(s0, in));
  state.counters["vertices"] = b.sim->num_vertices();
}

// One jvp() and one vjp() of a linearization (what the optimizer calls 20-80 times per frame).
void BM_BoardLinearJvpVjp(benchmark::State& state) {
  Board b = make_board(static_cast<int>(state.range(0)));
  const pbve::SimState s0 = b.sim->save();
  const pbve::StepInput in = b.input(b.frame);
  const auto lin = b.sim->linearize_step(s0, in);
  const Eigen::VectorXd du = Eigen::VectorXd::Constant(b.sim->control_layout().size(), 1e-3);
  const Eigen::VectorXd g =
      b.sim->position_cotangent(pbve::Vertices::Ones(b.sim->num_vertices(), 3));
  for (auto _ : state) {
    benchmark::DoNotOptimize(lin->jvp(Eigen::VectorXd(), du));
    benchmark::DoNotOptimize(lin->vjp(g));
  }
  state.counters["vertices"] = b.sim->num_vertices();
}

}  // namespace

BENCHMARK(BM_ClothStep)
    ->Arg(8)
    ->Arg(12)
    ->Arg(16)
    ->Arg(22)
    ->Arg(32)
    ->Arg(64)
    ->Arg(128)
    ->Arg(181)
    ->Arg(256)
    ->Unit(benchmark::kMillisecond);
BENCHMARK(BM_MultigridSheet)
    ->ArgsProduct({{32, 64, 128, 256}, {0, 10, 100}})
    ->Unit(benchmark::kMillisecond);
BENCHMARK(BM_ClothVjp)->Arg(22)->Arg(32)->Arg(64)->Arg(128)->Unit(benchmark::kMillisecond);
BENCHMARK(BM_ClothVjpReplay)->Arg(32)->Arg(64)->Unit(benchmark::kMillisecond);
// Board targets: 0 = example 1's own refinement (5 cm edges, 494 vertices); 1000, 4000, 8000,
// 16000, 30000 as in `pbve bench --vertices 1000,...` (838, 3 022, 8 090, 19 018 and 32 354
// vertices; from 8 090 on the edges are shorter than the board's 1 cm thickness); 30000 for
// the step only.
static void board_targets(benchmark::internal::Benchmark* b) {
  for (int target : {0, 1000, 4000, 8000, 16000}) b->Arg(target);
}
BENCHMARK(BM_BoardStep)->Apply(board_targets)->Arg(30000)->Unit(benchmark::kMillisecond);
BENCHMARK(BM_BoardVjp)->Arg(0)->Arg(1000)->Arg(4000)->Unit(benchmark::kMillisecond);
BENCHMARK(BM_BoardVjpReplay)->Arg(0)->Arg(1000)->Arg(4000)->Unit(benchmark::kMillisecond);
BENCHMARK(BM_BoardLinearize)->Apply(board_targets)->Unit(benchmark::kMillisecond);
BENCHMARK(BM_BoardLinearJvpVjp)->Apply(board_targets)->Unit(benchmark::kMillisecond);
BENCHMARK_MAIN();
