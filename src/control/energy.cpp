#include "pbve/control/energy.hpp"

#include <cmath>
#include <stdexcept>
#include <string>

#include <Eigen/Geometry>

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
