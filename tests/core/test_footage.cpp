#include "pbve/core/footage.hpp"

#include <cmath>
#include <string>
#include <vector>

#include <gtest/gtest.h>
#include <opencv2/imgcodecs.hpp>
#include <opencv2/imgproc.hpp>
#include <opencv2/videoio.hpp>

#include "pbve/core/error.hpp"
#include "support/test_util.hpp"

namespace {

namespace fs = std::filesystem;
using pbve::Footage;
using pbve::VideoWriter;
using pbve::test::TempDir;
using pbve::test::write_text;

const cv::Size kSize(64, 48);
constexpr double kFps = 25.0;
constexpr int kFrames = 40;  // more than the reader's forward-grab distance, so seeks happen

/// Frame `k` of a synthetic clip: a smooth gradient, a bright square whose position moves with
/// k and a k-dependent tint, so that frames stay distinguishable after lossy compression.
cv::Mat synthetic_frame(int k) {
  cv::Mat img(kSize, CV_8UC3);
  for (int y = 0; y < kSize.height; ++y)
    for (int x = 0; x < kSize.width; ++x)
      img.at<cv::Vec3b>(y, x) = cv::Vec3b(static_cast<uchar>(3 * x), static_cast<uchar>(4 * y),
                                          static_cast<uchar>((5 * k) % 200));
  const int px = (k * 7) % (kSize.width - 12), py = (k * 5) % (kSize.height - 12);
  cv::rectangle(img, cv::Rect(px, py, 12, 12), cv::Scalar(255, 255, 255), cv::FILLED);
  return img;
}

std::vector<cv::Mat> synthetic_clip(int n = kFrames) {
  std::vector<cv::Mat> frames;
  for (int k = 0; k < n; ++k) frames.push_back(synthetic_frame(k));
  return frames;
}

void write_clip(const fs::path& path, const std::vector<cv::Mat>& frames) {
  VideoWriter writer(path, kFps, kSize);
  for (const auto& f : frames) writer.write(f);
  EXPECT_EQ(writer.frames_written(), static_cast<int>(frames.size()));
  writer.close();
}

double mean_abs_diff(const cv::Mat& a, const cv::Mat& b) {
  return cv::norm(a, b, cv::NORM_L1) / static_cast<double>(a.total() * a.channels());
}

/// Index of the synthetic frame closest to `img`.
int closest_frame(const cv::Mat& img, const std::vector<cv::Mat>& frames) {
  int best = -1;
  double best_d = 1e300;
  for (int k = 0; k < static_cast<int>(frames.size()); ++k) {
    const double d = mean_abs_diff(img, frames[k]);
    if (d < best_d) best_d = d, best = k;
  }
  return best;
}

bool identical(const cv::Mat& a, const cv::Mat& b) {
  return a.size() == b.size() && a.type() == b.type() && cv::norm(a, b, cv::NORM_INF) == 0.0;
}

// ---- video round trip for every codec ---------------------------------------------------------

class VideoRoundTrip : public ::testing::TestWithParam<std::string> {};

TEST_P(VideoRoundTrip, WriteThenReadBack) {
  TempDir dir;
  const fs::path path = dir / ("clip" + GetParam());
  const auto clip = synthetic_clip();
  write_clip(path, clip);
  ASSERT_TRUE(fs::exists(path));
  EXPECT_FALSE(fs::exists(pbve::partial_path(path)));

  Footage footage = Footage::open_video(path);
  EXPECT_EQ(footage.frame_count(), kFrames);
  EXPECT_NEAR(footage.fps(), kFps, 1e-6);
  EXPECT_EQ(footage.size(), kSize);
  EXPECT_EQ(footage.source(), path.string());
  for (int k = 0; k < kFrames; ++k) {
    const cv::Mat f = footage.frame(k);
    ASSERT_EQ(f.type(), CV_8UC3);
    ASSERT_EQ(f.size(), kSize);
    // Lossy codecs blur, but every decoded frame is still nearest to its own source frame.
    EXPECT_EQ(closest_frame(f, clip), k);
  }
}

TEST_P(VideoRoundTrip, RandomAccessMatchesSequential) {
  TempDir dir;
  const fs::path path = dir / ("clip" + GetParam());
  write_clip(path, synthetic_clip());
  Footage footage = Footage::open_video(path);
  std::vector<cv::Mat> sequential;
  for (int k = 0; k < footage.frame_count(); ++k) sequential.push_back(footage.frame(k));
  ASSERT_EQ(static_cast<int>(sequential.size()), kFrames);
  // Backwards, far forwards, repeated and near-forward requests.
  for (int k : {39, 0, 37, 5, 5, 20, 2, 39, 1, 38, 12, 13, 0}) {
    EXPECT_TRUE(identical(footage.frame(k), sequential[k])) << "frame " << k;
  }
  // A fresh reader whose first request is a far seek.
  Footage fresh = Footage::open_video(path);
  EXPECT_TRUE(identical(fresh.frame(33), sequential[33]));
  EXPECT_THROW(fresh.frame(kFrames), std::out_of_range);
  EXPECT_THROW(fresh.frame(-1), std::out_of_range);
}

INSTANTIATE_TEST_SUITE_P(Codecs, VideoRoundTrip, ::testing::Values(".avi", ".mkv", ".mp4"),
                         [](const auto& info) { return info.param.substr(1); });

TEST(Footage, FrameCountIsWhatDecodesNotWhatTheHeaderSays) {
  TempDir dir;
  const fs::path path = dir / "truncated.avi";
  const auto clip = synthetic_clip();
  write_clip(path, clip);
  // Cut the file in half: the AVI header still announces all frames.
  fs::resize_file(path, fs::file_size(path) / 2);
  {
    cv::VideoCapture capture(path.string(), cv::CAP_FFMPEG);
    ASSERT_TRUE(capture.isOpened());
    ASSERT_EQ(static_cast<int>(capture.get(cv::CAP_PROP_FRAME_COUNT)), kFrames);
  }
  Footage footage = Footage::open_video(path);
  const int n = footage.frame_count();
  EXPECT_GT(n, 0);
  EXPECT_LT(n, kFrames);
  // The cut may fall inside the last frame, which then decodes only partly.
  EXPECT_EQ(footage.frame(n - 1).size(), kSize);
  for (int k = n - 2; k >= 0; k -= 3) EXPECT_EQ(closest_frame(footage.frame(k), clip), k);
  EXPECT_THROW(footage.frame(n), std::out_of_range);
}

TEST(VideoWriter, Ffv1IsLossless) {
  TempDir dir;
  const fs::path path = dir / "lossless.mkv";
  const auto clip = synthetic_clip(6);
  write_clip(path, clip);
  Footage footage = Footage::open_video(path);
  ASSERT_EQ(footage.frame_count(), 6);
  for (int k = 0; k < 6; ++k) EXPECT_TRUE(identical(footage.frame(k), clip[k])) << "frame " << k;
}

TEST(VideoWriter, DestroyedWithoutCloseLeavesNothing) {
  TempDir dir;
  const fs::path path = dir / "unfinished.avi";
  {
    VideoWriter writer(path, kFps, kSize);
    writer.write(synthetic_frame(0));
    EXPECT_EQ(writer.temporary_path(), pbve::partial_path(path));
    EXPECT_TRUE(fs::exists(writer.temporary_path()));
    EXPECT_FALSE(fs::exists(path));
  }
  EXPECT_FALSE(fs::exists(path));
  EXPECT_FALSE(fs::exists(pbve::partial_path(path)));
  EXPECT_TRUE(fs::is_empty(dir.path()));
}

TEST(VideoWriter, CloseLeavesOnlyTheTarget) {
  TempDir dir;
  const fs::path path = dir / "done.mkv";
  VideoWriter writer(path, kFps, kSize);
  writer.write(synthetic_frame(0));
  writer.close();
  EXPECT_TRUE(fs::exists(path));
  EXPECT_FALSE(fs::exists(writer.temporary_path()));
  EXPECT_EQ(std::distance(fs::directory_iterator(dir.path()), fs::directory_iterator{}), 1);
  EXPECT_THROW(writer.write(synthetic_frame(1)), std::logic_error);
}

TEST(VideoWriter, RejectsFramesOfWrongSizeOrType) {
  TempDir dir;
  VideoWriter writer(dir / "v.avi", kFps, kSize);
  EXPECT_THROW(writer.write(cv::Mat(kSize.height + 1, kSize.width, CV_8UC3, cv::Scalar::all(0))),
               std::invalid_argument);
  EXPECT_THROW(writer.write(cv::Mat(kSize, CV_8UC1, cv::Scalar::all(0))), std::invalid_argument);
  EXPECT_THROW(writer.write(cv::Mat(kSize, CV_32FC3, cv::Scalar::all(0))), std::invalid_argument);
  EXPECT_EQ(writer.frames_written(), 0);
}

// ---- image sequences and single images --------------------------------------------------------

TEST(Footage, ImageSequenceFromOne) {
  TempDir dir;
  fs::create_directories(dir / "frames");
  const auto clip = synthetic_clip(5);
  for (int k = 0; k < 5; ++k) {
    char name[32];
    std::snprintf(name, sizeof name, "frames/%04d.png", k + 1);
    ASSERT_TRUE(cv::imwrite((dir / name).string(), clip[k]));
  }
  const std::string pattern = (dir / "frames/%04d.png").string();
  Footage footage = Footage::open_sequence(pattern, 24.0);
  EXPECT_EQ(footage.frame_count(), 5);
  EXPECT_EQ(footage.fps(), 24.0);
  EXPECT_EQ(footage.size(), kSize);
  EXPECT_EQ(footage.source(), pattern);
  for (int k : {0, 1, 2, 3, 4, 2, 0}) EXPECT_TRUE(identical(footage.frame(k), clip[k])) << k;
  EXPECT_THROW(footage.frame(5), std::out_of_range);
}

TEST(Footage, ImageSequenceFromZeroConvertsGray) {
  TempDir dir;
  cv::Mat gray(kSize, CV_8UC1);
  for (int k = 0; k < 3; ++k) {
    gray.setTo(cv::Scalar(40 * k + 10));
    ASSERT_TRUE(cv::imwrite((dir / ("img_" + std::to_string(k) + ".png")).string(), gray));
  }
  Footage footage = Footage::open_sequence((dir / "img_%d.png").string());
  EXPECT_EQ(footage.frame_count(), 3);
  EXPECT_EQ(footage.fps(), 30.0);
  const cv::Mat f = footage.frame(2);
  ASSERT_EQ(f.type(), CV_8UC3);
  EXPECT_EQ(f.at<cv::Vec3b>(5, 5), cv::Vec3b(90, 90, 90));
}

TEST(Footage, SingleImageRepeated) {
  TempDir dir;
  const fs::path path = dir / "photo.png";
  cv::Mat bgra(kSize, CV_8UC4, cv::Scalar(10, 20, 30, 255));
  ASSERT_TRUE(cv::imwrite(path.string(), bgra));
  Footage footage = Footage::open_image(path, 7, 12.0);
  EXPECT_EQ(footage.frame_count(), 7);
  EXPECT_EQ(footage.fps(), 12.0);
  EXPECT_EQ(footage.size(), kSize);
  const cv::Mat expected(kSize, CV_8UC3, cv::Scalar(10, 20, 30));
  for (int k : {0, 6, 3}) EXPECT_TRUE(identical(footage.frame(k), expected)) << k;
  // Frames are independent copies: drawing on one does not change the next.
  cv::Mat f = footage.frame(1);
  f.setTo(cv::Scalar::all(0));
  EXPECT_TRUE(identical(footage.frame(1), expected));
  EXPECT_THROW(footage.frame(7), std::out_of_range);
}

// ---- bad input: InputError naming the file ----------------------------------------------------

/// Runs `fn`, expects an InputError whose message starts with `file` and contains `fragment`.
template <class Fn>
void expect_input_error(Fn&& fn, const std::string& file, const std::string& fragment) {
  try {
    fn();
    FAIL() << "expected InputError containing '" << fragment << "'";
  } catch (const pbve::InputError& e) {
    const std::string what = e.what();
    EXPECT_EQ(e.file().string(), file);
    EXPECT_EQ(what.rfind(file + ":", 0), 0u) << what;
    EXPECT_NE(what.find(fragment), std::string::npos) << what;
  }
}

TEST(FootageBadInput, MissingVideo) {
  TempDir dir;
  const fs::path path = dir / "nope.mp4";
  expect_input_error([&] { Footage::open_video(path); }, path.string(), "not found");
}

TEST(FootageBadInput, TextFileNamedMp4) {
  TempDir dir;
  const fs::path path = write_text(dir / "notes.mp4", "this is not a video\n");
  expect_input_error([&] { Footage::open_video(path); }, path.string(), "video");
}

TEST(FootageBadInput, EmptyImageSequence) {
  TempDir dir;
  const std::string pattern = (dir / "frames_%04d.png").string();
  expect_input_error([&] { Footage::open_sequence(pattern); }, pattern, "empty image sequence");
  expect_input_error([&] { Footage::open_sequence(pattern, 30.0, 7); }, pattern,
                     "frames_0007.png' does not exist");
}

TEST(FootageBadInput, ImageSequenceWithAGap) {
  // A missing frame in the middle is a broken render, not the end of the clip.
  TempDir dir;
  const cv::Mat gray(kSize, CV_8UC1, cv::Scalar(10));
  for (int k : {0, 1, 2, 4})
    ASSERT_TRUE(cv::imwrite((dir / ("img_" + std::to_string(k) + ".png")).string(), gray));
  const std::string pattern = (dir / "img_%d.png").string();
  expect_input_error([&] { Footage::open_sequence(pattern); }, pattern,
                     "the image sequence has a gap: '" + (dir / "img_3.png").string() +
                         "' is missing but '" + (dir / "img_4.png").string() + "' exists");
}

TEST(FootageBadInput, SequencePatternWithoutIntegerField) {
  TempDir dir;
  const std::string pattern = (dir / "frames_%s.png").string();
  expect_input_error([&] { Footage::open_sequence(pattern); }, pattern, "integer field");
}

TEST(FootageBadInput, SingleImageWithZeroFrames) {
  TempDir dir;
  const fs::path path = dir / "photo.png";
  ASSERT_TRUE(cv::imwrite(path.string(), synthetic_frame(0)));
  expect_input_error([&] { Footage::open_image(path, 0); }, path.string(), "at least 1, got 0");
}

TEST(FootageBadInput, MissingAndUnreadableImage) {
  TempDir dir;
  const fs::path missing = dir / "missing.png";
  expect_input_error([&] { Footage::open_image(missing, 3); }, missing.string(), "not found");
  const fs::path text = write_text(dir / "fake.png", "not an image");
  expect_input_error([&] { Footage::open_image(text, 3); }, text.string(), "not a readable image");
}

TEST(FootageBadInput, WriterFolderMissing) {
  TempDir dir;
  const fs::path folder = dir / "no_such_folder";
  expect_input_error([&] { VideoWriter(folder / "out.mp4", kFps, kSize); }, folder.string(),
                     "folder does not exist");
}

TEST(FootageBadInput, WriterUnknownExtensionListsWorkingOnes) {
  TempDir dir;
  const fs::path path = dir / "out.xyz";
  expect_input_error([&] { VideoWriter(path, kFps, kSize); }, path.string(), ".mkv (FFV1)");
  EXPECT_TRUE(fs::is_empty(dir.path()));
}

}  // namespace
