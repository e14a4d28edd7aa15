// Background plate: temporal median over uncovered frames, inpainting, extra masks, masks on
// disk, single images.

#include "pbve/render/plate.hpp"

#include <limits>

#include <gtest/gtest.h>

#include <opencv2/imgcodecs.hpp>
#include <opencv2/imgproc.hpp>

#include "pbve/core/error.hpp"
#include "render/render_scenes.hpp"
#include "support/test_util.hpp"

namespace pbve {
namespace {

Camera small_camera() {
  return test::centred_camera(320, 240, 250.0);
}

cv::Vec3f object_color(const Eigen::Vector3d& p) {
  return {static_cast<float>(128 + 100 * std::sin(20 * p.x())),
          static_cast<float>(128 + 100 * std::cos(17 * p.y())),
          static_cast<float>(128 + 100 * std::sin(23 * p.z()))};
}

/// A clip of `n` frames: a sphere (~42 px radius) moving 40 px from left to right over a
/// textured background, tumbling as it goes (the middle of its path is never uncovered), and a red
/// "hand" rectangle that follows it.
struct Clip {
  Camera camera = small_camera();
  Mesh mesh = test::icosphere(3, 0.25);
  cv::Mat background;
  std::vector<cv::Mat> frames;
  std::vector<cv::Mat> coverage;  // fraction of each pixel covered by the sphere
  std::vector<cv::Rect> hands;
  PoseTrack poses;

  explicit Clip(int n) {
    background = test::smooth_background({camera.width, camera.height});
    for (int i = 0; i < n; ++i) {
      Pose pose;
      pose.rotation =
          Eigen::AngleAxisd(0.2 * i, Eigen::Vector3d(0.3, 1, 0.2).normalized()).toRotationMatrix();
      pose.translation = Eigen::Vector3d(-0.12 + 0.24 * i / (n - 1), 0.03 * std::sin(0.5 * i), 1.5);
      poses.poses.push_back(pose);
      const test::SyntheticFrame f =
          test::render_object(mesh.triangles, mesh.vertices, pose.apply(mesh.vertices), camera,
                              background, object_color, 3);
      cv::Mat image = f.image.clone();
      const Eigen::Vector2d c = camera.project(pose.translation);
      const cv::Rect hand(static_cast<int>(c.x()) - 8, static_cast<int>(c.y()) + 40, 16, 60);
      cv::rectangle(image, hand, cv::Scalar(0, 0, 255), cv::FILLED);
      hands.push_back(hand & cv::Rect(0, 0, camera.width, camera.height));
      frames.push_back(image);
      coverage.push_back(f.coverage);
    }
  }
  cv::Mat hand_mask(int i) const {
    cv::Mat m(camera.height, camera.width, CV_8U, cv::Scalar(0));
    m(hands[i]).setTo(255);
    return m;
  }
  /// Pixels showing the true background in at least one frame (neither sphere nor hand).
  cv::Mat uncovered_once() const {
    cv::Mat once(camera.height, camera.width, CV_8U, cv::Scalar(0));
    for (size_t i = 0; i < frames.size(); ++i)
      once |= (coverage[i] == 0.0f) & (hand_mask(static_cast<int>(i)) == 0);
    return once;
  }
};

// The automatic plate matches the true background (PSNR >= 35 dB) over the pixels that were
// uncovered at least once. Where a pixel shows the background in some frame and is outside the
// enlarged, dilated silhouette and the hand mask in that frame, the median is over exact
// background values, so it is exact; the remaining error comes from the thin ring of pixels
// that were only ever uncovered within the dilation margin and are inpainted from their
// neighbours (a smooth background, so the inpainting error is small).
TEST(Plate, TemporalMedianRecoversTheBackground) {
  const Clip clip(30);
  PlateOptions options;
  options.extra_mask = [&](int i) { return clip.hand_mask(i); };
  const BackgroundPlate plate = estimate_plate(
      static_cast<int>(clip.frames.size()), [&](int i) { return clip.frames[i]; }, clip.poses,
      clip.mesh, clip.camera, options);
  EXPECT_EQ(plate.frames_used, 30);
  const cv::Mat once = clip.uncovered_once();
  ASSERT_GT(cv::countNonZero(once), clip.camera.width * clip.camera.height / 2);
  const double db = test::psnr(plate.image, clip.background, once);
  RecordProperty("psnr_db", std::to_string(db));
  EXPECT_GE(db, 35.0);
  // Pixels the plate saw as background are exact (median of identical values).
  EXPECT_EQ(test::mean_abs_diff(plate.image, clip.background, plate.observed), 0.0);
  // The sphere's path covers some pixels in every frame: those are inpainted, not left black.
  EXPECT_GT(cv::countNonZero(plate.inpainted), 0);
  EXPECT_LT(test::mean_abs_diff(plate.image, clip.background, plate.inpainted), 30.0);

  // Without the hand mask, the red hand leaks into the plate only where it covers a pixel in
  // the majority of that pixel's uncovered frames; with it, never (checked above: exact).
  const BackgroundPlate no_hand = estimate_plate(
      static_cast<int>(clip.frames.size()), [&](int i) { return clip.frames[i]; }, clip.poses,
      clip.mesh, clip.camera);
  EXPECT_LT(test::psnr(no_hand.image, clip.background, once), db);
}

// Memory bounds: with a small reservoir and every second frame only, the median is still exact
// where it saw the background, and lost poses are skipped.
TEST(Plate, SubsampledFramesAndLostPoses) {
  Clip clip(30);
  clip.poses.poses[4] = std::nullopt;
  PlateOptions options;
  options.samples_per_pixel = 5;
  options.max_frames = 15;
  options.extra_mask = [&](int i) { return clip.hand_mask(i); };
  const BackgroundPlate plate = estimate_plate(
      static_cast<int>(clip.frames.size()), [&](int i) { return clip.frames[i]; }, clip.poses,
      clip.mesh, clip.camera, options);
  EXPECT_EQ(plate.frames_used, 14);  // frames 0, 2, ..., 28 without the lost frame 4
  EXPECT_EQ(test::mean_abs_diff(plate.image, clip.background, plate.observed), 0.0);
  EXPECT_GE(test::psnr(plate.image, clip.background, clip.uncovered_once()), 30.0);
}

TEST(Plate, MaxFramesAsLargeAsIntUsesEveryFrame) {
  // "No limit" as INT_MAX: the subsampling step is 1 (its rounding once overflowed to 0, and
  // the frame loop never advanced).
  Clip clip(6);
  PlateOptions options;
  options.max_frames = std::numeric_limits<int>::max();
  int reads = 0;
  const BackgroundPlate plate = estimate_plate(
      static_cast<int>(clip.frames.size()),
      [&](int i) {
        ++reads;
        return clip.frames[static_cast<size_t>(i)];
      },
      clip.poses, clip.mesh, clip.camera, options);
  EXPECT_EQ(plate.frames_used, 6);
  EXPECT_EQ(reads, 6);
}

// Footage on disk (an image sequence) and masks on disk (`background.remove` pattern).
TEST(Plate, FromFootageAndMaskFiles) {
  const Clip clip(12);
  test::TempDir dir;
  std::filesystem::create_directories(dir / "masks");
  std::filesystem::create_directories(dir / "frames");
  for (size_t i = 0; i < clip.frames.size(); ++i) {
    char name[64];
    std::snprintf(name, sizeof name, "%04zu.png", i + 1);
    cv::imwrite((dir / "frames" / "").string() + name, clip.frames[i]);
    cv::imwrite((dir / "masks" / "").string() + name, clip.hand_mask(static_cast<int>(i)));
  }
  Footage footage = Footage::open_sequence((dir / "frames" / "%04d.png").string());
  ASSERT_EQ(footage.frame_count(), 12);
  const MaskSequence masks((dir / "masks" / "%04d.png").string(),
                           {clip.camera.width, clip.camera.height});
  EXPECT_EQ(masks.first_index(), 1);
  EXPECT_EQ(cv::countNonZero(masks.mask(4) != clip.hand_mask(4)), 0);
  EXPECT_TRUE(masks.mask(99).empty());
  PlateOptions options;
  options.extra_mask = [&](int i) { return masks.mask(i); };
  const BackgroundPlate plate =
      estimate_plate(footage, clip.poses, clip.mesh, clip.camera, options);
  EXPECT_EQ(test::mean_abs_diff(plate.image, clip.background, plate.observed), 0.0);
  EXPECT_THROW(MaskSequence("masks/none.png", {4, 4}, 0), InputError);
  EXPECT_THROW(MaskSequence((dir / "nothing_%d.png").string(), {4, 4}), InputError);
}

// A single image: nothing is ever uncovered, the object is inpainted.
TEST(Plate, SingleImageIsInpainted) {
  const Clip clip(2);
  PoseTrack one;
  one.poses.push_back(clip.poses.poses[1]);
  const BackgroundPlate plate = estimate_plate(
      1, [&](int) { return clip.frames[1]; }, one, clip.mesh, clip.camera);
  const cv::Mat object = clip.coverage[1] > 0.0f;
  EXPECT_EQ(cv::countNonZero(object & ~plate.inpainted), 0);
  // The inpainted disc is filled from its surroundings: no black, and roughly the background.
  EXPECT_LT(test::mean_abs_diff(plate.image, clip.background, plate.inpainted), 40.0);
  cv::Mat grey;
  cv::cvtColor(plate.image, grey, cv::COLOR_BGR2GRAY);
  double lowest = 0.0;
  cv::minMaxLoc(grey, &lowest, nullptr, nullptr, nullptr, plate.inpainted);
  EXPECT_GT(lowest, 20.0);
  // Outside, the image itself (the hand included: it was not masked).
  EXPECT_EQ(test::mean_abs_diff(plate.image, clip.frames[1], plate.observed), 0.0);
}

TEST(Plate, RejectsBadInput) {
  const Clip clip(2);
  PoseTrack lost;
  lost.poses = {std::nullopt, std::nullopt};
  const auto frame = [&](int i) { return clip.frames[i]; };
  EXPECT_THROW(estimate_plate(2, frame, lost, clip.mesh, clip.camera), InputError);
  PoseTrack short_track;
  short_track.poses.push_back(clip.poses.poses[0]);
  EXPECT_THROW(estimate_plate(2, frame, short_track, clip.mesh, clip.camera), InputError);
  EXPECT_THROW(
      estimate_plate(
          2, [](int) { return cv::Mat(10, 10, CV_8UC3); }, clip.poses, clip.mesh, clip.camera),
      InputError);
  test::TempDir dir;
  EXPECT_THROW(load_plate(dir / "missing.png", {320, 240}), InputError);
  cv::imwrite((dir / "small.png").string(), cv::Mat(10, 10, CV_8UC3, cv::Scalar::all(9)));
  EXPECT_THROW(load_plate(dir / "small.png", {320, 240}), InputError);
  EXPECT_EQ(load_plate(dir / "small.png", {10, 10}).at<cv::Vec3b>(3, 3), cv::Vec3b(9, 9, 9));
}

}  // namespace
}  // namespace pbve
