// pbve::mass_spring: one step (dt 1/30 s, default substeps) of an anchored cloth at 484, ~1k,
// 4k and 16k vertices, and one step_vjp relative to one step. For comparisons, environment
// variables override parameters: SUBS (substeps), NTOL (newton_tolerance), ITER (any value:
// block-Jacobi conjugate gradients instead of the automatic solver choice).

#include <cstdlib>

#include <benchmark/benchmark.h>

#include "pbve/mass_spring/mass_spring.hpp"

namespace {

using pbve::mass_spring::MassSpringSimulator;
using pbve::mass_spring::Material;
using pbve::mass_spring::Params;

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
  if (std::getenv("ITER")) prm.linear_solver = pbve::mass_spring::LinearSolver::iterative;
  MassSpringSimulator sim(m, {0, n - 1}, prm);
  // Start from a swinging state, not from rest.
  for (int s = 0; s < 5; ++s) sim.step(pbve::StepInput{});
  return sim;
}

void BM_ClothStep(benchmark::State& state) {
  MassSpringSimulator sim = make_cloth(static_cast<int>(state.range(0)));
  const pbve::SimState s0 = sim.save();
  pbve::StepInput in;
  in.control = Eigen::VectorXd::Constant(3 * sim.num_vertices(), 1e-5);
  double cg = 0, newton = 0, fact = 0;
  for (auto _ : state) {
    sim.restore(s0);
    sim.step(in);
    cg += sim.last_stats().cg_iterations;
    newton += sim.last_stats().newton_iterations;
    fact += sim.last_stats().factorizations;
  }
  state.counters["vertices"] = sim.num_vertices();
  state.counters["cg_iters"] = benchmark::Counter(cg, benchmark::Counter::kAvgIterations);
  state.counters["newton_iters"] = benchmark::Counter(newton, benchmark::Counter::kAvgIterations);
  state.counters["factorizations"] = benchmark::Counter(fact, benchmark::Counter::kAvgIterations);
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
  for (auto _ : state) benchmark::DoNotOptimize(sim.step_vjp(s0, in, g));
  state.counters["vertices"] = sim.num_vertices();
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

}  // namespace

BENCHMARK(BM_ClothStep)->Arg(22)->Arg(32)->Arg(64)->Arg(128)->Unit(benchmark::kMillisecond);
BENCHMARK(BM_ClothVjp)->Arg(22)->Arg(32)->Arg(64)->Unit(benchmark::kMillisecond);
BENCHMARK(BM_ClothVjpReplay)->Arg(32)->Arg(64)->Unit(benchmark::kMillisecond);
BENCHMARK_MAIN();
