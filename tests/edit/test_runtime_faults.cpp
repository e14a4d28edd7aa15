// Runtime faults during `pbve edit`: a diverging simulation is retried with more substeps and,
// failing that, stops the run with a valid shorter video and a report marked incomplete; a
// failing optimizer falls back to no control; Ctrl-C (SIGINT) or SIGTERM finishes the current frame
// and leaves valid, shorter results.

#include <signal.h>

#include <algorithm>
#include <filesystem>
#include <string>

#include <gtest/gtest.h>
#include <opencv2/videoio.hpp>

#include "edit/fault_simulator.hpp"
#include "pbve/core/error.hpp"
#include "pbve/edit/editor.hpp"
#include "pbve/edit/report.hpp"
#include "pbve/edit/scene.hpp"
#include "pbve/engines.hpp"
#include "support/cli.hpp"
#include "support/test_util.hpp"

namespace {

namespace fs = std::filesystem;
using pbve::test::FaultPlan;

/// Frames OpenCV decodes from a video file (0 when it does not open).
int decoded_frames(const fs::path& video) {
  cv::VideoCapture cap(video.string(), cv::CAP_FFMPEG);
  if (!cap.isOpened()) return 0;
  int n = 0;
  cv::Mat frame;
  while (cap.read(frame) && !frame.empty()) ++n;
  return n;
}

bool has_warning(const pbve::Report& r, const std::string& text) {
  return std::any_of(r.warnings.begin(), r.warnings.end(),
                     [&](const std::string& w) { return w.find(text) != std::string::npos; });
}

/// A 64x48, 5-frame synthetic clip edited in-process with a fault-injecting simulator.
class RuntimeFaults : public ::testing::Test {
 protected:
  void SetUp() override {
    const auto r = pbve::test::pbve_cmd("synth --size 64x48 --frames 5 --supersample 1 " +
                                        dir.path().string());
    ASSERT_EQ(r.status, 0) << r.output;
  }

  pbve::EditResult run(const FaultPlan& plan, bool control = false) {
    pbve::Scene scene = pbve::load_scene(dir / "scene.yaml");
    if (control) {
      // A small problem so that the optimizer runs quickly but does run.
      scene.object.refine = 0.0;
      scene.control.active_set = "all";
      scene.control.max_iterations = 5;
      // lT > lF: the optimizer runs in every frame (with lF >= lT it is skipped in frames
      // where zero control keeps everything hidden, and these faults need it to run).
      scene.control.weight_temporal = 2.0 * scene.control.weight_force;
    }
    pbve::EditOptions options;
    options.control = control;
    pbve::EditCallbacks cb;
    cb.make_simulator = [plan](const pbve::EngineRecipe& recipe) {
      return std::make_unique<pbve::test::FaultSimulator>(pbve::make_engine(recipe), plan);
    };
    return pbve::run_edit(scene, options, cb);
  }

  pbve::test::TempDir dir;
};

TEST_F(RuntimeFaults, AFactoryThatMakesNoSimulatorIsAnErrorAtTheEngineKey) {
  const pbve::Scene scene = pbve::load_scene(dir / "scene.yaml");
  pbve::EditCallbacks cb;
  cb.make_simulator = [](const pbve::EngineRecipe&) { return std::unique_ptr<pbve::Simulator>(); };
  try {
    pbve::run_edit(scene, pbve::EditOptions{}, cb);
    ADD_FAILURE() << "no error";
  } catch (const pbve::InputError& e) {
    EXPECT_EQ(e.file(), scene.file);
    EXPECT_EQ(e.line(), scene.line_of("simulation.engine"));
    EXPECT_NE(std::string(e.what()).find("made no simulator for engine 'mass_spring'"),
              std::string::npos)
        << e.what();
  }
  EXPECT_FALSE(fs::exists(dir / scene.output.video.filename()));
}

TEST_F(RuntimeFaults, DivergenceIsRetriedWithTwiceTheSubsteps) {
  FaultPlan plan;
  plan.frame = 2;
  plan.heal_factor = 2;
  const pbve::EditResult r = run(plan);
  EXPECT_EQ(r.status, pbve::EditStatus::completed);
  const pbve::Report rep = pbve::read_report(dir / "report.json");
  ASSERT_EQ(rep.frames.size(), 5u);
  EXPECT_TRUE(rep.complete);
  for (const auto& f : rep.frames) EXPECT_EQ(f.substep_factor, f.index == 2 ? 2 : 1) << f.index;
  EXPECT_TRUE(has_warning(rep,
                          "the simulation diverged in frame 2 (non-finite positions); the "
                          "frame was recomputed with 2x the substeps"));
  EXPECT_GT(rep.frames[2].physical_force, 0.0);
  EXPECT_EQ(decoded_frames(dir / "edited.mp4"), 5);
}

TEST_F(RuntimeFaults, DivergenceIsRetriedWithFourTimesTheSubsteps) {
  FaultPlan plan;
  plan.frame = 3;
  plan.heal_factor = 4;
  const pbve::EditResult r = run(plan);
  EXPECT_EQ(r.status, pbve::EditStatus::completed);
  const pbve::Report rep = pbve::read_report(dir / "report.json");
  ASSERT_EQ(rep.frames.size(), 5u);
  EXPECT_EQ(rep.frames[3].substep_factor, 4);
  EXPECT_EQ(rep.frames[2].substep_factor, 1);
  EXPECT_EQ(rep.frames[4].substep_factor, 1);
  EXPECT_TRUE(has_warning(rep, "recomputed with 4x the substeps"));
}

TEST_F(RuntimeFaults, PersistentDivergenceStopsWithAValidShorterVideo) {
  FaultPlan plan;
  plan.frame = 3;  // never heals
  const pbve::EditResult r = run(plan);
  EXPECT_EQ(r.status, pbve::EditStatus::diverged);
  EXPECT_FALSE(r.complete);
  // Frames 0-2 were edited and written; frame 3 diverged.
  EXPECT_EQ(decoded_frames(dir / "edited.mp4"), 3);
  EXPECT_FALSE(fs::exists(dir / "edited.partial.mp4"));
  const pbve::Report rep = pbve::read_report(dir / "report.json");
  EXPECT_FALSE(rep.complete);
  EXPECT_EQ(rep.stopped_at, 3);
  EXPECT_EQ(rep.frames.size(), 3u);
  EXPECT_NE(rep.stopped_reason.find("the simulation diverged in frame 3 (non-finite positions) "
                                    "even with 4x the substeps"),
            std::string::npos)
      << rep.stopped_reason;
  const std::string json = pbve::test::read_text(dir / "report.json");
  EXPECT_NE(json.find("\"complete\": false"), std::string::npos);
  EXPECT_NE(json.find("\"stopped_at\": 3"), std::string::npos);
}

TEST_F(RuntimeFaults, OptimizerExceptionFallsBackToZeroControl) {
  FaultPlan plan;
  plan.kind = FaultPlan::Kind::throw_if_control;
  plan.frame = 1;
  const pbve::EditResult r = run(plan, true);
  EXPECT_EQ(r.status, pbve::EditStatus::completed);
  const pbve::Report rep = pbve::read_report(dir / "report.json");
  ASSERT_EQ(rep.frames.size(), 5u);
  EXPECT_EQ(rep.frames[1].status, "failed");
  EXPECT_EQ(rep.frames[1].control_force, 0.0);
  EXPECT_TRUE(has_warning(rep,
                          "frame 1: the control optimizer failed (injected solver fault); "
                          "the frame was simulated without control forces"));
  EXPECT_NE(rep.frames[2].status, "failed");  // the next frames optimize again
  EXPECT_EQ(decoded_frames(dir / "edited.mp4"), 5);
}

TEST_F(RuntimeFaults, NonFiniteEnergyKeepsTheBestIterate) {
  // Every control but zero makes the simulation NaN in frame 1: the optimizer's best point is
  // the zero control, which is committed; the run goes on.
  FaultPlan plan;
  plan.kind = FaultPlan::Kind::nan_if_control;
  plan.frame = 1;
  const pbve::EditResult r = run(plan, true);
  EXPECT_EQ(r.status, pbve::EditStatus::completed);
  const pbve::Report rep = pbve::read_report(dir / "report.json");
  ASSERT_EQ(rep.frames.size(), 5u);
  EXPECT_GT(rep.frames[1].iterations, 0);  // the optimizer did try non-zero controls
  EXPECT_EQ(rep.frames[1].control_force, 0.0);
  EXPECT_EQ(rep.frames[1].substep_factor, 1);
  for (const auto& f : rep.frames) EXPECT_TRUE(std::isfinite(f.violation_pct));
  EXPECT_EQ(decoded_frames(dir / "edited.mp4"), 5);
}

class EditInterrupt : public ::testing::TestWithParam<int> {};

TEST_P(EditInterrupt, FinishesTheFrameAndWritesAnIncompleteReport) {
  pbve::test::TempDir dir;
  const auto s =
      pbve::test::pbve_cmd("synth --size 64x48 --frames 40 --supersample 1 " + dir.path().string());
  ASSERT_EQ(s.status, 0) << s.output;
  pbve::test::PbveProcess p({"edit", (dir / "scene.yaml").string(), "--no-control"});
  ASSERT_TRUE(p.started());
  ASSERT_TRUE(p.wait_for_line("frame 0 (1/40)")) << p.output();
  p.send(GetParam());
  const int status = p.wait();
  EXPECT_EQ(status, 130) << p.output();
  EXPECT_NE(p.output().find("stopped early: cancelled after frame"), std::string::npos)
      << p.output();
  const pbve::Report rep = pbve::read_report(dir / "report.json");
  EXPECT_FALSE(rep.complete);
  ASSERT_GE(rep.frames.size(), 1u);
  EXPECT_LT(rep.frames.size(), 40u);
  EXPECT_EQ(rep.stopped_at, static_cast<int>(rep.frames.size()));
  EXPECT_EQ(decoded_frames(dir / "edited.mp4"), static_cast<int>(rep.frames.size()));
  EXPECT_FALSE(fs::exists(dir / "edited.partial.mp4"));
  EXPECT_FALSE(fs::exists(dir / "report.partial.json"));
}

INSTANTIATE_TEST_SUITE_P(Signals, EditInterrupt, ::testing::Values(SIGINT, SIGTERM),
                         [](const ::testing::TestParamInfo<int>& info) {
                           return std::string(info.param == SIGINT ? "Sigint" : "Sigterm");
                         });

}  // namespace
