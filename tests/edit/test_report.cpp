// Report: summary statistics, faithfulness warnings, JSON round trip.

#include <fstream>
#include <iterator>
#include <string>

#include <cmath>
#include <limits>

#include <gtest/gtest.h>
#include <nlohmann/json.hpp>

#include "pbve/core/error.hpp"
#include "pbve/edit/report.hpp"
#include "pbve/edit/scene.hpp"
#include "support/test_util.hpp"

namespace {

pbve::FrameRecord frame(int i, double viol, double control, double physical) {
  pbve::FrameRecord f;
  f.index = i;
  f.violation_pct = viol;
  f.control_force = control;
  f.physical_force = physical;
  f.frame_ms = 10.0 * (i + 1);
  return f;
}

TEST(Report, SummaryStatistics) {
  pbve::Report r;
  r.frames = {frame(0, 0.0, 0.0, 1.0), frame(1, 3.0, 0.1, 1.0), frame(2, 6.0, 0.5, 1.0),
              frame(3, 1.0, 0.3, 0.0)};  // zero physical force: left out of the ratio median
  const pbve::ReportSummary s = r.summary();
  EXPECT_EQ(s.frames, 4);
  EXPECT_DOUBLE_EQ(s.violation_pct_mean, 2.5);
  EXPECT_DOUBLE_EQ(s.violation_pct_max, 6.0);
  EXPECT_DOUBLE_EQ(s.control_to_physical_force_median, 0.1);
  EXPECT_DOUBLE_EQ(s.ms_per_frame_mean, 25.0);
}

// A NaN figure (unknown; null in a report read back) is left out of its statistics and its
// frame counted: NaN in the ratios broke the ordering the median sorts by (the median came out
// NaN here, not 3) and NaN violation made the mean NaN but not the maximum.
TEST(Report, NaNFiguresAreLeftOutOfTheSummaryAndCounted) {
  const double nan = std::numeric_limits<double>::quiet_NaN();
  const double inf = std::numeric_limits<double>::infinity();
  pbve::Report r;
  const double control[] = {5.0, 1.0, nan, 4.0, 2.0, 3.0, inf};
  for (int i = 0; i < 7; ++i) r.frames.push_back(frame(i, i == 2 ? nan : 1.0 + i, control[i], 1.0));
  r.frames[6].physical_force = inf;  // inf / inf: no ratio
  r.frames[4].frame_ms = nan;
  pbve::ReportSummary s = r.summary();
  EXPECT_EQ(s.frames, 7);
  EXPECT_EQ(s.nan_frames, 2);  // frame 2 (violation, control force) and frame 4 (time)
  EXPECT_DOUBLE_EQ(s.control_to_physical_force_median, 3.0);  // of 5, 1, 4, 2, 3
  EXPECT_DOUBLE_EQ(s.violation_pct_mean, (1.0 + 2.0 + 4.0 + 5.0 + 6.0 + 7.0) / 6.0);
  EXPECT_DOUBLE_EQ(s.violation_pct_max, 7.0);
  EXPECT_DOUBLE_EQ(s.ms_per_frame_mean, (10.0 + 20.0 + 30.0 + 40.0 + 60.0 + 70.0) / 6.0);

  // The same through a report written and read back (NaN is null there).
  pbve::test::TempDir dir;
  pbve::write_report(r, dir / "r.json");
  const pbve::Report b = pbve::read_report(dir / "r.json");
  s = b.summary();
  EXPECT_EQ(s.nan_frames, 3);  // frame 6's infinite physical force came back NaN as well
  EXPECT_DOUBLE_EQ(s.control_to_physical_force_median, 3.0);
  std::ifstream in(dir / "r.json");
  const std::string text((std::istreambuf_iterator<char>(in)), std::istreambuf_iterator<char>());
  EXPECT_NE(text.find("\"nan_frames\": 2"), std::string::npos) << text;
  EXPECT_NE(text.find("\"control_to_physical_force_median\": 3.0"), std::string::npos) << text;

  // No frame with a number: the means and the maximum are NaN (null), the median 0.
  pbve::Report unknown;
  unknown.frames = {frame(0, nan, nan, 1.0), frame(1, nan, 0.5, nan)};
  unknown.frames[0].frame_ms = unknown.frames[1].frame_ms = nan;
  s = unknown.summary();
  EXPECT_EQ(s.nan_frames, 2);
  EXPECT_TRUE(std::isnan(s.violation_pct_mean));
  EXPECT_TRUE(std::isnan(s.violation_pct_max));
  EXPECT_TRUE(std::isnan(s.ms_per_frame_mean));
  EXPECT_DOUBLE_EQ(s.solve_ms_mean, 0.0);
  EXPECT_DOUBLE_EQ(s.control_to_physical_force_median, 0.0);
}

TEST(Report, FaithfulnessWarningsGroupRuns) {
  std::vector<pbve::FrameRecord> f;
  for (int i = 0; i < 60; ++i) f.push_back(frame(i, 0, (i >= 40 && i <= 52) ? 0.5 : 0.1, 1.0));
  f[55].control_force = 0.3;
  const auto w = pbve::faithfulness_warnings(f, 0.25);
  ASSERT_EQ(w.size(), 2u);
  EXPECT_EQ(w[0],
            "control forces exceed 25% of physical forces in frames 40-52: the requested physics "
            "is not faithfully reproduced");
  EXPECT_NE(w[1].find("in frame 55:"), std::string::npos) << w[1];
}

TEST(Report, JsonRoundTrip) {
  pbve::test::TempDir dir;
  pbve::Report r;
  r.frames = {frame(0, 1.5, 0.2, 2.0), frame(1, 0.5, 0.1, 1.0)};
  r.frames[1].pose_lost = true;
  r.warnings = {"something"};
  r.settings_yaml = "control: {solver: slsqp, window: 1}\n";
  r.complete = false;
  r.stopped_reason = "interrupted";
  pbve::write_report(r, dir / "r.json");
  EXPECT_FALSE(std::filesystem::exists(dir / "r.partial.json"));
  const pbve::Report b = pbve::read_report(dir / "r.json");
  ASSERT_EQ(b.frames.size(), 2u);
  EXPECT_DOUBLE_EQ(b.frames[0].violation_pct, 1.5);
  EXPECT_TRUE(b.frames[1].pose_lost);
  EXPECT_FALSE(b.complete);
  EXPECT_EQ(b.stopped_reason, "interrupted");
  EXPECT_EQ(b.warnings, r.warnings);
}

TEST(Report, AFigureThatIsNotFiniteComesBackAsNaN) {
  // JSON has no NaN: write_report() writes null, read_report() reads it back as NaN.
  pbve::test::TempDir dir;
  pbve::Report r;
  r.frames = {frame(0, 1.5, 0.2, 2.0)};
  r.frames[0].violation_pct = std::numeric_limits<double>::quiet_NaN();
  r.frames[0].physical_force = std::numeric_limits<double>::infinity();
  pbve::write_report(r, dir / "r.json");
  const pbve::Report b = pbve::read_report(dir / "r.json");
  ASSERT_EQ(b.frames.size(), 1u);
  EXPECT_TRUE(std::isnan(b.frames[0].violation_pct));
  EXPECT_TRUE(std::isnan(b.frames[0].physical_force));
  EXPECT_DOUBLE_EQ(b.frames[0].control_force, 0.2);
}

// JSON is UTF-8: a file name in Latin-1 stopped write_report() with nlohmann::json's type error
// 316 (after the whole edit). Each byte that is not valid UTF-8 is now written as U+FFFD; valid
// text, non-ASCII included, is kept as it is.
TEST(Report, StringsThatAreNotUtf8AreWrittenWithReplacementCharacters) {
  pbve::test::TempDir dir;
  const std::string latin1 = "/data/caf\xe9";  // "café" in Latin-1
  const std::string replaced = "/data/caf\xef\xbf\xbd";
  const std::string utf8 = "/data/caf\xc3\xa9 \xe6\x97\xa5";  // "café 日" in UTF-8
  pbve::Report r;
  r.frames = {frame(0, 1.5, 0.2, 2.0)};
  r.engine = "mass_spring";
  r.complete = false;
  r.stopped_reason = "cannot read " + latin1 + ".mkv";
  r.warnings = {latin1 + ".obj: 2 degenerate triangles", utf8 + ".obj", "\xff\xfe" + utf8};
  r.tracking = pbve::ReportTracking{};
  r.tracking->poses = latin1 + ".poses.txt";
  r.settings_yaml = pbve::scene_to_yaml(
      pbve::parse_scene("input: {video: clip.mp4}\ncamera: {fx: 1, fy: 1, cx: 0, cy: 0}\n"
                        "object: {mesh: m.obj, poses: p.txt}\noutput: {video: o.mkv}\n",
                        latin1 + "/s.yaml"));
  ASSERT_NO_THROW(pbve::write_report(r, dir / "r.json"));
  const pbve::Report b = pbve::read_report(dir / "r.json");
  ASSERT_EQ(b.warnings.size(), 3u);
  EXPECT_EQ(b.warnings[0], replaced + ".obj: 2 degenerate triangles");
  EXPECT_EQ(b.warnings[1], utf8 + ".obj");
  EXPECT_EQ(b.warnings[2], "\xef\xbf\xbd\xef\xbf\xbd" + utf8);
  EXPECT_EQ(b.stopped_reason, "cannot read " + replaced + ".mkv");
  std::ifstream in(dir / "r.json");
  const nlohmann::json j = nlohmann::json::parse(in);
  EXPECT_EQ(j["tracking"]["poses"], replaced + ".poses.txt");
  EXPECT_EQ(j["settings"]["input"]["video"], replaced + "/clip.mp4");
  EXPECT_EQ(j["settings"]["object"]["mesh"], replaced + "/m.obj");
}

// Settings that are not YAML (a report made in code) are written as their text.
TEST(Report, SettingsThatAreNotYamlAreWrittenAsText) {
  pbve::test::TempDir dir;
  pbve::Report r;
  r.frames = {frame(0, 1.5, 0.2, 2.0)};
  r.settings_yaml = "control: {solver: [slsqp\n";
  ASSERT_NO_THROW(pbve::write_report(r, dir / "r.json"));
  std::ifstream in(dir / "r.json");
  EXPECT_EQ(nlohmann::json::parse(in)["settings"], r.settings_yaml);
}

TEST(Report, ReadingGarbageNamesTheFile) {
  pbve::test::TempDir dir;
  const auto p = pbve::test::write_text(dir / "bad.json", "{not json");
  try {
    pbve::read_report(p);
    FAIL() << "no error";
  } catch (const pbve::InputError& e) {
    EXPECT_EQ(e.file(), p);
    EXPECT_NE(std::string(e.what()).find("bad.json"), std::string::npos);
  }
}

TEST(Report, AMalformedFieldIsNamed) {
  // A report edited by hand or by a script: each wrong field names the file and the field.
  pbve::test::TempDir dir;
  pbve::Report r;
  r.frames = {frame(0, 1.5, 0.2, 2.0), frame(1, 0.5, 0.1, 1.0)};
  pbve::write_report(r, dir / "r.json");
  std::ifstream in(dir / "r.json");
  const std::string text((std::istreambuf_iterator<char>(in)), std::istreambuf_iterator<char>());
  const auto error_of = [&](const std::string& from, const std::string& to) {
    std::string bad = text;
    const size_t at = bad.rfind(from);  // in the last frame
    if (at == std::string::npos) return std::string("'" + from + "' not in the report");
    bad.replace(at, from.size(), to);
    const auto p = pbve::test::write_text(dir / "bad.json", bad);
    try {
      pbve::read_report(p);
    } catch (const pbve::InputError& e) {
      EXPECT_EQ(e.file(), p);
      return std::string(e.what());
    }
    return std::string("no error");
  };
  std::string e = error_of("\"violation_pct\": 0.5", "\"violation_pct\": \"0.5\"");
  EXPECT_NE(e.find("key 'frames[1].violation_pct'"), std::string::npos) << e;
  EXPECT_NE(e.find("expected a number, found a string"), std::string::npos) << e;
  e = error_of("\"index\": 1", "\"index\": 1.5");
  EXPECT_NE(e.find("key 'frames[1].index': not a pbve report: expected a whole number, found 1.5"),
            std::string::npos)
      << e;
  e = error_of("\"control_force\": 0.1,", "");
  EXPECT_NE(e.find("key 'frames[1].control_force': not a pbve report: missing"), std::string::npos)
      << e;
  e = error_of("\"physical_force\": 1.0", "\"physical_force\": 1e999");  // beyond a double
  EXPECT_NE(e.find("bad.json: not valid JSON"), std::string::npos) << e;
}

}  // namespace

#include "pbve/edit/plot.hpp"

namespace {

TEST(Plot, DrawsEachRunInItsColour) {
  pbve::Report a, b;
  for (int i = 0; i < 30; ++i) {
    a.frames.push_back(frame(i, 10.0 * i / 29.0, 0.0, 1.0 + i));
    b.frames.push_back(frame(i, 0.2, 0.05 * (1 + i % 3), 1.0 + i));
  }
  const cv::Mat img = pbve::plot_reports({a, b}, {"unconstrained", "constrained"}, 900, 600);
  ASSERT_EQ(img.cols, 900);
  ASSERT_EQ(img.rows, 600);
  // Both series colours appear (first: (180,110,30), second: (30,120,230) in BGR).
  int first = 0, second = 0;
  for (int y = 0; y < img.rows; ++y)
    for (int x = 0; x < img.cols; ++x) {
      const cv::Vec3b p = img.at<cv::Vec3b>(y, x);
      first += p == cv::Vec3b(180, 110, 30);
      second += p == cv::Vec3b(30, 120, 230);
    }
  EXPECT_GT(first, 100);
  EXPECT_GT(second, 100);
}

TEST(Plot, ForcesThatAreNotFiniteLeaveGapsNotAHang) {
  // An infinite force once made the decade loop of the force axis endless.
  pbve::Report a;
  for (int i = 0; i < 10; ++i) a.frames.push_back(frame(i, 1.0, 0.1 * (1 + i), 2.0));
  a.frames[3].control_force = std::numeric_limits<double>::infinity();
  a.frames[4].physical_force = std::numeric_limits<double>::quiet_NaN();
  a.frames[5].violation_pct = std::numeric_limits<double>::quiet_NaN();
  const cv::Mat img = pbve::plot_reports({a}, {"run"}, 900, 600);
  ASSERT_EQ(img.cols, 900);
  int drawn = 0;
  for (int y = 0; y < img.rows; ++y)
    for (int x = 0; x < img.cols; ++x) drawn += img.at<cv::Vec3b>(y, x) == cv::Vec3b(180, 110, 30);
  EXPECT_GT(drawn, 100);
  EXPECT_TRUE(pbve::axis_ticks(-1e308, 1e308, 6).empty());
  EXPECT_EQ(pbve::axis_ticks(0.0, 10.0, std::numeric_limits<int>::max(), 1.0).size(), 11u);
}

TEST(Plot, ASizeWithoutRoomForThePanelsIsRefused) {
  pbve::Report a;
  a.frames.push_back(frame(0, 1.0, 0.1, 1.0));
  EXPECT_THROW(pbve::plot_reports({a}, {}, -10, -10), pbve::InputError);
  EXPECT_THROW(pbve::plot_reports({a}, {}, 399, 600), pbve::InputError);
  EXPECT_EQ(pbve::plot_reports({a}, {}, 400, 300).size(), cv::Size(400, 300));
}

TEST(Plot, AxisTicksAreRoundNumbersWithinTheRange) {
  using V = std::vector<double>;
  EXPECT_EQ(pbve::axis_ticks(0, 89, 6, 1.0), (V{0, 20, 40, 60, 80}));
  EXPECT_EQ(pbve::axis_ticks(0, 100, 6), (V{0, 20, 40, 60, 80, 100}));
  EXPECT_EQ(pbve::axis_ticks(0, 1, 6, 1.0), (V{0, 1}));  // a two-frame report: whole frames
  EXPECT_EQ(pbve::axis_ticks(14, 50, 6, 1.0), (V{20, 30, 40, 50}));
  EXPECT_EQ(pbve::axis_ticks(-3, 3, 6), (V{-3, -2, -1, 0, 1, 2, 3}));
  const V small = pbve::axis_ticks(0, 0.3, 6);
  ASSERT_EQ(small.size(), 7u);
  EXPECT_NEAR(small[6], 0.3, 1e-12);
  EXPECT_TRUE(pbve::axis_ticks(1, 0, 6).empty());
  EXPECT_EQ(pbve::axis_ticks(5, 5, 6), (V{5}));
  EXPECT_LE(pbve::axis_ticks(1e12, 1e12 + 1e-3, 6).size(), 7u);  // ends
}

TEST(Plot, TickLabelsAreShortAndPlain) {
  EXPECT_EQ(pbve::tick_label(0), "0");
  EXPECT_EQ(pbve::tick_label(0.25), "0.25");
  EXPECT_EQ(pbve::tick_label(40), "40");
  EXPECT_EQ(pbve::tick_label(100), "100");
  EXPECT_EQ(pbve::tick_label(1000), "1000");  // a force decade; was "1e+03"
  EXPECT_EQ(pbve::tick_label(2500), "2500");
  EXPECT_EQ(pbve::tick_label(1e4), "1e+04");
  EXPECT_EQ(pbve::tick_label(0.01), "0.01");
  EXPECT_EQ(pbve::tick_label(1e-3), "1e-03");
  EXPECT_EQ(pbve::tick_label(-20), "-20");
}

}  // namespace
