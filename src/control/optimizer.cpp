#include "pbve/control/optimizer.hpp"

#include <algorithm>
#include <cmath>
#include <limits>
#include <mutex>
#include <stdexcept>
#include <string>

#include <tbb/parallel_for.h>

#include "control/solvers.hpp"

namespace pbve {

namespace {

/// Runs probe(sim, q) for q = 0 .. count-1: on `base` itself in order, or in parallel over a
/// pool of clones of `base` (each probe restores the state it needs, so which simulator runs
/// which probe does not change its result).
template <class Probe>
void for_each_probe(Simulator& base, int count, bool parallel, const Probe& probe) {
  if (!parallel) {
    for (int q = 0; q < count; ++q) probe(base, q);
    return;
  }
  std::mutex mutex;
  std::vector<std::unique_ptr<Simulator>> owned;
  std::vector<Simulator*> free;
  tbb::parallel_for(0, count, [&](int q) {
    Simulator* s = nullptr;
    {
      std::lock_guard<std::mutex> lock(mutex);
      if (free.empty()) {
        owned.push_back(base.clone());
        free.push_back(owned.back().get());
      }
      s = free.back();
      free.pop_back();
    }
    probe(*s, q);
    std::lock_guard<std::mutex> lock(mutex);
    free.push_back(s);
  });
}

constexpr double kStandardGravity = 9.80665;  // m/s^2

using Clock = std::chrono::steady_clock;
double ms_since(Clock::time_point t0) {
  return std::chrono::duration<double, std::milli>(Clock::now() - t0).count();
}

// Everything one frame's (window's) optimization needs. Variables z are the control
// components of the active blocks, frame-major, in units of the block weight.
class WindowProblem {
 public:
  WindowProblem(Simulator& sim, std::span<const ControlFrameInput> window, int frames,
                const Triangles& triangles, const std::vector<std::uint8_t>& interior,
                const ControlOptions& options, const Eigen::VectorXd& previous,
                const Vertices& reference)
      : m_sim(sim), m_triangles(triangles), m_options(options) {
    m_layout = sim.control_layout();
    m_bs = m_layout.block_size();
    m_size = m_layout.size();
    if (m_layout.block_mass.size() != m_layout.num_blocks)
      throw std::invalid_argument("ControlLayout::block_mass has the wrong size");
    m_frames = frames;
    const auto nf = static_cast<size_t>(triangles.rows());
    const Vertices x0 = sim.positions();
    for (Eigen::Index j = 0; j < triangles.rows(); ++j)
      for (int c = 0; c < 3; ++c)
        if (triangles(j, c) < 0 || triangles(j, c) >= x0.rows())
          throw std::invalid_argument("ControlOptimizer: triangle " + std::to_string(j) +
                                      " refers to a vertex the simulator does not have");
    const Eigen::VectorXd weights = visibility_weights(x0, triangles);
    for (int k = 0; k < frames; ++k) {
      const ControlFrameInput& in = window[static_cast<size_t>(k)];
      if (in.unobserved.size() != nf)
        throw std::invalid_argument("ControlFrameInput::unobserved of frame " + std::to_string(k) +
                                    " has " + std::to_string(in.unobserved.size()) +
                                    " entries, expected " + std::to_string(nf));
      if (!in.observed.empty() && in.observed.size() != nf)
        throw std::invalid_argument("ControlFrameInput::observed of frame " + std::to_string(k) +
                                    " has " + std::to_string(in.observed.size()) +
                                    " entries, expected " + std::to_string(nf) +
                                    " (one per triangle) or none");
      StepInput s;
      s.dt = in.dt;
      s.anchor_targets = in.anchor_targets;
      m_inputs.push_back(std::move(s));
      std::vector<std::uint8_t> pen(nf, 0);
      for (size_t j = 0; j < nf; ++j)
        pen[j] =
            in.unobserved[j] || (options.penalize_interior && !interior.empty() && interior[j]);
      // Occlusion pairs from the positions at the start of the window.
      std::vector<OcclusionPair> pairs;
      if (options.occlusion_margin > 0.0 && in.observed.size() == nf &&
          reference.rows() == x0.rows())
        pairs = occlusion_pairs(x0, reference, triangles, pen, in.observed, 0.0);
      m_occlusion.push_back(std::move(pairs));
      m_penalized.push_back(std::move(pen));
    }
    m_weights = weights;
    m_previous = previous.size() == m_size ? previous : Eigen::VectorXd::Zero(m_size);
    // Torques count as the force |tau| / arm_b (EF, ET) and are scaled by m_b g0 arm_b.
    m_arm = Eigen::VectorXd::Constant(m_layout.num_blocks, options.torque_arm);
    if (m_bs == 6 && m_layout.block_arm.size() == m_layout.num_blocks)
      for (int b = 0; b < m_layout.num_blocks; ++b)
        if (m_layout.block_arm[b] > 0.0 && std::isfinite(m_layout.block_arm[b]))
          m_arm[b] = m_layout.block_arm[b];
    m_eps.resize(m_layout.num_blocks * (m_bs / 3));
    for (int b = 0; b < m_layout.num_blocks; ++b)
      for (int p = 0; p < m_bs / 3; ++p)
        m_eps[b * (m_bs / 3) + p] =
            options.force_smoothing * m_layout.block_mass[b] * kStandardGravity;
    if (m_bs == 6) {
      m_force_scale = Eigen::VectorXd::Ones(m_size);
      for (int b = 0; b < m_layout.num_blocks; ++b)
        m_force_scale.segment(6 * b + 3, 3).setConstant(1.0 / m_arm[b]);
    }
    m_force_unit = kStandardGravity * m_layout.block_mass.sum();
    if (!(m_force_unit > 0.0)) m_force_unit = 1.0;
    m_fixed.assign(static_cast<size_t>(frames), Eigen::VectorXd::Zero(m_size));
    m_state0 = sim.save();
  }

  const ControlLayout& layout() const { return m_layout; }
  const ControlOptions& options() const { return m_options; }
  int frames() const { return m_frames; }
  int size() const { return m_size; }
  int num_variables() const { return m_frames * m_nv; }
  int variables_per_frame() const { return m_nv; }
  const SimState& state0() const { return m_state0; }
  const std::vector<std::uint8_t>& penalized(int k) const {
    return m_penalized[static_cast<size_t>(k)];
  }
  const Eigen::VectorXd& previous() const { return m_previous; }

  // One variable per component of every active block, in units of the block's weight.
  void set_active(std::vector<int> active) {
    m_active = std::move(active);
    m_columns.clear();
    for (int b : m_active)
      for (int c = 0; c < m_bs; ++c)
        m_columns.push_back(
            {{b * m_bs + c, m_layout.block_mass[b] * kStandardGravity * (c < 3 ? 1.0 : m_arm[b])}});
    m_nv = static_cast<int>(m_columns.size());
  }
  // Reduced control space (vertex forces): variable 3 c + d is the acceleration along axis d,
  // in units of g0, shared by the active blocks of cluster c (block b receives m_b g0 z).
  void set_clusters(std::vector<int> active, const std::vector<int>& cluster, int clusters) {
    m_active = std::move(active);
    m_columns.assign(static_cast<size_t>(3 * clusters), {});
    for (size_t a = 0; a < m_active.size(); ++a) {
      const int b = m_active[a];
      for (int d = 0; d < 3; ++d)
        m_columns[static_cast<size_t>(3 * cluster[a] + d)].push_back(
            {b * 3 + d, m_layout.block_mass[b] * kStandardGravity});
    }
    m_nv = static_cast<int>(m_columns.size());
  }
  void set_fixed(const Eigen::VectorXd& u) {
    for (int k = 0; k < m_frames; ++k)
      m_fixed[static_cast<size_t>(k)] = u.segment(k * m_size, m_size);
  }
  // Control components moved by variable i of a frame, with their coefficients (du / dz).
  struct Entry {
    int component;
    double coef;
  };
  const std::vector<Entry>& column(int i) const { return m_columns[static_cast<size_t>(i)]; }
  // d/dz_i of a function with gradient g with respect to one frame's control.
  double chain(const Eigen::VectorXd& g, int i) const {
    double out = 0.0;
    for (const Entry& e : column(i)) out += e.coef * g[e.component];
    return out;
  }
  // Adds h along variable i to a frame's control.
  void perturb(Eigen::VectorXd& u, int i, double h) const {
    for (const Entry& e : column(i)) u[e.component] += h * e.coef;
  }

  // z from full controls (frame-major): per variable, the least-squares fit over its column.
  Eigen::VectorXd to_z(const Eigen::VectorXd& u) const {
    Eigen::VectorXd z(num_variables());
    for (int k = 0; k < m_frames; ++k)
      for (int i = 0; i < m_nv; ++i) {
        double num = 0.0, den = 0.0;
        for (const Entry& e : column(i)) {
          num += e.coef * u[k * m_size + e.component];
          den += e.coef * e.coef;
        }
        z[k * m_nv + i] = den > 0.0 ? num / den : 0.0;
      }
    return z;
  }
  std::vector<Eigen::VectorXd> expand(const double* z) const {
    std::vector<Eigen::VectorXd> u = m_fixed;
    for (int k = 0; k < m_frames; ++k) {
      Eigen::VectorXd& uk = u[static_cast<size_t>(k)];
      for (const auto& col : m_columns)
        for (const Entry& e : col) uk[e.component] = 0.0;
      for (int i = 0; i < m_nv; ++i) perturb(uk, i, z[k * m_nv + i]);
    }
    return u;
  }

  // EC of frame k at positions x (and its gradient): the facing barrier of the must-stay-hidden
  // triangles plus the occlusion barrier of the vertices observed triangles hide.
  double visibility(int k, const Vertices& x, Vertices* grad) const {
    const auto kk = static_cast<size_t>(k);
    double e =
        visibility_energy(x, m_triangles, m_penalized[kk], m_weights, m_options.barrier, grad);
    if (!m_occlusion[kk].empty()) {
      Vertices g;
      e += occlusion_energy(x, m_triangles, m_occlusion[kk], occlusion_barrier(),
                            grad ? &g : nullptr);
      if (grad) *grad += g;
    }
    return e;
  }
  VisibilityBarrier occlusion_barrier() const {
    return {m_options.occlusion_margin, m_options.barrier.clamp};
  }
  const std::vector<OcclusionPair>& occlusion(int k) const {
    return m_occlusion[static_cast<size_t>(k)];
  }

  // lF EF + lT ET over the window with gradients w.r.t. each frame's full control; EF and ET
  // in units of the object's weight (dimensionless).
  double force_terms(const std::vector<Eigen::VectorXd>& u, std::vector<Eigen::VectorXd>* grad,
                     double* ef_sum, double* et_sum) const {
    const int nb = static_cast<int>(m_eps.size());
    const int block = 3;
    double ef = 0.0, et = 0.0;
    Eigen::VectorXd g1, g2;
    if (grad) grad->assign(u.size(), Eigen::VectorXd::Zero(m_size));
    // Body wrenches: torques as forces at the lever arm (u scaled by m_force_scale).
    const bool scaled = m_force_scale.size() == m_size;
    for (size_t k = 0; k < u.size(); ++k) {
      const Eigen::VectorXd& prev = k == 0 ? m_previous : u[k - 1];
      if (scaled) {
        ef +=
            smoothed_norm_sum(u[k].cwiseProduct(m_force_scale), block, m_eps, grad ? &g1 : nullptr);
        et += smoothed_norm_sum((u[k] - prev).cwiseProduct(m_force_scale), block, m_eps,
                                grad ? &g2 : nullptr);
        if (grad) {
          g1 = g1.cwiseProduct(m_force_scale);
          g2 = g2.cwiseProduct(m_force_scale);
        }
      } else {
        ef += smoothed_norm_sum(u[k], block, m_eps, grad ? &g1 : nullptr);
        et += smoothed_norm_sum(u[k] - prev, block, m_eps, grad ? &g2 : nullptr);
      }
      if (grad) {
        (*grad)[k] +=
            (m_options.weights.force * g1 + m_options.weights.temporal * g2) / m_force_unit;
        if (k > 0) (*grad)[k - 1] -= (m_options.weights.temporal / m_force_unit) * g2;
      }
    }
    (void)nb;
    ef /= m_force_unit;
    et /= m_force_unit;
    if (ef_sum) *ef_sum = ef;
    if (et_sum) *et_sum = et;
    return m_options.weights.force * ef + m_options.weights.temporal * et;
  }

  // Simulates frames k0.. from `start` with controls u (frame k0's variable `var` shifted by
  // `delta` when var >= 0) on `sim`; returns the sum of EC over those frames.
  double probe(Simulator& sim, const SimState& start, int k0, const std::vector<Eigen::VectorXd>& u,
               int var, double delta) const {
    sim.restore(start);
    double ec = 0.0;
    StepInput in;
    for (int k = k0; k < m_frames; ++k) {
      const StepInput& base = m_inputs[static_cast<size_t>(k)];
      in.dt = base.dt;
      in.anchor_targets = base.anchor_targets;
      in.control = u[static_cast<size_t>(k)];
      if (k == k0 && var >= 0) perturb(in.control, var, delta);
      sim.step(in);
      ec += visibility(k, sim.positions(), nullptr);
    }
    return ec;
  }

  // Facing values of the penalized triangles of frame k at positions x (NaN elsewhere).
  Eigen::VectorXd facing(int k, const Vertices& x) const {
    Eigen::VectorXd s =
        Eigen::VectorXd::Constant(m_triangles.rows(), std::numeric_limits<double>::quiet_NaN());
    for (Eigen::Index j = 0; j < m_triangles.rows(); ++j)
      if (m_penalized[static_cast<size_t>(k)][static_cast<size_t>(j)])
        s[j] =
            facing_value(x.row(m_triangles(j, 0)).transpose(), x.row(m_triangles(j, 1)).transpose(),
                         x.row(m_triangles(j, 2)).transpose(), nullptr);
    return s;
  }

  StepInput input(int k, const Eigen::VectorXd& u) const {
    StepInput in = m_inputs[static_cast<size_t>(k)];
    in.control = u;
    return in;
  }

  struct Eval {
    double energy = 0.0, ec = 0.0, ef = 0.0, et = 0.0;
  };
  // The simulator right after the first frame's step of an evaluation: committing that
  // evaluation's controls is restoring it (the same state bit for bit as stepping again).
  struct Snapshot {
    SimState state;
    Eigen::VectorXd physical;  // Simulator::physical_force_magnitudes() of that step
    bool valid = false;
  };
  const Snapshot& last_snapshot() const { return m_snapshot; }
  // The one-frame window already simulated at zero control from state0 (positions after the
  // step and its snapshot): evaluate() at zero control uses it instead of stepping again, and
  // the adjoint's step_vjp can reuse the simulator's record of that step.
  void set_zero_step(Vertices positions, Snapshot first) {
    m_zero_positions = std::move(positions);
    m_zero_first = std::move(first);
    m_has_zero_step = m_frames == 1 && m_zero_first.valid;
  }

  // Energy at z; gradient dE/dz when grad is not null, by `mode` (resolved: central,
  // compressed or adjoint; compressed falls back to central where it does not apply).
  Eval evaluate(const double* z, double* grad, GradientMode mode, bool parallel) {
    const bool adjoint = mode == GradientMode::adjoint;
    const bool respond = !adjoint && mode == GradientMode::compressed && m_compressed;
    const bool cotangents = grad && (adjoint || respond);
    const std::vector<Eigen::VectorXd> u = expand(z);
    Eval ev;
    ev.energy = force_terms(u, nullptr, &ev.ef, &ev.et);
    std::vector<SimState>& states = m_last_states;
    std::vector<Vertices>& positions = m_last_positions;
    states.clear();
    positions.clear();
    std::vector<Vertices> dx;
    const bool reuse_zero = m_has_zero_step && u[0].isZero(0.0);
    if (reuse_zero) {
      states.push_back(m_state0);
      positions.push_back(m_zero_positions);
      Vertices g;
      ev.ec = visibility(0, m_zero_positions, cotangents ? &g : nullptr);
      if (cotangents) dx.push_back(std::move(g));
      m_snapshot = m_zero_first;
    } else {
      m_sim.restore(m_state0);
    }
    for (int k = reuse_zero ? m_frames : 0; k < m_frames; ++k) {
      states.push_back(m_sim.save());
      m_sim.step(input(k, u[static_cast<size_t>(k)]));
      if (k == 0) {
        m_snapshot.state = m_sim.save();
        m_snapshot.physical = checked_force_magnitudes(m_sim);
        m_snapshot.valid = true;
      }
      positions.push_back(m_sim.positions());
      Vertices g;
      ev.ec += visibility(k, positions.back(), cotangents ? &g : nullptr);
      if (cotangents) dx.push_back(std::move(g));
    }
    ev.energy += m_options.weights.visibility * ev.ec;
    if (!grad) return ev;

    const auto t0 = Clock::now();
    std::vector<Eigen::VectorXd> gu;
    force_terms(u, &gu, nullptr, nullptr);
    const int nv = m_nv;
    const double lc = m_options.weights.visibility;
    if (adjoint) {
      Eigen::VectorXd gs = Eigen::VectorXd::Zero(m_sim.state_dim());
      for (int k = m_frames - 1; k >= 0; --k) {
        // position_cotangent() is taken at the state after frame k: the simulator is there
        // after the forward pass for the last frame; step_vjp() leaves it elsewhere.
        if (k + 1 < m_frames)
          m_sim.restore(states[static_cast<size_t>(k + 1)]);
        else if (reuse_zero)
          m_sim.restore(m_zero_first.state);
        gs += m_sim.position_cotangent(dx[static_cast<size_t>(k)]);
        StepVjp vjp =
            m_sim.step_vjp(states[static_cast<size_t>(k)], input(k, u[static_cast<size_t>(k)]), gs);
        gu[static_cast<size_t>(k)] += lc * vjp.control;
        gs = std::move(vjp.state);
      }
      for (int k = 0; k < m_frames; ++k)
        for (int i = 0; i < nv; ++i) grad[k * nv + i] = chain(gu[static_cast<size_t>(k)], i);
    } else if (respond) {
      // One frame: dEC/dz_i is the surface cotangent dotted with variable i's response.
      const std::vector<Vertices> response = this->response(u[0], parallel);
      for (int i = 0; i < nv; ++i)
        grad[i] = chain(gu[0], i) + lc * response_dot(response, i, dx[0]);
    } else {
      const int n = num_variables();
      std::vector<double> ep(static_cast<size_t>(n)), em(static_cast<size_t>(n));
      const double h = m_options.fd_step;
      auto run = [&](Simulator& sim, int q) {
        const int i = q / 2, k = i / nv;
        const double e =
            probe(sim, states[static_cast<size_t>(k)], k, u, i % nv, q % 2 == 0 ? h : -h);
        (q % 2 == 0 ? ep : em)[static_cast<size_t>(i)] = e;
      };
      for_each_probe(m_sim, 2 * n, parallel, run);
      m_probes += 2 * n;
      for (int i = 0; i < n; ++i) {
        const int k = i / nv;
        const double dec = (ep[static_cast<size_t>(i)] - em[static_cast<size_t>(i)]) / (2.0 * h);
        grad[i] = chain(gu[static_cast<size_t>(k)], i % nv) + lc * dec;
      }
    }
    m_gradient_ms += ms_since(t0);
    ++m_gradients;
    return ev;
  }

  // Probe groups of the difference estimates. The variables of a frame come in units of
  // m_group consecutive ones (the components of one block or one cluster); a probe perturbs
  // one component of every unit of a colour. With rings >= 0, one force per vertex block and
  // a one-frame window, a unit's response is kept on its ball (the vertices of its block grown
  // by `rings` rings of `adjacency`) and units whose balls do not overlap share a colour
  // (greedy, in unit order); otherwise every unit has its own colour and keeps its response
  // on every vertex (plain central differences).
  void set_probe_groups(const std::vector<std::vector<int>>& adjacency, int rings) {
    m_group = m_bs == 6 ? 6 : 3;
    const int units = m_nv / m_group;
    m_colours.clear();
    m_ball.assign(static_cast<size_t>(units), {});
    bool single = true;
    for (int a = 0; a < units; ++a) single = single && column(a * m_group).size() == 1;
    m_compressed = rings >= 0 && m_bs == 3 && single && m_frames == 1;
    if (!m_compressed) {
      for (int a = 0; a < units; ++a) m_colours.push_back({a});
      return;
    }
    const int nvtx = static_cast<int>(m_layout.vertex_block.size());
    std::vector<std::vector<int>> block_vertices(static_cast<size_t>(m_layout.num_blocks));
    for (int v = 0; v < nvtx; ++v)
      if (const int b = m_layout.vertex_block[static_cast<size_t>(v)]; b >= 0)
        block_vertices[static_cast<size_t>(b)].push_back(v);
    std::vector<int> mark(static_cast<size_t>(nvtx), -1);
    std::vector<std::vector<int>> claim(static_cast<size_t>(nvtx));  // units whose ball has v
    std::vector<int> colour_of(static_cast<size_t>(units), 0), taken;
    for (int a = 0; a < units; ++a) {
      std::vector<int>& ball = m_ball[static_cast<size_t>(a)];
      auto add = [&](int v) {
        if (v < 0 || v >= nvtx || mark[static_cast<size_t>(v)] == a) return;
        mark[static_cast<size_t>(v)] = a;
        ball.push_back(v);
      };
      for (int v : block_vertices[static_cast<size_t>(column(a * m_group).front().component / 3)])
        add(v);
      for (int r = 0, begin = 0; r < rings; ++r) {
        const int end = static_cast<int>(ball.size());
        if (end == begin) break;  // the ball stopped growing: more rings add nothing
        for (int q = begin; q < end; ++q)
          if (const auto v = static_cast<size_t>(ball[static_cast<size_t>(q)]);
              v < adjacency.size())
            for (int w : adjacency[v]) add(w);
        begin = end;
      }
      std::sort(ball.begin(), ball.end());
      for (int v : ball)
        for (int o : claim[static_cast<size_t>(v)])
          taken[static_cast<size_t>(colour_of[static_cast<size_t>(o)])] = a;
      int c = 0;
      while (c < static_cast<int>(m_colours.size()) && taken[static_cast<size_t>(c)] == a) ++c;
      if (c == static_cast<int>(m_colours.size())) {
        m_colours.emplace_back();
        taken.push_back(-1);
      }
      m_colours[static_cast<size_t>(c)].push_back(a);
      colour_of[static_cast<size_t>(a)] = c;
      for (int v : ball) claim[static_cast<size_t>(v)].push_back(a);
    }
  }
  // Numbers response() holds at its peak: the responses and the probes' positions.
  double response_numbers() const {
    const double nvtx = static_cast<double>(m_layout.vertex_block.size());
    double kept = 0.0;
    for (size_t a = 0; a < m_ball.size(); ++a)
      kept += 3.0 * m_group * (m_compressed ? static_cast<double>(m_ball[a].size()) : nvtx);
    return kept + 2.0 * 3.0 * nvtx * static_cast<double>(m_colours.size()) * m_group;
  }

  // The response of the surface positions after frame 0 to every variable of that frame at
  // its controls u0, by central differences over the probe groups: per variable, the rows of
  // its unit's ball (compressed) or #V rows. 2 * #colours * m_group simulations.
  std::vector<Vertices> response(const Eigen::VectorXd& u0, bool parallel) {
    const int probes = static_cast<int>(m_colours.size()) * m_group;
    const double h = m_options.fd_step;
    std::vector<Vertices> plus(static_cast<size_t>(probes)), minus(static_cast<size_t>(probes));
    auto run = [&](Simulator& sim, int q) {
      const int p = q / 2;
      StepInput in = input(0, u0);
      for (int a : m_colours[static_cast<size_t>(p / m_group)])
        perturb(in.control, a * m_group + p % m_group, q % 2 == 0 ? h : -h);
      sim.restore(m_state0);
      sim.step(in);
      (q % 2 == 0 ? plus : minus)[static_cast<size_t>(p)] = sim.positions();
    };
    for_each_probe(m_sim, 2 * probes, parallel, run);
    m_probes += 2 * probes;
    std::vector<Vertices> out(static_cast<size_t>(m_nv));
    for (int p = 0; p < probes; ++p) {
      const Vertices d = (plus[static_cast<size_t>(p)] - minus[static_cast<size_t>(p)]) / (2.0 * h);
      plus[static_cast<size_t>(p)] = Vertices();
      minus[static_cast<size_t>(p)] = Vertices();
      for (int a : m_colours[static_cast<size_t>(p / m_group)]) {
        const std::vector<int>& ball = m_ball[static_cast<size_t>(a)];
        Vertices& j = out[static_cast<size_t>(a * m_group + p % m_group)];
        if (!m_compressed) {
          j = d;
          continue;
        }
        j.resize(static_cast<Eigen::Index>(ball.size()), 3);
        for (size_t r = 0; r < ball.size(); ++r)
          j.row(static_cast<Eigen::Index>(r)) = d.row(ball[r]);
      }
    }
    return out;
  }
  // Sum over the rows of variable i's response of their dot products with g (#V by 3).
  double response_dot(const std::vector<Vertices>& response, int i, const Vertices& g) const {
    const Vertices& j = response[static_cast<size_t>(i)];
    const std::vector<int>& ball = m_ball[static_cast<size_t>(i / m_group)];
    if (!m_compressed) return j.cwiseProduct(g).sum();
    double out = 0.0;
    for (size_t r = 0; r < ball.size(); ++r)
      out += j.row(static_cast<Eigen::Index>(r)).dot(g.row(ball[r]));
    return out;
  }
  // x += s * (variable i's response).
  void add_response(Vertices& x, const std::vector<Vertices>& response, int i, double s) const {
    const Vertices& j = response[static_cast<size_t>(i)];
    const std::vector<int>& ball = m_ball[static_cast<size_t>(i / m_group)];
    if (!m_compressed) {
      x += s * j;
      return;
    }
    for (size_t r = 0; r < ball.size(); ++r)
      x.row(ball[r]) += s * j.row(static_cast<Eigen::Index>(r));
  }
  int probes() const { return m_probes; }

  // Hard-constraint mode: c = margin - s_j <= 0 for the listed (frame, triangle) pairs, and
  // the Jacobian by central differences.
  void set_constraints(std::vector<std::pair<int, int>> list) { m_constraints = std::move(list); }
  int num_constraints() const { return static_cast<int>(m_constraints.size()); }
  void constraints(const double* z, double* c, double* jac, bool parallel) {
    const std::vector<Eigen::VectorXd> u = expand(z);
    const int m = num_constraints();
    auto values = [&](Simulator& sim, const SimState& start, int k0,
                      const std::vector<Eigen::VectorXd>& uu, int var, double delta,
                      std::vector<SimState>* states) {
      Eigen::VectorXd out = Eigen::VectorXd::Zero(m);
      sim.restore(start);
      for (int k = k0; k < m_frames; ++k) {
        if (states) states->push_back(sim.save());
        StepInput in = input(k, uu[static_cast<size_t>(k)]);
        if (k == k0 && var >= 0) perturb(in.control, var, delta);
        sim.step(in);
        const Eigen::VectorXd s = facing(k, sim.positions());
        for (int j = 0; j < m; ++j)
          if (m_constraints[static_cast<size_t>(j)].first == k)
            out[j] = m_options.barrier.margin - s[m_constraints[static_cast<size_t>(j)].second];
      }
      return out;
    };
    std::vector<SimState> states;
    const Eigen::VectorXd c0 = values(m_sim, m_state0, 0, u, -1, 0.0, &states);
    for (int j = 0; j < m; ++j) c[j] = c0[j];
    if (!jac) return;
    const auto t0 = Clock::now();
    const int n = num_variables();
    const int nv = m_nv;
    const double h = m_options.fd_step;
    std::vector<Eigen::VectorXd> cp(static_cast<size_t>(n)), cm(static_cast<size_t>(n));
    auto run = [&](Simulator& sim, int q) {
      const int i = q / 2, k = i / nv;
      Eigen::VectorXd v =
          values(sim, states[static_cast<size_t>(k)], k, u, i % nv, q % 2 == 0 ? h : -h, nullptr);
      // Constraints of earlier frames do not depend on this variable.
      for (int j = 0; j < m; ++j)
        if (m_constraints[static_cast<size_t>(j)].first < k) v[j] = c0[j];
      (q % 2 == 0 ? cp : cm)[static_cast<size_t>(i)] = std::move(v);
    };
    for_each_probe(m_sim, 2 * n, parallel, run);
    m_probes += 2 * n;
    for (int j = 0; j < m; ++j)
      for (int i = 0; i < n; ++i)
        jac[j * n + i] =
            (cp[static_cast<size_t>(i)][j] - cm[static_cast<size_t>(i)][j]) / (2.0 * h);
    m_gradient_ms += ms_since(t0);
  }

  double gradient_ms() const { return m_gradient_ms; }
  int gradients() const { return m_gradients; }
  void add_gradient(double ms) {
    m_gradient_ms += ms;
    ++m_gradients;
  }
  Simulator& simulator() const { return m_sim; }
  // The state before each window frame and the surface positions after it, of the latest
  // evaluate().
  const std::vector<SimState>& last_states() const { return m_last_states; }
  const std::vector<Vertices>& last_positions() const { return m_last_positions; }

 private:
  Simulator& m_sim;
  const Triangles& m_triangles;
  const ControlOptions& m_options;
  ControlLayout m_layout;
  int m_bs = 3, m_size = 0, m_frames = 1;
  std::vector<StepInput> m_inputs;
  std::vector<std::vector<std::uint8_t>> m_penalized;
  std::vector<std::vector<OcclusionPair>> m_occlusion;  // per frame
  Eigen::VectorXd m_weights;
  Eigen::VectorXd m_previous;
  Eigen::VectorXd m_eps;
  Eigen::VectorXd m_arm;          // lever arm per block (body wrenches), metres
  Eigen::VectorXd m_force_scale;  // body wrenches: 1 for forces, 1 / arm for torques
  double m_force_unit = 1.0;      // the object's weight g0 * sum of block masses, newtons
  std::vector<Eigen::VectorXd> m_fixed;
  SimState m_state0;
  std::vector<int> m_active;
  std::vector<std::vector<Entry>> m_columns;  // per variable of a frame
  Snapshot m_snapshot;                        // of the latest evaluate()
  std::vector<SimState> m_last_states;        // of the latest evaluate()
  std::vector<Vertices> m_last_positions;
  Vertices m_zero_positions;  // see set_zero_step()
  Snapshot m_zero_first;
  bool m_has_zero_step = false;
  int m_nv = 0;  // variables per frame
  // Probe groups (set_probe_groups()).
  int m_group = 3;
  bool m_compressed = false;
  std::vector<std::vector<int>> m_colours;  // units per colour
  std::vector<std::vector<int>> m_ball;     // per unit, sorted (compressed; else every vertex)
  int m_probes = 0;
  std::vector<std::pair<int, int>> m_constraints;
  double m_gradient_ms = 0.0;
  int m_gradients = 0;
};

// The energy of a window with its dynamics linearized at a point, minimized by the linearized
// search between true evaluations.
class SearchModel {
 public:
  virtual ~SearchModel() = default;
  virtual double evaluate(const double* z, double* grad) = 0;
};

// The window energy with the dynamics linearized at a point z_lin: the positions after frame k
// are X_k + dX_k, X_k those of the true evaluation at z_lin and dX_k the tangent of the chained
// step linearizations along u(z) - u(z_lin); the force terms are exact. Each evaluation costs
// one jvp per frame, each gradient one vjp per frame (Simulator::linearize_step()).
class LinearModel final : public SearchModel {
 public:
  // `problem`'s latest evaluate() must be the one at z_lin.
  LinearModel(WindowProblem& problem, const Eigen::VectorXd& z_lin)
      : m_problem(problem), m_u_lin(problem.expand(z_lin.data())) {
    Simulator& sim = problem.simulator();
    m_x_lin = problem.last_positions();
    const std::vector<SimState> states = problem.last_states();
    for (int k = 0; k < problem.frames(); ++k)
      m_lin.push_back(sim.linearize_step(states[static_cast<size_t>(k)],
                                         problem.input(k, m_u_lin[static_cast<size_t>(k)])));
  }

  double evaluate(const double* z, double* grad) override {
    const auto t0 = Clock::now();
    Simulator& sim = m_problem.simulator();
    const int frames = m_problem.frames();
    const std::vector<Eigen::VectorXd> u = m_problem.expand(z);
    std::vector<Eigen::VectorXd> gu;
    double energy = m_problem.force_terms(u, grad ? &gu : nullptr, nullptr, nullptr);
    const double lc = m_problem.options().weights.visibility;
    Eigen::VectorXd ds;
    std::vector<Vertices> gx(static_cast<size_t>(frames));
    for (int k = 0; k < frames; ++k) {
      const auto kk = static_cast<size_t>(k);
      ds = m_lin[kk]->jvp(ds, u[kk] - m_u_lin[kk]);
      const Vertices x = m_x_lin[kk] + m_lin[kk]->position_tangent(ds);
      energy += lc * m_problem.visibility(k, x, grad ? &gx[kk] : nullptr);
    }
    if (!grad) return energy;
    Eigen::VectorXd gs = Eigen::VectorXd::Zero(sim.state_dim());
    for (int k = frames - 1; k >= 0; --k) {
      const auto kk = static_cast<size_t>(k);
      gs += m_lin[kk]->position_cotangent(gx[kk]);
      StepVjp vjp = m_lin[kk]->vjp(gs);
      gu[kk] += lc * vjp.control;
      gs = std::move(vjp.state);
    }
    const int nv = m_problem.variables_per_frame();
    for (int k = 0; k < frames; ++k)
      for (int i = 0; i < nv; ++i)
        grad[k * nv + i] = m_problem.chain(gu[static_cast<size_t>(k)], i);
    m_problem.add_gradient(ms_since(t0));
    return energy;
  }

 private:
  WindowProblem& m_problem;
  std::vector<Eigen::VectorXd> m_u_lin;
  std::vector<Vertices> m_x_lin;
  std::vector<std::unique_ptr<StepLinearization>> m_lin;
};

// A one-frame window whose positions after the step are X + sum_i (z_i - z_lin_i) J_i: X those
// of the true evaluation at z_lin, J_i the response to variable i estimated by (compressed)
// central differences at z_lin (WindowProblem::response(), the probes of one gradient); the
// force terms are exact. Evaluations and gradients are products with the responses.
class DifferenceModel final : public SearchModel {
 public:
  // `problem`'s latest evaluate() must be the one at z_lin.
  DifferenceModel(WindowProblem& problem, const Eigen::VectorXd& z_lin, bool parallel)
      : m_problem(problem), m_z_lin(z_lin), m_x_lin(problem.last_positions().front()) {
    const auto t0 = Clock::now();
    m_response = problem.response(problem.expand(z_lin.data()).front(), parallel);
    problem.add_gradient(ms_since(t0));
  }

  double evaluate(const double* z, double* grad) override {
    const std::vector<Eigen::VectorXd> u = m_problem.expand(z);
    std::vector<Eigen::VectorXd> gu;
    double energy = m_problem.force_terms(u, grad ? &gu : nullptr, nullptr, nullptr);
    const int n = m_problem.variables_per_frame();
    Vertices x = m_x_lin;
    for (int i = 0; i < n; ++i)
      if (const double dz = z[i] - m_z_lin[i]; dz != 0.0)
        m_problem.add_response(x, m_response, i, dz);
    const double lc = m_problem.options().weights.visibility;
    Vertices gx;
    energy += lc * m_problem.visibility(0, x, grad ? &gx : nullptr);
    if (!grad) return energy;
    for (int i = 0; i < n; ++i)
      grad[i] = m_problem.chain(gu[0], i) + lc * m_problem.response_dot(m_response, i, gx);
    return energy;
  }

 private:
  WindowProblem& m_problem;
  Eigen::VectorXd m_z_lin;
  Vertices m_x_lin;
  std::vector<Vertices> m_response;
};

int window_frames(const ControlOptions& options, std::span<const ControlFrameInput> window) {
  if (window.empty()) throw std::invalid_argument("ControlOptimizer: empty window");
  return std::min<int>(std::max(options.window, 1), static_cast<int>(window.size()));
}

// Blocks moving free vertices (anchored vertices and vertices without a block excluded).
std::vector<char> free_blocks(const Simulator& sim, const ControlLayout& layout) {
  std::vector<char> is_free(static_cast<size_t>(layout.num_blocks), 0);
  std::vector<char> anchored(static_cast<size_t>(sim.num_vertices()), 0);
  for (int a : sim.anchors()) anchored[static_cast<size_t>(a)] = 1;
  for (size_t v = 0; v < layout.vertex_block.size(); ++v)
    if (layout.vertex_block[v] >= 0 && !anchored[v])
      is_free[static_cast<size_t>(layout.vertex_block[v])] = 1;
  return is_free;
}

double free_force_sum(const Simulator& sim, const Eigen::VectorXd& magnitudes) {
  std::vector<char> anchored(static_cast<size_t>(sim.num_vertices()), 0);
  for (int a : sim.anchors()) anchored[static_cast<size_t>(a)] = 1;
  double sum = 0.0;
  for (Eigen::Index v = 0; v < magnitudes.size(); ++v)
    if (!anchored[static_cast<size_t>(v)]) sum += magnitudes[v];
  return sum;
}

double control_force_sum(const Eigen::VectorXd& u, int bs) {
  double sum = 0.0;
  for (Eigen::Index b = 0; b * bs < u.size(); ++b) sum += u.segment(b * bs, 3).norm();
  return sum;
}

}  // namespace

GradientMode resolve_gradient(const Simulator& sim, GradientMode mode) {
  switch (mode) {
    case GradientMode::central:
    case GradientMode::compressed:
      return mode;
    case GradientMode::adjoint:
      if (!sim.has_derivatives())
        throw std::invalid_argument("gradient: adjoint requested but " + sim.name() +
                                    " offers no derivatives");
      return mode;
    case GradientMode::automatic:
      return sim.has_derivatives() ? GradientMode::adjoint : GradientMode::compressed;
  }
  return GradientMode::central;
}

ControlOptimizer::ControlOptimizer(Triangles triangles, std::vector<std::uint8_t> interior,
                                   ControlOptions options)
    : m_triangles(std::move(triangles)), m_interior(std::move(interior)) {
  if (!m_interior.empty() && m_interior.size() != static_cast<size_t>(m_triangles.rows()))
    throw std::invalid_argument("ControlOptimizer: interior has " +
                                std::to_string(m_interior.size()) + " entries, expected " +
                                std::to_string(m_triangles.rows()));
  set_options(options);
  const int nv = m_triangles.size() > 0 ? m_triangles.maxCoeff() + 1 : 0;
  m_adjacency = vertex_adjacency(m_triangles, nv);
}

void ControlOptimizer::set_options(const ControlOptions& options) {
  options.validate();
  m_options = options;
}

std::vector<int> ControlOptimizer::active_blocks(Simulator& sim,
                                                 std::span<const ControlFrameInput> window) {
  return select_blocks(sim, window, nullptr, nullptr, nullptr);
}

std::vector<int> ControlOptimizer::select_blocks(Simulator& sim,
                                                 std::span<const ControlFrameInput> window,
                                                 std::vector<Vertices>* predicted, SimState* first,
                                                 Eigen::VectorXd* first_physical) {
  const int frames = window_frames(m_options, window);
  const ControlLayout layout = sim.control_layout();
  const std::vector<char> is_free = free_blocks(sim, layout);
  std::vector<int> out;
  if (m_options.active_set == ActiveSet::all) {
    for (int b = 0; b < layout.num_blocks; ++b)
      if (is_free[static_cast<size_t>(b)]) out.push_back(b);
    return out;
  }
  WindowProblem problem(sim, window, frames, m_triangles, m_interior, m_options, m_previous,
                        m_reference);
  const int nvtx = sim.num_vertices();
  std::vector<char> seed(static_cast<size_t>(nvtx), 0);
  auto mark = [&](int k, const Vertices& x) {
    const Eigen::VectorXd s = problem.facing(k, x);
    for (Eigen::Index j = 0; j < m_triangles.rows(); ++j)
      if (problem.penalized(k)[static_cast<size_t>(j)] && s[j] < m_options.active_band)
        for (int c = 0; c < 3; ++c) seed[static_cast<size_t>(m_triangles(j, c))] = 1;
    // Hidden vertices within 1.5 occlusion margins of the plane of the triangle hiding them.
    for (const OcclusionPair& pr : problem.occlusion(k))
      if (occlusion_depth(x, m_triangles, pr, nullptr) < 1.5 * m_options.occlusion_margin) {
        seed[static_cast<size_t>(pr.vertex)] = 1;
        for (int c = 0; c < 3; ++c) seed[static_cast<size_t>(m_triangles(pr.triangle, c))] = 1;
      }
  };
  mark(0, sim.positions());
  // Predicted uncontrolled steps of the window.
  const SimState s0 = problem.state0();
  for (int k = 0; k < frames; ++k) {
    // An explicit zero control: the same input as an evaluation at zero control.
    sim.step(problem.input(k, Eigen::VectorXd::Zero(problem.size())));
    const Vertices x = sim.positions();
    mark(k, x);
    if (predicted) predicted->push_back(x);
    if (k == 0 && first) *first = sim.save();
    if (k == 0 && first_physical) *first_physical = checked_force_magnitudes(sim);
  }
  sim.restore(s0);
  // k-ring growth.
  std::vector<char> in = seed;
  for (int r = 0; r < m_options.active_rings; ++r) {
    std::vector<char> next = in;
    for (int v = 0; v < nvtx; ++v)
      if (in[static_cast<size_t>(v)] && static_cast<size_t>(v) < m_adjacency.size())
        for (int w : m_adjacency[static_cast<size_t>(v)]) next[static_cast<size_t>(w)] = 1;
    if (next == in) break;  // the rings stopped growing: more of them add nothing
    in.swap(next);
  }
  std::vector<char> chosen(static_cast<size_t>(layout.num_blocks), 0);
  for (int v = 0; v < nvtx && static_cast<size_t>(v) < layout.vertex_block.size(); ++v)
    if (in[static_cast<size_t>(v)] && layout.vertex_block[static_cast<size_t>(v)] >= 0)
      chosen[static_cast<size_t>(layout.vertex_block[static_cast<size_t>(v)])] = 1;
  // Blocks that carried a force in the previous frame may relax it smoothly.
  const int bs = layout.block_size();
  if (m_previous.size() == layout.size() && m_options.weights.temporal > 0.0)
    for (int b = 0; b < layout.num_blocks; ++b)
      if (m_previous.segment(b * bs, bs).squaredNorm() > 0.0) chosen[static_cast<size_t>(b)] = 1;
  for (int b = 0; b < layout.num_blocks; ++b)
    if (chosen[static_cast<size_t>(b)] && is_free[static_cast<size_t>(b)]) out.push_back(b);
  return out;
}

namespace {

/// Groups the active vertex-force blocks into at most `clusters` spatial clusters: farthest-point
/// seeds on the blocks' current positions, then two Lloyd iterations; empty clusters are
/// dropped (`used` receives the count). Deterministic: ties go to the lowest index.
std::vector<int> cluster_blocks(const Simulator& sim, const std::vector<int>& active, int clusters,
                                int* used) {
  const ControlLayout layout = sim.control_layout();
  const Vertices x = sim.positions();
  Vertices block_pos = Vertices::Zero(layout.num_blocks, 3);
  Eigen::VectorXd count = Eigen::VectorXd::Zero(layout.num_blocks);
  for (size_t v = 0; v < layout.vertex_block.size(); ++v)
    if (const int b = layout.vertex_block[v]; b >= 0) {
      block_pos.row(b) += x.row(static_cast<Eigen::Index>(v));
      count[b] += 1.0;
    }
  const auto na = static_cast<Eigen::Index>(active.size());
  Vertices p(na, 3);
  for (Eigen::Index a = 0; a < na; ++a) {
    const int b = active[static_cast<size_t>(a)];
    p.row(a) = block_pos.row(b) / std::max(1.0, count[b]);
  }
  // Farthest-point seeds.
  Vertices centre(clusters, 3);
  centre.row(0) = p.row(0);
  Eigen::VectorXd dist = (p.rowwise() - centre.row(0)).rowwise().squaredNorm();
  for (int c = 1; c < clusters; ++c) {
    Eigen::Index far = 0;
    dist.maxCoeff(&far);
    centre.row(c) = p.row(far);
    dist = dist.cwiseMin((p.rowwise() - centre.row(c)).rowwise().squaredNorm());
  }
  std::vector<int> cluster(active.size(), 0);
  for (int iter = 0; iter < 3; ++iter) {
    for (Eigen::Index a = 0; a < na; ++a) {
      Eigen::Index best = 0;
      (centre.rowwise() - p.row(a)).rowwise().squaredNorm().minCoeff(&best);
      cluster[static_cast<size_t>(a)] = static_cast<int>(best);
    }
    if (iter == 2) break;
    Vertices sum = Vertices::Zero(clusters, 3);
    Eigen::VectorXd n = Eigen::VectorXd::Zero(clusters);
    for (Eigen::Index a = 0; a < na; ++a) {
      sum.row(cluster[static_cast<size_t>(a)]) += p.row(a);
      n[cluster[static_cast<size_t>(a)]] += 1.0;
    }
    for (int c = 0; c < clusters; ++c)
      if (n[c] > 0.0) centre.row(c) = sum.row(c) / n[c];
  }
  // Renumber without empty clusters.
  std::vector<int> id(static_cast<size_t>(clusters), -1);
  int next = 0;
  for (int& c : cluster) {
    if (id[static_cast<size_t>(c)] < 0) id[static_cast<size_t>(c)] = next++;
    c = id[static_cast<size_t>(c)];
  }
  *used = next;
  return cluster;
}

}  // namespace

ControlEnergyEval ControlOptimizer::evaluate(Simulator& sim,
                                             std::span<const ControlFrameInput> window,
                                             const Eigen::VectorXd& u, GradientMode mode,
                                             const std::vector<int>& active) {
  const int frames = window_frames(m_options, window);
  const GradientMode resolved = resolve_gradient(sim, mode);
  WindowProblem problem(sim, window, frames, m_triangles, m_interior, m_options, m_previous,
                        m_reference);
  const int size = problem.size();
  if (u.size() != 0 && u.size() != frames * size)
    throw std::invalid_argument("evaluate: u has " + std::to_string(u.size()) +
                                " entries, expected " + std::to_string(frames * size));
  const Eigen::VectorXd uu = u.size() ? u : Eigen::VectorXd::Zero(frames * size);
  std::vector<int> blocks = active;
  for (const int b : blocks)
    if (b < 0 || b >= problem.layout().num_blocks)
      throw std::invalid_argument("evaluate: active block " + std::to_string(b) + " outside [0, " +
                                  std::to_string(problem.layout().num_blocks) + ")");
  if (blocks.empty()) {
    const std::vector<char> is_free = free_blocks(sim, problem.layout());
    for (int b = 0; b < problem.layout().num_blocks; ++b)
      if (is_free[static_cast<size_t>(b)]) blocks.push_back(b);
  }
  problem.set_active(blocks);
  problem.set_probe_groups(m_adjacency,
                           resolved == GradientMode::compressed ? m_options.difference_rings : -1);
  problem.set_fixed(uu);
  const Eigen::VectorXd z = problem.to_z(uu);
  Eigen::VectorXd gz(z.size());
  const auto ev = problem.evaluate(z.data(), gz.data(), resolved, m_options.parallel);
  sim.restore(problem.state0());

  ControlEnergyEval out;
  out.energy = ev.energy;
  out.visibility_energy = ev.ec;
  out.force_energy = ev.ef;
  out.temporal_energy = ev.et;
  out.probes = problem.probes();
  out.gradient = Eigen::VectorXd::Zero(frames * size);
  const int nv = problem.variables_per_frame();
  for (int k = 0; k < frames; ++k)
    for (int i = 0; i < nv; ++i) {
      const auto& e = problem.column(i).front();  // one component per variable here
      out.gradient[k * size + e.component] = gz[k * nv + i] / e.coef;
    }
  return out;
}

ControlFrameResult ControlOptimizer::step_uncontrolled(Simulator& sim,
                                                       const ControlFrameInput& frame) {
  const auto t0 = Clock::now();
  check_simulator(sim);
  capture_reference(sim);
  const ControlLayout layout = sim.control_layout();
  ControlFrameResult r;
  r.solver = m_options.solver;
  r.control = Eigen::VectorXd::Zero(layout.size());
  std::span<const ControlFrameInput> one(&frame, 1);
  ControlOptions single = m_options;
  single.window = 1;
  WindowProblem problem(sim, one, 1, m_triangles, m_interior, single, m_previous, m_reference);
  sim.step(problem.input(0, Eigen::VectorXd()));
  r.visibility_energy = problem.visibility(0, sim.positions(), nullptr);
  std::vector<Eigen::VectorXd> u{r.control};
  problem.force_terms(u, nullptr, &r.force_energy, &r.temporal_energy);
  r.energy = m_options.weights.visibility * r.visibility_energy +
             m_options.weights.force * r.force_energy +
             m_options.weights.temporal * r.temporal_energy;
  r.initial_energy = r.final_energy = r.energy;
  r.physical_force = free_force_sum(sim, checked_force_magnitudes(sim));
  m_previous = r.control;
  r.total_ms = ms_since(t0);
  return r;
}

void ControlOptimizer::capture_reference(const Simulator& sim) {
  if (m_reference.rows() != sim.num_vertices()) m_reference = sim.positions();
}

ControlFrameResult ControlOptimizer::step(Simulator& sim, std::span<const ControlFrameInput> window,
                                          const ControlCallbacks& callbacks) {
  const auto t_start = Clock::now();
  check_simulator(sim);
  capture_reference(sim);
  const int frames = window_frames(m_options, window);
  const GradientMode mode = resolve_gradient(sim, m_options.gradient);
  const bool adjoint = mode == GradientMode::adjoint;
  const bool hard = m_options.constraint == ConstraintMode::hard;
  if (hard && m_options.solver == ControlSolver::lbfgs)
    throw std::invalid_argument("the hard-constraint mode needs slsqp, mma, cobyla or ipopt");

  ControlFrameResult r;
  r.solver = m_options.solver;
  r.adjoint = adjoint && !hard;
  // The linearized search: on the step linearizations, or with differences on the responses
  // of a one-frame window.
  bool linear = m_options.linearized && !hard && (adjoint ? sim.has_linearization() : frames == 1);

  std::vector<Vertices> predicted;  // uncontrolled window, when the active-set rule simulated it
  WindowProblem::Snapshot predicted_first;
  const std::vector<int> active =
      select_blocks(sim, window, &predicted, &predicted_first.state, &predicted_first.physical);
  predicted_first.valid = static_cast<int>(predicted.size()) == frames;
  WindowProblem problem(sim, window, frames, m_triangles, m_interior, m_options, m_previous,
                        m_reference);
  const int size = problem.size();
  const int bs = problem.layout().block_size();
  const int clusters = m_options.clusters;
  if (clusters > 0 && bs == 3 && static_cast<int>(active.size()) > clusters) {
    int used = 0;
    const std::vector<int> cluster = cluster_blocks(sim, active, clusters, &used);
    problem.set_clusters(active, cluster, used);
  } else {
    problem.set_active(active);
  }
  problem.set_probe_groups(m_adjacency,
                           mode == GradientMode::compressed ? m_options.difference_rings : -1);
  // Responses that would not fit in memory (plain central differences of thousands of vertex
  // forces on a large mesh: #variables x #V x 3 numbers): every evaluation simulates instead.
  constexpr double kMaxResponseNumbers = 1.25e8;  // 1 GB
  if (linear && !adjoint && problem.response_numbers() > kMaxResponseNumbers) linear = false;
  r.linearized = linear;
  if (predicted_first.valid) problem.set_zero_step(predicted.front(), predicted_first);
  r.active_blocks = static_cast<int>(active.size());
  const int n = problem.num_variables();
  r.variables = n;

  // Initial guess.
  Eigen::VectorXd u0 = Eigen::VectorXd::Zero(frames * size);
  if (m_options.initial_guess == InitialGuess::previous && m_previous.size() == size)
    for (int k = 0; k < frames; ++k) u0.segment(k * size, size) = m_previous;
  Eigen::VectorXd z0 = problem.to_z(u0);

  Eigen::VectorXd z_best = z0;
  // The simulator after the first frame's step with z_best, when an evaluation made it.
  WindowProblem::Snapshot best_snapshot;
  if (n > 0) {
    if (hard) {
      // At-risk must-stay-hidden triangles of the predicted uncontrolled window.
      std::vector<std::pair<int, int>> list;
      const std::vector<Eigen::VectorXd> uz = problem.expand(z0.data());
      sim.restore(problem.state0());
      for (int k = 0; k < frames; ++k) {
        sim.step(problem.input(k, uz[static_cast<size_t>(k)]));
        const Eigen::VectorXd s = problem.facing(k, sim.positions());
        for (Eigen::Index j = 0; j < s.size(); ++j)
          if (problem.penalized(k)[static_cast<size_t>(j)] && s[j] < m_options.active_band)
            list.emplace_back(k, static_cast<int>(j));
      }
      problem.set_constraints(std::move(list));
    }
    const bool par = m_options.parallel;
    double best = std::numeric_limits<double>::infinity();
    int evaluations = 0;
    detail::SolverProblem sp;
    sp.n = n;
    sp.m = problem.num_constraints();
    sp.objective = [&](const double* z, double* grad) {
      double e;
      if (hard) {
        // Objective lF EF + lT ET only (analytic).
        const std::vector<Eigen::VectorXd> u = problem.expand(z);
        std::vector<Eigen::VectorXd> gu;
        e = problem.force_terms(u, grad ? &gu : nullptr, nullptr, nullptr);
        if (grad) {
          const int nv = problem.variables_per_frame();
          for (int k = 0; k < frames; ++k)
            for (int i = 0; i < nv; ++i)
              grad[k * nv + i] = problem.chain(gu[static_cast<size_t>(k)], i);
        }
      } else {
        e = problem.evaluate(z, grad, mode, par).energy;
      }
      ++evaluations;
      if (!hard && e < best) {
        best = e;
        z_best = Eigen::Map<const Eigen::VectorXd>(z, n);
        best_snapshot = problem.last_snapshot();
      }
      if (callbacks.progress) callbacks.progress({evaluations, e, best});
      return e;
    };
    sp.constraints = [&](const double* z, double* c, double* jac) {
      problem.constraints(z, c, jac, par);
    };
    if (callbacks.cancel) sp.cancelled = callbacks.cancel;
    sp.lb = Eigen::VectorXd::Constant(n, -std::numeric_limits<double>::infinity());
    sp.ub = Eigen::VectorXd::Constant(n, std::numeric_limits<double>::infinity());
    if (m_options.force_bound > 0.0) {
      sp.lb.setConstant(-m_options.force_bound);
      sp.ub.setConstant(m_options.force_bound);
      z0 = z0.cwiseMax(sp.lb).cwiseMin(sp.ub);
    }
    // Energy at the initial guess; at zero control the active-set rule has just simulated
    // that window (same state and inputs, so the same positions bit for bit).
    WindowProblem::Eval initial;
    if (u0.isZero(0.0) && predicted_first.valid && !linear) {
      initial.energy =
          problem.force_terms(problem.expand(z0.data()), nullptr, &initial.ef, &initial.et);
      for (int k = 0; k < frames; ++k)
        initial.ec += problem.visibility(k, predicted[static_cast<size_t>(k)], nullptr);
      initial.energy += m_options.weights.visibility * initial.ec;
      best_snapshot = predicted_first;
    } else {
      initial = problem.evaluate(z0.data(), nullptr, mode, par);
      best_snapshot = problem.last_snapshot();
    }
    r.initial_energy = initial.energy;
    if (!hard) {
      best = r.initial_energy;
      z_best = z0;
    }
    // Nothing at risk: with zero control every must-stay-hidden triangle stays beyond the
    // margin (EC = 0 there, and so is its gradient), and when lF >= lT the force terms
    // lF rho(u) + lT rho(u - f~) are smallest at u = 0 up to the smoothing (rho is 1-Lipschitz,
    // so E(u) - E(0) >= (lF - lT)|u| - lF eps_b per block): zero control is optimal and the
    // solver is not run.
    const bool nothing_at_risk = !hard && initial.ec == 0.0 && z0.isZero(0.0) &&
                                 m_options.weights.force >= m_options.weights.temporal;
    if (nothing_at_risk) {
      r.message = "no triangle at risk with zero control";
      r.evaluations = 1;
      r.final_energy = r.initial_energy;
    } else if (linear) {
      // Outer iterations: linearize the window's dynamics at the current point, let the solver
      // minimize the energy of that model (cheap: products with the linearization), check the
      // candidate with a true simulation and keep it when it lowers the true energy; else try
      // half and a quarter of the move, then stop.
      const auto t_solve = Clock::now();
      Eigen::VectorXd z_cur = z0;
      double e_cur = r.initial_energy;
      int model_evaluations = 0, linearizations = 0;
      // The model is a local approximation, checked by a true step: its minimum is not worth
      // finding to more than model_ftol_rel.
      ControlOptions inner = m_options;
      inner.ftol_rel = std::max(m_options.ftol_rel, m_options.model_ftol_rel);
      detail::SolverOutcome out;
      bool stop = false;
      for (int outer = 0; outer < m_options.max_linearizations && !stop; ++outer) {
        if (callbacks.cancel && callbacks.cancel()) {
          out.status = ControlStatus::cancelled;
          break;
        }
        // The latest evaluate() is the one at z_cur.
        std::unique_ptr<SearchModel> model;
        if (adjoint)
          model = std::make_unique<LinearModel>(problem, z_cur);
        else
          model = std::make_unique<DifferenceModel>(problem, z_cur, par);
        ++linearizations;
        double model_best = std::numeric_limits<double>::infinity();
        Eigen::VectorXd z_model = z_cur;
        detail::SolverProblem mp = sp;
        mp.objective = [&](const double* z, double* grad) {
          const double e = model->evaluate(z, grad);
          ++model_evaluations;
          if (e < model_best) {
            model_best = e;
            z_model = Eigen::Map<const Eigen::VectorXd>(z, n);
          }
          return e;
        };
        out = m_options.solver == ControlSolver::ipopt ? detail::solve_ipopt(mp, z_cur, inner)
                                                       : detail::solve_nlopt(mp, z_cur, inner);
        if (out.status == ControlStatus::cancelled || !(model_best < e_cur)) break;
        bool accepted = false;
        for (double t : {1.0, 0.5, 0.25}) {
          const Eigen::VectorXd z_try = z_cur + t * (z_model - z_cur);
          const double e = problem.evaluate(z_try.data(), nullptr, mode, par).energy;
          ++evaluations;
          if (callbacks.progress) callbacks.progress({evaluations, e, std::min(e, e_cur)});
          if (e < e_cur) {
            stop = e_cur - e <= m_options.ftol_rel * std::abs(e_cur) ||
                   e_cur - e < m_options.linearized_ftol_initial * std::abs(r.initial_energy);
            z_cur = z_try;
            e_cur = e;
            best_snapshot = problem.last_snapshot();
            accepted = true;
            break;
          }
        }
        if (!accepted) stop = true;
      }
      z_best = z_cur;
      r.solve_ms = ms_since(t_solve);
      r.status = out.status;
      r.message = out.message;
      r.iterations = model_evaluations;
      r.model_evaluations = model_evaluations;
      r.linearizations = linearizations;
      r.evaluations = evaluations;
      r.gradient_evaluations = problem.gradients();
      r.gradient_ms = problem.gradient_ms();
      r.probes = problem.probes();
      if (frames > 1) r.final_energy = problem.evaluate(z_best.data(), nullptr, mode, par).energy;
    } else {
      const auto t_solve = Clock::now();
      const detail::SolverOutcome out = m_options.solver == ControlSolver::ipopt
                                            ? detail::solve_ipopt(sp, z0, m_options)
                                            : detail::solve_nlopt(sp, z0, m_options);
      r.solve_ms = ms_since(t_solve);
      r.status = out.status;
      r.message = out.message;
      r.iterations = out.iterations;
      r.evaluations = evaluations;
      r.gradient_evaluations = problem.gradients();
      r.gradient_ms = problem.gradient_ms();
      r.probes = problem.probes();
      if (hard && out.z.size() == n) {
        z_best = out.z;
        best_snapshot.valid = false;  // the solver's point, not necessarily an evaluated one
      }
      // With one frame the committed step below gives the window energy at the solution.
      if (frames > 1) r.final_energy = problem.evaluate(z_best.data(), nullptr, mode, par).energy;
    }
  } else {
    r.message = "no control block at risk";
    r.initial_energy = r.final_energy = problem.evaluate(z0.data(), nullptr, mode, false).energy;
    best_snapshot = problem.last_snapshot();
  }

  // Commit the first frame: restore the state its evaluation reached, or step.
  const std::vector<Eigen::VectorXd> u = problem.expand(z_best.data());
  Eigen::VectorXd physical;
  if (best_snapshot.valid) {
    sim.restore(best_snapshot.state);
    physical = std::move(best_snapshot.physical);
  } else {
    sim.restore(problem.state0());
    sim.step(problem.input(0, u[0]));
    physical = checked_force_magnitudes(sim);
  }
  r.control = u[0];
  r.visibility_energy = problem.visibility(0, sim.positions(), nullptr);
  std::vector<Eigen::VectorXd> first{u[0]};
  problem.force_terms(first, nullptr, &r.force_energy, &r.temporal_energy);
  r.energy = m_options.weights.visibility * r.visibility_energy +
             m_options.weights.force * r.force_energy +
             m_options.weights.temporal * r.temporal_energy;
  if (frames == 1 && n > 0) r.final_energy = r.energy;
  r.control_force = control_force_sum(r.control, bs);
  r.physical_force = free_force_sum(sim, physical);
  m_previous = r.control;
  r.total_ms = ms_since(t_start);
  return r;
}

}  // namespace pbve
