#include "pbve/track/tracker.hpp"

#include <algorithm>
#include <chrono>
#include <cmath>
#include <limits>
#include <map>
#include <numbers>
#include <string>
#include <utility>

#include <opencv2/calib3d.hpp>
#include <opencv2/core/eigen.hpp>
#include <opencv2/imgproc.hpp>
#include <opencv2/video/tracking.hpp>

#include "pbve/core/error.hpp"
#include "pbve/visibility/ray_scene.hpp"

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

struct PoseTracker::Impl {
  Mesh mesh;
  Camera camera;
  TrackOptions options;
  RayScene scene;  // mesh coordinates: rays are brought into the mesh frame

  bool started = false;
  // Keyframe.
  std::vector<cv::Mat> key_pyramid;
  Features key;
  size_t key_initial = 0;
  Pose key_pose;
  // Previous frame.
  std::vector<cv::Mat> prev_pyramid;
  Features prev;
  Pose prev_pose, coast;
  // Last frame-to-frame motion in the camera frame: x -> velocity_rotation x +
  // velocity_translation.
  Eigen::Matrix3d velocity_rotation = Eigen::Matrix3d::Identity();
  Eigen::Vector3d velocity_translation = Eigen::Vector3d::Zero();
  bool have_velocity = false;
  bool last_lost = false;

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

  // The object's mask under `pose`: its front-facing triangles filled.
  cv::Mat mask(const Pose& pose) const {
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
    // Keep corners at least half a Lucas-Kanade window inside the silhouette: a window that
    // straddles it sees the static background and drags the flow towards zero.
    const int e = options.window | 1;
    cv::erode(m, m, cv::getStructuringElement(cv::MORPH_ELLIPSE, cv::Size(e, e)));
    return m;
  }

  // Corners of `g` on the object under `pose`, with their mesh points (first hits of the rays
  // through them).
  Features detect(const cv::Mat& g, const Pose& pose) const {
    std::vector<cv::Point2f> corners;
    cv::goodFeaturesToTrack(g, corners, options.max_corners, options.corner_quality,
                            options.corner_distance, mask(pose));
    if (corners.empty()) return {};
    cv::cornerSubPix(g, corners, cv::Size(5, 5), cv::Size(-1, -1),
                     cv::TermCriteria(cv::TermCriteria::EPS + cv::TermCriteria::COUNT, 20, 0.01));
    const Eigen::Matrix3d rt = pose.rotation.transpose();
    const Vector3d origin = -rt * pose.translation;  // camera centre in mesh coordinates
    // Five rays per corner: through it, and half a window left, right, up and down. A corner
    // is kept when the four neighbours land on the plane of its own hit (within 1% of the
    // depth): its window then sees one surface, not an occluding contour (a limb in front of
    // the body) whose two sides move differently.
    const double h = 0.5 * options.window;
    const double offsets[5][2] = {{0, 0}, {-h, 0}, {h, 0}, {0, -h}, {0, h}};
    const Eigen::Index nc = static_cast<Eigen::Index>(corners.size());
    Eigen::MatrixX3d o(5 * nc, 3), d(5 * nc, 3);
    for (Eigen::Index i = 0; i < nc; ++i)
      for (int k = 0; k < 5; ++k) {
        const Vector2d px(corners[static_cast<size_t>(i)].x + offsets[k][0],
                          corners[static_cast<size_t>(i)].y + offsets[k][1]);
        o.row(5 * i + k) = origin.transpose();
        d.row(5 * i + k) = (rt * camera.ray_direction(px)).transpose();
      }
    const std::vector<RayHit> hits = scene.intersect(o, d);
    auto point = [&](const RayHit& hit) {
      const auto t = mesh.triangles.row(hit.triangle);
      const double u = hit.u, v = hit.v;
      return Vector3d((1 - u - v) * Vector3d(mesh.vertices.row(t(0))) +
                      u * Vector3d(mesh.vertices.row(t(1))) +
                      v * Vector3d(mesh.vertices.row(t(2))));
    };
    Features out;
    for (Eigen::Index i = 0; i < nc; ++i) {
      const RayHit& c = hits[static_cast<size_t>(5 * i)];
      if (c.triangle < 0) continue;
      const Vector3d p = point(c);
      const auto t = mesh.triangles.row(c.triangle);
      const Vector3d n =
          (Vector3d(mesh.vertices.row(t(1))) - Vector3d(mesh.vertices.row(t(0))))
              .cross(Vector3d(mesh.vertices.row(t(2))) - Vector3d(mesh.vertices.row(t(0))));
      bool one_surface = true;
      for (int k = 1; k < 5 && one_surface; ++k) {
        const RayHit& q = hits[static_cast<size_t>(5 * i + k)];
        const Vector3d dir = d.row(5 * i + k).transpose();
        const double along = n.dot(dir);
        if (q.triangle < 0 || std::abs(along) < 1e-12) {
          one_surface = false;
          break;
        }
        const double t_plane = n.dot(p - origin) / along;
        one_surface = std::abs(static_cast<double>(q.t) - t_plane) <= 0.01 * c.t;
      }
      if (!one_surface) continue;
      out.pixels.push_back(corners[static_cast<size_t>(i)]);
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
};

PoseTracker::PoseTracker(const Mesh& mesh, const Camera& camera, TrackOptions options)
    : m_impl(std::make_unique<Impl>()) {
  if (mesh.num_vertices() == 0 || mesh.num_triangles() == 0)
    throw InputError("tracking needs a mesh with triangles");
  camera.validate();
  if (options.max_corners < 8 || options.min_inliers < 4 || options.window < 5 ||
      options.pyramid_levels < 0 || !(options.ransac_px > 0) || !(options.back_track_px > 0))
    throw InputError("invalid tracking options");
  m_impl->mesh = mesh;
  m_impl->camera = camera;
  m_impl->options = options;
  m_impl->scene.set_mesh(mesh.vertices, mesh.triangles);
}

PoseTracker::~PoseTracker() = default;

void PoseTracker::start(const cv::Mat& frame, const Pose& pose) {
  Impl& m = *m_impl;
  if (frame.cols != m.camera.width || frame.rows != m.camera.height)
    throw InputError("frame of " + std::to_string(frame.cols) + "x" + std::to_string(frame.rows) +
                     " pixels, the camera expects " + std::to_string(m.camera.width) + "x" +
                     std::to_string(m.camera.height));
  const cv::Mat g = grey(frame);
  m.key = m.detect(g, pose);
  if (static_cast<int>(m.key.size()) < m.options.min_inliers)
    throw InputError("the object shows " + std::to_string(m.key.size()) +
                     " trackable corners in the first frame under the initial pose (at least " +
                     std::to_string(m.options.min_inliers) +
                     " needed): check the initial pose and the intrinsics");
  m.key_pyramid = m.pyramid(g);
  m.key_initial = m.key.size();
  m.key_pose = pose;
  m.prev = m.key;
  m.prev_pyramid = m.key_pyramid;
  m.prev_pose = m.coast = pose;
  m.have_velocity = false;
  m.last_lost = false;
  m.started = true;
}

std::optional<Pose> PoseTracker::track(const cv::Mat& frame, TrackFrameInfo* info) {
  Impl& m = *m_impl;
  if (!m.started) throw std::logic_error("PoseTracker::track() before start()");
  if (frame.cols != m.camera.width || frame.rows != m.camera.height)
    throw InputError("frame of " + std::to_string(frame.cols) + "x" + std::to_string(frame.rows) +
                     " pixels, the camera expects " + std::to_string(m.camera.width) + "x" +
                     std::to_string(m.camera.height));
  TrackFrameInfo local;
  TrackFrameInfo& out = info ? *info : local;
  out = TrackFrameInfo{};
  const cv::Mat g = grey(frame);
  const std::vector<cv::Mat> pyr = m.pyramid(g);

  // Constant-velocity prediction in the camera frame; while lost, the coasting pose keeps
  // moving with the last velocity (to tell an object that left the view from a hidden one).
  const Pose predicted = m.have_velocity ? m.extrapolate(m.prev_pose) : m.prev_pose;
  m.coast = m.have_velocity ? m.extrapolate(m.coast) : m.coast;
  out.in_view = m.in_view(m.coast);

  std::vector<cv::Point3d> object;
  std::vector<cv::Point2d> image;
  m.follow(m.key_pyramid, m.key, pyr, predicted, object, image);
  const size_t n_key = object.size();
  // Keyframe corners carry exact mesh points and drop out where an occluder covers them
  // (their window no longer matches); the previous frame's are re-detected every frame, on an
  // occluder too. So the previous frame's corners only help when the keyframe's run short.
  const bool enough_key = static_cast<int>(n_key) >= 3 * m.options.min_inliers;
  if (!m.last_lost && !enough_key) m.follow(m.prev_pyramid, m.prev, pyr, predicted, object, image);
  out.correspondences = static_cast<int>(object.size());

  std::optional<Pose> result;
  std::vector<int> inliers;
  if (static_cast<int>(object.size()) >= m.options.min_inliers) {
    cv::Mat rvec, tvec;
    to_cv(predicted, rvec, tvec);
    const cv::Matx33d k = camera_matrix(m.camera);
    // SQPnP (globally optimal, also for nearly planar point sets) inside RANSAC; the iterative
    // solver started from the prediction can run away there.
    const bool ok = cv::solvePnPRansac(object, image, k, cv::noArray(), rvec, tvec, false, 200,
                                       static_cast<float>(m.options.ransac_px), 0.999, inliers,
                                       cv::SOLVEPNP_SQPNP);
    if (ok && static_cast<int>(inliers.size()) >= m.options.min_inliers) {
      std::vector<cv::Point3d> oi;
      std::vector<cv::Point2d> ii;
      for (int i : inliers) {
        oi.push_back(object[static_cast<size_t>(i)]);
        ii.push_back(image[static_cast<size_t>(i)]);
      }
      auto rms = [&](const cv::Mat& r, const cv::Mat& t) {
        std::vector<cv::Point2d> proj;
        cv::projectPoints(oi, r, t, k, cv::noArray(), proj);
        double sq = 0.0;
        for (size_t i = 0; i < proj.size(); ++i) sq += std::pow(cv::norm(proj[i] - ii[i]), 2);
        const double v = std::sqrt(sq / static_cast<double>(proj.size()));
        return std::isfinite(v) && t.at<double>(2) > 0 ? v
                                                       : std::numeric_limits<double>::infinity();
      };
      // Levenberg-Marquardt on the inliers, kept only when it lowers their error (it can
      // run away on nearly planar point sets).
      cv::Mat r2 = rvec.clone(), t2 = tvec.clone();
      cv::solvePnPRefineLM(oi, ii, k, cv::noArray(), r2, t2);
      out.rms_px = rms(rvec, tvec);
      const double refined = rms(r2, t2);
      if (refined < out.rms_px) {
        out.rms_px = refined;
        rvec = r2;
        tvec = t2;
      }
      const Pose p = from_cv(rvec, tvec);
      out.inliers = static_cast<int>(inliers.size());
      if (p.translation.z() > 0 && out.rms_px <= m.options.ransac_px) result = p;
    }
  }

  if (!result) {
    out.lost = true;
    m.last_lost = true;
    return std::nullopt;  // keep the keyframe and the last pose: resume near it
  }
  const Pose& pose = *result;
  int key_inliers = 0;
  for (int i : inliers) key_inliers += static_cast<size_t>(i) < n_key;

  // Next frame's short-baseline corners, found anew in this frame.
  m.prev = m.detect(g, pose);
  m.prev_pyramid = pyr;
  if (m.last_lost) {
    m.have_velocity = false;  // the last pose is old: no velocity from it
  } else {
    m.velocity_rotation = pose.rotation * m.prev_pose.rotation.transpose();
    m.velocity_translation = pose.translation - m.velocity_rotation * m.prev_pose.translation;
    m.have_velocity = true;
  }
  m.prev_pose = m.coast = pose;
  m.last_lost = false;

  const double turned =
      rotation_angle(m.key_pose.rotation, pose.rotation) * 180.0 / std::numbers::pi;
  if (turned > m.options.keyframe_angle_deg ||
      key_inliers < m.options.keyframe_keep * static_cast<double>(m.key_initial)) {
    if (static_cast<int>(m.prev.size()) >= m.options.min_inliers) {
      m.key = m.prev;
      m.key_pyramid = pyr;
      m.key_initial = m.key.size();
      m.key_pose = pose;
      out.new_keyframe = true;
    }
  }
  return result;
}

TrackResult track_footage(Footage& footage, const Mesh& mesh, const Camera& camera,
                          const Pose& initial, const TrackOptions& options,
                          const TrackFrameCallback& on_frame) {
  TrackResult out;
  const int n = footage.frame_count();
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
  std::vector<cv::Point3d> o;
  std::vector<cv::Point2d> i;
  for (size_t k = 0; k < pixels.size(); ++k) {
    o.emplace_back(mesh_points[k].x(), mesh_points[k].y(), mesh_points[k].z());
    i.emplace_back(pixels[k].x(), pixels[k].y());
  }
  const cv::Matx33d kmat = camera_matrix(camera);
  cv::Mat rvec, tvec;
  const int method = o.size() >= 6 ? cv::SOLVEPNP_ITERATIVE : cv::SOLVEPNP_SQPNP;
  if (!cv::solvePnP(o, i, kmat, cv::noArray(), rvec, tvec, false, method))
    throw InputError("correspondences: no pose fits them");
  cv::solvePnPRefineLM(o, i, kmat, cv::noArray(), rvec, tvec);
  std::vector<cv::Point2d> proj;
  cv::projectPoints(o, rvec, tvec, kmat, cv::noArray(), proj);
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

void draw_mesh_edges(cv::Mat& image, const Mesh& mesh, const Camera& camera, const Pose& pose,
                     const cv::Scalar& color, double crease_deg) {
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
