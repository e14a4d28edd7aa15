// Pose tracking: PnP from correspondences, and the tracker on synthetic clips whose true poses
// are known (pbve synth).

#include "pbve/track/tracker.hpp"

#include <algorithm>
#include <cmath>
#include <vector>

#include <gtest/gtest.h>

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
