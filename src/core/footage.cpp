#include "pbve/core/footage.hpp"

#include <algorithm>
#include <cctype>
#include <charconv>
#include <cmath>
#include <cstdio>
#include <stdexcept>
#include <system_error>
#include <utility>
#include <vector>

#include <unistd.h>

#include <opencv2/imgcodecs.hpp>
#include <opencv2/imgproc.hpp>
#include <opencv2/videoio.hpp>

#include "pbve/core/error.hpp"

namespace fs = std::filesystem;

namespace pbve {

namespace {

/// Converts a decoded image to 8-bit BGR (grayscale and alpha are converted, deeper
/// images scaled). Returns an empty Mat for an empty input.
cv::Mat to_bgr8(const cv::Mat& in) {
  if (in.empty()) return {};
  cv::Mat img = in;
  if (img.depth() != CV_8U) {
    cv::Mat scaled;
    const double scale = img.depth() == CV_16U   ? 1.0 / 257.0
                         : img.depth() == CV_32F ? 255.0
                         : img.depth() == CV_64F ? 255.0
                                                 : 1.0;
    img.convertTo(scaled, CV_MAKETYPE(CV_8U, img.channels()), scale);
    img = scaled;
  }
  cv::Mat out;
  switch (img.channels()) {
    case 1:
      cv::cvtColor(img, out, cv::COLOR_GRAY2BGR);
      return out;
    case 4:
      cv::cvtColor(img, out, cv::COLOR_BGRA2BGR);
      return out;
    case 3:
      return img;
    default:
      return {};
  }
}

void require_fps(double fps, const std::string& source) {
  if (!std::isfinite(fps) || fps <= 0.0)
    throw InputError("frame rate must be a positive number, got " + std::to_string(fps), source, 0,
                     "fps");
}

std::string size_text(cv::Size s) {
  return std::to_string(s.width) + "x" + std::to_string(s.height);
}

/// A printf pattern with exactly one integer field ("%d", "%04d", ...), split so that only
/// that field is ever formatted (a user's pattern is never passed to printf whole).
struct SequencePattern {
  std::string prefix, spec, suffix;

  static SequencePattern parse(const std::string& pattern) {
    SequencePattern p;
    std::string* target = &p.prefix;
    int fields = 0;
    for (std::size_t i = 0; i < pattern.size(); ++i) {
      const char c = pattern[i];
      if (c != '%') {
        target->push_back(c);
        continue;
      }
      if (i + 1 < pattern.size() && pattern[i + 1] == '%') {
        target->push_back('%');
        ++i;
        continue;
      }
      std::size_t j = i + 1;
      while (j < pattern.size() && pattern[j] == '0') ++j;
      while (j < pattern.size() && std::isdigit(static_cast<unsigned char>(pattern[j]))) ++j;
      if (j >= pattern.size() || (pattern[j] != 'd' && pattern[j] != 'i') || ++fields > 1 ||
          j - i > 8)
        throw InputError(
            "an image sequence pattern needs exactly one integer field such as %04d, e.g. "
            "'frames/%04d.png'",
            pattern);
      p.spec = pattern.substr(i, j - i) + "d";
      target = &p.suffix;
      i = j;
    }
    if (fields != 1)
      throw InputError(
          "an image sequence pattern needs exactly one integer field such as %04d, e.g. "
          "'frames/%04d.png'",
          pattern);
    return p;
  }

  std::string file(int index) const {
    char buf[32];
    std::snprintf(buf, sizeof buf, spec.c_str(), index);
    return prefix + buf + suffix;
  }
};

}  // namespace

bool in_image_sequence(const std::filesystem::path& file, const std::string& pattern) {
  if (pattern.empty() || file.empty()) return false;
  // The number the file's name would carry in the pattern's file name, then whether the
  // pattern's file of that number is this file (through any spelling or link).
  SequencePattern name_pattern, full;
  try {
    name_pattern = SequencePattern::parse(fs::path(pattern).filename().string());
    full = SequencePattern::parse(pattern);
  } catch (const InputError&) {
    return false;  // not a pattern (Footage::open_sequence() says why), or a field in a folder
  }
  const std::string name = file.filename().string();
  const std::string& pre = name_pattern.prefix;
  const std::string& suf = name_pattern.suffix;
  if (name.size() <= pre.size() + suf.size() || name.compare(0, pre.size(), pre) != 0 ||
      name.compare(name.size() - suf.size(), suf.size(), suf) != 0)
    return false;
  const std::string digits = name.substr(pre.size(), name.size() - pre.size() - suf.size());
  int index = 0;
  const auto [end, ec] = std::from_chars(digits.data(), digits.data() + digits.size(), index);
  if (ec != std::errc() || end != digits.data() + digits.size()) return false;
  return same_file(file, full.file(index));
}

namespace {

/// Frames grabbed forward rather than seeking when the target is this close ahead.
constexpr int kMaxForwardGrab = 32;

}  // namespace

struct Footage::Impl {
  enum class Kind { video, sequence, image };
  Kind kind = Kind::video;
  std::string source;
  double fps = 30.0;
  cv::Size size;
  int count = 0;

  // Video: the capture and the index of the frame its next read() returns.
  fs::path path;
  cv::VideoCapture capture;
  int next_index = 0;

  // Sequence.
  SequencePattern pattern;
  int first_index = 0;

  // Image, or the last decoded frame (so repeated requests decode once).
  cv::Mat image;
  int cached_index = -1;
  cv::Mat cached;

  void reopen() {
    capture.release();
    if (!capture.open(path.string(), cv::CAP_FFMPEG))
      throw InputError("cannot reopen the video", path);
    next_index = 0;
  }

  /// Positions the capture so that its next read() returns frame `index`.
  void position_video(int index) {
    if (index == next_index) return;
    if (index > next_index && index - next_index <= kMaxForwardGrab) {
      while (next_index < index) {
        if (!capture.grab())
          throw InputError("cannot decode frame " + std::to_string(next_index), path);
        ++next_index;
      }
      return;
    }
    // Seek, then verify where the decoder landed; fall back to decoding from the start.
    if (capture.set(cv::CAP_PROP_POS_FRAMES, index) &&
        static_cast<int>(std::lround(capture.get(cv::CAP_PROP_POS_FRAMES))) == index) {
      next_index = index;
      return;
    }
    reopen();
    while (next_index < index) {
      if (!capture.grab())
        throw InputError("cannot decode frame " + std::to_string(next_index), path);
      ++next_index;
    }
  }

  cv::Mat decode(int index) {
    switch (kind) {
      case Kind::image:
        return image;
      case Kind::sequence: {
        const std::string file = pattern.file(first_index + index);
        cv::Mat img = to_bgr8(cv::imread(file, cv::IMREAD_UNCHANGED));
        if (img.empty()) throw InputError("cannot read the image", file);
        if (img.size() != size)
          throw InputError("image size " + size_text(img.size()) +
                               " differs from the sequence's first image (" + size_text(size) + ")",
                           file);
        return img;
      }
      case Kind::video: {
        position_video(index);
        cv::Mat raw;
        if (!capture.read(raw) || raw.empty()) {
          // The position is unknown after a failed read; start over next time.
          next_index = -1;
          throw InputError("cannot decode frame " + std::to_string(index), path);
        }
        ++next_index;
        cv::Mat img = to_bgr8(raw);
        if (img.size() != size)
          throw InputError("frame " + std::to_string(index) + " has size " + size_text(img.size()) +
                               ", the video's first frame " + size_text(size),
                           path);
        return img;
      }
    }
    return {};
  }
};

Footage::Footage(std::unique_ptr<Impl> impl) : m_impl(std::move(impl)) {}
Footage::Footage(Footage&&) noexcept = default;
Footage& Footage::operator=(Footage&&) noexcept = default;
Footage::~Footage() = default;

Footage Footage::open_video(const std::filesystem::path& path) {
  std::error_code ec;
  if (!fs::exists(path, ec)) throw InputError("video file not found", path);
  if (!fs::is_regular_file(path, ec)) throw InputError("not a regular file", path);
  auto impl = std::make_unique<Impl>();
  impl->kind = Impl::Kind::video;
  impl->path = path;
  impl->source = path.string();
  if (!impl->capture.open(path.string(), cv::CAP_FFMPEG))
    throw InputError("not a readable video: OpenCV/FFmpeg cannot open it, no decodable frame",
                     path);

  // The container's frame count (CAP_PROP_FRAME_COUNT) is an estimate that can be wrong, so
  // count the decodable frames: the first is decoded fully, the rest only grabbed.
  cv::Mat first;
  if (!impl->capture.read(first) || first.empty())
    throw InputError("no decodable frame: not a video, or a codec missing here", path);
  first = to_bgr8(first);
  if (first.empty()) throw InputError("unsupported pixel format in the first frame", path);
  int count = 1;
  while (impl->capture.grab()) ++count;

  impl->size = first.size();
  impl->count = count;
  const double fps = impl->capture.get(cv::CAP_PROP_FPS);
  impl->fps = std::isfinite(fps) && fps > 0.0 ? fps : 30.0;
  impl->cached_index = 0;
  impl->cached = first;
  impl->reopen();
  return Footage(std::move(impl));
}

// How far past a sequence's first missing file open_sequence() looks for a later one.
constexpr int kSequenceGapLookahead = 1000;

Footage Footage::open_sequence(const std::string& pattern, double fps, int first_index) {
  require_fps(fps, pattern);
  auto impl = std::make_unique<Impl>();
  impl->kind = Impl::Kind::sequence;
  impl->source = pattern;
  impl->fps = fps;
  impl->pattern = SequencePattern::parse(pattern);
  std::error_code ec;
  const auto exists = [&](int i) { return fs::is_regular_file(impl->pattern.file(i), ec); };
  if (first_index < 0) {
    if (exists(0)) {
      first_index = 0;
    } else if (exists(1)) {
      first_index = 1;
    } else {
      throw InputError("empty image sequence: neither '" + impl->pattern.file(0) + "' nor '" +
                           impl->pattern.file(1) + "' exists",
                       pattern);
    }
  } else if (!exists(first_index)) {
    throw InputError(
        "empty image sequence: '" + impl->pattern.file(first_index) + "' does not exist", pattern);
  }
  int count = 1;
  while (exists(first_index + count)) ++count;
  // The sequence ends at its first missing file: a later file means a gap, not an end (a
  // shorter clip would be edited without a word).
  for (int k = first_index + count + 1; k <= first_index + count + kSequenceGapLookahead; ++k)
    if (exists(k))
      throw InputError("the image sequence has a gap: '" + impl->pattern.file(first_index + count) +
                           "' is missing but '" + impl->pattern.file(k) + "' exists",
                       pattern);
  impl->first_index = first_index;
  impl->count = count;

  const std::string first_file = impl->pattern.file(first_index);
  cv::Mat first = to_bgr8(cv::imread(first_file, cv::IMREAD_UNCHANGED));
  if (first.empty()) throw InputError("not a readable image", first_file);
  impl->size = first.size();
  impl->cached_index = 0;
  impl->cached = first;
  return Footage(std::move(impl));
}

Footage Footage::open_image(const std::filesystem::path& path, int frames, double fps) {
  if (frames < 1)
    throw InputError("the number of frames must be at least 1, got " + std::to_string(frames), path,
                     0, "frames");
  require_fps(fps, path.string());
  std::error_code ec;
  if (!fs::exists(path, ec)) throw InputError("image file not found", path);
  cv::Mat img = to_bgr8(cv::imread(path.string(), cv::IMREAD_UNCHANGED));
  if (img.empty()) throw InputError("not a readable image", path);
  auto impl = std::make_unique<Impl>();
  impl->kind = Impl::Kind::image;
  impl->source = path.string();
  impl->path = path;
  impl->fps = fps;
  impl->count = frames;
  impl->size = img.size();
  impl->image = img;
  return Footage(std::move(impl));
}

int Footage::frame_count() const {
  return m_impl->count;
}
double Footage::fps() const {
  return m_impl->fps;
}
cv::Size Footage::size() const {
  return m_impl->size;
}
const std::string& Footage::source() const {
  return m_impl->source;
}

cv::Mat Footage::frame(int index) {
  Impl& d = *m_impl;
  if (index < 0 || index >= d.count)
    throw std::out_of_range("frame " + std::to_string(index) + " out of range [0, " +
                            std::to_string(d.count) + ") of " + d.source);
  if (d.kind == Impl::Kind::image) return d.image.clone();
  if (index != d.cached_index) {
    if (d.kind == Impl::Kind::video && d.next_index < 0) d.reopen();
    d.cached = d.decode(index);
    d.cached_index = index;
  }
  return d.cached.clone();
}

// ---------------------------------------------------------------------------------------------
// VideoWriter

namespace {

struct CodecChoice {
  const char* extension;
  std::vector<const char*> fourccs;
};

const std::vector<CodecChoice>& codec_table() {
  static const std::vector<CodecChoice> table = {
      {".mp4", {"mp4v", "avc1"}},
      {".avi", {"MJPG"}},
      {".mkv", {"FFV1"}},
  };
  return table;
}

int fourcc_of(const char* c) {
  return cv::VideoWriter::fourcc(c[0], c[1], c[2], c[3]);
}

std::string lower(std::string s) {
  for (char& c : s) c = static_cast<char>(std::tolower(static_cast<unsigned char>(c)));
  return s;
}

/// The extensions (with codec) for which a writer opens on this machine, probed in the
/// system's temporary folder.
std::string working_extensions() {
  std::string list;
  std::error_code ec;
  const fs::path dir = fs::temp_directory_path(ec);
  for (const auto& choice : codec_table()) {
    for (const char* fourcc : choice.fourccs) {
      const fs::path probe =
          dir / ("pbve_codec_probe_" + std::to_string(::getpid()) + choice.extension);
      bool ok = false;
      {
        cv::VideoWriter w;
        ok =
            w.open(probe.string(), cv::CAP_FFMPEG, fourcc_of(fourcc), 25.0, cv::Size(64, 64), true);
      }
      fs::remove(probe, ec);
      if (ok) {
        if (!list.empty()) list += ", ";
        list += std::string(choice.extension) + " (" + fourcc + ")";
        break;
      }
    }
  }
  return list.empty() ? "none" : list;
}

const CodecChoice* codec_for(const fs::path& path) {
  const std::string ext = lower(path.extension().string());
  const auto& table = codec_table();
  const auto choice = std::find_if(table.begin(), table.end(),
                                   [&](const CodecChoice& c) { return ext == c.extension; });
  if (choice == table.end())
    throw InputError("no video codec for the extension '" + ext +
                         "'; extensions that work here: " + working_extensions(),
                     path);
  return &*choice;
}

}  // namespace

void VideoWriter::check_extension(const std::filesystem::path& path) {
  codec_for(path);
}

struct VideoWriter::Impl {
  cv::VideoWriter writer;
  bool closed = false;
};

VideoWriter::VideoWriter(const std::filesystem::path& path, double fps, cv::Size size)
    : m_path(path), m_size(size), m_impl(std::make_unique<Impl>()) {
  if (!std::isfinite(fps) || fps <= 0.0)
    throw std::invalid_argument("VideoWriter: frame rate must be positive, got " +
                                std::to_string(fps));
  if (size.width <= 0 || size.height <= 0)
    throw std::invalid_argument("VideoWriter: frame size must be positive, got " + size_text(size));
  std::error_code ec;
  const fs::path folder = path.parent_path().empty() ? fs::path(".") : path.parent_path();
  if (!fs::is_directory(folder, ec))
    throw InputError("cannot write '" + path.filename().string() + "': the folder does not exist",
                     folder);
  if (::access(folder.c_str(), W_OK) != 0)
    throw InputError("cannot write '" + path.filename().string() + "': the folder is not writable",
                     folder);

  const CodecChoice* choice = codec_for(path);
  check_writable(path);
  m_tmp = reserve_partial(path);
  for (const char* fourcc : choice->fourccs) {
    if (m_impl->writer.open(m_tmp.string(), cv::CAP_FFMPEG, fourcc_of(fourcc), fps, size, true))
      return;
  }
  fs::remove(m_tmp, ec);
  std::string tried;
  for (const char* fourcc : choice->fourccs)
    tried += (tried.empty() ? "" : ", ") + std::string(fourcc);
  throw InputError("cannot open a video writer (tried " + tried +
                       "); extensions that work here: " + working_extensions(),
                   path);
}

VideoWriter::~VideoWriter() {
  if (!m_impl || m_impl->closed) return;
  m_impl->writer.release();
  std::error_code ec;
  fs::remove(m_tmp, ec);
}

void VideoWriter::write(const cv::Mat& frame) {
  if (m_impl->closed) throw std::logic_error("VideoWriter::write after close: " + m_path.string());
  if (frame.type() != CV_8UC3)
    throw std::invalid_argument("VideoWriter::write: expected an 8-bit BGR frame (CV_8UC3), got " +
                                cv::typeToString(frame.type()) + " for " + m_path.string());
  if (frame.size() != m_size)
    throw std::invalid_argument("VideoWriter::write: frame size " + size_text(frame.size()) +
                                " differs from the writer's " + size_text(m_size) + " for " +
                                m_path.string());
  m_impl->writer.write(frame);
  ++m_frames;
}

void VideoWriter::close() {
  if (m_impl->closed) return;
  m_impl->writer.release();
  m_impl->closed = true;
  // The encoder reports no write error (a full disk leaves a file without its index): read the
  // finished file back before it takes the final name. Containers store the frame count
  // (.mp4, .avi) or give it from the duration (.mkv, within a frame).
  if (m_frames > 0) {
    cv::VideoCapture check(m_tmp.string(), cv::CAP_FFMPEG);
    const double count = check.isOpened() ? check.get(cv::CAP_PROP_FRAME_COUNT) : 0.0;
    check.release();
    if (!(count >= std::max(1, m_frames - 1))) {
      std::error_code ec;
      fs::remove(m_tmp, ec);
      throw InputError("the video could not be written completely (" + std::to_string(m_frames) +
                           " frames written, " + std::to_string(static_cast<long long>(count)) +
                           " readable; is the disk full?)",
                       m_path);
    }
  }
  commit_partial(m_tmp, m_path);
}

}  // namespace pbve
