#include "pbve/track/tracker.hpp"

#include <algorithm>
#include <chrono>
#include <cmath>
#include <fstream>
#include <limits>
#include <map>
#include <numbers>
#include <sstream>
#include <string>
#include <utility>

#include <Eigen/Geometry>
#include <Eigen/SVD>

#include <opencv2/calib3d.hpp>
#include <opencv2/core/eigen.hpp>
#include <opencv2/features2d.hpp>
#include <opencv2/imgproc.hpp>
#include <opencv2/video/tracking.hpp>

#include "pbve/core/error.hpp"
#include "pbve/visibility/ray_scene.hpp"
#include "track/region.hpp"

namespace pbve {

namespace {

using Eigen::Vector2d;
using Eigen::Vector3d;

cv::Mat grey(const cv::Mat& frame) {
  if (frame.channels() == 1) return frame;
  cv::Mat g;
  cv::cvtColor(frame, g, frame.channels() == 4 ? cv::COLOR_BGRA2GRAY : cv::COLOR_BGR2GRAY);
  return g;
}

cv::Mat colour(const cv::Mat& frame) {
  if (frame.channels() == 3) return frame;
  cv::Mat c;
  cv::cvtColor(frame, c, frame.channels() == 4 ? cv::COLOR_BGRA2BGR : cv::COLOR_GRAY2BGR);
  return c;
}

cv::Matx33d camera_matrix(const Camera& c) {
  return {c.fx, 0, c.cx, 0, c.fy, c.cy, 0, 0, 1};
}

void to_cv(const Pose& p, cv::Mat& rvec, cv::Mat& tvec) {
  const Vector3d r = p.rodrigues();
  rvec = (cv::Mat_<double>(3, 1) << r.x(), r.y(), r.z());
  tvec = (cv::Mat_<double>(3, 1) << p.translation.x(), p.translation.y(), p.translation.z());
}

Pose from_cv(const cv::Mat& rvec, const cv::Mat& tvec) {
  return Pose::from_rodrigues({rvec.at<double>(0), rvec.at<double>(1), rvec.at<double>(2)},
                              {tvec.at<double>(0), tvec.at<double>(1), tvec.at<double>(2)});
}

double rotation_angle(const Eigen::Matrix3d& a, const Eigen::Matrix3d& b) {
  const double c = std::clamp(((a.transpose() * b).trace() - 1.0) / 2.0, -1.0, 1.0);
  return std::acos(c);
}

// Corners with their mesh points: pixel in the frame they were found in, point in mesh
// coordinates.
struct Features {
  std::vector<cv::Point2f> pixels;
  std::vector<Vector3d> points;
  size_t size() const { return pixels.size(); }
};

}  // namespace

// Offsets searched along a correspondence line, in segments either way.
constexpr int kLineRange = 5;
// Grid spacing (pixels) of the keyframe view's map.
constexpr int kViewStep = 4;
// Keyframes kept (the first one always).
constexpr size_t kMaxKeyframes = 24;

struct PoseTracker::Impl {
  Mesh mesh;
  Camera camera;
  TrackOptions options;
  RayScene scene;          // mesh coordinates: rays are brought into the mesh frame
  double mesh_size = 1.0;  // bounding box diagonal, mesh units
  std::vector<track_detail::MeshEdge> edges;
  track_detail::ColourModel colours;
  cv::Ptr<cv::ORB> orb;

  bool started = false;
  // Keyframe: its image, depth map (camera z, +infinity off the object) and corners.
  std::vector<cv::Mat> key_pyramid;
  cv::Mat key_grey, key_bgr, key_depth;
  Features key;
  // This frame's occlusion map: 255 where the frame differs from the keyframe's view of the
  // object warped to the predicted pose (an occluder in front of it); empty when unknown.
  cv::Mat occlusion;
  size_t key_initial = 0;
  Pose key_pose;
  int key_generation = 0;  // keyframes between it and the first one (0 for the first)
  int key_index = 0;       // in `keyframes`
  // Every keyframe taken, so that a view seen before is followed from the keyframe nearest to
  // the first (fewest keyframe changes, least drift) instead of the latest.
  struct Keyframe {
    std::vector<cv::Mat> pyramid;
    cv::Mat grey, bgr, depth;
    Features corners;
    Pose pose;
    int generation = 0;
  };
  std::vector<Keyframe> keyframes;
  // Previous frame; its corners are found only when needed.
  cv::Mat prev_grey, prev_bgr;
  std::vector<cv::Mat> prev_pyramid;
  Pose prev_pose, coast;
  // Last frame-to-frame motion in the camera frame: x -> velocity_rotation x +
  // velocity_translation.
  Eigen::Matrix3d velocity_rotation = Eigen::Matrix3d::Identity();
  Eigen::Vector3d velocity_translation = Eigen::Vector3d::Zero();
  bool have_velocity = false;
  bool last_lost = false;
  // Re-detection after a loss: ORB descriptors of keyframe corners with their mesh points.
  cv::Mat landmark_descriptors;
  std::vector<Vector3d> landmark_points;
  std::vector<int> landmark_rows;  // rows of each keyframe's block, oldest first

  Pose extrapolate(const Pose& p) const {
    Pose q;
    q.rotation = velocity_rotation * p.rotation;
    q.translation = velocity_rotation * p.translation + velocity_translation;
    return q;
  }

  std::vector<cv::Mat> pyramid(const cv::Mat& g) const {
    std::vector<cv::Mat> out;
    cv::buildOpticalFlowPyramid(g, out, cv::Size(options.window, options.window),
                                options.pyramid_levels);
    return out;
  }

  // The object's mask under `pose` (its front-facing triangles filled), eroded by `erode`
  // pixels (an odd diameter; 0 = none).
  cv::Mat mask(const Pose& pose, int erode) const {
    cv::Mat m = cv::Mat::zeros(camera.height, camera.width, CV_8U);
    const Vertices v = pose.apply(mesh.vertices);
    std::vector<cv::Point> tri(3);
    for (int f = 0; f < mesh.num_triangles(); ++f) {
      const Vector3d a = v.row(mesh.triangles(f, 0)), b = v.row(mesh.triangles(f, 1)),
                     c = v.row(mesh.triangles(f, 2));
      if (a.z() <= 0 || b.z() <= 0 || c.z() <= 0) continue;
      if ((b - a).cross(c - a).dot(a) >= 0.0) continue;  // turned away
      const Vector3d* p[3] = {&a, &b, &c};
      for (int k = 0; k < 3; ++k) {
        const Vector2d q = camera.project(*p[k]);
        tri[static_cast<size_t>(k)] = cv::Point(static_cast<int>(std::lround(q.x() * 4)),
                                                static_cast<int>(std::lround(q.y() * 4)));
      }
      cv::fillConvexPoly(m, tri, cv::Scalar(255), cv::LINE_8, 2);
    }
    if (erode > 1) {
      const cv::Rect box = cv::boundingRect(m);
      if (box.area() > 0) {
        const cv::Rect roi = (box + cv::Size(2 * erode, 2 * erode) - cv::Point(erode, erode)) &
                             cv::Rect(0, 0, m.cols, m.rows);
        cv::Mat part = m(roi);
        cv::erode(part, part, cv::getStructuringElement(cv::MORPH_ELLIPSE, cv::Size(erode, erode)));
      }
    }
    return m;
  }

  // Mean foreground probability of the colours in a (2r+1)^2 patch.
  double foreground_near(const cv::Mat& bgr, cv::Point2f p, int r) const {
    const int x0 = static_cast<int>(std::lround(p.x)), y0 = static_cast<int>(std::lround(p.y));
    double sum = 0.0;
    int n = 0;
    for (int y = std::max(0, y0 - r); y <= std::min(bgr.rows - 1, y0 + r); ++y)
      for (int x = std::max(0, x0 - r); x <= std::min(bgr.cols - 1, x0 + r); ++x) {
        sum += colours.foreground(bgr.at<cv::Vec3b>(y, x));
        ++n;
      }
    return n > 0 ? sum / n : 0.0;
  }

  // Mesh points of the first hits of the rays through `pixels` under `pose` (triangle -1 for a
  // miss), and the hits themselves.
  std::vector<RayHit> cast(const std::vector<Vector2d>& pixels, const Pose& pose) const {
    const Eigen::Matrix3d rt = pose.rotation.transpose();
    const Vector3d origin = -rt * pose.translation;
    const Eigen::Index n = static_cast<Eigen::Index>(pixels.size());
    Eigen::MatrixX3d o(n, 3), d(n, 3);
    for (Eigen::Index i = 0; i < n; ++i) {
      o.row(i) = origin.transpose();
      d.row(i) = (rt * camera.ray_direction(pixels[static_cast<size_t>(i)])).transpose();
    }
    return scene.intersect(o, d);
  }
  Vector3d hit_point(const RayHit& hit) const {
    const auto t = mesh.triangles.row(hit.triangle);
    const double u = hit.u, v = hit.v;
    return (1 - u - v) * Vector3d(mesh.vertices.row(t(0))) + u * Vector3d(mesh.vertices.row(t(1))) +
           v * Vector3d(mesh.vertices.row(t(2)));
  }

  // Corners of `g` on the object under `pose`, with their mesh points (first hits of the rays
  // through them). With a colour model, corners whose surroundings do not look like the object
  // (an occluder in front of it) are dropped.
  Features detect(const cv::Mat& g, const cv::Mat& bgr, const Pose& pose) const {
    std::vector<cv::Point2f> corners;
    // Keep corners at least half a Lucas-Kanade window inside the silhouette: a window that
    // straddles it sees the static background and drags the flow towards zero.
    const cv::Mat m = mask(pose, options.window | 1);
    const cv::Rect box = cv::boundingRect(m);
    if (box.area() == 0) return {};
    // Searched in the object's box only (the quality level is relative to its best corner).
    const cv::Rect roi = (box + cv::Size(8, 8) - cv::Point(4, 4)) & cv::Rect(0, 0, g.cols, g.rows);
    cv::goodFeaturesToTrack(g(roi), corners, options.max_corners, options.corner_quality,
                            options.corner_distance, m(roi));
    if (corners.empty()) return {};
    for (auto& c : corners) c += cv::Point2f(static_cast<float>(roi.x), static_cast<float>(roi.y));
    cv::cornerSubPix(g, corners, cv::Size(5, 5), cv::Size(-1, -1),
                     cv::TermCriteria(cv::TermCriteria::EPS + cv::TermCriteria::COUNT, 20, 0.01));
    if (options.region && !colours.empty() && !bgr.empty()) {
      std::vector<cv::Point2f> kept;
      for (const auto& c : corners)
        if (foreground_near(bgr, c, 3) >= options.occlusion_threshold) kept.push_back(c);
      corners.swap(kept);
    }
    const Eigen::Matrix3d rt = pose.rotation.transpose();
    const Vector3d origin = -rt * pose.translation;  // camera centre in mesh coordinates
    // Five rays per corner: through it, and half a window left, right, up and down. A corner
    // is kept when the four neighbours land on the plane of its own hit (within 1% of the
    // depth): its window then sees one surface, not an occluding contour (a limb in front of
    // the body) whose two sides move differently.
    const double h = 0.5 * options.window;
    const double offsets[5][2] = {{0, 0}, {-h, 0}, {h, 0}, {0, -h}, {0, h}};
    std::vector<Vector2d> px;
    for (const auto& c : corners)
      for (const auto& off : offsets) px.emplace_back(c.x + off[0], c.y + off[1]);
    const std::vector<RayHit> hits = cast(px, pose);
    Features out;
    for (size_t i = 0; i < corners.size(); ++i) {
      const RayHit& c = hits[5 * i];
      if (c.triangle < 0) continue;
      const Vector3d p = hit_point(c);
      const auto t = mesh.triangles.row(c.triangle);
      const Vector3d n =
          (Vector3d(mesh.vertices.row(t(1))) - Vector3d(mesh.vertices.row(t(0))))
              .cross(Vector3d(mesh.vertices.row(t(2))) - Vector3d(mesh.vertices.row(t(0))));
      bool one_surface = true;
      for (size_t k = 1; k < 5 && one_surface; ++k) {
        const RayHit& q = hits[5 * i + k];
        const Vector3d dir = rt * camera.ray_direction(px[5 * i + k]);
        const double along = n.dot(dir);
        if (q.triangle < 0 || std::abs(along) < 1e-12) {
          one_surface = false;
          break;
        }
        const double t_plane = n.dot(p - origin) / along;
        one_surface = std::abs(static_cast<double>(q.t) - t_plane) <= 0.01 * c.t;
      }
      if (!one_surface) continue;
      out.pixels.push_back(corners[i]);
      out.points.push_back(p);
    }
    return out;
  }

  // Follows `from` (found in the image of `from_pyramid`) into `to_pyramid`, starting at the
  // projections under `predicted`; appends the surviving pairs. Returns the survivors' indices.
  std::vector<size_t> follow(const std::vector<cv::Mat>& from_pyramid, const Features& from,
                             const std::vector<cv::Mat>& to_pyramid, const Pose& predicted,
                             std::vector<cv::Point3d>& object, std::vector<cv::Point2d>& image) {
    std::vector<size_t> kept;
    if (from.size() == 0) return kept;
    std::vector<cv::Point2f> guess(from.size()), back;
    for (size_t i = 0; i < from.size(); ++i) {
      const Vector3d pc = predicted.apply(from.points[i]);
      if (pc.z() <= 0) {
        guess[i] = from.pixels[i];
        continue;
      }
      const Vector2d q = camera.project(pc);
      guess[i] = cv::Point2f(static_cast<float>(q.x()), static_cast<float>(q.y()));
    }
    std::vector<uchar> ok, ok_back;
    std::vector<float> err;
    const cv::Size win(options.window, options.window);
    const cv::TermCriteria term(cv::TermCriteria::COUNT + cv::TermCriteria::EPS, 30, 0.01);
    std::vector<cv::Point2f> to = guess;
    cv::calcOpticalFlowPyrLK(from_pyramid, to_pyramid, from.pixels, to, ok, err, win,
                             options.pyramid_levels, term, cv::OPTFLOW_USE_INITIAL_FLOW);
    back = from.pixels;
    cv::calcOpticalFlowPyrLK(to_pyramid, from_pyramid, to, back, ok_back, err, win,
                             options.pyramid_levels, term, cv::OPTFLOW_USE_INITIAL_FLOW);
    const float w = static_cast<float>(camera.width), h = static_cast<float>(camera.height);
    for (size_t i = 0; i < from.size(); ++i) {
      if (!ok[i] || !ok_back[i]) continue;
      if (cv::norm(back[i] - from.pixels[i]) > options.back_track_px) continue;
      if (to[i].x < 0 || to[i].y < 0 || to[i].x > w - 1 || to[i].y > h - 1) continue;
      if (occluded_at(to[i])) continue;
      object.emplace_back(from.points[i].x(), from.points[i].y(), from.points[i].z());
      image.emplace_back(to[i].x, to[i].y);
      kept.push_back(i);
    }
    return kept;
  }

  bool in_view(const Pose& pose) const {
    const Vertices v = pose.apply(mesh.vertices);
    for (Eigen::Index i = 0; i < v.rows(); ++i) {
      if (v(i, 2) <= 0) continue;
      const Vector2d q = camera.project(v.row(i).transpose());
      if (q.x() >= 0 && q.y() >= 0 && q.x() <= camera.width - 1 && q.y() <= camera.height - 1)
        return true;
    }
    return false;
  }

  // ---- keyframe views at the predicted pose ---------------------------------------------

  // The image rectangle covering the object's projection at `pose`, grown by `margin` pixels
  // and clipped to the image (empty when it misses the image).
  cv::Rect object_box(const Pose& pose, int margin) const {
    const Vertices v = pose.apply(mesh.vertices);
    double x0 = 1e18, y0 = 1e18, x1 = -1e18, y1 = -1e18;
    for (Eigen::Index i = 0; i < v.rows(); ++i) {
      if (v(i, 2) <= 1e-9) continue;
      const Vector2d q = camera.project(v.row(i).transpose());
      x0 = std::min(x0, q.x());
      y0 = std::min(y0, q.y());
      x1 = std::max(x1, q.x());
      y1 = std::max(y1, q.y());
    }
    if (x0 > x1) return {};
    const cv::Rect r(static_cast<int>(std::floor(std::max(x0 - margin, -1.0))),
                     static_cast<int>(std::floor(std::max(y0 - margin, -1.0))), 0, 0);
    const int w = static_cast<int>(std::ceil(std::min(x1 + margin, 1e6))) - r.x + 1;
    const int h = static_cast<int>(std::ceil(std::min(y1 + margin, 1e6))) - r.y + 1;
    return cv::Rect(r.x, r.y, std::max(0, w), std::max(0, h)) &
           cv::Rect(0, 0, camera.width, camera.height);
  }

  // First hits of the rays through every pixel of `box` at `pose` (row-major in the box).
  std::vector<RayHit> cast_box(const Pose& pose, const cv::Rect& box) const {
    std::vector<Vector2d> px;
    px.reserve(static_cast<size_t>(box.area()));
    for (int y = box.y; y < box.y + box.height; ++y)
      for (int x = box.x; x < box.x + box.width; ++x) px.emplace_back(x, y);
    return cast(px, pose);
  }

  // Camera depth of the object at every pixel (+infinity off it) at `pose`.
  cv::Mat depth_map(const Pose& pose) const {
    cv::Mat d(camera.height, camera.width, CV_32F,
              cv::Scalar(std::numeric_limits<float>::infinity()));
    const cv::Rect box = object_box(pose, 2);
    if (box.area() == 0) return d;
    const std::vector<RayHit> hits = cast_box(pose, box);
    size_t k = 0;
    for (int y = box.y; y < box.y + box.height; ++y)
      for (int x = box.x; x < box.x + box.width; ++x, ++k)
        if (hits[k].triangle >= 0)
          d.at<float>(y, x) = static_cast<float>(pose.apply(hit_point(hits[k])).z());
    return d;
  }

  // The current frame with the object replaced by the keyframe's view of it warped to `pose`
  // (through the mesh: each pixel's surface point looked up in the keyframe, where the
  // keyframe saw it). Lucas-Kanade between this view and the frame then only has to recover
  // the pose error, not the foreshortening and turning since the keyframe, which drag
  // corners on a curved turning surface off their points.
  //
  // Also sets `occlusion`: where the keyframe's colours, warped, differ from the frame's after
  // a blur that forgives a misalignment of a few pixels, something else covers the object.
  cv::Mat keyframe_view(const Pose& pose, const cv::Mat& current, const cv::Mat& current_bgr) {
    cv::Mat out = current.clone();
    occlusion = cv::Mat::zeros(current.size(), CV_8U);
    const cv::Rect box = object_box(pose, options.window);
    if (box.area() == 0) return out;
    cv::Mat view_bgr(box.size(), CV_8UC3, cv::Scalar::all(0));
    cv::Mat shown(box.size(), CV_8U, cv::Scalar(0));
    // The map from this view to the keyframe's pixels on a grid of kViewStep pixels (a ray per
    // node), interpolated bilinearly inside cells whose four nodes the keyframe saw.
    const int gw = box.width / kViewStep + 2, gh = box.height / kViewStep + 2;
    std::vector<Vector2d> nodes;
    nodes.reserve(static_cast<size_t>(gw * gh));
    for (int j = 0; j < gh; ++j)
      for (int i = 0; i < gw; ++i) nodes.emplace_back(box.x + i * kViewStep, box.y + j * kViewStep);
    const std::vector<RayHit> hits = cast(nodes, pose);
    std::vector<cv::Point2f> map(nodes.size());
    std::vector<char> seen(nodes.size(), 0);
    for (size_t n = 0; n < nodes.size(); ++n) {
      if (hits[n].triangle < 0) continue;
      const Vector3d xk = key_pose.apply(hit_point(hits[n]));
      if (xk.z() <= 0) continue;
      const Vector2d q = camera.project(xk);
      const int qx = static_cast<int>(std::lround(q.x())),
                qy = static_cast<int>(std::lround(q.y()));
      if (qx < 0 || qy < 0 || qx >= camera.width - 1 || qy >= camera.height - 1) continue;
      if (!(std::abs(key_depth.at<float>(qy, qx) - xk.z()) <= 0.01 * xk.z())) continue;
      map[n] = cv::Point2f(static_cast<float>(q.x()), static_cast<float>(q.y()));
      seen[n] = 1;
    }
    const float inv = 1.0f / kViewStep;
    for (int y = box.y; y < box.y + box.height; ++y) {
      const int j = (y - box.y) / kViewStep;
      const float fy = (y - box.y) * inv - j;
      uchar* row = out.ptr<uchar>(y);
      for (int x = box.x; x < box.x + box.width; ++x) {
        const int i = (x - box.x) / kViewStep;
        const size_t n00 = static_cast<size_t>(j * gw + i), n10 = n00 + 1,
                     n01 = n00 + static_cast<size_t>(gw), n11 = n01 + 1;
        if (!(seen[n00] && seen[n10] && seen[n01] && seen[n11])) continue;
        const float fx = (x - box.x) * inv - i;
        const cv::Point2f q = (1 - fy) * ((1 - fx) * map[n00] + fx * map[n10]) +
                              fy * ((1 - fx) * map[n01] + fx * map[n11]);
        const int x0 = static_cast<int>(q.x), y0 = static_cast<int>(q.y);
        if (x0 < 0 || y0 < 0 || x0 >= camera.width - 1 || y0 >= camera.height - 1) continue;
        const float ax = q.x - x0, ay = q.y - y0;
        const uchar* k0 = key_grey.ptr<uchar>(y0) + x0;
        const uchar* k1 = key_grey.ptr<uchar>(y0 + 1) + x0;
        const float v =
            (1 - ay) * ((1 - ax) * k0[0] + ax * k0[1]) + ay * ((1 - ax) * k1[0] + ax * k1[1]);
        row[x] = cv::saturate_cast<uchar>(v);
        const cv::Vec3b* c0 = key_bgr.ptr<cv::Vec3b>(y0) + x0;
        const cv::Vec3b* c1 = key_bgr.ptr<cv::Vec3b>(y0 + 1) + x0;
        cv::Vec3b& vc = view_bgr.at<cv::Vec3b>(y - box.y, x - box.x);
        for (int ch = 0; ch < 3; ++ch)
          vc[ch] = cv::saturate_cast<uchar>((1 - ay) * ((1 - ax) * c0[0][ch] + ax * c0[1][ch]) +
                                            ay * ((1 - ax) * c1[0][ch] + ax * c1[1][ch]));
        shown.at<uchar>(y - box.y, x - box.x) = 255;
      }
    }
    if (options.occlusion_colour_difference > 0) {
      cv::Mat a, b, d;
      const cv::Size k(7, 7);
      cv::GaussianBlur(view_bgr, a, k, 2.0);
      cv::GaussianBlur(current_bgr(box), b, k, 2.0);
      cv::absdiff(a, b, d);
      cv::Mat sum;
      cv::transform(d, sum, cv::Matx13f(1, 1, 1));
      cv::Mat hidden = sum > options.occlusion_colour_difference;
      // Only where the view and its blur lie on the object.
      cv::erode(shown, shown, cv::getStructuringElement(cv::MORPH_RECT, k));
      hidden &= shown;
      hidden.copyTo(occlusion(box));
    }
    return out;
  }

  bool occluded_at(cv::Point2f p) const {
    if (occlusion.empty()) return false;
    const int x = static_cast<int>(std::lround(p.x)), y = static_cast<int>(std::lround(p.y));
    return x >= 0 && y >= 0 && x < occlusion.cols && y < occlusion.rows &&
           occlusion.at<uchar>(y, x) != 0;
  }

  // Keyframe corners into `to_pyramid` from the keyframe's view at `predicted`: each starts at
  // its projection there (where the view shows it) and must come back within back_track_px.
  void follow_key(const cv::Mat& current, const cv::Mat& current_bgr,
                  const std::vector<cv::Mat>& to_pyramid, const Pose& predicted,
                  std::vector<cv::Point3d>& object, std::vector<cv::Point2d>& image) {
    if (key.size() == 0) return;
    const cv::Mat view = keyframe_view(predicted, current, current_bgr);
    std::vector<cv::Point2f> from;
    std::vector<size_t> id;
    std::vector<Vector2d> px;
    for (size_t i = 0; i < key.size(); ++i) {
      const Vector3d pc = predicted.apply(key.points[i]);
      if (pc.z() <= 0) continue;
      const Vector2d q = camera.project(pc);
      if (q.x() < 0 || q.y() < 0 || q.x() > camera.width - 1 || q.y() > camera.height - 1) continue;
      from.emplace_back(static_cast<float>(q.x()), static_cast<float>(q.y()));
      px.push_back(q);
      id.push_back(i);
    }
    if (from.empty()) return;
    // Only corners the predicted view shows (not hidden behind another part of the object).
    const std::vector<RayHit> hits = cast(px, predicted);
    std::vector<cv::Point2f> f2;
    std::vector<size_t> id2;
    for (size_t j = 0; j < from.size(); ++j) {
      if (hits[j].triangle < 0) continue;
      const double z = predicted.apply(hit_point(hits[j])).z();
      const double zp = predicted.apply(key.points[id[j]]).z();
      if (std::abs(z - zp) > 0.01 * zp) continue;
      f2.push_back(from[j]);
      id2.push_back(id[j]);
    }
    if (f2.empty()) return;
    std::vector<cv::Mat> view_pyramid = pyramid(view);
    std::vector<cv::Point2f> to = f2, back = f2;
    std::vector<uchar> ok, ok_back;
    std::vector<float> err;
    const cv::Size win(options.window, options.window);
    const cv::TermCriteria term(cv::TermCriteria::COUNT + cv::TermCriteria::EPS, 30, 0.01);
    cv::calcOpticalFlowPyrLK(view_pyramid, to_pyramid, f2, to, ok, err, win, options.pyramid_levels,
                             term, cv::OPTFLOW_USE_INITIAL_FLOW);
    cv::calcOpticalFlowPyrLK(to_pyramid, view_pyramid, to, back, ok_back, err, win,
                             options.pyramid_levels, term, cv::OPTFLOW_USE_INITIAL_FLOW);
    const float w = static_cast<float>(camera.width), h = static_cast<float>(camera.height);
    for (size_t j = 0; j < f2.size(); ++j) {
      if (!ok[j] || !ok_back[j]) continue;
      if (cv::norm(back[j] - f2[j]) > options.back_track_px) continue;
      if (to[j].x < 0 || to[j].y < 0 || to[j].x > w - 1 || to[j].y > h - 1) continue;
      if (occluded_at(to[j])) continue;
      const Vector3d& p = key.points[id2[j]];
      object.emplace_back(p.x(), p.y(), p.z());
      image.emplace_back(to[j].x, to[j].y);
    }
  }

  void use_keyframe(size_t i) {
    const Keyframe& k = keyframes[i];
    key = k.corners;
    key_pyramid = k.pyramid;
    key_grey = k.grey;
    key_bgr = k.bgr;
    key_depth = k.depth;
    key_pose = k.pose;
    key_initial = key.size();
    key_generation = k.generation;
    key_index = static_cast<int>(i);
  }

  void set_keyframe(const cv::Mat& g, const cv::Mat& bgr, const std::vector<cv::Mat>& pyr,
                    const Pose& pose, Features corners) {
    Keyframe k;
    k.corners = std::move(corners);
    k.pyramid = pyr;
    k.grey = g;
    k.bgr = bgr;
    k.pose = pose;
    k.depth = depth_map(pose);
    k.generation = keyframes.empty() ? 0 : key_generation + 1;
    if (keyframes.size() >= kMaxKeyframes) keyframes.erase(keyframes.begin() + 1);
    keyframes.push_back(std::move(k));
    use_keyframe(keyframes.size() - 1);
  }

  // Switches to the stored keyframe of the lowest generation whose view is within 3/4 of the
  // keyframe angle of `predicted`, when it is older than the current one.
  void choose_keyframe(const Pose& predicted) {
    const double limit = 0.75 * options.keyframe_angle_deg * std::numbers::pi / 180.0;
    int best = -1;
    for (size_t i = 0; i < keyframes.size(); ++i) {
      if (keyframes[i].generation >= key_generation) continue;
      if (rotation_angle(keyframes[i].pose.rotation, predicted.rotation) > limit) continue;
      if (best < 0 || keyframes[i].generation < keyframes[static_cast<size_t>(best)].generation)
        best = static_cast<int>(i);
    }
    if (best >= 0) use_keyframe(static_cast<size_t>(best));
  }

  // ---- region (silhouette) term --------------------------------------------------------

  // The colour statistics from scratch: the object's projection, and a band around it.
  void init_colours(const cv::Mat& bgr, const Pose& pose) {
    const cv::Mat inside = mask(pose, 0);
    cv::Mat around;
    const int band = 2 * options.colour_band_px + 1;
    cv::dilate(inside, around, cv::getStructuringElement(cv::MORPH_ELLIPSE, cv::Size(band, band)));
    std::vector<cv::Vec3b> fg, bg;
    for (int y = 0; y < bgr.rows; ++y)
      for (int x = 0; x < bgr.cols; ++x) {
        if (inside.at<uchar>(y, x))
          fg.push_back(bgr.at<cv::Vec3b>(y, x));
        else if (around.at<uchar>(y, x))
          bg.push_back(bgr.at<cv::Vec3b>(y, x));
      }
    colours = {};
    colours.update(fg, bg, 1.0);
  }

  struct Silhouette {
    std::vector<track_detail::ContourPoint> contour;
    std::vector<track_detail::LineEstimate> lines;
    double agreement = 0.0;  // fraction of contour points whose line agrees, see TrackFrameInfo
  };

  Silhouette silhouette(const cv::Mat& bgr, const Pose& pose, int scale) const {
    Silhouette s;
    track_detail::LineOptions lo;
    lo.scale = scale;
    lo.range = kLineRange;
    const double reach = (lo.range + lo.context) * scale + 1.0;
    s.contour =
        track_detail::sample_contour(mesh, edges, scene, camera, pose, options.contour_spacing_px,
                                     options.contour_points, reach);
    s.lines.reserve(s.contour.size());
    int agree = 0;
    for (const auto& c : s.contour) {
      s.lines.push_back(track_detail::estimate_line(bgr, colours, c, lo));
      auto& l = s.lines.back();
      // Covered where the keyframe's view says so, over the inner half of the line.
      if (!occlusion.empty() &&
          track_detail::line_fraction(occlusion, c, -(lo.range + lo.context) * scale, -1) >
              options.occluded_line_fraction)
        l.inner_foreground = 0.0;
      agree += l.valid && l.inner_foreground >= options.occlusion_threshold &&
               l.outer_background >= options.occlusion_threshold &&
               std::abs(l.mean_px) <= 2.0 * scale;
    }
    s.agreement = s.contour.empty() ? 0.0 : static_cast<double>(agree) / s.contour.size();
    return s;
  }

  // Gauss-Newton on the joint cost: the 2-D/3-D pairs' reprojection errors (Huber) and the
  // contour's offsets along its correspondence lines (each weighted by the inverse variance of
  // its posterior; lines whose inner side does not look like the object are left out),
  // coarse to fine. Returns the refined pose.
  Pose refine(const cv::Mat& bgr, Pose pose, const std::vector<cv::Point3d>& object,
              const std::vector<cv::Point2d>& image) const {
    using Matrix6d = Eigen::Matrix<double, 6, 6>;
    using Vector6d = Eigen::Matrix<double, 6, 1>;
    using Row6d = Eigen::Matrix<double, 1, 6>;
    auto jacobian = [&](const Vector3d& x, Eigen::Matrix<double, 2, 6>& j) {
      const double iz = 1.0 / x.z();
      Eigen::Matrix<double, 2, 3> jp;
      jp << camera.fx * iz, 0, -camera.fx * x.x() * iz * iz, 0, camera.fy * iz,
          -camera.fy * x.y() * iz * iz;
      Eigen::Matrix3d skew;
      skew << 0, x.z(), -x.y(), -x.z(), 0, x.x(), x.y(), -x.x(), 0;  // d(w x X)/dw = -[X]x
      j.leftCols<3>() = jp * skew;
      j.rightCols<3>() = jp;
    };
    const double sf2 = options.feature_sigma_px * options.feature_sigma_px;
    for (int scale : options.region_scales) {
      for (int it = 0; it < options.region_iterations; ++it) {
        Matrix6d H = Matrix6d::Zero();
        Vector6d g = Vector6d::Zero();
        Eigen::Matrix<double, 2, 6> j;
        for (size_t i = 0; i < object.size(); ++i) {
          const Vector3d x = pose.apply(Vector3d(object[i].x, object[i].y, object[i].z));
          if (x.z() <= 0) continue;
          const Vector2d r = camera.project(x) - Vector2d(image[i].x, image[i].y);
          const double n = r.norm(), k = 1.5 * options.feature_sigma_px;
          const double w = (n <= k ? 1.0 : k / n) / sf2;
          jacobian(x, j);
          H += w * j.transpose() * j;
          g += w * j.transpose() * r;
        }
        if (options.region && !colours.empty()) {
          const Silhouette s = silhouette(bgr, pose, scale);
          for (size_t i = 0; i < s.contour.size(); ++i) {
            const auto& l = s.lines[i];
            if (!l.valid || l.inner_foreground < options.occlusion_threshold) continue;
            // An estimate at the end of the search range: the contour is not in it.
            if (std::abs(l.mean_px) > 0.8 * kLineRange * scale) continue;
            const Vector3d x = pose.apply(s.contour[i].point);
            jacobian(x, j);
            const Row6d jl = s.contour[i].normal.transpose() * j;
            const double sigma = std::sqrt(l.variance_px2);
            const double z = std::abs(l.mean_px) / sigma, k = 2.0;
            const double w = options.region_weight / l.variance_px2 * (z <= k ? 1.0 : k / z);
            H += w * jl.transpose() * jl;
            g += w * jl.transpose() * (-l.mean_px);
          }
        }
        // A weak pull towards the current pose keeps directions that neither term observes
        // (a turn of a body of revolution about its axis, without corners) where they are.
        for (int d = 0; d < 3; ++d) H(d, d) += 100.0;
        for (int d = 3; d < 6; ++d) H(d, d) += 1e4;
        const Vector6d delta = H.ldlt().solve(-g);
        if (!delta.allFinite()) break;
        const Vector3d w = delta.head<3>();
        const Eigen::Matrix3d dr =
            w.norm() > 0 ? Eigen::AngleAxisd(w.norm(), w.normalized()).toRotationMatrix()
                         : Eigen::Matrix3d::Identity();
        pose.rotation = dr * pose.rotation;
        pose.translation = dr * pose.translation + delta.tail<3>();
        if (delta.norm() < 1e-7) break;
      }
    }
    return pose;
  }

  // Blends this frame's colours into the statistics: the pixels inside the contour along
  // lines that look like the object there, and those outside it along every line. Each side
  // learns only colours the other does not claim (foreground probability on its side of
  // 0.5): an occluder's colours, seen around the object before it passes in front, stay
  // background, and a small misalignment does not move colours across.
  void update_colours(const cv::Mat& bgr, const Silhouette& s) {
    std::vector<cv::Vec3b> fg, bg, px;
    const int inner = options.colour_band_px, outer = options.colour_band_px;
    for (size_t i = 0; i < s.contour.size(); ++i) {
      const auto& l = s.lines[i];
      if (!l.valid) continue;
      if (l.inner_foreground >= options.colour_update_threshold) {
        px.clear();
        track_detail::line_pixels(bgr, s.contour[i], -inner, -2, px);
        for (const auto& c : px)
          if (colours.foreground(c) >= 0.5f) fg.push_back(c);
      }
      px.clear();
      track_detail::line_pixels(bgr, s.contour[i], 2, outer, px);
      for (const auto& c : px)
        if (colours.foreground(c) <= 0.5f) bg.push_back(c);
    }
    colours.update(fg, bg, options.colour_rate);
  }

  // ---- re-detection ----------------------------------------------------------------------

  void add_landmarks(const cv::Mat& g, const Pose& pose) {
    if (!orb) orb = cv::ORB::create(500);
    std::vector<cv::KeyPoint> kp;
    cv::Mat desc;
    orb->detectAndCompute(g, mask(pose, 5), kp, desc);
    if (kp.empty()) return;
    std::vector<Vector2d> px;
    for (const auto& k : kp) px.emplace_back(k.pt.x, k.pt.y);
    const std::vector<RayHit> hits = cast(px, pose);
    cv::Mat rows;
    std::vector<Vector3d> points;
    for (size_t i = 0; i < kp.size(); ++i) {
      if (hits[i].triangle < 0) continue;
      rows.push_back(desc.row(static_cast<int>(i)));
      points.push_back(hit_point(hits[i]));
    }
    if (points.empty()) return;
    // The first keyframe's block stays; later ones replace the oldest of them beyond 8 blocks.
    if (landmark_rows.size() >= 9) {
      const int first = landmark_rows[0], drop = landmark_rows[1];
      cv::Mat kept;
      kept.push_back(landmark_descriptors.rowRange(0, first));
      if (landmark_descriptors.rows > first + drop)
        kept.push_back(landmark_descriptors.rowRange(first + drop, landmark_descriptors.rows));
      landmark_descriptors = kept;
      landmark_points.erase(landmark_points.begin() + first,
                            landmark_points.begin() + first + drop);
      landmark_rows.erase(landmark_rows.begin() + 1);
    }
    landmark_descriptors.push_back(rows);
    landmark_points.insert(landmark_points.end(), points.begin(), points.end());
    landmark_rows.push_back(rows.rows);
  }

  // The pose from ORB matches of the whole frame against the keyframes' landmarks, or nullopt.
  // `near`: where the object was last seen; the search covers the object's box there grown by
  // its size each way (the whole frame when that misses the image).
  std::optional<Pose> redetect(const cv::Mat& g, const Pose& near, int& inlier_count) const {
    inlier_count = 0;
    if (!orb || landmark_points.size() < 4) return std::nullopt;
    std::vector<cv::KeyPoint> kp;
    cv::Mat desc;
    cv::Mat where;
    const cv::Rect seen = object_box(near, 0);
    if (seen.area() > 0) {
      where = cv::Mat::zeros(g.size(), CV_8U);
      where(object_box(near, std::max(seen.width, seen.height))).setTo(255);
    }
    cv::Ptr<cv::ORB> detector = cv::ORB::create(1000);
    detector->detectAndCompute(g, where, kp, desc);  // an empty mask: the whole frame
    if (kp.size() < 4) return std::nullopt;
    cv::BFMatcher matcher(cv::NORM_HAMMING);
    std::vector<std::vector<cv::DMatch>> knn;
    matcher.knnMatch(desc, landmark_descriptors, knn, 4);
    std::vector<cv::Point3d> object;
    std::vector<cv::Point2d> image;
    // Ratio test against the best match of another mesh point: keyframes share points, whose
    // near-identical descriptors would fail a plain ratio test.
    const double same_point = 0.01 * mesh_size;
    for (const auto& m : knn) {
      if (m.empty()) continue;
      const Vector3d& p = landmark_points[static_cast<size_t>(m[0].trainIdx)];
      bool distinct = true;
      for (size_t r = 1; r < m.size(); ++r) {
        if ((landmark_points[static_cast<size_t>(m[r].trainIdx)] - p).norm() <= same_point)
          continue;
        distinct = m[0].distance < 0.8f * m[r].distance;
        break;
      }
      if (!distinct) continue;
      object.emplace_back(p.x(), p.y(), p.z());
      image.emplace_back(kp[static_cast<size_t>(m[0].queryIdx)].pt);
    }
    if (static_cast<int>(object.size()) < options.min_inliers) return std::nullopt;
    cv::Mat rvec, tvec;
    std::vector<int> inliers;
    try {
      if (!cv::solvePnPRansac(object, image, camera_matrix(camera), cv::noArray(), rvec, tvec,
                              false, 500, 3.0f, 0.999, inliers, cv::SOLVEPNP_SQPNP))
        return std::nullopt;
    } catch (const cv::Exception&) {
      return std::nullopt;
    }
    inlier_count = static_cast<int>(inliers.size());
    if (inlier_count < options.min_inliers) return std::nullopt;
    const Pose p = from_cv(rvec, tvec);
    if (!(p.translation.z() > 0)) return std::nullopt;
    return p;
  }
};

PoseTracker::PoseTracker(const Mesh& mesh, const Camera& camera, TrackOptions options)
    : m_impl(std::make_unique<Impl>()) {
  if (mesh.num_vertices() == 0 || mesh.num_triangles() == 0)
    throw InputError("tracking needs a mesh with triangles");
  camera.validate();
  bool scales_ok = !options.region_scales.empty();
  for (int s : options.region_scales) scales_ok = scales_ok && s >= 1 && s <= 8;
  if (options.max_corners < 8 || options.min_inliers < 4 || options.window < 5 ||
      options.pyramid_levels < 0 || !(options.ransac_px > 0) || !(options.back_track_px > 0) ||
      !scales_ok || options.region_iterations < 1 || options.contour_points < 8 ||
      !(options.contour_spacing_px > 0) || !(options.region_weight >= 0) ||
      !(options.feature_sigma_px > 0) || !(options.colour_rate > 0 && options.colour_rate <= 1) ||
      options.colour_band_px < 4)
    throw InputError("invalid tracking options");
  m_impl->mesh = mesh;
  m_impl->camera = camera;
  m_impl->options = options;
  m_impl->scene.set_mesh(mesh.vertices, mesh.triangles);
  m_impl->edges = track_detail::mesh_edges(mesh);
  m_impl->mesh_size =
      (mesh.vertices.colwise().maxCoeff() - mesh.vertices.colwise().minCoeff()).norm();
}

PoseTracker::~PoseTracker() = default;

namespace {

void check_size(const cv::Mat& frame, const Camera& camera) {
  if (frame.cols != camera.width || frame.rows != camera.height)
    throw InputError("frame of " + std::to_string(frame.cols) + "x" + std::to_string(frame.rows) +
                     " pixels, the camera expects " + std::to_string(camera.width) + "x" +
                     std::to_string(camera.height));
}

/// "(x, y, ...)" with the stream's default precision (nan and inf as such).
template <class Vector>
std::string coordinates(const Vector& v) {
  std::ostringstream s;
  s << '(';
  for (Eigen::Index k = 0; k < v.size(); ++k) s << (k ? ", " : "") << v[k];
  s << ')';
  return s.str();
}

/// The frame's size and type: 8-bit grey, BGR or BGRA (what corners and optical flow take).
void check_frame(const cv::Mat& frame, const Camera& camera, const char* where) {
  check_size(frame, camera);
  const int channels = frame.channels();
  if (frame.depth() != CV_8U || (channels != 1 && channels != 3 && channels != 4))
    throw InputError(std::string(where) + ": frame of type " + cv::typeToString(frame.type()) +
                     ", expected 8-bit grey, BGR or BGRA (CV_8UC1, CV_8UC3 or CV_8UC4)");
}

/// `f()`, with an OpenCV exception (a check of OpenCV's that the input fails) as an InputError
/// naming `where`.
template <class F>
auto opencv_checked(const char* where, F f) {
  try {
    return f();
  } catch (const cv::Exception& e) {
    throw InputError(std::string(where) + ": OpenCV refused the input (" + e.err + " in " + e.func +
                     ")");
  }
}

}  // namespace

void PoseTracker::start(const cv::Mat& frame, const Pose& pose) {
  Impl& m = *m_impl;
  check_frame(frame, m.camera, "PoseTracker::start");
  if (!pose.rotation.allFinite() || !pose.translation.allFinite())
    throw InputError("PoseTracker::start: the initial pose is not finite");
  opencv_checked("PoseTracker::start", [&] { start_checked(frame, pose); });
}

void PoseTracker::start_checked(const cv::Mat& frame, const Pose& pose) {
  Impl& m = *m_impl;
  const cv::Mat g = grey(frame), bgr = colour(frame);
  m.colours = {};
  m.key = m.detect(g, cv::Mat(), pose);
  if (static_cast<int>(m.key.size()) < m.options.min_inliers)
    throw InputError("the object shows " + std::to_string(m.key.size()) +
                     " trackable corners in the first frame under the initial pose (at least " +
                     std::to_string(m.options.min_inliers) +
                     " needed): check the initial pose and the intrinsics");
  m.init_colours(bgr, pose);
  m.keyframes.clear();
  m.set_keyframe(g, bgr, m.pyramid(g), pose, std::move(m.key));
  m.prev_grey = g;
  m.prev_bgr = bgr;
  m.prev_pyramid = m.key_pyramid;
  m.prev_pose = m.coast = pose;
  m.have_velocity = false;
  m.last_lost = false;
  m.landmark_descriptors = cv::Mat();
  m.landmark_points.clear();
  m.landmark_rows.clear();
  m.add_landmarks(g, pose);
  m.started = true;
}

std::optional<Pose> PoseTracker::track(const cv::Mat& frame, TrackFrameInfo* info) {
  if (!m_impl->started) throw std::logic_error("PoseTracker::track() before start()");
  check_frame(frame, m_impl->camera, "PoseTracker::track");
  return opencv_checked("PoseTracker::track", [&] { return track_checked(frame, info); });
}

std::optional<Pose> PoseTracker::track_checked(const cv::Mat& frame, TrackFrameInfo* info) {
  Impl& m = *m_impl;
  TrackFrameInfo local;
  TrackFrameInfo& out = info ? *info : local;
  out = TrackFrameInfo{};
  const cv::Mat g = grey(frame), bgr = colour(frame);
  const std::vector<cv::Mat> pyr = m.pyramid(g);

  // Constant-velocity prediction in the camera frame; while lost, the coasting pose keeps
  // moving with the last velocity (to tell an object that left the view from a hidden one).
  const Pose predicted = m.have_velocity ? m.extrapolate(m.prev_pose) : m.prev_pose;
  m.coast = m.have_velocity ? m.extrapolate(m.coast) : m.coast;
  out.in_view = m.in_view(m.coast);

  std::vector<cv::Point3d> object;
  std::vector<cv::Point2d> image;
  if (!m.last_lost) m.choose_keyframe(predicted);
  m.occlusion = cv::Mat();
  if (m.options.warp_keyframe)
    m.follow_key(g, bgr, pyr, predicted, object, image);
  else
    m.follow(m.key_pyramid, m.key, pyr, predicted, object, image);
  const size_t n_key = object.size();
  // Keyframe corners carry exact mesh points and drop out where an occluder covers them
  // (their window no longer matches); the previous frame's are found anew, so they only help
  // when the keyframe's run short.
  const bool enough_key = static_cast<int>(n_key) >= 3 * m.options.min_inliers;
  if (!m.last_lost && !enough_key) {
    const Features prev = m.detect(m.prev_grey, m.prev_bgr, m.prev_pose);
    m.follow(m.prev_pyramid, prev, pyr, predicted, object, image);
  }
  out.correspondences = static_cast<int>(object.size());

  // Features: RANSAC over SQPnP (globally optimal, also for nearly planar point sets); the
  // iterative solver started from the prediction can run away there.
  std::optional<Pose> from_features;
  std::vector<int> inliers;
  std::vector<cv::Point3d> oi;
  std::vector<cv::Point2d> ii;
  if (static_cast<int>(object.size()) >= m.options.min_inliers) {
    cv::Mat rvec, tvec;
    to_cv(predicted, rvec, tvec);
    bool ok = false;
    try {
      ok = cv::solvePnPRansac(object, image, camera_matrix(m.camera), cv::noArray(), rvec, tvec,
                              false, 200, static_cast<float>(m.options.ransac_px), 0.999, inliers,
                              cv::SOLVEPNP_SQPNP);
    } catch (const cv::Exception&) {
      ok = false;  // a degenerate sample set (e.g. nearly collinear points)
    }
    if (ok && static_cast<int>(inliers.size()) >= m.options.min_inliers) {
      for (int i : inliers) {
        oi.push_back(object[static_cast<size_t>(i)]);
        ii.push_back(image[static_cast<size_t>(i)]);
      }
      const Pose p = from_cv(rvec, tvec);
      if (p.translation.z() > 0) from_features = p;
      out.inliers = static_cast<int>(inliers.size());
    }
  }
  if (!from_features) {
    oi.clear();
    ii.clear();
    inliers.clear();
  }

  // Joint refinement with the silhouette, from the features' pose or the prediction.
  auto finish = [&](const Pose& start, const std::vector<cv::Point3d>& o,
                    const std::vector<cv::Point2d>& i, Impl::Silhouette& s) {
    const Pose p = m.refine(bgr, start, o, i);
    if (m.options.region) s = m.silhouette(bgr, p, 1);
    return p;
  };
  Impl::Silhouette sil;
  Pose pose = finish(from_features.value_or(predicted), oi, ii, sil);
  double rms = 0.0;
  if (!oi.empty()) {
    double sq = 0.0;
    for (size_t k = 0; k < oi.size(); ++k)
      sq += (m.camera.project(pose.apply(Vector3d(oi[k].x, oi[k].y, oi[k].z))) -
             Vector2d(ii[k].x, ii[k].y))
                .squaredNorm();
    rms = std::sqrt(sq / static_cast<double>(oi.size()));
  }
  out.rms_px = rms;
  out.agreement = m.options.region ? sil.agreement : 1.0;
  const bool features_ok = from_features && rms <= m.options.ransac_px;
  auto trusted = [&](bool features, double agreement) {
    if (!m.options.region) return features;
    return agreement >= m.options.lost_agreement &&
           (features || agreement >= m.options.region_only_agreement);
  };
  bool ok = pose.translation.z() > 0 && trusted(features_ok, out.agreement);

  if (!ok && m.options.redetect) {
    // Re-detection against the keyframes' descriptors, then the same refinement.
    int count = 0;
    const std::optional<Pose> found = m.redetect(g, m.prev_pose, count);
    if (found) {
      Impl::Silhouette s2;
      const Pose p = finish(*found, {}, {}, s2);
      const double a = m.options.region ? s2.agreement : 1.0;
      if (p.translation.z() > 0 && a >= m.options.region_only_agreement) {
        pose = p;
        sil = std::move(s2);
        out.agreement = a;
        out.inliers = count;
        out.relocalized = true;
        ok = true;
        inliers.clear();
      }
    }
  }

  if (!ok) {
    out.lost = true;
    m.last_lost = true;
    return std::nullopt;  // keep the keyframe and the last pose: resume near it
  }
  int key_inliers = 0;
  for (int i : inliers) key_inliers += static_cast<size_t>(i) < n_key;
  if (m.options.region && out.agreement >= m.options.colour_update_agreement)
    m.update_colours(bgr, sil);

  if (m.last_lost) {
    m.have_velocity = false;  // the last pose is old: no velocity from it
  } else {
    m.velocity_rotation = pose.rotation * m.prev_pose.rotation.transpose();
    m.velocity_translation = pose.translation - m.velocity_rotation * m.prev_pose.translation;
    m.have_velocity = true;
  }
  m.prev_pose = m.coast = pose;
  m.prev_grey = g;
  m.prev_bgr = bgr;
  m.prev_pyramid = pyr;
  m.last_lost = false;

  const double turned =
      rotation_angle(m.key_pose.rotation, pose.rotation) * 180.0 / std::numbers::pi;
  // A keyframe passes its pose on to every later frame that follows it: none is taken while
  // the silhouette agrees poorly (an occluder over the object), where its corners would run
  // short too. Corners lost to an occluder come back when it has passed.
  const bool clear_view = !m.options.region || out.agreement >= m.options.keyframe_agreement;
  if (clear_view && (out.relocalized || turned > m.options.keyframe_angle_deg ||
                     key_inliers < m.options.keyframe_keep * static_cast<double>(m.key_initial))) {
    Features fresh = m.detect(g, bgr, pose);
    if (static_cast<int>(fresh.size()) >= m.options.min_inliers) {
      m.set_keyframe(g, bgr, pyr, pose, std::move(fresh));
      out.new_keyframe = true;
      if (m.options.redetect && out.agreement >= m.options.colour_update_agreement)
        m.add_landmarks(g, pose);
    }
  }
  return pose;
}

TrackResult track_footage(Footage& footage, const Mesh& mesh, const Camera& camera,
                          const Pose& initial, const TrackOptions& options,
                          const TrackFrameCallback& on_frame) {
  TrackResult out;
  const int n = options.end_frame < 0 ? footage.frame_count()
                                      : std::min(options.end_frame, footage.frame_count());
  PoseTracker tracker(mesh, camera, options);
  double ms = 0.0;
  int out_of_view_from = -1;
  for (int t = 0; t < n; ++t) {
    const cv::Mat frame = footage.frame(t);
    TrackFrameInfo info;
    std::optional<Pose> pose;
    const auto t0 = std::chrono::steady_clock::now();
    if (t == 0) {
      tracker.start(frame, initial);
      pose = initial;
      info.agreement = 1.0;  // the given pose
    } else {
      pose = tracker.track(frame, &info);
    }
    ms += std::chrono::duration<double, std::milli>(std::chrono::steady_clock::now() - t0).count();
    if (pose)
      out_of_view_from = -1;
    else if (!info.in_view && out_of_view_from < 0)
      out_of_view_from = t;
    out.track.poses.push_back(pose);
    out.frames.push_back(info);
    if (on_frame) on_frame(t, frame, pose, info);
  }
  out.track_ms_per_frame = n > 0 ? ms / n : 0.0;
  out.left_view_at = out_of_view_from;
  return out;
}

Pose pose_from_correspondences(const std::vector<Eigen::Vector3d>& mesh_points,
                               const std::vector<Eigen::Vector2d>& pixels, const Camera& camera,
                               double max_rms_px) {
  if (mesh_points.size() != pixels.size())
    throw InputError("correspondences: " + std::to_string(mesh_points.size()) +
                     " mesh points but " + std::to_string(pixels.size()) + " pixels");
  if (mesh_points.size() < 4)
    throw InputError("correspondences: at least 4 are needed to solve for a pose, got " +
                     std::to_string(mesh_points.size()));
  camera.validate();
  const auto n = static_cast<Eigen::Index>(mesh_points.size());
  Eigen::MatrixX3d centred(n, 3);
  for (Eigen::Index k = 0; k < n; ++k) {
    const Vector3d& p = mesh_points[static_cast<size_t>(k)];
    const Vector2d& q = pixels[static_cast<size_t>(k)];
    if (!p.allFinite())
      throw InputError("correspondences: pair " + std::to_string(k) + ": mesh point " +
                       coordinates(p) + " is not finite");
    if (!q.allFinite())
      throw InputError("correspondences: pair " + std::to_string(k) + ": pixel " + coordinates(q) +
                       " is not finite");
    centred.row(k) = p.transpose();
  }
  // The rotation about a line through every mesh point is undetermined (PnP solvers fail or
  // return any of them): the points must span a plane at least.
  centred.rowwise() -= centred.colwise().mean();
  const Eigen::Vector3d spread = Eigen::JacobiSVD<Eigen::MatrixX3d>(centred).singularValues();
  if (!(spread[0] > 0.0))
    throw InputError("correspondences: all " + std::to_string(n) +
                     " mesh points are the same point: no pose follows from them");
  if (!(spread[1] > 1e-6 * spread[0]))
    throw InputError("correspondences: all " + std::to_string(n) +
                     " mesh points lie on one line, which leaves the rotation about it "
                     "undetermined: add points off that line");
  std::vector<cv::Point3d> o;
  std::vector<cv::Point2d> i;
  for (size_t k = 0; k < pixels.size(); ++k) {
    o.emplace_back(mesh_points[k].x(), mesh_points[k].y(), mesh_points[k].z());
    i.emplace_back(pixels[k].x(), pixels[k].y());
  }
  const cv::Matx33d kmat = camera_matrix(camera);
  cv::Mat rvec, tvec;
  const int method = o.size() >= 6 ? cv::SOLVEPNP_ITERATIVE : cv::SOLVEPNP_SQPNP;
  std::vector<cv::Point2d> proj;
  try {
    if (!cv::solvePnP(o, i, kmat, cv::noArray(), rvec, tvec, false, method))
      throw InputError("correspondences: no pose fits them");
    cv::solvePnPRefineLM(o, i, kmat, cv::noArray(), rvec, tvec);
    cv::projectPoints(o, rvec, tvec, kmat, cv::noArray(), proj);
  } catch (const cv::Exception& e) {  // a degenerate configuration the checks above let pass
    throw InputError("correspondences: no pose fits them (the solver refused them: " + e.err +
                     "): check that the points are spread out and the pairs are right");
  }
  double sq = 0.0;
  for (size_t k = 0; k < proj.size(); ++k) sq += std::pow(cv::norm(proj[k] - i[k]), 2);
  const double rms = std::sqrt(sq / static_cast<double>(proj.size()));
  const Pose p = from_cv(rvec, tvec);
  for (const auto& q : mesh_points)
    if (!(p.apply(q).z() > 0))
      throw InputError("correspondences: the best-fitting pose puts the object behind the camera");
  if (!(rms <= max_rms_px))
    throw InputError("correspondences: the best-fitting pose leaves an RMS reprojection error of " +
                     std::to_string(rms) + " pixels (at most " + std::to_string(max_rms_px) +
                     " accepted): check the pairs and the intrinsics");
  return p;
}

// Correspondence file: one pair per line, `VERTEX u v` (a mesh vertex index and its pixel) or
// `x y z u v` (a point in mesh coordinates and its pixel); `#` starts a comment.
Pose pose_from_correspondence_file(const std::filesystem::path& path, const Mesh& mesh,
                                   const Camera& camera, double max_rms_px) {
  camera.validate();  // its own error, not one about the file
  std::ifstream in(path);
  if (!in) throw InputError("cannot read the correspondence file", path);
  std::vector<Eigen::Vector3d> points;
  std::vector<Eigen::Vector2d> pixels;
  std::string line;
  for (int n = 1; std::getline(in, line); ++n) {
    line = line.substr(0, line.find('#'));
    std::istringstream ls(line);
    std::vector<std::string> tok;
    for (std::string t; ls >> t;) tok.push_back(t);
    if (tok.empty()) continue;
    std::vector<double> x;
    for (const auto& t : tok) {
      try {
        size_t used = 0;
        x.push_back(std::stod(t, &used));
        if (used != t.size() || !std::isfinite(x.back())) throw std::invalid_argument(t);
      } catch (const std::exception&) {
        throw InputError("expected a number, found '" + t + "'", path, n);
      }
    }
    if (x.size() == 3) {
      const double id = x[0];
      if (id != std::floor(id) || id < 0 || id >= mesh.num_vertices())
        throw InputError("vertex index " + tok[0] + " out of range (the mesh has " +
                             std::to_string(mesh.num_vertices()) + " vertices)",
                         path, n);
      points.push_back(mesh.vertices.row(static_cast<Eigen::Index>(id)).transpose());
      pixels.emplace_back(x[1], x[2]);
    } else if (x.size() == 5) {
      points.emplace_back(x[0], x[1], x[2]);
      pixels.emplace_back(x[3], x[4]);
    } else {
      throw InputError(
          "expected 'VERTEX u v' or 'x y z u v', found " + std::to_string(x.size()) + " numbers",
          path, n);
    }
  }
  try {
    return pose_from_correspondences(points, pixels, camera, max_rms_px);
  } catch (const InputError& e) {
    throw InputError(e.message(), path);
  }
}

void draw_mesh_edges(cv::Mat& image, const Mesh& mesh, const Camera& camera, const Pose& pose,
                     const cv::Scalar& color, double crease_deg) {
  check_triangle_indices(mesh.triangles, mesh.num_vertices(), "draw_mesh_edges");
  const Vertices v = pose.apply(mesh.vertices);
  const int nf = mesh.num_triangles();
  std::vector<Vector3d> normal(static_cast<size_t>(nf));
  std::vector<char> front(static_cast<size_t>(nf));
  for (int f = 0; f < nf; ++f) {
    const Vector3d a = v.row(mesh.triangles(f, 0)), b = v.row(mesh.triangles(f, 1)),
                   c = v.row(mesh.triangles(f, 2));
    normal[static_cast<size_t>(f)] = (b - a).cross(c - a);
    front[static_cast<size_t>(f)] =
        a.z() > 0 && b.z() > 0 && c.z() > 0 && normal[static_cast<size_t>(f)].dot(a) < 0.0;
  }
  std::map<std::pair<int, int>, std::vector<int>> edge_faces;
  for (int f = 0; f < nf; ++f)
    for (int k = 0; k < 3; ++k) {
      const int a = mesh.triangles(f, k), b = mesh.triangles(f, (k + 1) % 3);
      edge_faces[{std::min(a, b), std::max(a, b)}].push_back(f);
    }
  const double cos_crease = std::cos(crease_deg * std::numbers::pi / 180.0);
  for (const auto& [edge, faces] : edge_faces) {
    bool any_front = false, any_back = false;
    for (int f : faces) (front[static_cast<size_t>(f)] ? any_front : any_back) = true;
    if (!any_front) continue;
    bool draw = any_back || faces.size() != 2;  // silhouette or open boundary
    if (!draw) {
      const Vector3d& n0 = normal[static_cast<size_t>(faces[0])];
      const Vector3d& n1 = normal[static_cast<size_t>(faces[1])];
      const double denom = n0.norm() * n1.norm();
      draw = denom > 0.0 && n0.dot(n1) / denom < cos_crease;
    }
    if (!draw) continue;
    const Vector2d p = camera.project(v.row(edge.first).transpose());
    const Vector2d q = camera.project(v.row(edge.second).transpose());
    cv::line(image,
             cv::Point(static_cast<int>(std::lround(p.x() * 16)),
                       static_cast<int>(std::lround(p.y() * 16))),
             cv::Point(static_cast<int>(std::lround(q.x() * 16)),
                       static_cast<int>(std::lround(q.y() * 16))),
             color, 1, cv::LINE_AA, 4);
  }
}

double reprojection_error_px(const Mesh& mesh, const Camera& camera, const Pose& a, const Pose& b) {
  double sum = 0.0;
  int n = 0;
  for (Eigen::Index i = 0; i < mesh.vertices.rows(); ++i) {
    const Vector3d p = mesh.vertices.row(i).transpose();
    const Vector3d pa = a.apply(p), pb = b.apply(p);
    if (pa.z() <= 0 || pb.z() <= 0) continue;
    sum += (camera.project(pa) - camera.project(pb)).norm();
    ++n;
  }
  return n > 0 ? sum / n : std::numeric_limits<double>::infinity();
}

}  // namespace pbve
