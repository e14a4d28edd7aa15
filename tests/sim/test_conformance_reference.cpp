// The conformance suite proven on a reference adapter, and shown to catch broken adapters.

#include "pbve/testing/simulator_conformance.hpp"
#include "sim/particle_simulator.hpp"

namespace {

using pbve::Simulator;
using pbve::test::ParticleSimulator;
using pbve::testing::ConformanceCase;

ConformanceCase reference_case() {
  ConformanceCase c;
  c.name = "particles";
  c.make = [] {
    return std::make_unique<ParticleSimulator>(pbve::test::particle_grid(4),
                                               std::vector<int>{0, 3});
  };
  return c;
}

INSTANTIATE_TEST_SUITE_P(Reference, SimulatorConformance, ::testing::Values(reference_case()),
                         pbve::testing::case_name);

// Broken: restore() brings positions back but forgets the velocities.
class DropsVelocities : public ParticleSimulator {
 public:
  using ParticleSimulator::ParticleSimulator;
  void restore(const pbve::SimState& s) override {
    ParticleSimulator::restore(s);
    m_v.setZero();
  }
  std::unique_ptr<Simulator> clone() const override {
    return std::make_unique<DropsVelocities>(*this);
  }
};

// Broken: applies the control force twice (f = 2 m a).
class DoublesForce : public ParticleSimulator {
 public:
  using ParticleSimulator::ParticleSimulator;
  void step(const pbve::StepInput& in) override {
    pbve::StepInput twice = in;
    if (twice.control.size() > 0) twice.control *= 2.0;
    ParticleSimulator::step(twice);
  }
  std::unique_ptr<Simulator> clone() const override {
    return std::make_unique<DoublesForce>(*this);
  }
};

// Broken: leaves anchors a fraction short of their targets.
class LagsAnchors : public ParticleSimulator {
 public:
  using ParticleSimulator::ParticleSimulator;
  void step(const pbve::StepInput& in) override {
    ParticleSimulator::step(in);
    for (int a : m_anchors) m_x.row(a) *= 1.0 - 1e-9;
  }
  std::unique_ptr<Simulator> clone() const override { return std::make_unique<LagsAnchors>(*this); }
};

// Broken: clone() shares nothing wrong, but starts from rest instead of the current state.
class ClonesFromRest : public ParticleSimulator {
 public:
  ClonesFromRest(const pbve::Vertices& p, std::vector<int> a)
      : ParticleSimulator(p, a), m_rest(p) {}
  std::unique_ptr<Simulator> clone() const override {
    return std::make_unique<ClonesFromRest>(m_rest, m_anchors);
  }

 private:
  pbve::Vertices m_rest;
};

template <class T>
ConformanceCase broken_case() {
  ConformanceCase c = reference_case();
  c.make = [] { return std::make_unique<T>(pbve::test::particle_grid(4), std::vector<int>{0, 3}); };
  return c;
}

TEST(ConformanceSuite, ReferencePassesEveryCheck) {
  const ConformanceCase c = reference_case();
  EXPECT_TRUE(pbve::testing::check_save_restore(c));
  EXPECT_TRUE(pbve::testing::check_force_mass(c));
  EXPECT_TRUE(pbve::testing::check_anchors(c));
  EXPECT_TRUE(pbve::testing::check_clone(c));
}

TEST(ConformanceSuite, CatchesRestoreThatDropsVelocities) {
  const auto r = pbve::testing::check_save_restore(broken_case<DropsVelocities>());
  EXPECT_FALSE(r);
  EXPECT_NE(std::string(r.message()).find("after restore"), std::string::npos) << r.message();
}

TEST(ConformanceSuite, CatchesWrongForceScaling) {
  const auto r = pbve::testing::check_force_mass(broken_case<DoublesForce>());
  EXPECT_FALSE(r);
  EXPECT_NE(std::string(r.message()).find("relative error"), std::string::npos) << r.message();
}

TEST(ConformanceSuite, CatchesAnchorsOffTarget) {
  EXPECT_FALSE(pbve::testing::check_anchors(broken_case<LagsAnchors>()));
}

TEST(ConformanceSuite, CatchesCloneThatForgetsState) {
  EXPECT_FALSE(pbve::testing::check_clone(broken_case<ClonesFromRest>()));
}

TEST(ConformanceSuite, CatchesWrongDerivatives) {
  // A VJP that forgets the 1/m factor on the control.
  class WrongVjp : public ParticleSimulator {
   public:
    using ParticleSimulator::ParticleSimulator;
    pbve::StepVjp step_vjp(const pbve::SimState& b, const pbve::StepInput& in,
                           const Eigen::VectorXd& g) override {
      pbve::StepVjp r = ParticleSimulator::step_vjp(b, in, g);
      r.control *= m_mass;
      return r;
    }
  };
  ConformanceCase c = reference_case();
  c.make = [] {
    return std::make_unique<WrongVjp>(pbve::test::particle_grid(4), std::vector<int>{0});
  };
  EXPECT_FALSE(pbve::testing::check_vjp(c));
}

}  // namespace
