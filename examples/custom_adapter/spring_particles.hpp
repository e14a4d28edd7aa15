// A complete pbve engine adapter written from scratch: particles joined by damped springs
// along the mesh edges, integrated with symplectic Euler substeps. It implements every required
// member of pbve::Simulator (no derivatives: the optimizer then uses central differences).
// docs/writing-an-adapter.md walks through it.
#pragma once

#include <algorithm>
#include <cmath>
#include <memory>
#include <set>
#include <stdexcept>
#include <string>
#include <vector>

#include "pbve/sim/simulator.hpp"

namespace example {

/// The parameters of SpringParticles.
struct SpringParams {
  double stiffness = 200.0;  ///< N/m per spring
  double mass = 0.002;       ///< kg per particle
  double damping = 2.0;      ///< 1/s, mass-proportional
  /// Substeps per step() at least; more when a step needs them for stability (see step()).
  int substeps = 40;
  Eigen::Vector3d gravity{0.0, 9.81, 0.0};  ///< m/s^2, camera frame
};

class SpringParticles final : public pbve::Simulator {
 public:
  using Params = SpringParams;

  /// mesh: topology; rest: #V by 3 start positions (camera frame, metres); anchors: vertex ids.
  SpringParticles(const pbve::Mesh& mesh, const pbve::Vertices& rest, std::vector<int> anchors,
                  const Params& params = {})
      : m_x(rest),
        m_v(pbve::Vertices::Zero(rest.rows(), 3)),
        m_f(m_v),
        m_magnitude(Eigen::VectorXd::Zero(rest.rows())),
        m_anchors(std::move(anchors)),
        m_p(params) {
    if (!(m_p.stiffness >= 0 && m_p.mass > 0 && m_p.damping >= 0 && m_p.substeps >= 1))
      throw std::invalid_argument("stiffness and damping must be >= 0, mass > 0, substeps >= 1");
    std::set<std::pair<int, int>> edges;
    for (Eigen::Index t = 0; t < mesh.triangles.rows(); ++t)
      for (int e = 0; e < 3; ++e) {
        const int a = mesh.triangles(t, e), b = mesh.triangles(t, (e + 1) % 3);
        edges.insert({std::min(a, b), std::max(a, b)});
      }
    std::vector<int> degree(static_cast<size_t>(rest.rows()), 0);
    for (const auto& [a, b] : edges) {
      m_springs.push_back({a, b, (rest.row(a) - rest.row(b)).norm()});
      ++degree[static_cast<size_t>(a)];
      ++degree[static_cast<size_t>(b)];
    }
    // Symplectic Euler is stable for h < 2 / omega_max; omega_max^2 <= 2 k deg_max / m (the
    // largest eigenvalue of the spring graph's Laplacian is at most twice its largest degree).
    const int deg = degree.empty() ? 0 : *std::max_element(degree.begin(), degree.end());
    const double omega2 = 2.0 * m_p.stiffness * deg / m_p.mass;
    m_max_substep = omega2 > 0 ? 0.9 * 2.0 / std::sqrt(omega2) : 1e9;
    std::sort(m_anchors.begin(), m_anchors.end());
    m_anchored.assign(static_cast<size_t>(rest.rows()), 0);
    for (int a : m_anchors) {
      if (a < 0 || a >= rest.rows()) throw std::invalid_argument("anchor index out of range");
      m_anchored[static_cast<size_t>(a)] = 1;
    }
  }

  std::string name() const override { return "spring_particles"; }
  int num_vertices() const override { return static_cast<int>(m_x.rows()); }
  pbve::Vertices positions() const override { return m_x; }
  pbve::Vertices velocities() const override { return m_v; }
  std::vector<int> anchors() const override { return m_anchors; }
  pbve::Vertices physical_forces() const override { return m_f; }
  // The scale pbve compares control forces with: per particle, the norms of gravity, of each
  // spring force and of damping, summed (the net force vanishes where they balance).
  Eigen::VectorXd physical_force_magnitudes() const override { return m_magnitude; }

  pbve::ControlLayout control_layout() const override {
    pbve::ControlLayout layout;  // one 3-D force per vertex
    layout.num_blocks = num_vertices();
    layout.block_mass = Eigen::VectorXd::Constant(num_vertices(), m_p.mass);
    for (int i = 0; i < num_vertices(); ++i) layout.vertex_block.push_back(i);
    return layout;
  }

  void step(const pbve::StepInput& in) override {
    const Eigen::Index n = m_x.rows();
    if (!(in.dt > 0)) throw std::invalid_argument("dt must be positive");
    if (in.control.size() != 0 && in.control.size() != 3 * n)
      throw std::invalid_argument("control must have 3 * num_vertices() entries");
    if (in.anchor_targets.rows() != 0 &&
        in.anchor_targets.rows() != static_cast<Eigen::Index>(m_anchors.size()))
      throw std::invalid_argument("anchor_targets must have one row per anchor");
    // The substeps asked for, or as many more as stability needs (any dt is legal).
    const int substeps = std::max(m_p.substeps, static_cast<int>(std::ceil(in.dt / m_max_substep)));
    const double h = in.dt / substeps;
    pbve::Vertices start(static_cast<Eigen::Index>(m_anchors.size()), 3);
    for (size_t i = 0; i < m_anchors.size(); ++i)
      start.row(static_cast<Eigen::Index>(i)) = m_x.row(m_anchors[i]);
    m_f.setZero();
    m_magnitude.setZero();
    for (int s = 1; s <= substeps; ++s) {
      pbve::Vertices force = pbve::Vertices::Zero(n, 3);
      Eigen::VectorXd magnitude = Eigen::VectorXd::Zero(n);
      for (const Spring& sp : m_springs) {  // Hooke's law along each edge
        const Eigen::RowVector3d d = m_x.row(sp.b) - m_x.row(sp.a);
        const double len = d.norm();
        if (len <= 0) continue;
        const Eigen::RowVector3d f = m_p.stiffness * (len - sp.rest) * d / len;
        force.row(sp.a) += f;
        force.row(sp.b) -= f;
        magnitude[sp.a] += f.norm();
        magnitude[sp.b] += f.norm();
      }
      for (Eigen::Index i = 0; i < n; ++i) {
        if (m_anchored[static_cast<size_t>(i)]) continue;
        const Eigen::RowVector3d weight = m_p.mass * m_p.gravity.transpose();
        const Eigen::RowVector3d drag = -m_p.damping * m_p.mass * m_v.row(i);
        force.row(i) += weight + drag;
        // Averages over the step: the physical force and the sum of its terms' norms.
        m_f.row(i) += force.row(i) / substeps;
        m_magnitude[i] += (magnitude[i] + weight.norm() + drag.norm()) / substeps;
        Eigen::RowVector3d total = force.row(i);
        if (in.control.size()) total += in.control.segment<3>(3 * i).transpose();
        m_v.row(i) += h * total / m_p.mass;  // symplectic Euler: velocity first,
        m_x.row(i) += h * m_v.row(i);        // then position with the new velocity
      }
      for (size_t k = 0; k < m_anchors.size(); ++k) {  // anchors follow their targets
        const auto r = static_cast<Eigen::Index>(k);
        if (in.anchor_targets.rows() == 0) {
          m_v.row(m_anchors[k]).setZero();
          continue;
        }
        const double w = static_cast<double>(s) / substeps;
        const Eigen::RowVector3d target =
            s == substeps
                ? Eigen::RowVector3d(in.anchor_targets.row(r))
                : Eigen::RowVector3d((1 - w) * start.row(r) + w * in.anchor_targets.row(r));
        m_v.row(m_anchors[k]) = (target - m_x.row(m_anchors[k])) / h;
        m_x.row(m_anchors[k]) = target;
      }
    }
  }

  pbve::SimState save() const override {  // positions and velocities are the whole state
    pbve::SimState s;
    s.values.assign(m_x.data(), m_x.data() + m_x.size());
    s.values.insert(s.values.end(), m_v.data(), m_v.data() + m_v.size());
    return s;
  }
  void restore(const pbve::SimState& s) override {
    if (s.values.size() != static_cast<size_t>(2 * m_x.size()))
      throw std::invalid_argument("state of another simulator");
    std::copy_n(s.values.begin(), m_x.size(), m_x.data());
    std::copy_n(s.values.begin() + m_x.size(), m_v.size(), m_v.data());
  }
  std::unique_ptr<pbve::Simulator> clone() const override {
    return std::make_unique<SpringParticles>(*this);
  }

 private:
  struct Spring {
    int a, b;
    double rest;
  };
  pbve::Vertices m_x, m_v, m_f;
  Eigen::VectorXd m_magnitude;
  std::vector<int> m_anchors;
  std::vector<char> m_anchored;
  std::vector<Spring> m_springs;
  Params m_p;
  double m_max_substep = 0;  // s: the stability limit of a substep, with a 10% margin
};

}  // namespace example
