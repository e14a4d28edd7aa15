#include "pbve/control/energy.hpp"

#include <cmath>
#include <stdexcept>
#include <string>

#include <Eigen/Geometry>

#include "pbve/visibility/ray_scene.hpp"

namespace pbve {

namespace {

// The log barrier and its first two derivatives on (0, 1).
void log_barrier(double s, double& f, double& d1, double& d2) {
  const double l = std::log(s);
  const double q = s - 1.0;
  f = -q * q * l;
  d1 = -2.0 * q * l - q * q / s;
  d2 = -2.0 * l - 4.0 * q / s + q * q / (s * s);
}

}  // namespace

double visibility_barrier(double sigma, const VisibilityBarrier& barrier, double* derivative) {
  if (sigma >= 1.0) {
    if (derivative) *derivative = 0.0;
    return 0.0;
  }
  double f, d1, d2;
  if (sigma >= barrier.clamp) {
    log_barrier(sigma, f, d1, d2);
    if (derivative) *derivative = d1;
    return f;
  }
  log_barrier(barrier.clamp, f, d1, d2);
  const double t = sigma - barrier.clamp;
  if (derivative) *derivative = d1 + d2 * t;
  return f + d1 * t + 0.5 * d2 * t * t;
}

double facing_value(const Eigen::Vector3d& a, const Eigen::Vector3d& b, const Eigen::Vector3d& c,
                    Eigen::Matrix3d* grad) {
  const Eigen::Vector3d n = (b - a).cross(c - a);
  const Eigen::Vector3d m = (a + b + c) / 3.0;
  const double nn = n.norm(), mn = m.norm();
  if (grad) grad->setZero();
  if (!(nn > 0.0) || !(mn > 0.0)) return 0.0;
  const double det = n.dot(a);  // = det[a, b, c] = <n, m>
  const double s = det / (nn * mn);
  if (grad) {
    const Eigen::Vector3d nh = n / nn, mh = m / mn;
    const double inv = 1.0 / (nn * mn);
    // d det: (b x c, c x a, a x b); d|n|: ((b - c) x nh, (c - a) x nh, nh x (b - a));
    // d|m| = mh / 3 for each vertex.
    const Eigen::Vector3d dd[3] = {b.cross(c), c.cross(a), a.cross(b)};
    const Eigen::Vector3d dn[3] = {(b - c).cross(nh), (c - a).cross(nh), nh.cross(b - a)};
    for (int k = 0; k < 3; ++k)
      grad->row(k) = (dd[k] * inv - s * (dn[k] / nn + mh / (3.0 * mn))).transpose();
  }
  return s;
}

Eigen::VectorXd visibility_weights(const Vertices& vertices, const Triangles& triangles) {
  check_triangle_indices(triangles, vertices.rows(), "visibility_weights");
  Eigen::VectorXd w(triangles.rows());
  double total = 0.0;
  for (Eigen::Index j = 0; j < triangles.rows(); ++j) {
    const Eigen::Vector3d a = vertices.row(triangles(j, 0)).transpose();
    const Eigen::Vector3d b = vertices.row(triangles(j, 1)).transpose();
    const Eigen::Vector3d c = vertices.row(triangles(j, 2)).transpose();
    w[j] = 0.5 * (b - a).cross(c - a).norm();
    total += w[j];
  }
  if (total > 0.0) w /= total;
  return w;
}

double visibility_energy(const Vertices& vertices, const Triangles& triangles,
                         const std::vector<std::uint8_t>& penalized, const Eigen::VectorXd& weights,
                         const VisibilityBarrier& barrier, Vertices* gradient) {
  const auto nf = static_cast<size_t>(triangles.rows());
  if (penalized.size() != nf || static_cast<size_t>(weights.size()) != nf)
    throw std::invalid_argument("visibility_energy: penalized and weights need " +
                                std::to_string(nf) + " entries");
  if (!(barrier.margin > 0.0) || !(barrier.clamp > 0.0 && barrier.clamp < 1.0))
    throw std::invalid_argument("visibility_energy: need margin > 0 and 0 < clamp < 1");
  check_triangle_indices(triangles, vertices.rows(), "visibility_energy");
  if (gradient) gradient->setZero(vertices.rows(), 3);
  double e = 0.0;
  Eigen::Matrix3d g;
  for (size_t j = 0; j < nf; ++j) {
    if (!penalized[j] || weights[static_cast<Eigen::Index>(j)] == 0.0) continue;
    const auto jj = static_cast<Eigen::Index>(j);
    const int ia = triangles(jj, 0), ib = triangles(jj, 1), ic = triangles(jj, 2);
    const double s = facing_value(vertices.row(ia).transpose(), vertices.row(ib).transpose(),
                                  vertices.row(ic).transpose(), gradient ? &g : nullptr);
    const double sigma = s / barrier.margin;
    if (sigma >= 1.0) continue;
    double d = 0.0;
    e += weights[jj] * visibility_barrier(sigma, barrier, &d);
    if (gradient) {
      const double k = weights[jj] * d / barrier.margin;
      gradient->row(ia) += k * g.row(0);
      gradient->row(ib) += k * g.row(1);
      gradient->row(ic) += k * g.row(2);
    }
  }
  return e;
}

double occlusion_depth(const Vertices& vertices, const Triangles& triangles,
                       const OcclusionPair& pair, Eigen::Matrix<double, 4, 3>* grad) {
  const auto t = static_cast<Eigen::Index>(pair.triangle);
  const Eigen::Index nv = vertices.rows();
  auto bad_vertex = [nv](Eigen::Index v) { return v < 0 || v >= nv; };
  if (bad_vertex(pair.vertex) || t < 0 || t >= triangles.rows() || bad_vertex(triangles(t, 0)) ||
      bad_vertex(triangles(t, 1)) || bad_vertex(triangles(t, 2)))
    throw std::invalid_argument("occlusion_depth: pair (vertex " + std::to_string(pair.vertex) +
                                ", triangle " + std::to_string(pair.triangle) +
                                ") is outside the mesh (" + std::to_string(nv) + " vertices, " +
                                std::to_string(triangles.rows()) + " triangles)");
  const Eigen::Vector3d p = vertices.row(pair.vertex).transpose();
  const Eigen::Vector3d a = vertices.row(triangles(t, 0)).transpose();
  const Eigen::Vector3d b = vertices.row(triangles(t, 1)).transpose();
  const Eigen::Vector3d c = vertices.row(triangles(t, 2)).transpose();
  const Eigen::Vector3d e1 = b - a, e2 = c - a, n = e1.cross(e2), q = p - a;
  const double nn = n.norm();
  if (grad) grad->setZero();
  if (!(nn > 0.0) || !(pair.rest_depth > 0.0)) return 0.0;
  const double inv = 1.0 / (pair.rest_depth * nn);
  const double h = -n.dot(q) * inv;
  if (grad) {
    // h = -<n, q> / (|n| D): d/dq = -n / (|n| D); d/dn = g = -q / (|n| D) - h n / |n|^2, and
    // with n = e1 x e2: d/de1 = e2 x g, d/de2 = g x e1.
    const Eigen::Vector3d dq = -n * inv;
    const Eigen::Vector3d g = -q * inv - (h / (nn * nn)) * n;
    const Eigen::Vector3d de1 = e2.cross(g), de2 = g.cross(e1);
    grad->row(0) = dq.transpose();
    grad->row(1) = (-dq - de1 - de2).transpose();
    grad->row(2) = de1.transpose();
    grad->row(3) = de2.transpose();
  }
  return h;
}

double occlusion_energy(const Vertices& vertices, const Triangles& triangles,
                        const std::vector<OcclusionPair>& pairs, const VisibilityBarrier& barrier,
                        Vertices* gradient) {
  if (!(barrier.margin > 0.0) || !(barrier.clamp > 0.0 && barrier.clamp < 1.0))
    throw std::invalid_argument("occlusion_energy: need margin > 0 and 0 < clamp < 1");
  if (gradient) gradient->setZero(vertices.rows(), 3);
  double e = 0.0;
  Eigen::Matrix<double, 4, 3> g;
  for (const OcclusionPair& pr : pairs) {
    const double sigma =
        occlusion_depth(vertices, triangles, pr, gradient ? &g : nullptr) / barrier.margin;
    if (sigma >= 1.0 || pr.weight == 0.0) continue;
    double d = 0.0;
    e += pr.weight * visibility_barrier(sigma, barrier, &d);
    if (gradient) {
      const double k = pr.weight * d / barrier.margin;
      const auto t = static_cast<Eigen::Index>(pr.triangle);
      gradient->row(pr.vertex) += k * g.row(0);
      for (int c = 0; c < 3; ++c) gradient->row(triangles(t, c)) += k * g.row(1 + c);
    }
  }
  return e;
}

std::vector<OcclusionPair> occlusion_pairs(const Vertices& current, const Vertices& reference,
                                           const Triangles& triangles,
                                           const std::vector<std::uint8_t>& penalized,
                                           const std::vector<std::uint8_t>& observed,
                                           double min_depth) {
  const auto nf = static_cast<size_t>(triangles.rows());
  if (penalized.size() != nf || observed.size() != nf)
    throw std::invalid_argument("occlusion_pairs: penalized and observed need " +
                                std::to_string(nf) + " entries");
  if (reference.rows() != current.rows())
    throw std::invalid_argument("occlusion_pairs: reference has " +
                                std::to_string(reference.rows()) + " vertices, expected " +
                                std::to_string(current.rows()));
  check_triangle_indices(triangles, current.rows(), "occlusion_pairs");
  const auto nv = static_cast<size_t>(current.rows());
  std::vector<char> on_observed(nv, 0), candidate(nv, 0);
  std::vector<int> observed_ids;
  for (size_t j = 0; j < nf; ++j) {
    const auto jj = static_cast<Eigen::Index>(j);
    if (observed[j]) {
      observed_ids.push_back(static_cast<int>(j));
      for (int c = 0; c < 3; ++c) on_observed[static_cast<size_t>(triangles(jj, c))] = 1;
    } else if (penalized[j]) {
      for (int c = 0; c < 3; ++c) candidate[static_cast<size_t>(triangles(jj, c))] = 1;
    }
  }
  std::vector<int> vertices;
  for (size_t v = 0; v < nv; ++v)
    if (candidate[v] && !on_observed[v]) vertices.push_back(static_cast<int>(v));
  std::vector<OcclusionPair> out;
  if (vertices.empty() || observed_ids.empty()) return out;

  Triangles front(static_cast<Eigen::Index>(observed_ids.size()), 3);
  for (size_t k = 0; k < observed_ids.size(); ++k)
    front.row(static_cast<Eigen::Index>(k)) = triangles.row(observed_ids[k]);
  const RayScene scene(current, front);
  const auto nr = static_cast<Eigen::Index>(vertices.size());
  Eigen::MatrixX3d origins = Eigen::MatrixX3d::Zero(nr, 3), directions(nr, 3);
  for (Eigen::Index r = 0; r < nr; ++r)
    directions.row(r) = current.row(vertices[static_cast<size_t>(r)]);
  // Hits strictly in front of p (t = 1 is p itself).
  const std::vector<RayHit> hits = scene.intersect(origins, directions, 0.0, 1.0 - 1e-6);

  // Vertex area shares on the reference shape.
  Eigen::VectorXd share = Eigen::VectorXd::Zero(current.rows());
  const Eigen::VectorXd area = visibility_weights(reference, triangles);  // area / total
  for (size_t j = 0; j < nf; ++j)
    for (int c = 0; c < 3; ++c)
      share[triangles(static_cast<Eigen::Index>(j), c)] += area[static_cast<Eigen::Index>(j)] / 3.0;
  for (Eigen::Index r = 0; r < nr; ++r) {
    const RayHit& hit = hits[static_cast<size_t>(r)];
    if (hit.triangle < 0) continue;
    OcclusionPair pr;
    pr.vertex = vertices[static_cast<size_t>(r)];
    pr.triangle = observed_ids[static_cast<size_t>(hit.triangle)];
    pr.rest_depth = 1.0;
    // Depth behind T's plane in the reference shape: h with rest depth 1 is that depth.
    const double depth = occlusion_depth(reference, triangles, pr, nullptr);
    if (!(depth > min_depth)) continue;
    pr.rest_depth = depth;
    pr.weight = share[pr.vertex];
    out.push_back(pr);
  }
  return out;
}

double smoothed_norm_sum(const Eigen::VectorXd& x, int block, const Eigen::VectorXd& eps,
                         Eigen::VectorXd* gradient) {
  if (block <= 0 || x.size() != eps.size() * block)
    throw std::invalid_argument("smoothed_norm_sum: x has " + std::to_string(x.size()) +
                                " entries, expected " + std::to_string(eps.size() * block));
  if (gradient) gradient->setZero(x.size());
  double e = 0.0;
  for (Eigen::Index b = 0; b < eps.size(); ++b) {
    const auto xb = x.segment(b * block, block);
    const double r = std::sqrt(xb.squaredNorm() + eps[b] * eps[b]);
    e += r - eps[b];
    if (gradient && r > 0.0) gradient->segment(b * block, block) = xb / r;
  }
  return e;
}

}  // namespace pbve
