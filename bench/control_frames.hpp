#pragma once
// Shared by the control benchmarks: frames of the swung cloth board (tests/control/
// cloth_scene.hpp) from a saved simulator, with or without control, timed without the metric.

#include <algorithm>
#include <chrono>
#include <span>
#include <vector>

#include <benchmark/benchmark.h>

#include "control/cloth_scene.hpp"

namespace pbve::bench {

/// Runs frames first..first + inputs.size() - 1 of `scene` from a clone of `sim0`, once per
/// benchmark iteration, with control (`control`) or without, and sets the counters
/// ms_per_frame (wall time of the frames without the metric), violation_pct (mean),
/// force_ratio (median control / physical force), evals_per_frame, variables (per frame),
/// probes_per_frame (central-difference simulations), model_evals_per_frame (evaluations of
/// the linearized search's model) and vertices.
inline void run_control_frames(benchmark::State& state, const test::ClothScene& scene,
                               const Simulator& sim0, int first,
                               const std::vector<ControlFrameInput>& inputs,
                               const ControlOptions& options, bool control) {
  using clock = std::chrono::steady_clock;
  auto ms_since = [](clock::time_point t0) {
    return std::chrono::duration<double, std::milli>(clock::now() - t0).count();
  };
  double violation = 0.0, ratio = 0.0, ms = 0.0, evaluations = 0.0, variables = 0.0, probes = 0.0,
         model = 0.0;
  for (auto _ : state) {
    ms = violation = evaluations = variables = probes = model = 0.0;
    const auto t0 = clock::now();
    auto sim = sim0.clone();
    ControlOptimizer opt(scene.two_sided, {}, options);
    std::vector<double> ratios;
    for (size_t k = 0; k < inputs.size(); ++k) {
      const auto r = control ? opt.step(*sim, std::span(&inputs[k], 1))
                             : opt.step_uncontrolled(*sim, inputs[k]);
      ratios.push_back(r.physical_force > 0.0 ? r.control_force / r.physical_force : 0.0);
      evaluations += r.evaluations;
      variables += r.variables;
      probes += r.probes;
      model += r.model_evaluations;
      const auto t1 = clock::now();
      violation += scene.violation_pct(sim->positions(), first + static_cast<int>(k));
      ms -= ms_since(t1);
    }
    ms += ms_since(t0);
    std::sort(ratios.begin(), ratios.end());
    ratio = ratios[ratios.size() / 2];
  }
  const auto n = static_cast<double>(inputs.size());
  state.counters["ms_per_frame"] = ms / n;
  state.counters["violation_pct"] = violation / n;
  state.counters["force_ratio"] = ratio;
  state.counters["evals_per_frame"] = evaluations / n;
  state.counters["variables"] = variables / n;
  state.counters["probes_per_frame"] = probes / n;
  state.counters["model_evals_per_frame"] = model / n;
  state.counters["vertices"] = scene.num_vertices();
}

}  // namespace pbve::bench
