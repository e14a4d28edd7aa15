#pragma once
/// @file
/// Input footage (video, image sequence or a single image) and the video writer.

#include <filesystem>
#include <memory>
#include <string>

#include <opencv2/core.hpp>

#include "pbve/core/files.hpp"

namespace pbve {

/// Read access to input frames (8-bit BGR, as OpenCV). Sequential access decodes each frame
/// once; random access seeks (video) or loads the file (sequence).
class Footage {
 public:
  /// A video file readable by OpenCV's videoio (FFmpeg backend). Throws InputError naming the
  /// file when it is missing, unreadable, or has no decodable frame. The frame count is the
  /// number of frames that decode: the file is decoded once on opening, because the count in
  /// the container's header can be wrong.
  static Footage open_video(const std::filesystem::path& path);
  /// An image sequence given as a printf pattern, e.g. "frames/%04d.png"; frames are numbered
  /// from `first_index` (the first existing of 0 and 1 when -1) until the first missing file.
  /// Throws InputError when a file after it exists (within 1000 numbers): a gap, not an end.
  static Footage open_sequence(const std::string& pattern, double fps = 30.0, int first_index = -1);
  /// A single image repeated `frames` times (the paper's single-picture mode).
  static Footage open_image(const std::filesystem::path& path, int frames, double fps = 30.0);

  /// A moved-from Footage may only be assigned to or destroyed.
  Footage(Footage&&) noexcept;
  Footage& operator=(Footage&&) noexcept;
  ~Footage();

  int frame_count() const;
  double fps() const;
  cv::Size size() const;
  /// Frame `index` (0-based), 8-bit BGR. Throws std::out_of_range for a bad index and
  /// InputError when the frame cannot be decoded.
  cv::Mat frame(int index);
  /// Where the frames come from (file or pattern), for messages.
  const std::string& source() const;

 private:
  struct Impl;
  explicit Footage(std::unique_ptr<Impl> impl);
  std::unique_ptr<Impl> m_impl;
};

/// Whether `file` is a frame of the image sequence `pattern` (as Footage::open_sequence() reads
/// it: "frames/%04d.png"), whether or not it exists yet, through any spelling or link.
bool in_image_sequence(const std::filesystem::path& file, const std::string& pattern);

/// Writes frames to a video file. Frames go to a temporary name beside the target
/// ("name.partial.ext") which is renamed to the target by close(); a writer destroyed
/// without close() removes the temporary file, so no partial output is left under the
/// final name. The codec is chosen by extension: .mp4 -> mp4v (or avc1), .avi -> MJPG,
/// .mkv -> FFV1 (lossless).
class VideoWriter {
 public:
  /// Throws InputError naming the file if the folder is not writable or no codec for the
  /// extension is available (the message lists the extensions that work).
  VideoWriter(const std::filesystem::path& path, double fps, cv::Size size);
  /// Throws InputError naming the file when no codec is known for its extension (the
  /// constructor's check, for callers that check their outputs before any work).
  static void check_extension(const std::filesystem::path& path);
  VideoWriter(const VideoWriter&) = delete;
  VideoWriter& operator=(const VideoWriter&) = delete;
  ~VideoWriter();

  /// Appends a frame (8-bit BGR of the writer's size).
  void write(const cv::Mat& frame);
  /// Finishes the file and renames it to the target path.
  void close();
  int frames_written() const { return m_frames; }
  const std::filesystem::path& path() const { return m_path; }
  const std::filesystem::path& temporary_path() const { return m_tmp; }

 private:
  std::filesystem::path m_path;
  std::filesystem::path m_tmp;
  cv::Size m_size;
  int m_frames = 0;
  struct Impl;
  std::unique_ptr<Impl> m_impl;
};

}  // namespace pbve
