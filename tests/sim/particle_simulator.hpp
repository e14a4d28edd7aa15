#pragma once
// A tiny reference adapter for the conformance suite: free particles (one per surface vertex)
// under gravity, symplectic Euler with substeps, anchors, and exact derivatives.

#include <stdexcept>
#include <string>
#include <vector>

#include "pbve/sim/simulator.hpp"

namespace pbve::test {

class ParticleSimulator : public Simulator {
 public:
  ParticleSimulator(const Vertices& positions, std::vector<int> anchors, double mass = 0.01,
                    int substeps = 4)
      : m_x(positions),
        m_v(Vertices::Zero(positions.rows(), 3)),
        m_f(Vertices::Zero(positions.rows(), 3)),
        m_anchors(std::move(anchors)),
        m_mass(mass),
        m_substeps(substeps) {
    m_anchored.assign(static_cast<size_t>(positions.rows()), 0);
    for (int a : m_anchors) {
      if (a < 0 || a >= positions.rows()) throw std::invalid_argument("anchor out of range");
      m_anchored[static_cast<size_t>(a)] = 1;
    }
  }

  std::string name() const override { return "particles"; }
  int num_vertices() const override { return static_cast<int>(m_x.rows()); }
  Vertices positions() const override { return m_x; }
  Vertices velocities() const override { return m_v; }
  ControlLayout control_layout() const override {
    ControlLayout l;
    l.space = ControlSpace::vertex_force;
    l.num_blocks = num_vertices();
    l.block_mass = Eigen::VectorXd::Constant(num_vertices(), m_mass);
    l.vertex_block.resize(static_cast<size_t>(num_vertices()));
    for (int i = 0; i < num_vertices(); ++i) l.vertex_block[static_cast<size_t>(i)] = i;
    return l;
  }
  std::vector<int> anchors() const override { return m_anchors; }
  Vertices physical_forces() const override { return m_f; }

  void step(const StepInput& in) override {
    check(in);
    const double h = in.dt / m_substeps;
    const Vertices a0 = anchor_rows(m_x);
    m_f.setZero();
    for (int s = 1; s <= m_substeps; ++s) {
      for (Eigen::Index i = 0; i < m_x.rows(); ++i) {
        if (m_anchored[static_cast<size_t>(i)]) continue;
        Eigen::RowVector3d acc = m_gravity.transpose();
        if (in.control.size() > 0) acc += in.control.segment<3>(3 * i).transpose() / m_mass;
        m_v.row(i) += h * acc;
        m_x.row(i) += h * m_v.row(i);
        m_f.row(i) = m_mass * m_gravity.transpose();
      }
      move_anchors(in, a0, s, h);
    }
  }

  SimState save() const override {
    SimState s;
    s.values.assign(m_x.data(), m_x.data() + m_x.size());
    s.values.insert(s.values.end(), m_v.data(), m_v.data() + m_v.size());
    return s;
  }
  void restore(const SimState& s) override {
    if (s.values.size() != static_cast<size_t>(2 * m_x.size()))
      throw std::invalid_argument("state of the wrong size");
    std::copy(s.values.begin(), s.values.begin() + m_x.size(), m_x.data());
    std::copy(s.values.begin() + m_x.size(), s.values.end(), m_v.data());
  }
  std::unique_ptr<Simulator> clone() const override {
    return std::make_unique<ParticleSimulator>(*this);
  }

  bool has_derivatives() const override { return true; }
  int state_dim() const override { return static_cast<int>(2 * m_x.size()); }
  Eigen::VectorXd position_cotangent(const Vertices& d) const override {
    Eigen::VectorXd g = Eigen::VectorXd::Zero(state_dim());
    for (Eigen::Index i = 0; i < d.rows(); ++i) g.segment<3>(3 * i) = d.row(i).transpose();
    return g;
  }
  // State layout: [x (row-major #V x 3), v (row-major #V x 3)].
  StepVjp step_vjp(const SimState& before, const StepInput& in,
                   const Eigen::VectorXd& g_after) override {
    restore(before);
    check(in);
    const Eigen::Index n = m_x.rows();
    const double h = in.dt / m_substeps;
    Eigen::VectorXd gx = g_after.head(3 * n), gv = g_after.tail(3 * n);
    StepVjp out;
    out.control = Eigen::VectorXd::Zero(3 * n);
    for (int s = m_substeps; s >= 1; --s) {
      for (Eigen::Index i = 0; i < n; ++i) {
        if (m_anchored[static_cast<size_t>(i)]) {
          // Prescribed: no dependence on the state or the control (velocity follows targets).
          gx.segment<3>(3 * i).setZero();
          gv.segment<3>(3 * i).setZero();
          continue;
        }
        // x' = x + h v', v' = v + h (g + u / m).
        const Eigen::Vector3d gvp = gv.segment<3>(3 * i) + h * gx.segment<3>(3 * i);
        gv.segment<3>(3 * i) = gvp;
        out.control.segment<3>(3 * i) += (h / m_mass) * gvp;
      }
    }
    out.state.resize(6 * n);
    out.state << gx, gv;
    return out;
  }

 protected:
  void check(const StepInput& in) const {
    if (!(in.dt > 0.0)) throw std::invalid_argument("dt must be positive");
    if (in.control.size() != 0 && in.control.size() != 3 * m_x.rows())
      throw std::invalid_argument("control has " + std::to_string(in.control.size()) +
                                  " entries, expected " + std::to_string(3 * m_x.rows()));
    if (in.anchor_targets.rows() != 0 &&
        in.anchor_targets.rows() != static_cast<Eigen::Index>(m_anchors.size()))
      throw std::invalid_argument("anchor_targets has the wrong number of rows");
  }
  Vertices anchor_rows(const Vertices& x) const {
    Vertices a(static_cast<Eigen::Index>(m_anchors.size()), 3);
    for (size_t k = 0; k < m_anchors.size(); ++k)
      a.row(static_cast<Eigen::Index>(k)) = x.row(m_anchors[k]);
    return a;
  }
  void move_anchors(const StepInput& in, const Vertices& a0, int s, double h) {
    if (in.anchor_targets.rows() == 0) {
      for (int a : m_anchors) m_v.row(a).setZero();
      return;
    }
    const double t = static_cast<double>(s) / m_substeps;
    for (size_t k = 0; k < m_anchors.size(); ++k) {
      const auto r = static_cast<Eigen::Index>(k);
      const Eigen::RowVector3d target =
          s == m_substeps
              ? Eigen::RowVector3d(in.anchor_targets.row(r))
              : Eigen::RowVector3d((1.0 - t) * a0.row(r) + t * in.anchor_targets.row(r));
      m_v.row(m_anchors[k]) = (target - m_x.row(m_anchors[k])) / h;
      m_x.row(m_anchors[k]) = target;
    }
  }

  Vertices m_x, m_v, m_f;
  std::vector<int> m_anchors;
  std::vector<char> m_anchored;
  double m_mass;
  int m_substeps;
  Eigen::Vector3d m_gravity{0.0, 9.81, 0.0};
};

/// A small grid of particles, anchored at its first vertex.
inline Vertices particle_grid(int n) {
  Vertices p(n * n, 3);
  for (int i = 0; i < n; ++i)
    for (int j = 0; j < n; ++j) p.row(i * n + j) << 0.05 * i, 0.05 * j, 1.0;
  return p;
}

}  // namespace pbve::test
