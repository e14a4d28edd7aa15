#include "track/region.hpp"

#include <algorithm>
#include <cmath>
#include <map>
#include <stdexcept>
#include <string>
#include <utility>

namespace pbve::track_detail {

using Eigen::Vector2d;
using Eigen::Vector3d;

std::vector<MeshEdge> mesh_edges(const Mesh& mesh) {
  std::map<std::pair<int, int>, size_t> index;
  std::vector<MeshEdge> edges;
  for (int f = 0; f < mesh.num_triangles(); ++f)
    for (int k = 0; k < 3; ++k) {
      const int a = mesh.triangles(f, k), b = mesh.triangles(f, (k + 1) % 3);
      const int o = mesh.triangles(f, (k + 2) % 3);
      const auto key = std::minmax(a, b);
      const auto [it, added] = index.try_emplace(key, edges.size());
      if (added) {
        MeshEdge e;
        e.a = key.first;
        e.b = key.second;
        e.face[0] = f;
        e.opposite[0] = o;
        edges.push_back(e);
      } else if (edges[it->second].face[1] < 0) {
        edges[it->second].face[1] = f;
        edges[it->second].opposite[1] = o;
      }
      // A third face on an edge (non-manifold) is ignored here.
    }
  return edges;
}

std::vector<ContourPoint> sample_contour(const Mesh& mesh, const std::vector<MeshEdge>& edges,
                                         const RayScene& scene, const Camera& camera,
                                         const Pose& pose, double spacing_px, int max_points,
                                         double reach_px, double probe_px) {
  const Vertices v = pose.apply(mesh.vertices);
  const Eigen::Index nv = v.rows();
  std::vector<Vector2d> q(static_cast<size_t>(nv));
  std::vector<char> ahead(static_cast<size_t>(nv));
  for (Eigen::Index i = 0; i < nv; ++i) {
    ahead[static_cast<size_t>(i)] = v(i, 2) > 1e-9;
    if (ahead[static_cast<size_t>(i)])
      q[static_cast<size_t>(i)] = camera.project(v.row(i).transpose());
  }
  const int nf = mesh.num_triangles();
  std::vector<char> front(static_cast<size_t>(nf));
  for (int f = 0; f < nf; ++f) {
    const Vector3d a = v.row(mesh.triangles(f, 0)), b = v.row(mesh.triangles(f, 1)),
                   c = v.row(mesh.triangles(f, 2));
    front[static_cast<size_t>(f)] = (b - a).cross(c - a).dot(a) < 0.0;
  }
  struct Segment {
    const MeshEdge* edge;
    Vector2d normal;
    double length;
  };
  std::vector<Segment> segments;
  double total = 0.0;
  for (const MeshEdge& e : edges) {
    const bool f0 = e.face[0] >= 0 && front[static_cast<size_t>(e.face[0])];
    const bool f1 = e.face[1] >= 0 && front[static_cast<size_t>(e.face[1])];
    if (f0 == f1) continue;
    const int o = f0 ? e.opposite[0] : e.opposite[1];
    if (!ahead[static_cast<size_t>(e.a)] || !ahead[static_cast<size_t>(e.b)] ||
        !ahead[static_cast<size_t>(o)])
      continue;
    const Vector2d p0 = q[static_cast<size_t>(e.a)], p1 = q[static_cast<size_t>(e.b)];
    const Vector2d d = p1 - p0;
    const double len = d.norm();
    if (!(len > 1e-9)) continue;
    Vector2d n(d.y() / len, -d.x() / len);
    if (n.dot(q[static_cast<size_t>(o)] - p0) > 0) n = -n;  // away from the facing face
    segments.push_back({&e, n, len});
    total += len;
  }
  std::vector<ContourPoint> out;
  if (segments.empty() || max_points <= 0) return out;
  const double step = std::max(spacing_px, total / max_points);
  std::vector<ContourPoint> candidates;
  double s = 0.5 * step;
  for (const Segment& seg : segments) {
    for (; s < seg.length; s += step) {
      const double lambda = s / seg.length;
      ContourPoint c;
      c.point = (1 - lambda) * Vector3d(mesh.vertices.row(seg.edge->a)) +
                lambda * Vector3d(mesh.vertices.row(seg.edge->b));
      c.pixel = camera.project(pose.apply(c.point));
      c.normal = seg.normal;
      const Vector2d lo = c.pixel - reach_px * c.normal, hi = c.pixel + reach_px * c.normal;
      const double w = camera.width - 1, h = camera.height - 1;
      if (std::min(lo.x(), hi.x()) < 0 || std::min(lo.y(), hi.y()) < 0 ||
          std::max(lo.x(), hi.x()) > w || std::max(lo.y(), hi.y()) > h)
        continue;
      candidates.push_back(c);
    }
    s -= seg.length;
  }
  if (candidates.empty()) return out;
  // Keep the points whose outer side shows no part of the object: a ray just outside misses.
  const Eigen::Matrix3d rt = pose.rotation.transpose();
  const Vector3d origin = -rt * pose.translation;
  const Eigen::Index n = static_cast<Eigen::Index>(candidates.size());
  Eigen::MatrixX3d o(n, 3), d(n, 3);
  for (Eigen::Index i = 0; i < n; ++i) {
    const ContourPoint& c = candidates[static_cast<size_t>(i)];
    o.row(i) = origin.transpose();
    d.row(i) = (rt * camera.ray_direction(c.pixel + probe_px * c.normal)).transpose();
  }
  const std::vector<RayHit> hits = scene.intersect(o, d);
  for (Eigen::Index i = 0; i < n; ++i)
    if (hits[static_cast<size_t>(i)].triangle < 0)
      out.push_back(candidates[static_cast<size_t>(i)]);
  return out;
}

void ColourModel::update(const std::vector<cv::Vec3b>& fg, const std::vector<cv::Vec3b>& bg,
                         double rate) {
  constexpr size_t kBins = 32 * 32 * 32;
  auto blend = [&](std::vector<float>& h, const std::vector<cv::Vec3b>& pixels) {
    if (h.empty()) h.assign(kBins, 0.0f);
    if (pixels.empty()) return;
    const bool replace = rate >= 1.0;
    const float keep = replace ? 0.0f : static_cast<float>(1.0 - rate);
    for (float& x : h) x *= keep;
    const float add =
        static_cast<float>((replace ? 1.0 : rate) / static_cast<double>(pixels.size()));
    for (const cv::Vec3b& c : pixels) h[static_cast<size_t>(index(c))] += add;
  };
  const bool first = m_fg.empty();
  if (first) rate = 1.0;
  blend(m_fg, fg);
  blend(m_bg, bg);
}

namespace {

inline cv::Vec3b pixel_at(const cv::Mat& bgr, const Vector2d& p) {
  const int x = std::clamp(static_cast<int>(std::lround(p.x())), 0, bgr.cols - 1);
  const int y = std::clamp(static_cast<int>(std::lround(p.y())), 0, bgr.rows - 1);
  return bgr.at<cv::Vec3b>(y, x);
}

}  // namespace

LineEstimate estimate_line(const cv::Mat& bgr, const ColourModel& model, const ContourPoint& c,
                           const LineOptions& o) {
  LineEstimate out;
  // The work arrays below are sized for lines of at most kMaxOffsets offsets either way and
  // kMaxSegments segments either way (the tracker uses 5 and 10).
  constexpr int kMaxOffsets = 31, kMaxSegments = 32;
  if (o.range < 0 || o.context < 0 || o.range > kMaxOffsets || o.range + o.context > kMaxSegments)
    throw std::invalid_argument("estimate_line: range " + std::to_string(o.range) +
                                " and context " + std::to_string(o.context) +
                                " outside 0 <= range <= 31, range + context <= 32");
  const int k = std::max(1, o.scale);
  const int segments = o.range + o.context;  // either way
  const int from = -segments * k, to = segments * k;
  const Vector2d lo = c.pixel + from * c.normal, hi = c.pixel + to * c.normal;
  if (std::min(lo.x(), hi.x()) < -0.5 || std::min(lo.y(), hi.y()) < -0.5 ||
      std::max(lo.x(), hi.x()) > bgr.cols - 0.5 || std::max(lo.y(), hi.y()) > bgr.rows - 0.5)
    return out;
  // Per pixel, P(foreground | colour); per segment, the same for its k pixels together.
  float pf[256];
  const int npx = to - from;
  if (npx > 256) return out;
  for (int i = 0; i < npx; ++i) {
    const float p = model.foreground(pixel_at(bgr, c.pixel + (from + i + 0.5) * c.normal));
    pf[i] = std::clamp(p, 1e-3f, 1.0f - 1e-3f);
  }
  double seg_f[128];
  const int ns = 2 * segments;
  for (int s = 0; s < ns; ++s) {
    double pf_all = 1.0, pb_all = 1.0;
    for (int j = 0; j < k; ++j) {
      pf_all *= pf[s * k + j];
      pb_all *= 1.0f - pf[s * k + j];
    }
    seg_f[s] = pf_all / (pf_all + pb_all);
  }
  // Posterior of the contour at offset m (segments, positive outwards): segment s, centred at
  // x = s - segments + 0.5, is foreground with probability h_f(x - m). x - m takes the values
  // d + 0.5 for integer d in [-segments - range, segments + range).
  double hf_table[128];
  const int d0 = -segments - o.range;
  for (int d = d0; d < segments + o.range; ++d)
    hf_table[d - d0] = 0.5 - o.amplitude * std::tanh((d + 0.5) / (2.0 * o.slope));
  double logp[64];
  const int nm = 2 * o.range + 1;
  double best = -1e300;
  for (int mi = 0; mi < nm; ++mi) {
    const int m = mi - o.range;
    // Products of at most 8 factors (each at least 0.5 - amplitude) stay far from underflow.
    double l = 0.0, prod = 1.0;
    for (int s = 0; s < ns; ++s) {
      const double hf = hf_table[s - segments - m - d0];
      prod *= hf * seg_f[s] + (1.0 - hf) * (1.0 - seg_f[s]);
      if ((s & 7) == 7) {
        l += std::log(prod);
        prod = 1.0;
      }
    }
    l += std::log(prod);
    logp[mi] = l;
    best = std::max(best, l);
  }
  double sum = 0.0, mean = 0.0;
  for (int mi = 0; mi < nm; ++mi) {
    logp[mi] = std::exp(logp[mi] - best);
    sum += logp[mi];
    mean += logp[mi] * (mi - o.range);
  }
  mean /= sum;
  double var = 0.0;
  for (int mi = 0; mi < nm; ++mi) var += logp[mi] / sum * std::pow(mi - o.range - mean, 2);
  out.mean_px = mean * k;
  out.variance_px2 = k * k * std::max(var, 0.1) + 0.25;
  double fi = 0.0, bo = 0.0;
  int ni = 0, no = 0;
  // Measured from the projected contour, not from the estimate: an occluder covering the
  // object's rim moves the estimate inwards, to where the object shows again.
  for (int i = 0; i < npx; ++i) {
    const double x = from + i + 0.5;
    if (x < -2.0) {
      fi += pf[i];
      ++ni;
    } else if (x > 2.0) {
      bo += 1.0 - pf[i];
      ++no;
    }
  }
  out.inner_foreground = ni > 0 ? fi / ni : 0.0;
  out.outer_background = no > 0 ? bo / no : 0.0;
  out.valid = true;
  return out;
}

void line_pixels(const cv::Mat& bgr, const ContourPoint& c, int from_px, int to_px,
                 std::vector<cv::Vec3b>& out) {
  for (int o = from_px; o < to_px; ++o) {
    const Vector2d p = c.pixel + (o + 0.5) * c.normal;
    if (p.x() < -0.5 || p.y() < -0.5 || p.x() > bgr.cols - 0.5 || p.y() > bgr.rows - 0.5) continue;
    out.push_back(pixel_at(bgr, p));
  }
}

double line_fraction(const cv::Mat& mask, const ContourPoint& c, int from_px, int to_px) {
  int n = 0, on = 0;
  for (int o = from_px; o < to_px; ++o) {
    const Vector2d p = c.pixel + (o + 0.5) * c.normal;
    const int x = static_cast<int>(std::lround(p.x())), y = static_cast<int>(std::lround(p.y()));
    if (x < 0 || y < 0 || x >= mask.cols || y >= mask.rows) continue;
    ++n;
    on += mask.at<uchar>(y, x) != 0;
  }
  return n > 0 ? static_cast<double>(on) / n : 0.0;
}

}  // namespace pbve::track_detail
