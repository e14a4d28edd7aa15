#include "pbve/visibility/energy.hpp"

#include <cmath>
#include <limits>
#include <string>

#include <Eigen/Geometry>

#include "pbve/core/error.hpp"

namespace pbve {
namespace {

void check_size(size_t size, Eigen::Index expected, const char* name) {
  if (size != static_cast<size_t>(expected))
    throw InputError(std::string(name) + " has " + std::to_string(size) + " entries, expected " +
                     std::to_string(expected));
}

}  // namespace

std::vector<std::uint8_t> constrained_triangles(const std::vector<std::uint8_t>& observed_in_input,
                                                const std::vector<std::uint8_t>& interior) {
  if (!interior.empty())
    check_size(interior.size(), static_cast<Eigen::Index>(observed_in_input.size()), "interior");
  std::vector<std::uint8_t> mask(observed_in_input.size());
  for (size_t j = 0; j < mask.size(); ++j)
    mask[j] = !observed_in_input[j] && (interior.empty() || !interior[j]);
  return mask;
}

ExactVisibilityEnergy visibility_energy_exact(const std::vector<std::uint8_t>& observed_in_input,
                                              const TriangleVisibility& simulated,
                                              const std::vector<std::uint8_t>& interior) {
  const Eigen::Index nf = simulated.num_triangles();
  check_size(observed_in_input.size(), nf, "observed_in_input");
  if (!interior.empty()) check_size(interior.size(), nf, "interior");
  check_size(static_cast<size_t>(simulated.projected_area_px.size()), nf, "projected_area_px");
  ExactVisibilityEnergy e;
  for (Eigen::Index j = 0; j < nf; ++j) {
    const size_t i = static_cast<size_t>(j);
    if (!simulated.visible[i]) continue;
    const double a = simulated.projected_area_px[j];
    e.total_area_px += a;
    if (!observed_in_input[i] && (interior.empty() || !interior[i])) {
      ++e.violating_count;
      e.violating_area_px += a;
    }
  }
  e.value = e.total_area_px > 0.0 ? e.violating_area_px / e.total_area_px : 0.0;
  return e;
}

PenaltyValue smooth_penalty(double s, const SmoothVisibilityOptions& options) {
  const double mu = options.margin;
  PenaltyValue p;
  if (s >= mu) return p;
  if (options.penalty == SmoothPenalty::quadratic) {
    const double d = mu - s;
    p.value = d * d;
    p.d1 = -2.0 * d;
    p.d2 = 2.0;
    return p;
  }
  // Clamped log barrier b(s) = -(s - mu)^2 log(s / mu) on (s_floor, mu).
  auto barrier = [mu](double x) {
    const double d = x - mu, l = std::log(x / mu);
    PenaltyValue b;
    b.value = -d * d * l;
    b.d1 = -2.0 * d * l - d * d / x;
    b.d2 = -2.0 * l - 4.0 * d / x + d * d / (x * x);
    return b;
  };
  const double s_floor = options.barrier_floor * mu;
  if (s > s_floor) return barrier(s);
  const PenaltyValue f = barrier(s_floor);
  const double h = s - s_floor;
  p.value = f.value + f.d1 * h + 0.5 * f.d2 * h * h;
  p.d1 = f.d1 + f.d2 * h;
  p.d2 = f.d2;
  return p;
}

FacingGradient facing_gradient(const Eigen::Vector3d& a, const Eigen::Vector3d& b,
                               const Eigen::Vector3d& c) {
  FacingGradient r;
  const Eigen::Vector3d e1 = b - a, e2 = c - a;
  const Eigen::Vector3d n = e1.cross(e2);
  const Eigen::Vector3d centroid = (a + b + c) / 3.0;
  const double nn = n.norm(), cn = centroid.norm();
  if (!(nn > 0.0) || !(cn > 0.0)) return r;
  // g = <n, centroid> = det[a, b, c]; s = g / (|n| |centroid|).
  const double g = a.dot(b.cross(c));
  r.s = g / (nn * cn);
  const Eigen::Vector3d nh = n / nn, ch = centroid / cn;
  // dg: b x c, c x a, a x b.  d|n|: -(e2 x nh + nh x e1), e2 x nh, nh x e1.  d|c| = ch / 3.
  const Eigen::Vector3d dn_b = e2.cross(nh), dn_c = nh.cross(e1);
  const Eigen::Vector3d dn_a = -(dn_b + dn_c);
  const double inv = 1.0 / (nn * cn);
  const double kn = r.s / nn, kc = r.s / (3.0 * cn);
  r.da = inv * b.cross(c) - kn * dn_a - kc * ch;
  r.db = inv * c.cross(a) - kn * dn_b - kc * ch;
  r.dc = inv * a.cross(b) - kn * dn_c - kc * ch;
  return r;
}

SmoothVisibilityEnergy visibility_energy_smooth(const Vertices& vertices,
                                                const Triangles& triangles,
                                                const std::vector<std::uint8_t>& constrained,
                                                const Eigen::VectorXd& weights,
                                                const SmoothVisibilityOptions& options) {
  const Eigen::Index nf = triangles.rows();
  check_triangle_indices(triangles, vertices.rows(), "visibility_energy_smooth");
  check_size(constrained.size(), nf, "constrained");
  check_size(static_cast<size_t>(weights.size()), nf, "weights");
  if (!(options.margin > 0.0)) throw InputError("smooth visibility margin must be positive");
  if (options.penalty == SmoothPenalty::log_barrier &&
      !(options.barrier_floor > 0.0 && options.barrier_floor < 1.0))
    throw InputError("barrier_floor must lie in (0, 1)");
  SmoothVisibilityEnergy e;
  e.gradient = Vertices::Zero(vertices.rows(), 3);
  for (Eigen::Index j = 0; j < nf; ++j) {
    if (!constrained[static_cast<size_t>(j)] || weights[j] == 0.0) continue;
    const int ia = triangles(j, 0), ib = triangles(j, 1), ic = triangles(j, 2);
    const Eigen::Vector3d a = vertices.row(ia).transpose(), b = vertices.row(ib).transpose(),
                          c = vertices.row(ic).transpose();
    const Eigen::Vector3d n = (b - a).cross(c - a);
    const Eigen::Vector3d centroid = (a + b + c) / 3.0;
    const double scale = n.norm() * centroid.norm();
    const double s = scale > 0.0 ? n.dot(centroid) / scale : 0.0;
    if (s >= options.margin) continue;
    const PenaltyValue p = smooth_penalty(s, options);
    e.value += weights[j] * p.value;
    ++e.active_count;
    const FacingGradient fg = facing_gradient(a, b, c);
    const double k = weights[j] * p.d1;
    e.gradient.row(ia) += k * fg.da.transpose();
    e.gradient.row(ib) += k * fg.db.transpose();
    e.gradient.row(ic) += k * fg.dc.transpose();
  }
  return e;
}

Eigen::VectorXd area_weights(const Vertices& vertices, const Triangles& triangles) {
  check_triangle_indices(triangles, vertices.rows(), "area_weights");
  Eigen::VectorXd w(triangles.rows());
  for (Eigen::Index j = 0; j < triangles.rows(); ++j) {
    const Eigen::Vector3d a = vertices.row(triangles(j, 0)).transpose();
    const Eigen::Vector3d b = vertices.row(triangles(j, 1)).transpose();
    const Eigen::Vector3d c = vertices.row(triangles(j, 2)).transpose();
    w[j] = 0.5 * (b - a).cross(c - a).norm();
  }
  const double total = w.sum();
  if (total > 0.0) w /= total;
  return w;
}

namespace {

ForceEnergy smoothed_norm_sum(const ForceMatrix& diff, double eps) {
  if (!(eps > 0.0)) throw InputError("force smoothing eps must be positive");
  ForceEnergy e;
  e.gradient.resize(diff.rows(), diff.cols());
  for (Eigen::Index i = 0; i < diff.rows(); ++i) {
    const double r = std::sqrt(diff.row(i).squaredNorm() + eps * eps);
    e.value += r - eps;
    e.gradient.row(i) = diff.row(i) / r;
  }
  return e;
}

}  // namespace

ForceEnergy force_energy(const ForceMatrix& forces, double eps) {
  return smoothed_norm_sum(forces, eps);
}

ForceEnergy temporal_energy(const ForceMatrix& forces, const ForceMatrix& previous_forces,
                            double eps) {
  if (forces.rows() != previous_forces.rows() || forces.cols() != previous_forces.cols())
    throw InputError("previous forces are " + std::to_string(previous_forces.rows()) + " by " +
                     std::to_string(previous_forces.cols()) + ", forces are " +
                     std::to_string(forces.rows()) + " by " + std::to_string(forces.cols()));
  return smoothed_norm_sum(forces - previous_forces, eps);
}

FrameEnergy frame_energy(const Vertices& vertices, const Triangles& triangles,
                         const std::vector<std::uint8_t>& constrained,
                         const Eigen::VectorXd& weights, const ForceMatrix& forces,
                         const ForceMatrix& previous_forces, const EnergyWeights& w) {
  FrameEnergy e;
  const SmoothVisibilityEnergy ec =
      visibility_energy_smooth(vertices, triangles, constrained, weights, w.smooth);
  const ForceEnergy ef = force_energy(forces, w.force_eps);
  const ForceEnergy et = previous_forces.rows() == 0
                             ? force_energy(forces, w.force_eps)
                             : temporal_energy(forces, previous_forces, w.force_eps);
  e.visibility = ec.value;
  e.force = ef.value;
  e.temporal = et.value;
  e.value = w.visibility * ec.value + w.force * ef.value + w.temporal * et.value;
  e.gradient_positions = w.visibility * ec.gradient;
  e.gradient_forces = w.force * ef.gradient + w.temporal * et.gradient;
  return e;
}

}  // namespace pbve
