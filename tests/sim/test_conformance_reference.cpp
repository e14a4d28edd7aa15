// The conformance suite proven on a reference adapter, and shown to catch broken adapters.

#include <atomic>
#include <memory>
#include <stdexcept>
#include <string>

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

// Broken: reports every vertex at rest (velocities() returns zeros).
class ReportsNoVelocity : public ParticleSimulator {
 public:
  using ParticleSimulator::ParticleSimulator;
  pbve::Vertices velocities() const override { return pbve::Vertices::Zero(num_vertices(), 3); }
  std::unique_ptr<Simulator> clone() const override {
    return std::make_unique<ReportsNoVelocity>(*this);
  }
};

// Broken: physical_forces() is empty and physical_force_magnitudes() too long.
class WrongForceSizes : public ParticleSimulator {
 public:
  using ParticleSimulator::ParticleSimulator;
  pbve::Vertices physical_forces() const override { return pbve::Vertices(0, 3); }
  Eigen::VectorXd physical_force_magnitudes() const override {
    return Eigen::VectorXd::Ones(num_vertices() + 100);
  }
  std::unique_ptr<Simulator> clone() const override {
    return std::make_unique<WrongForceSizes>(*this);
  }
};

// Broken: reports gravity on its anchored vertices too.
class ForcesOnAnchors : public ParticleSimulator {
 public:
  using ParticleSimulator::ParticleSimulator;
  pbve::Vertices physical_forces() const override {
    pbve::Vertices f = m_f;
    for (int a : m_anchors) f.row(a) = m_mass * m_gravity.transpose();
    return f;
  }
  std::unique_ptr<Simulator> clone() const override {
    return std::make_unique<ForcesOnAnchors>(*this);
  }
};

// Broken: lists one anchor past the last vertex (and out of order).
class AnchorOutOfRange : public ParticleSimulator {
 public:
  using ParticleSimulator::ParticleSimulator;
  std::vector<int> anchors() const override {
    std::vector<int> a = m_anchors;
    a.insert(a.begin(), num_vertices());
    return a;
  }
  std::unique_ptr<Simulator> clone() const override {
    return std::make_unique<AnchorOutOfRange>(*this);
  }
};

// Broken: clones share a counter of steps taken (as a shared warm-start cache would) that
// scales the gravity of the next step.
class SharesStepCount : public ParticleSimulator {
 public:
  using ParticleSimulator::ParticleSimulator;
  void step(const pbve::StepInput& in) override {
    m_gravity.y() = 9.81 * (1.0 + 0.01 * (*m_count)++);
    ParticleSimulator::step(in);
  }
  std::unique_ptr<Simulator> clone() const override {
    return std::make_unique<SharesStepCount>(*this);
  }

 private:
  std::shared_ptr<std::atomic<int>> m_count = std::make_shared<std::atomic<int>>(0);
};

// Broken: its clones cannot step.
class ClonesThrow : public ParticleSimulator {
 public:
  using ParticleSimulator::ParticleSimulator;
  void step(const pbve::StepInput& in) override {
    if (m_clone) throw std::runtime_error("clone cannot step");
    ParticleSimulator::step(in);
  }
  std::unique_ptr<Simulator> clone() const override {
    auto c = std::make_unique<ClonesThrow>(*this);
    c->m_clone = true;
    return c;
  }

 private:
  bool m_clone = false;
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
  EXPECT_TRUE(pbve::testing::check_physical_forces(c));
  EXPECT_TRUE(pbve::testing::check_clones_in_parallel(c));
}

TEST(ConformanceSuite, CatchesVelocitiesThatDoNotFollowTheMotion) {
  const auto r = pbve::testing::check_force_mass(broken_case<ReportsNoVelocity>());
  EXPECT_FALSE(r);
  EXPECT_NE(std::string(r.message()).find("extra velocity"), std::string::npos) << r.message();
}

TEST(ConformanceSuite, CatchesPhysicalForcesOfTheWrongSize) {
  const auto r = pbve::testing::check_physical_forces(broken_case<WrongForceSizes>());
  EXPECT_FALSE(r);
  EXPECT_NE(std::string(r.message()).find("0 rows"), std::string::npos) << r.message();
  // The editor and the optimizer read the magnitudes through this check.
  auto sim = broken_case<WrongForceSizes>().make();
  try {
    pbve::checked_force_magnitudes(*sim);
    ADD_FAILURE() << "no error for " << sim->physical_force_magnitudes().size() << " entries";
  } catch (const std::logic_error& e) {
    EXPECT_NE(std::string(e.what()).find("engine 'particles': physical_force_magnitudes() has 116 "
                                         "entries, num_vertices() 16"),
              std::string::npos)
        << e.what();
  }
}

TEST(ConformanceSuite, CatchesPhysicalForcesOnAnchors) {
  const auto r = pbve::testing::check_physical_forces(broken_case<ForcesOnAnchors>());
  EXPECT_FALSE(r);
  EXPECT_NE(std::string(r.message()).find("anchored vertex 0"), std::string::npos) << r.message();
}

TEST(ConformanceSuite, CatchesAnchorsOutOfRange) {
  const auto r = pbve::testing::check_layout(broken_case<AnchorOutOfRange>());
  EXPECT_FALSE(r);
  EXPECT_NE(std::string(r.message()).find("anchors() lists vertex 16, outside 0..15"),
            std::string::npos)
      << r.message();
}

TEST(ConformanceSuite, CatchesStateSharedBetweenClones) {
  const auto r = pbve::testing::check_clones_in_parallel(broken_case<SharesStepCount>());
  EXPECT_FALSE(r);
  EXPECT_NE(std::string(r.message()).find("clone"), std::string::npos) << r.message();
}

TEST(ConformanceSuite, AClonesErrorOnEitherThreadIsAnErrorNotAnAbort) {
  // Both threads' steps throw: the check joins the other thread before rethrowing.
  EXPECT_THROW(pbve::testing::check_clones_in_parallel(broken_case<ClonesThrow>()),
               std::runtime_error);
}

TEST(CheckSimulator, NamesTheEngineAndTheFirstInconsistency) {
  // A control layout whose vertex_block points past the last block.
  class BadLayout : public ParticleSimulator {
   public:
    using ParticleSimulator::ParticleSimulator;
    pbve::ControlLayout control_layout() const override {
      pbve::ControlLayout l = ParticleSimulator::control_layout();
      l.vertex_block[5] = l.num_blocks;
      return l;
    }
  };
  const BadLayout bad(pbve::test::particle_grid(4), {0, 3});
  try {
    pbve::check_simulator(bad);
    ADD_FAILURE() << "no error";
  } catch (const std::logic_error& e) {
    EXPECT_STREQ(e.what(),
                 "engine 'particles': control_layout().vertex_block of vertex 5 is 16, not -1 or "
                 "a block below 16");
  }
  EXPECT_NO_THROW(pbve::check_simulator(*reference_case().make()));
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
