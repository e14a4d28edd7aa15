// Pose tracking: PnP from correspondences, and the tracker on synthetic clips whose true poses
// are known (pbve synth).

#include "pbve/track/tracker.hpp"

#include <algorithm>
#include <cmath>
#include <limits>
#include <string>
#include <vector>

#include <gtest/gtest.h>
#include <opencv2/imgcodecs.hpp>

#include "pbve/core/error.hpp"
#include "pbve/edit/synth.hpp"
#include "support/test_util.hpp"

namespace pbve {
namespace {

Camera vga() {
  Camera c;
  c.fx = c.fy = 600;
  c.cx = 319.5;
  c.cy = 239.5;
  return c;
}

Pose some_pose() {
  return Pose::from_rodrigues({0.2, -0.4, 0.1}, {0.03, -0.02, 1.2});
}

TEST(TrackPnP, ExactProjectionsGiveThePoseBack) {
  const Mesh box = make_box_mesh(0.3, 0.2, 0.1);
  const Camera cam = vga();
  const Pose truth = some_pose();
  std::vector<Eigen::Vector3d> points;
  std::vector<Eigen::Vector2d> pixels;
  for (int i = 0; i < box.num_vertices(); ++i) {
    points.push_back(box.vertices.row(i).transpose());
    pixels.push_back(cam.project(truth.apply(points.back())));
  }
  const Pose p = pose_from_correspondences(points, pixels, cam);
  EXPECT_LT((p.rotation - truth.rotation).cwiseAbs().maxCoeff(), 1e-8);
  EXPECT_LT((p.translation - truth.translation).norm(), 1e-8);
  EXPECT_LT(reprojection_error_px(box, cam, p, truth), 1e-6);
  // Four points suffice.
  points.resize(4);
  pixels.resize(4);
  const Pose q = pose_from_correspondences(points, pixels, cam);
  EXPECT_LT(reprojection_error_px(box, cam, q, truth), 1e-6);
}

TEST(TrackPnP, TooFewOrInconsistentPairsAreErrors) {
  const Mesh box = make_box_mesh(0.3, 0.2, 0.1);
  const Camera cam = vga();
  std::vector<Eigen::Vector3d> points;
  std::vector<Eigen::Vector2d> pixels;
  for (int i = 0; i < 3; ++i) {
    points.push_back(box.vertices.row(i).transpose());
    pixels.push_back(cam.project(some_pose().apply(points.back())));
  }
  EXPECT_THROW(pose_from_correspondences(points, pixels, cam), InputError);
  // Pixels that no pose explains: all eight corners at the image centre but one.
  points.clear();
  pixels.clear();
  for (int i = 0; i < box.num_vertices(); ++i) {
    points.push_back(box.vertices.row(i).transpose());
    pixels.emplace_back(i == 0 ? 600.0 : 320.0, 240.0 + i);
  }
  EXPECT_THROW(pose_from_correspondences(points, pixels, cam), InputError);
}

// Degenerate pairs are InputErrors that say what is wrong, never OpenCV's exceptions: mesh
// points on one line (SQPnP's assertion for 4, any rotation about the line for 8), all one
// point, nearly on one line (the solver's own refusal), or coordinates that are not finite.
TEST(TrackPnP, DegeneratePairsAreInputErrorsThatSayWhy) {
  const Camera cam = vga();
  const double nan = std::numeric_limits<double>::quiet_NaN();
  auto expect_error = [&](const std::vector<Eigen::Vector3d>& points,
                          const std::vector<Eigen::Vector2d>& pixels, const std::string& what) {
    try {
      pose_from_correspondences(points, pixels, cam);
      ADD_FAILURE() << "no error, expected '" << what << "'";
    } catch (const InputError& e) {
      const std::string m = e.what();
      EXPECT_NE(m.find(what), std::string::npos) << m;
    } catch (const std::exception& e) {
      ADD_FAILURE() << "not an InputError: " << e.what();
    }
  };
  for (const size_t n : {size_t{4}, size_t{8}}) {
    std::vector<Eigen::Vector3d> line, same, nearly;
    std::vector<Eigen::Vector2d> pixels;
    for (size_t i = 0; i < n; ++i) {
      const double t = 0.1 * static_cast<double>(i);
      line.emplace_back(t, 0.5 * t, 0.0);
      same.emplace_back(0.1, 0.2, 0.3);
      nearly.emplace_back(t, i == 2 ? 1e-7 : 0.0, 0.0);
      pixels.emplace_back(300.0 + 100.0 * t, 200.0 + 50.0 * t);
    }
    expect_error(line, pixels, "all " + std::to_string(n) + " mesh points lie on one line");
    expect_error(same, pixels, "all " + std::to_string(n) + " mesh points are the same point");
    expect_error(nearly, pixels, "mesh points lie on one line");
  }
  // Just off a line: what the solver makes of it is its business, but it is an InputError.
  std::vector<Eigen::Vector3d> off;
  std::vector<Eigen::Vector2d> pixels;
  for (int i = 0; i < 4; ++i) {
    off.emplace_back(0.1 * i, i == 2 ? 1e-6 : 0.0, 0.0);
    pixels.emplace_back(300.0 + 10.0 * i, 200.0 + 5.0 * i);
  }
  expect_error(off, pixels, "correspondences: ");
  // Not finite: the pair is named.
  const Mesh box = make_box_mesh(0.3, 0.2, 0.1);
  std::vector<Eigen::Vector3d> points;
  pixels.clear();
  for (int i = 0; i < box.num_vertices(); ++i) {
    points.push_back(box.vertices.row(i).transpose());
    pixels.push_back(cam.project(some_pose().apply(points.back())));
  }
  auto bad_point = points;
  bad_point[3].x() = nan;
  expect_error(bad_point, pixels, "pair 3: mesh point (nan, ");
  auto bad_pixel = pixels;
  bad_pixel[5].y() = std::numeric_limits<double>::infinity();
  expect_error(points, bad_pixel, "pair 5: pixel (");
  EXPECT_NO_THROW(pose_from_correspondences(points, pixels, cam));
}

// The setting at a reduced length: a textured board moved around and turned on a
// cluttered background while a hand passes in front of it (pbve synth --motion orbit
// --occluder), tracked from its first pose. Per frame, the mean over vertices of the
// reprojection error against the true pose; the median over frames at most 1.5 px and no frame
// above 5 px.
TEST(Tracker, FollowsAMovingTurningBoardBehindAHand) {
  test::TempDir dir;
  SynthOptions o;
  o.shape = "board";
  o.motion = "orbit";
  o.frames = 75;
  o.supersample = 2;
  o.occluder = true;
  const SynthOutput clip = synthesize(o, dir.path());
  Footage footage = Footage::open_video(clip.video);
  ASSERT_EQ(footage.frame_count(), 75);
  const TrackResult r = track_footage(footage, clip.mesh_data, clip.camera, *clip.track.poses[0]);
  ASSERT_EQ(r.track.size(), 75);
  EXPECT_EQ(r.left_view_at, -1);
  std::vector<double> errors;
  for (int t = 0; t < 75; ++t) {
    const auto& p = r.track.poses[static_cast<size_t>(t)];
    errors.push_back(p ? reprojection_error_px(clip.mesh_data, clip.camera, *p,
                                               *clip.track.poses[static_cast<size_t>(t)])
                       : std::numeric_limits<double>::infinity());
  }
  std::vector<double> sorted = errors;
  std::sort(sorted.begin(), sorted.end());
  EXPECT_LE(sorted[sorted.size() / 2], 1.5);
  EXPECT_LE(sorted.back(), 5.0);
  EXPECT_EQ(r.frames[0].lost, false);
}

std::vector<double> errors_against(const Mesh& mesh, const Camera& camera, const PoseTrack& tracked,
                                   const PoseTrack& truth) {
  std::vector<double> errors;
  for (int t = 0; t < tracked.size(); ++t) {
    const auto& p = tracked.poses[static_cast<size_t>(t)];
    errors.push_back(
        p ? reprojection_error_px(mesh, camera, *p, *truth.poses[static_cast<size_t>(t)])
          : std::numeric_limits<double>::infinity());
  }
  return errors;
}

double median(std::vector<double> v) {
  std::sort(v.begin(), v.end());
  return v[v.size() / 2];
}

// The clip: the 36 cm figurine (round, smoothly shaded, few corners) moved around and
// turned on the cluttered background for 150 frames while a hand covering most of it passes in
// front from about frame 50 to 100. Median at most 1.5 px, no frame above 5 px, none lost.
TEST(Tracker, FollowsAMovingTurningFigurineBehindAHand) {
  test::TempDir dir;
  SynthOptions o;
  o.shape = "figurine";
  o.motion = "orbit";
  o.frames = 150;
  o.supersample = 1;  // rendering time; docs/benchmarks.md has the antialiased clips too
  o.occluder = true;
  const SynthOutput clip = synthesize(o, dir.path());
  Footage footage = Footage::open_video(clip.video);
  const TrackResult r = track_footage(footage, clip.mesh_data, clip.camera, *clip.track.poses[0]);
  ASSERT_EQ(r.track.size(), 150);
  EXPECT_EQ(r.track.lost_count(), 0);
  EXPECT_EQ(r.left_view_at, -1);
  const std::vector<double> e = errors_against(clip.mesh_data, clip.camera, r.track, clip.track);
  EXPECT_LE(median(e), 1.5);
  EXPECT_LE(*std::max_element(e.begin(), e.end()), 5.0);
}

// Frames 24-33 show the background only (the object hidden): they are lost, and the tracker
// finds the object again when it shows (re-detection), moved and turned meanwhile.
TEST(Tracker, LosesAHiddenObjectAndFindsItAgain) {
  test::TempDir dir;
  SynthOptions o;
  o.shape = "figurine";
  o.motion = "orbit";
  o.frames = 60;
  o.supersample = 1;
  const SynthOutput clip = synthesize(o, dir.path());
  Footage footage = Footage::open_video(clip.video);
  const cv::Mat plate = cv::imread(clip.plate.string(), cv::IMREAD_COLOR);
  ASSERT_FALSE(plate.empty());
  PoseTracker tracker(clip.mesh_data, clip.camera);
  tracker.start(footage.frame(0), *clip.track.poses[0]);
  PoseTrack tracked{{clip.track.poses[0]}};
  int lost_hidden = 0;
  for (int t = 1; t < 60; ++t) {
    const bool hidden = t >= 24 && t < 34;
    TrackFrameInfo info;
    tracked.poses.push_back(tracker.track(hidden ? plate : footage.frame(t), &info));
    if (hidden) lost_hidden += info.lost;
  }
  EXPECT_GE(lost_hidden, 9);
  const std::vector<double> e = errors_against(clip.mesh_data, clip.camera, tracked, clip.track);
  for (int t = 38; t < 60; ++t) EXPECT_LE(e[static_cast<size_t>(t)], 5.0) << "frame " << t;
}

// The object moves out of the image for good: the final frames are lost and left_view_at says
// from when.
TEST(Tracker, ObjectLeavingTheViewForGoodIsReported) {
  const SynthRecipe recipe = [] {
    SynthOptions o;
    o.shape = "figurine";
    o.motion = "still";
    o.frames = 1;
    return synth_recipe(o);
  }();
  const cv::Mat background = make_background(cv::Size(640, 480), 7);
  const SurfaceTexture texture = procedural_texture(0.06);
  std::vector<cv::Mat> frames;
  PoseTrack truth;
  for (int t = 0; t < 40; ++t) {
    Pose p = *recipe.track.poses[0];
    p.translation.x() += t < 8 ? 0.0 : 0.04 * (t - 8);  // 18 px per frame to the right
    truth.poses.emplace_back(p);
    frames.push_back(render_object(recipe.mesh, p, recipe.camera, texture, background, 1));
  }
  test::TempDir dir;
  const auto video = dir.path() / "leaving.mkv";
  {
    VideoWriter w(video, 30.0, cv::Size(640, 480));
    for (const auto& f : frames) w.write(f);
    w.close();
  }
  Footage footage = Footage::open_video(video);
  const TrackResult r = track_footage(footage, recipe.mesh, recipe.camera, *truth.poses[0]);
  ASSERT_EQ(r.track.size(), 40);
  ASSERT_GE(r.left_view_at, 8);
  EXPECT_LE(r.left_view_at, 34);
  for (int t = r.left_view_at; t < 40; ++t) EXPECT_FALSE(r.track.poses[static_cast<size_t>(t)]);
  // Before it left, the poses it gave were right.
  const std::vector<double> e = errors_against(recipe.mesh, recipe.camera, r.track, truth);
  for (int t = 0; t < r.left_view_at; ++t)
    if (r.track.poses[static_cast<size_t>(t)]) {
      EXPECT_LE(e[static_cast<size_t>(t)], 5.0) << t;
    }
}

TEST(Tracker, ObjectWithoutCornersUnderTheInitialPoseIsAnError) {
  test::TempDir dir;
  SynthOptions o;
  o.frames = 3;
  o.supersample = 1;
  const SynthOutput clip = synthesize(o, dir.path());
  Footage footage = Footage::open_video(clip.video);
  // A pose far to the side: the object's projection misses the image.
  Pose away = *clip.track.poses[0];
  away.translation.x() += 5.0;
  PoseTracker tracker(clip.mesh_data, clip.camera);
  EXPECT_THROW(tracker.start(footage.frame(0), away), InputError);
}

// Frames the tracker cannot read (not 8-bit, or two channels) and poses that are not finite
// are InputErrors naming the call, in start() and in track() alike.
TEST(Tracker, FramesOfAnotherTypeAndNonFinitePosesAreInputErrors) {
  test::TempDir dir;
  SynthOptions o;
  o.frames = 2;
  o.supersample = 1;
  const SynthOutput clip = synthesize(o, dir.path());
  Footage footage = Footage::open_video(clip.video);
  const cv::Mat f0 = footage.frame(0), f1 = footage.frame(1);
  const Pose p0 = *clip.track.poses[0];
  cv::Mat two(f0.rows, f0.cols, CV_8UC2, cv::Scalar(40, 80)), wide, real;
  f0.convertTo(wide, CV_16UC3, 256.0);
  f1.convertTo(real, CV_32FC3, 1.0 / 255.0);
  auto expect_error = [](const std::string& what, auto call) {
    try {
      call();
      ADD_FAILURE() << "no error, expected '" << what << "'";
    } catch (const InputError& e) {
      EXPECT_NE(std::string(e.what()).find(what), std::string::npos) << e.what();
    } catch (const std::exception& e) {
      ADD_FAILURE() << "not an InputError: " << e.what();
    }
  };
  for (const cv::Mat* bad : {&two, &wide, &real}) {
    PoseTracker tracker(clip.mesh_data, clip.camera);
    expect_error("PoseTracker::start: frame of type CV_", [&] { tracker.start(*bad, p0); });
    tracker.start(f0, p0);
    expect_error("PoseTracker::track: frame of type CV_", [&] { tracker.track(*bad); });
    EXPECT_TRUE(tracker.track(f1).has_value());  // the refused frame changed nothing
  }
  Pose nan_pose = p0;
  nan_pose.translation.z() = std::numeric_limits<double>::quiet_NaN();
  PoseTracker tracker(clip.mesh_data, clip.camera);
  expect_error("PoseTracker::start: the initial pose is not finite",
               [&] { tracker.start(f0, nan_pose); });
}

}  // namespace
}  // namespace pbve
