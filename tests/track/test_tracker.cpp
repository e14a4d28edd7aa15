// Pose tracking: PnP from correspondences, and the tracker on synthetic clips whose true poses
// are known (pbve synth).

#include "pbve/track/tracker.hpp"

#include <algorithm>
#include <cmath>
#include <limits>
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

}  // namespace
}  // namespace pbve
