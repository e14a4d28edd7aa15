#pragma once
// A Simulator that wraps a real one and injects faults in one frame of the edit, for testing
// how the editor copes with a diverging simulation or a failing optimizer.

#include <cmath>
#include <limits>
#include <memory>
#include <stdexcept>
#include <string>
#include <vector>

#include "pbve/sim/simulator.hpp"

namespace pbve::test {

/// What goes wrong, and when.
struct FaultPlan {
  enum class Kind {
    nan_positions,    ///< positions and velocities become NaN (a diverging engine)
    nan_if_control,   ///< NaN only when the step carries a non-zero control
    throw_if_control  ///< step() throws when it carries a non-zero control
  };
  Kind kind = Kind::nan_positions;
  /// The faulty frame: steps inside the time interval ((frame - 1) dt, frame dt] (frames counted
  /// from the first edited frame, where the simulation starts at time 0) are affected.
  int frame = 2;
  double frame_dt = 1.0 / 30.0;
  /// nan_positions heals when the step is at most frame_dt / heal_factor (0 = never heals).
  int heal_factor = 0;
};

class FaultSimulator final : public Simulator {
 public:
  FaultSimulator(std::unique_ptr<Simulator> inner, FaultPlan plan)
      : m_inner(std::move(inner)), m_plan(plan) {}

  std::string name() const override { return "fault(" + m_inner->name() + ")"; }
  int num_vertices() const override { return m_inner->num_vertices(); }
  Vertices positions() const override { return poisoned(m_inner->positions()); }
  Vertices velocities() const override { return poisoned(m_inner->velocities()); }
  ControlLayout control_layout() const override { return m_inner->control_layout(); }
  std::vector<int> anchors() const override { return m_inner->anchors(); }
  Vertices physical_forces() const override { return m_inner->physical_forces(); }
  Eigen::VectorXd physical_force_magnitudes() const override {
    return m_inner->physical_force_magnitudes();
  }

  void step(const StepInput& in) override {
    const double t0 = m_time, t1 = m_time + in.dt;
    const double eps = 1e-9 * m_plan.frame_dt;
    const bool in_frame = t0 < m_plan.frame * m_plan.frame_dt - eps &&
                          t1 > (m_plan.frame - 1) * m_plan.frame_dt + eps;
    const bool with_control = in.control.size() > 0 && in.control.cwiseAbs().maxCoeff() > 0.0;
    if (in_frame && with_control && m_plan.kind == FaultPlan::Kind::throw_if_control)
      throw std::runtime_error("injected solver fault");
    m_inner->step(in);
    m_time = t1;
    if (!in_frame) return;
    if (m_plan.kind == FaultPlan::Kind::nan_positions &&
        (m_plan.heal_factor == 0 || in.dt > m_plan.frame_dt / m_plan.heal_factor + eps))
      m_poisoned = true;
    if (m_plan.kind == FaultPlan::Kind::nan_if_control && with_control) m_poisoned = true;
  }

  SimState save() const override {
    SimState s = m_inner->save();
    s.values.push_back(m_time);
    s.values.push_back(m_poisoned ? 1.0 : 0.0);
    return s;
  }
  void restore(const SimState& state) override {
    SimState s = state;
    m_poisoned = s.values.back() != 0.0;
    s.values.pop_back();
    m_time = s.values.back();
    s.values.pop_back();
    m_inner->restore(s);
  }
  std::unique_ptr<Simulator> clone() const override {
    auto c = std::make_unique<FaultSimulator>(m_inner->clone(), m_plan);
    c->m_time = m_time;
    c->m_poisoned = m_poisoned;
    return c;
  }

 private:
  Vertices poisoned(Vertices v) const {
    if (m_poisoned) v.setConstant(std::numeric_limits<double>::quiet_NaN());
    return v;
  }

  std::unique_ptr<Simulator> m_inner;
  FaultPlan m_plan;
  double m_time = 0.0;
  bool m_poisoned = false;
};

}  // namespace pbve::test
