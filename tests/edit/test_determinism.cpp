// The same scene run twice gives byte-identical decoded frames and the same report apart from
// timing fields, with control on.

#include <filesystem>
#include <string>

#include <gtest/gtest.h>
#include <opencv2/core.hpp>

#include "pbve/core/footage.hpp"
#include "pbve/edit/report.hpp"
#include "support/cli.hpp"
#include "support/test_util.hpp"

namespace {

namespace fs = std::filesystem;

TEST(Determinism, TwoControlledRunsGiveIdenticalFramesAndReports) {
  pbve::test::TempDir dir;
  auto r =
      pbve::test::pbve_cmd("synth --size 64x48 --frames 4 --supersample 1 " + dir.path().string());
  ASSERT_EQ(r.status, 0) << r.output;
  std::string scene = pbve::test::read_text(dir / "scene.yaml");
  scene.replace(scene.find("  refine: 0.05\n"), 14, "");
  scene.replace(scene.find("max_iterations: 20"), 18, "max_iterations: 5\n  active_set: all");
  // lT > lF: the optimizer runs in every frame, even where zero control keeps everything hidden.
  scene.replace(scene.find("temporal: 0.03"), 14, "temporal: 0.06");
  pbve::test::write_text(dir / "scene.yaml", scene);
  for (const char* name : {"a", "b"}) {
    r = pbve::test::pbve_cmd("edit " + (dir / "scene.yaml").string() + " --quiet -o " +
                             (dir / (std::string(name) + ".mkv")).string() + " --report " +
                             (dir / (std::string(name) + ".json")).string());
    ASSERT_EQ(r.status, 0) << r.output;
  }
  pbve::Footage a = pbve::Footage::open_video(dir / "a.mkv");
  pbve::Footage b = pbve::Footage::open_video(dir / "b.mkv");
  ASSERT_EQ(a.frame_count(), 4);
  ASSERT_EQ(b.frame_count(), 4);
  for (int t = 0; t < 4; ++t) EXPECT_EQ(cv::norm(a.frame(t), b.frame(t), cv::NORM_INF), 0.0) << t;
  const pbve::Report ra = pbve::read_report(dir / "a.json");
  const pbve::Report rb = pbve::read_report(dir / "b.json");
  ASSERT_EQ(ra.frames.size(), rb.frames.size());
  for (size_t i = 0; i < ra.frames.size(); ++i) {
    EXPECT_EQ(ra.frames[i].violation_pct, rb.frames[i].violation_pct);
    EXPECT_EQ(ra.frames[i].control_force, rb.frames[i].control_force);
    EXPECT_EQ(ra.frames[i].physical_force, rb.frames[i].physical_force);
    EXPECT_EQ(ra.frames[i].iterations, rb.frames[i].iterations);
    EXPECT_EQ(ra.frames[i].status, rb.frames[i].status);
  }
  EXPECT_GT(ra.frames[1].iterations, 0);
  EXPECT_EQ(ra.warnings, rb.warnings);
}

}  // namespace
