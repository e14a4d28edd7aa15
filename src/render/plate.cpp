#include "pbve/render/plate.hpp"

#include <algorithm>
#include <cctype>
#include <cstdio>
#include <string>
#include <vector>

#include <tbb/blocked_range.h>
#include <tbb/parallel_for.h>
#include <opencv2/imgcodecs.hpp>
#include <opencv2/imgproc.hpp>
#include <opencv2/photo.hpp>

#include "pbve/core/error.hpp"
#include "pbve/render/renderer.hpp"
#include "pbve/visibility/ray_scene.hpp"

namespace pbve {
namespace {

void check_frame(const cv::Mat& image, int type, const Camera& camera, const std::string& what) {
  if (image.type() != type || image.cols != camera.width || image.rows != camera.height)
    throw InputError(what + ": expected " + std::to_string(camera.width) + "x" +
                     std::to_string(camera.height) +
                     (type == CV_8UC3 ? " 8-bit BGR" : " 8-bit single-channel") + ", got " +
                     std::to_string(image.cols) + "x" + std::to_string(image.rows) + " with " +
                     std::to_string(image.channels()) + " channel(s)");
}

/// A well-mixed 32-bit hash of (pixel, count): the reservoir's random slot choice, deterministic
/// so that the plate does not change between runs.
inline std::uint32_t mix(std::uint32_t a, std::uint32_t b) {
  std::uint32_t h = a * 0x9E3779B1u ^ (b + 0x7F4A7C15u + (a << 6) + (a >> 2));
  h ^= h >> 16;
  h *= 0x85EBCA6Bu;
  h ^= h >> 13;
  h *= 0xC2B2AE35u;
  h ^= h >> 16;
  return h;
}

/// Median of the first n values (n >= 1); the mean of the two middle values for even n.
inline std::uint8_t median(std::uint8_t* values, int n) {
  const int mid = n / 2;
  std::nth_element(values, values + mid, values + n);
  if (n % 2 == 1) return values[mid];
  const std::uint8_t upper = values[mid];
  const std::uint8_t lower = *std::max_element(values, values + mid);
  return static_cast<std::uint8_t>((lower + upper + 1) / 2);
}

}  // namespace

BackgroundPlate inpaint_plate(const cv::Mat& image, const cv::Mat& remove,
                              double inpaint_radius_px) {
  if (image.empty() || image.type() != CV_8UC3)
    throw InputError("inpaint_plate(): expected an 8-bit BGR image");
  if (remove.size() != image.size() || remove.type() != CV_8UC1)
    throw InputError("inpaint_plate(): the mask must be 8-bit single-channel of the image's size");
  BackgroundPlate plate;
  plate.inpainted = remove != 0;
  plate.observed = remove == 0;
  plate.frames_used = 1;
  if (cv::countNonZero(plate.inpainted) == 0) {
    plate.image = image.clone();
  } else {
    cv::inpaint(image, plate.inpainted, plate.image, inpaint_radius_px, cv::INPAINT_TELEA);
  }
  return plate;
}

BackgroundPlate estimate_plate(int frame_count, const std::function<cv::Mat(int)>& frame,
                               const PoseTrack& poses, const Mesh& mesh, const Camera& camera,
                               const PlateOptions& options) {
  camera.validate();
  if (frame_count < 1) throw InputError("estimate_plate(): the clip has no frame");
  if (poses.size() < frame_count)
    throw InputError("estimate_plate(): " + std::to_string(frame_count) + " frames but only " +
                     std::to_string(poses.size()) + " poses");
  if (options.samples_per_pixel < 1 || options.samples_per_pixel > 255)
    throw InputError("samples_per_pixel must be in [1, 255], got " +
                     std::to_string(options.samples_per_pixel));
  if (options.max_frames < 1) throw InputError("max_frames must be >= 1");
  if (!(options.scale > 0.0) || options.dilate_px < 0)
    throw InputError("scale must be positive and dilate_px >= 0");

  const int width = camera.width, height = camera.height;
  const size_t pixels = static_cast<size_t>(width) * height;
  const int K = options.samples_per_pixel;
  // ceil(frame_count / max_frames), without overflow for a max_frames up to INT_MAX.
  const int step = frame_count > 0 ? 1 + (frame_count - 1) / options.max_frames : 1;
  // Reservoir: K background colours per pixel (pixel-major), and how many frames showed the
  // background at each pixel so far.
  std::vector<std::uint8_t> samples(pixels * K * 3);
  std::vector<std::uint32_t> seen(pixels, 0);

  RayScene scene(mesh.vertices, mesh.triangles);
  cv::Mat mask;
  BackgroundPlate plate;
  for (int f = 0; f < frame_count; f += step) {
    const std::optional<Pose>& pose = poses.poses[f];
    if (!pose) continue;  // the object's whereabouts are unknown in this frame
    const cv::Mat image = frame(f);
    check_frame(image, CV_8UC3, camera, "frame " + std::to_string(f));
    silhouette_mask(scene, pose->apply(mesh.vertices), camera, options.scale, options.dilate_px,
                    mask);
    if (options.extra_mask) {
      const cv::Mat extra = options.extra_mask(f);
      if (!extra.empty()) {
        check_frame(extra, CV_8UC1, camera, "extra mask of frame " + std::to_string(f));
        mask |= (extra != 0);
      }
    }
    ++plate.frames_used;
    tbb::parallel_for(tbb::blocked_range<int>(0, height, 8), [&](const tbb::blocked_range<int>& r) {
      for (int y = r.begin(); y != r.end(); ++y) {
        const cv::Vec3b* row = image.ptr<cv::Vec3b>(y);
        const std::uint8_t* m = mask.ptr<std::uint8_t>(y);
        for (int x = 0; x < width; ++x) {
          if (m[x]) continue;
          const size_t p = static_cast<size_t>(y) * width + x;
          const std::uint32_t n = seen[p]++;
          // Reservoir sampling: keep the first K, then replace a random slot with
          // probability K / (n + 1), so the kept colours are a uniform subset.
          std::uint32_t slot = n;
          if (n >= static_cast<std::uint32_t>(K)) {
            slot = mix(static_cast<std::uint32_t>(p), n) % (n + 1);
            if (slot >= static_cast<std::uint32_t>(K)) continue;
          }
          std::uint8_t* s = &samples[(p * K + slot) * 3];
          s[0] = row[x][0];
          s[1] = row[x][1];
          s[2] = row[x][2];
        }
      }
    });
  }
  if (plate.frames_used == 0)
    throw InputError("estimate_plate(): no frame has a known pose (all are 'lost')");

  cv::Mat median_image(height, width, CV_8UC3, cv::Scalar::all(0));
  plate.observed.create(height, width, CV_8U);
  tbb::parallel_for(tbb::blocked_range<int>(0, height, 8), [&](const tbb::blocked_range<int>& r) {
    std::vector<std::uint8_t> channel(static_cast<size_t>(K));
    for (int y = r.begin(); y != r.end(); ++y) {
      cv::Vec3b* out = median_image.ptr<cv::Vec3b>(y);
      std::uint8_t* obs = plate.observed.ptr<std::uint8_t>(y);
      for (int x = 0; x < width; ++x) {
        const size_t p = static_cast<size_t>(y) * width + x;
        const int n = static_cast<int>(std::min<std::uint32_t>(seen[p], K));
        obs[x] = n > 0 ? 255 : 0;
        if (n == 0) continue;
        for (int c = 0; c < 3; ++c) {
          for (int k = 0; k < n; ++k) channel[k] = samples[(p * K + k) * 3 + c];
          out[x][c] = median(channel.data(), n);
        }
      }
    }
  });
  BackgroundPlate filled =
      inpaint_plate(median_image, plate.observed == 0, options.inpaint_radius_px);
  plate.image = std::move(filled.image);
  plate.inpainted = std::move(filled.inpainted);
  return plate;
}

BackgroundPlate estimate_plate(Footage& footage, const PoseTrack& poses, const Mesh& mesh,
                               const Camera& camera, const PlateOptions& options) {
  return estimate_plate(
      footage.frame_count(), [&](int i) { return footage.frame(i); }, poses, mesh, camera, options);
}

cv::Mat load_plate(const std::filesystem::path& path, cv::Size size) {
  cv::Mat image = cv::imread(path.string(), cv::IMREAD_COLOR);
  if (image.empty()) throw InputError("cannot read the background plate", path);
  if (image.size() != size)
    throw InputError("background plate is " + std::to_string(image.cols) + "x" +
                         std::to_string(image.rows) + ", the footage is " +
                         std::to_string(size.width) + "x" + std::to_string(size.height),
                     path);
  return image;
}

MaskSequence::MaskSequence(std::string pattern, cv::Size size, int first_index)
    : m_pattern(std::move(pattern)), m_size(size), m_first(first_index) {
  // Exactly one integer conversion (%d, %04d, ...) and no other conversion.
  int conversions = 0;
  for (size_t i = 0; i < m_pattern.size(); ++i) {
    if (m_pattern[i] != '%') continue;
    if (i + 1 < m_pattern.size() && m_pattern[i + 1] == '%') {
      ++i;
      continue;
    }
    size_t j = i + 1;
    while (j < m_pattern.size() &&
           (std::isdigit(static_cast<unsigned char>(m_pattern[j])) || m_pattern[j] == '0'))
      ++j;
    if (j >= m_pattern.size() || (m_pattern[j] != 'd' && m_pattern[j] != 'i'))
      throw InputError("mask pattern '" + m_pattern +
                       "' must contain one integer conversion such as %04d");
    ++conversions;
    i = j;
  }
  if (conversions != 1)
    throw InputError("mask pattern '" + m_pattern +
                     "' must contain exactly one integer conversion such as %04d");
  if (m_first < 0) {
    m_first = 0;
    if (!std::filesystem::exists(path(0))) {
      m_first = 1;
      if (!std::filesystem::exists(path(0)))
        throw InputError("no mask file for the first frame (tried index 0 and 1)", m_pattern);
    }
  }
}

std::string MaskSequence::path(int frame) const {
  char buffer[4096];
  std::snprintf(buffer, sizeof buffer, m_pattern.c_str(), m_first + frame);
  return buffer;
}

cv::Mat MaskSequence::mask(int frame) const {
  const std::string file = path(frame);
  if (!std::filesystem::exists(file)) return {};
  const cv::Mat image = cv::imread(file, cv::IMREAD_GRAYSCALE);
  if (image.empty()) throw InputError("cannot read the mask", file);
  if (image.size() != m_size)
    throw InputError("mask is " + std::to_string(image.cols) + "x" + std::to_string(image.rows) +
                         ", the footage is " + std::to_string(m_size.width) + "x" +
                         std::to_string(m_size.height),
                     file);
  return image != 0;
}

}  // namespace pbve
