#include "pbve/mass_spring/mass_spring.hpp"

#include <algorithm>
#include <cmath>
#include <cstring>
#include <limits>
#include <numeric>
#include <optional>
#include <stdexcept>
#include <string>

#include <tbb/blocked_range.h>
#include <tbb/parallel_for.h>
#include <Eigen/LU>

#include "cholesky.hpp"
#include "factor.hpp"
#include "model.hpp"
#include "pbve/core/thin_sheet.hpp"
#include "pseudo_random.hpp"

namespace pbve::mass_spring {

namespace {

using detail::Model;
using detail::Spring;
using Eigen::Matrix3d;
using Eigen::Vector3d;
using Eigen::VectorXd;

bool same_values(const VectorXd& a, const VectorXd& b) {
  return a.size() == b.size() &&
         (a.size() == 0 ||
          std::memcmp(a.data(), b.data(), sizeof(double) * static_cast<size_t>(a.size())) == 0);
}

bool same_input(const StepInput& a, const StepInput& b) {
  return std::memcmp(&a.dt, &b.dt, sizeof(double)) == 0 && same_values(a.control, b.control) &&
         a.anchor_targets.rows() == b.anchor_targets.rows() &&
         (a.anchor_targets.size() == 0 ||
          std::memcmp(a.anchor_targets.data(), b.anchor_targets.data(),
                      sizeof(double) * static_cast<size_t>(a.anchor_targets.size())) == 0);
}

// Quantities frozen at the start of a substep (lagged): spring directions for the stiffness
// damping, friction coefficients, and the external force (gravity + control).
struct Lag {
  std::vector<Vector3d> dir;    // per spring, unit direction at x (zero if degenerate)
  std::vector<double> inv_len;  // per spring, 1 / |x_b - x_a| (0 if degenerate)
  VectorXd fric;                // per node and plane: friction coefficient c, kg/s
  VectorXd fext;                // 3N, newtons
};

}  // namespace

struct MassSpringSimulator::Impl {
  std::shared_ptr<const Model> model;
  // A thin closed cloth simulated as one sheet (Params::single_sheet): the model's nodes are the
  // sheet's nodes, the other surface vertices follow it; null otherwise.
  std::shared_ptr<const ThinSheet> sheet;
  Params user_params;             // as given (the sheet model carries the whole board's mass)
  std::vector<int> vertex_block;  // per surface vertex: the node that moves it most

  int num_vertices() const {
    return sheet ? static_cast<int>(sheet->vertex_node.size()) : model->num_surface;
  }
  // Node positions (#surface nodes by 3) from a 3N vector.
  Vertices sheet_nodes(const VectorXd& xn) const {
    return Eigen::Map<const Vertices>(xn.data(), model->num_surface, 3);
  }
  // Surface vertex positions (#V by 3) at node positions xn (3N).
  Vertices surface_positions(const VectorXd& xn) const {
    const Vertices nodes = sheet_nodes(xn);
    if (!sheet) return nodes;
    const Vertices normals = sheet_normals(*sheet, nodes);
    Vertices out(num_vertices(), 3);
    for (int v = 0; v < num_vertices(); ++v) {
      const int node = sheet->vertex_node[static_cast<size_t>(v)];
      out.row(v) = node >= 0 ? Eigen::RowVector3d(nodes.row(node))
                             : attached_position(*sheet, sheet->attachment[static_cast<size_t>(v)],
                                                 nodes, normals)
                                   .transpose();
    }
    return out;
  }
  // With a sheet: d surface positions / d node positions at xn, 3V by 3N (row 3 v + d, column
  // 3 node + d).
  using SurfaceJacobian = Eigen::SparseMatrix<double, Eigen::RowMajor>;
  SurfaceJacobian surface_jacobian(const VectorXd& xn) const {
    const Vertices nodes = sheet_nodes(xn);
    // Row by row (rows in order, columns ascending within a row), straight into compressed
    // storage sized by a first pass: 3 entries per row of a node's vertex, 3 per involved node
    // in a row of an attached one.
    std::vector<int> involved;
    Eigen::Matrix<double, 3, Eigen::Dynamic> jac;
    const int nv = num_vertices();
    Eigen::Index nnz = 0;
    for (int v = 0; v < nv; ++v) {
      const int node = sheet->vertex_node[static_cast<size_t>(v)];
      if (node >= 0) {
        nnz += 3;
        continue;
      }
      attached_position_support(*sheet, sheet->attachment[static_cast<size_t>(v)], involved);
      nnz += 9 * static_cast<Eigen::Index>(involved.size());
    }
    SurfaceJacobian out(3 * nv, 3 * N());
    out.resizeNonZeros(nnz);
    int* outer = out.outerIndexPtr();
    int* inner = out.innerIndexPtr();
    double* value = out.valuePtr();
    int k = 0;
    outer[0] = 0;
    for (int v = 0; v < nv; ++v) {
      const int node = sheet->vertex_node[static_cast<size_t>(v)];
      if (node >= 0) {
        for (int d = 0; d < 3; ++d) {
          inner[k] = 3 * node + d;
          value[k++] = 1.0;
          outer[3 * v + d + 1] = k;
        }
        continue;
      }
      attached_position_jacobian(*sheet, sheet->attachment[static_cast<size_t>(v)], nodes, involved,
                                 jac);
      for (int d = 0; d < 3; ++d) {
        for (size_t i = 0; i < involved.size(); ++i)
          for (int c = 0; c < 3; ++c) {
            inner[k] = 3 * involved[i] + c;
            value[k++] = jac(d, 3 * static_cast<Eigen::Index>(i) + c);
          }
        outer[3 * v + d + 1] = k;
      }
    }
    return out;
  }
  // Tangent of the surface positions along a tangent dxn of the node positions (3N), at xn
  // (with a sheet, `jacobian` is surface_jacobian(xn) when given).
  Vertices surface_tangent(const VectorXd& xn, const VectorXd& dxn,
                           const SurfaceJacobian* jacobian = nullptr) const {
    if (!sheet) return sheet_nodes(dxn);
    const VectorXd t = jacobian ? VectorXd(*jacobian * dxn) : VectorXd(surface_jacobian(xn) * dxn);
    return Eigen::Map<const Vertices>(t.data(), num_vertices(), 3);
  }
  // The transpose: a cotangent d (#V by 3) of the surface positions as a 3N node cotangent.
  VectorXd surface_cotangent(const VectorXd& xn, const Vertices& d,
                             const SurfaceJacobian* jacobian = nullptr) const {
    VectorXd out = VectorXd::Zero(3 * N());
    if (!sheet) {
      for (int i = 0; i < model->num_surface; ++i) out.segment<3>(3 * i) = d.row(i).transpose();
      return out;
    }
    const Eigen::Map<const VectorXd> flat(d.data(), d.size());
    if (jacobian)
      out.noalias() = jacobian->transpose() * flat;
    else
      out.noalias() = surface_jacobian(xn).transpose() * flat;
    return out;
  }
  // Per-node rows (#surface nodes) spread to the surface vertices (zero on attached ones).
  template <class M>
  M scatter_rows(const M& per_node) const {
    if (!sheet) return per_node;
    M out = M::Zero(num_vertices(), per_node.cols());
    for (size_t i = 0; i < sheet->node_vertex.size(); ++i)
      out.row(sheet->node_vertex[i]) = per_node.row(static_cast<Eigen::Index>(i));
    return out;
  }
  VectorXd x, v;              // 3N positions (m) and velocities (m/s)
  Vertices phys;              // #V by 3, last step's averaged physical forces
  Eigen::VectorXd phys_norm;  // #V, last step's averaged |m g| + |other physical forces|
  StepStats stats;

  Eigen::SparseMatrix<double> J;
  // A sparse LL^T factorization (its symbolic analysis is the model's, shared by every
  // clone). A copy starts without a factor.
  struct Solver {
    detail::SparseCholesky chol;
    bool valid = false;  // holds the factorization of the matrix `key` describes
    // `base` only: the step's first (exact) Newton matrix was not positive definite, so this
    // is the factorization of the projected one that replaced it.
    bool projected = false;
    VectorXd key;
    Solver() = default;
    Solver(const Solver& other) : chol(other.chol) {}
    Solver& operator=(const Solver& other) {
      chol = other.chol;
      valid = false;
      return *this;
    }
  };
  // Direct mode keeps two factorizations. `base` is of the first Newton matrix of a step,
  // which depends only on the start state, the anchor targets and dt (not on the control): it
  // is kept for the next step() or step_vjp() from the same start (an optimizer evaluates many
  // controls from one state), and preconditions conjugate gradients for the later Newton
  // iterations, substeps and adjoint solves. `work` is refactorized within a call when those
  // stall. Every result is a function of the call's inputs alone (bit-exact replay).
  Solver base, work;
  Solver* active = nullptr;  // the preconditioner of the current call, if any
  bool in_adjoint = false;   // step_vjp() running: never write `base`
  // A solve that needed more CG iterations than this (each about one triangular solve pair,
  // against about 7 for a factorization) makes the next one factorize anew.
  static constexpr int refactor_iterations = 6;
  static constexpr int max_reuse_iterations = 25;
  // Multigrid-preconditioned CG: iteration counts do not grow with the resolution, so a solve
  // that needs more than this has met an indefinite or ill-posed matrix.
  static constexpr int max_multigrid_iterations = 200;
  int last_reuse_iterations = 0;
  // Set by pcg() when it meets a search direction p of non-positive curvature p^T J p: p and
  // that curvature (a certificate that J is not positive definite).
  bool curvature_found = false;
  VectorXd curvature_direction;
  double curvature = 0.0;
  int solves_in_call = 0;               // linear_solve() calls since begin_call()
  std::vector<Matrix3d> precond;        // inverse diagonal blocks (iterative solver)
  detail::Multigrid multigrid;          // LinearSolver::multigrid: set up per solve
  std::vector<Matrix3d> spring_blocks;  // assemble(): per spring
  std::vector<Vector3d> spring_forces;  // residual(): per spring, on its end b
  // assemble() computes the spring blocks of at least this many springs in parallel.
  static constexpr size_t parallel_springs = 20000;
  // The next multigrid setup recomputes the coarse levels (set at each substep's start, so
  // that a step's result depends only on its start and input; later solves of the substep
  // keep the coarse levels and take only the new finest matrix).
  bool multigrid_coarse_stale = true;
  // The last substep's Newton remainder: the residual its first update left beyond that
  // solve's own linear residual, as a fraction of the residual before it (0: none measured in
  // this step).
  double newton_remainder = 0.0;
  // Adjoint solves of indefinite exact Hessians: LL^T, else LDL^T, else LU (a copy starts
  // empty).
  struct Fallback {
    std::unique_ptr<detail::SymmetricFactor> factor;
    Fallback() = default;
    Fallback(const Fallback&) {}
    Fallback& operator=(const Fallback&) {
      factor.reset();
      return *this;
    }
  } fallback;

  std::shared_ptr<const detail::CholeskyAnalysis> analysis() const {
    return model->cholesky->get(
        [this] { return std::make_shared<const detail::CholeskyAnalysis>(model->pattern); });
  }

  // Start of a step() or step_vjp() from `start` = [x; v]: keeps `base` if it was made for
  // this start.
  void begin_call(const VectorXd& start, const StepInput& in) {
    VectorXd key(start.size() + in.anchor_targets.size() + 1);
    key << start, Eigen::Map<const VectorXd>(in.anchor_targets.data(), in.anchor_targets.size()),
        in.dt;
    if (!(base.valid && same_values(base.key, key))) {
      base.valid = false;
      base.key = std::move(key);
    }
    active = base.valid ? &base : nullptr;
    last_reuse_iterations = 0;
    solves_in_call = 0;
  }

  // Trajectory of the last step (for step_vjp).
  struct Tape {
    bool valid = false;
    VectorXd before;  // [x; v] at the start
    StepInput in;
    std::vector<VectorXd> xs, vs;  // substeps + 1 entries
  } tape;

  const Params& P() const { return model->params; }
  int N() const { return model->num_nodes; }

  // ----- per-substep physics -------------------------------------------------------------

  void make_lag(const VectorXd& xn, const VectorXd& vn, const VectorXd& u, Lag& lag) const {
    const Model& m = *model;
    lag.dir.resize(m.springs.size());
    lag.inv_len.resize(m.springs.size());
    for (size_t s = 0; s < m.springs.size(); ++s) {
      const Vector3d d = xn.segment<3>(3 * m.springs[s].b) - xn.segment<3>(3 * m.springs[s].a);
      const double l = d.norm();
      lag.dir[s] = l > 0.0 ? Vector3d(d / l) : Vector3d::Zero();
      lag.inv_len[s] = l > 0.0 ? 1.0 / l : 0.0;
    }
    const int np = static_cast<int>(P().planes.size());
    lag.fric = VectorXd::Zero(static_cast<Eigen::Index>(N()) * np);
    for (int p = 0; p < np; ++p) {
      const Plane& pl = P().planes[static_cast<size_t>(p)];
      const Vector3d n = pl.normal.normalized();
      for (int i = 0; i < N(); ++i) {
        const double phi = (xn.segment<3>(3 * i) - pl.point).dot(n);
        if (phi >= 0.0 || pl.friction == 0.0) continue;
        const Vector3d vt = vn.segment<3>(3 * i) - n * n.dot(vn.segment<3>(3 * i));
        const double normal_force = -P().contact_stiffness * phi;
        lag.fric[static_cast<Eigen::Index>(i) * np + p] =
            pl.friction * normal_force / std::max(vt.norm(), P().friction_velocity);
      }
    }
    lag.fext.resize(3 * N());
    for (int i = 0; i < N(); ++i) lag.fext.segment<3>(3 * i) = m.mass[i] * P().gravity;
    if (u.size() > 0)
      for (int i = 0; i < m.num_surface; ++i) lag.fext.segment<3>(3 * i) += u.segment<3>(3 * i);
  }

  // The sum of term(k) over [0, n): in one pass on small models, else in fixed chunks of 4096
  // summed in parallel, then in order: the same bits whatever the threads.
  template <class F>
  static double sum_over(size_t n, F term) {
    if (n < parallel_springs) {
      double e = 0.0;
      for (size_t k = 0; k < n; ++k) e += term(k);
      return e;
    }
    constexpr size_t chunk = 4096;
    std::vector<double> part((n + chunk - 1) / chunk);
    tbb::parallel_for(size_t{0}, part.size(), [&](size_t c) {
      double e = 0.0;
      for (size_t k = c * chunk; k < std::min(n, (c + 1) * chunk); ++k) e += term(k);
      part[c] = e;
    });
    double e = 0.0;
    for (double p : part) e += p;
    return e;
  }

  // Incremental potential whose gradient is the backward Euler residual (J-units: kg m).
  double potential(const VectorXd& y, const VectorXd& xn, const VectorXd& vn, const Lag& lag,
                   double h) const {
    const Model& m = *model;
    const double a = P().damping_alpha, b = P().damping_beta;
    double e = 0.0;
    for (int i = 0; i < N(); ++i) {
      const Vector3d w = y.segment<3>(3 * i) - xn.segment<3>(3 * i);
      const Vector3d wp = w - h * vn.segment<3>(3 * i);
      e += 0.5 * m.mass[i] * (wp.squaredNorm() + h * a * w.squaredNorm()) -
           h * h * lag.fext.segment<3>(3 * i).dot(y.segment<3>(3 * i));
    }
    e += sum_over(m.springs.size(), [&](size_t s) {
      const Spring& sp = m.springs[s];
      const Vector3d d = y.segment<3>(3 * sp.b) - y.segment<3>(3 * sp.a);
      const double l = d.norm();
      const Vector3d w = relative_step(y, xn, sp);
      const double dw = lag.dir[s].dot(w);
      double es = 0.5 * h * h * sp.k * (l - sp.rest) * (l - sp.rest) + 0.5 * h * b * sp.k * dw * dw;
      if (sp.iso != 0.0) es += 0.5 * sp.iso * (h * h * d.squaredNorm() + h * b * w.squaredNorm());
      return es;
    });
    if (m.bend_rest_force.size() > 0) e += h * h * m.bend_rest_force.dot(y);
    const int np = static_cast<int>(P().planes.size());
    for (int p = 0; p < np; ++p) {
      const Plane& pl = P().planes[static_cast<size_t>(p)];
      const Vector3d n = pl.normal.normalized();
      for (int i = 0; i < N(); ++i) {
        const double phi = (y.segment<3>(3 * i) - pl.point).dot(n);
        if (phi < 0.0) e += 0.5 * h * h * P().contact_stiffness * phi * phi;
        const double c = lag.fric[static_cast<Eigen::Index>(i) * np + p];
        if (c > 0.0) {
          const Vector3d w = y.segment<3>(3 * i) - xn.segment<3>(3 * i);
          e += 0.5 * h * c * (w - n * n.dot(w)).squaredNorm();
        }
      }
    }
    return e;
  }

  // Residual r(y) on the free nodes (3 per free node, in free_nodes order): each spring's force
  // first (in parallel on large models), then each node's own terms plus its springs' forces in
  // spring order, the sums of a serial pass over the springs whatever the threads.
  void residual(const VectorXd& y, const VectorXd& xn, const VectorXd& vn, const Lag& lag, double h,
                VectorXd& rf) {
    const Model& m = *model;
    const double a = P().damping_alpha, b = P().damping_beta;
    spring_forces.resize(m.springs.size());
    auto springs = [&](size_t begin, size_t end) {
      for (size_t s = begin; s != end; ++s) {
        const Spring& sp = m.springs[s];
        const Vector3d d = y.segment<3>(3 * sp.b) - y.segment<3>(3 * sp.a);
        const double l = d.norm();
        Vector3d g = Vector3d::Zero();
        if (l > 0.0) g = (h * h * sp.k * (l - sp.rest) / l) * d;
        const Vector3d w = relative_step(y, xn, sp);
        const double dw = lag.dir[s].dot(w);
        g += (h * b * sp.k * dw) * lag.dir[s];
        if (sp.iso != 0.0) g += (h * h * sp.iso) * d + (h * b * sp.iso) * w;
        spring_forces[s] = g;  // on b; minus on a
      }
    };
    const int np = static_cast<int>(P().planes.size());
    rf.resize(3 * static_cast<Eigen::Index>(m.free_nodes.size()));
    auto nodes = [&](size_t begin, size_t end) {
      for (size_t f = begin; f != end; ++f) {
        const int i = m.free_nodes[f];
        const Vector3d w = y.segment<3>(3 * i) - xn.segment<3>(3 * i);
        Vector3d r = m.mass[i] * ((1.0 + h * a) * w - h * vn.segment<3>(3 * i)) -
                     h * h * lag.fext.segment<3>(3 * i);
        for (int k = m.incident_start[f]; k < m.incident_start[f + 1]; ++k) {
          const auto s = static_cast<size_t>(m.incident_spring[static_cast<size_t>(k)]);
          if (m.springs[s].b == i)
            r += spring_forces[s];
          else
            r -= spring_forces[s];
        }
        if (m.bend_rest_force.size() > 0) r += (h * h) * m.bend_rest_force.segment<3>(3 * i);
        for (int p = 0; p < np; ++p) {
          const Plane& pl = P().planes[static_cast<size_t>(p)];
          const Vector3d n = pl.normal.normalized();
          const double phi = (y.segment<3>(3 * i) - pl.point).dot(n);
          if (phi < 0.0) r += (h * h * P().contact_stiffness * phi) * n;
          const double c = lag.fric[static_cast<Eigen::Index>(i) * np + p];
          if (c > 0.0) r += (h * c) * (w - n * n.dot(w));
        }
        rf.segment<3>(3 * static_cast<Eigen::Index>(f)) = r;
      }
    };
    if (m.springs.size() < parallel_springs) {
      springs(0, m.springs.size());
      nodes(0, m.free_nodes.size());
      return;
    }
    in_parallel(m.springs.size(), 4096, springs);
    in_parallel(m.free_nodes.size(), 1024, nodes);
  }

  // f(begin, end) over [0, n) in chunks of at least `grain`, in parallel.
  template <class F>
  static void in_parallel(size_t n, size_t grain, F f) {
    tbb::parallel_for(tbb::blocked_range<size_t>(0, n, grain),
                      [&](const tbb::blocked_range<size_t>& r) { f(r.begin(), r.end()); });
  }

  // The step of b relative to a: (y - xn)_b - (y - xn)_a.
  static Vector3d relative_step(const VectorXd& y, const VectorXd& xn, const Spring& sp) {
    return (y.segment<3>(3 * sp.b) - xn.segment<3>(3 * sp.b)) -
           (y.segment<3>(3 * sp.a) - xn.segment<3>(3 * sp.a));
  }

  // Spring block of the Jacobian: h^2 * Hessian (projected to PSD unless exact) + h*beta*k*uu^T,
  // plus (h^2 + h*beta) * iso * I.
  static Matrix3d spring_block(const Spring& sp, const Vector3d& d, const Vector3d& lag_dir,
                               double h, double beta, bool exact) {
    const double l = d.norm();
    Matrix3d H = Matrix3d::Zero();
    if (l > 0.0) {
      const Vector3d u = d / l;
      double t = 1.0 - sp.rest / l;
      if (!exact) t = std::max(t, 0.0);
      H = sp.k * ((1.0 - t) * u * u.transpose() + t * Matrix3d::Identity());
    }
    return h * h * H + (h * beta * sp.k) * lag_dir * lag_dir.transpose() +
           ((h * h + h * beta) * sp.iso) * Matrix3d::Identity();
  }

  Matrix3d node_block(int i, const VectorXd& y, const Lag& lag, double h) const {
    Matrix3d B = (model->mass[i] * (1.0 + h * P().damping_alpha)) * Matrix3d::Identity();
    const int np = static_cast<int>(P().planes.size());
    for (int p = 0; p < np; ++p) {
      const Plane& pl = P().planes[static_cast<size_t>(p)];
      const Vector3d n = pl.normal.normalized();
      const double phi = (y.segment<3>(3 * i) - pl.point).dot(n);
      if (phi < 0.0) B += (h * h * P().contact_stiffness) * n * n.transpose();
      const double c = lag.fric[static_cast<Eigen::Index>(i) * np + p];
      if (c > 0.0) B += (h * c) * (Matrix3d::Identity() - n * n.transpose());
    }
    return B;
  }

  // Fills J (free-free) at y.
  void assemble(const VectorXd& y, const Lag& lag, double h, bool exact) {
    const Model& m = *model;
    if (J.size() == 0) J = m.pattern;
    double* val = J.valuePtr();
    const int* outer = J.outerIndexPtr();
    auto add = [val](const int* off, const Matrix3d& B, double sign) {
      for (int j = 0; j < 3; ++j)
        for (int i = 0; i < 3; ++i) val[off[j] + i] += sign * B(i, j);
    };
    const bool parallel = m.springs.size() >= parallel_springs;
    // The spring blocks (in parallel on large models), then each block column on its own: the
    // node's block plus its springs' blocks in spring order on the diagonal, minus each spring's
    // block off it. The sums are those of a pass over the springs in order, so the result does
    // not depend on the threads.
    spring_blocks.resize(m.springs.size());
    auto springs = [&](size_t begin, size_t end) {
      for (size_t s = begin; s != end; ++s) {
        const Spring& sp = m.springs[s];
        spring_blocks[s] = spring_block(sp, y.segment<3>(3 * sp.b) - y.segment<3>(3 * sp.a),
                                        lag.dir[s], h, P().damping_beta, exact);
      }
    };
    auto columns = [&](size_t begin, size_t end) {
      for (size_t f = begin; f != end; ++f) {
        std::fill(val + outer[3 * f], val + outer[3 * f + 3], 0.0);
        const int* diag = m.diag_offset[f].data();
        add(diag, node_block(m.free_nodes[f], y, lag, h), 1.0);
        for (int k = m.incident_start[f]; k < m.incident_start[f + 1]; ++k) {
          const auto s = static_cast<size_t>(m.incident_spring[static_cast<size_t>(k)]);
          const Matrix3d& B = spring_blocks[s];
          add(diag, B, 1.0);
          const int column = m.incident_column[static_cast<size_t>(k)];
          if (column >= 0) add(m.spring_offset[s].data() + column, B, -1.0);
        }
      }
    };
    if (!parallel) {
      springs(0, m.springs.size());
      columns(0, m.free_nodes.size());
      return;
    }
    in_parallel(m.springs.size(), 4096, springs);
    in_parallel(m.free_nodes.size(), 1024, columns);
  }

  bool use_direct() const {
    const auto dofs = 3 * model->free_nodes.size();
    switch (P().linear_solver) {
      case LinearSolver::direct:
        return true;
      case LinearSolver::iterative:
      case LinearSolver::multigrid:
        return false;
      case LinearSolver::automatic:
        break;
    }
    const int limit = model->layer_ties > 0
                          ? std::max(P().direct_solver_max_dofs, P().direct_solver_max_dofs_layered)
                          : P().direct_solver_max_dofs;
    return dofs <= static_cast<size_t>(limit);
  }
  bool use_block_jacobi() const { return P().linear_solver == LinearSolver::iterative; }
  bool use_multigrid() const { return !use_direct() && !use_block_jacobi(); }

  // y = J x for the symmetric J stored with both triangles: row i is column i (parallel gather).
  void spmv(const VectorXd& xin, VectorXd& yout) const {
    yout.resize(J.rows());
    const int* outer = J.outerIndexPtr();
    const int* inner = J.innerIndexPtr();
    const double* val = J.valuePtr();
    auto rows = [&](Eigen::Index begin, Eigen::Index end) {
      for (Eigen::Index c = begin; c != end; ++c) {
        double acc = 0.0;
        for (int k = outer[c]; k < outer[c + 1]; ++k) acc += val[k] * xin[inner[k]];
        yout[c] = acc;
      }
    };
    // Threads pay off only for large systems (about 20k unknowns on this kind of pattern).
    if (J.nonZeros() < 1000000) {
      rows(0, J.cols());
      return;
    }
    tbb::parallel_for(
        tbb::blocked_range<Eigen::Index>(0, J.cols(), 4096),
        [&](const tbb::blocked_range<Eigen::Index>& range) { rows(range.begin(), range.end()); });
  }

  // 3x3 block-Jacobi preconditioner from the diagonal blocks of J.
  void build_preconditioner() {
    const Model& m = *model;
    precond.resize(m.free_nodes.size());
    const double* val = J.valuePtr();
    for (size_t f = 0; f < m.free_nodes.size(); ++f) {
      Matrix3d B;
      for (int j = 0; j < 3; ++j)
        for (int i = 0; i < 3; ++i) B(i, j) = val[m.diag_offset[f][static_cast<size_t>(j)] + i];
      precond[f] = B.inverse();
    }
  }

  // Preconditioned conjugate gradients on J x = b from x = 0, with z = precondition(r) and the
  // product J p = multiply(p) (spmv() unless given). Stops when stop(residual) holds. Returns
  // false on breakdown (non-positive curvature) or no convergence within max_iterations.
  template <class Precondition, class Stop>
  bool pcg(const VectorXd& b, VectorXd& xout, Precondition precondition, Stop stop,
           int max_iterations) {
    return pcg(b, xout, precondition, stop, max_iterations,
               [this](const VectorXd& in, VectorXd& out) { spmv(in, out); });
  }
  template <class Precondition, class Stop, class Multiply>
  bool pcg(const VectorXd& b, VectorXd& xout, Precondition precondition, Stop stop,
           int max_iterations, Multiply multiply) {
    const Eigen::Index n = b.size();
    xout = VectorXd::Zero(n);
    VectorXd r = b, z(n), p, Ap;
    if (stop(r)) return true;
    precondition(r, z);
    p = z;
    double rz = r.dot(z);
    if (!(rz > 0.0)) return false;  // not a positive definite preconditioner
    for (int it = 0; it < max_iterations; ++it) {
      multiply(p, Ap);
      const double pAp = p.dot(Ap);
      if (!(pAp > 0.0)) {
        if (pAp <= 0.0) {
          curvature_found = true;
          curvature_direction = p;
          curvature = pAp;
        }
        return false;
      }
      const double a = rz / pAp;
      xout += a * p;
      r -= a * Ap;
      ++stats.cg_iterations;
      if (stop(r)) return true;
      precondition(r, z);
      const double rz_new = r.dot(z);
      if (!(rz_new > 0.0)) return false;
      p = z + (rz_new / rz) * p;
      rz = rz_new;
    }
    return false;
  }

  // The model's multigrid hierarchy: coarse spaces from the springs between free nodes,
  // weighted by their stiffness, and the free nodes' rest positions.
  std::shared_ptr<const detail::MultigridHierarchy> multigrid_hierarchy() const {
    const Model& m = *model;
    return m.multigrid->get([&m] {
      const auto n = static_cast<Eigen::Index>(m.free_nodes.size());
      std::vector<Eigen::Triplet<double>> links;
      for (const Spring& sp : m.springs) {
        const int fa = m.free_index[static_cast<size_t>(sp.a)];
        const int fb = m.free_index[static_cast<size_t>(sp.b)];
        if (fa < 0 || fb < 0 || fa == fb) continue;
        links.emplace_back(fa, fb, sp.k);
        links.emplace_back(fb, fa, sp.k);
      }
      Eigen::SparseMatrix<double> strength(n, n);
      strength.setFromTriplets(links.begin(), links.end());
      Eigen::MatrixX3d rest(n, 3);
      for (Eigen::Index f = 0; f < n; ++f)
        rest.row(f) = m.rest.segment<3>(3 * m.free_nodes[static_cast<size_t>(f)]).transpose();
      return std::make_shared<const detail::MultigridHierarchy>(m.pattern, strength, rest);
    });
  }

  // Block-Jacobi preconditioner (built from the current J by build_preconditioner()).
  void apply_block_jacobi(const VectorXd& in, VectorXd& out) const {
    out.resize(in.size());
    for (size_t f = 0; f < precond.size(); ++f)
      out.segment<3>(3 * static_cast<Eigen::Index>(f)) =
          precond[f] * in.segment<3>(3 * static_cast<Eigen::Index>(f));
  }

  // Solves J x = b (free rows) for the current (Newton) J. Direct mode: conjugate gradients
  // preconditioned by the active factorization; the first solve of a step without `base`
  // factorizes J into it, and a solve after a stalled one factorizes J into `work`. So a step
  // costs about one factorization, none when `base` is reused. A new factorization runs the
  // same CG as a reused one (converging at once), so a result does not depend on whether
  // `base` was kept from an earlier call: replays and clones match bit for bit. Multigrid
  // mode: CG preconditioned by a V-cycle set up for this J (nothing kept between solves).
  // Iterative mode: block-Jacobi CG. Returns false if J could not be factorized (or, with
  // multigrid, has a diagonal block or coarsest matrix that is not positive definite) or CG
  // failed.
  //
  // `exact`: J holds the exact Hessian, which may be indefinite. A step's first solve factorizes
  // it into `base` when `base` is not kept; if that fails, `base` then holds the projected matrix
  // (`projected`), and a call reusing that `base` fails its first exact solve the same way
  // without factorizing, so that it takes the same path. An exact solve whose CG met negative
  // curvature (curvature_found) returns false without factorizing: J is indefinite.
  template <class Stop>
  bool linear_solve(const VectorXd& b, VectorXd& xout, Stop stop, bool exact = false) {
    const bool first = solves_in_call++ == 0;
    if (use_multigrid()) {
      if (multigrid.empty()) multigrid = detail::Multigrid(multigrid_hierarchy());
      const bool ready = multigrid.setup(J, multigrid_coarse_stale);
      multigrid_coarse_stale = !ready;
      if (!ready) return false;
      const bool ok = pcg(
          b, xout, [this](const VectorXd& in, VectorXd& out) { multigrid.apply(in, out); }, stop,
          max_multigrid_iterations,
          [this](const VectorXd& in, VectorXd& out) { multigrid.multiply(in, out); });
      // J may be indefinite, and so may be coarse levels made from it: the next matrix (the
      // projected Hessian) gets its own.
      multigrid_coarse_stale = !ok;
      return ok;
    }
    if (!use_direct()) {
      build_preconditioner();
      return pcg(
          b, xout, [this](const VectorXd& in, VectorXd& out) { apply_block_jacobi(in, out); }, stop,
          20 * static_cast<int>(b.size()) + 100);
    }
    auto cg = [&] {
      const int before = stats.cg_iterations;
      const bool ok = pcg(
          b, xout, [this](const VectorXd& in, VectorXd& out) { active->chol.solve(in, out); }, stop,
          max_reuse_iterations);
      last_reuse_iterations = stats.cg_iterations - before;
      return ok;
    };
    const bool first_base = first && !in_adjoint;
    if (first_base && exact && active == &base && base.projected) return false;
    if (active && last_reuse_iterations <= refactor_iterations && cg()) return true;
    // Conjugate gradients met negative curvature: J is indefinite, and factorizing fails.
    if (exact && curvature_found) return false;
    Solver& slot = base.valid || in_adjoint ? work : base;
    const bool ok = factorize(slot);
    if (first_base && &slot == &base) base.projected = !ok && exact;
    if (!ok) {
      if (active == &slot) active = nullptr;
      return false;
    }
    active = &slot;
    return cg();
  }

  // Solves J x = b for the exact Hessian J at y (symmetric, possibly indefinite) by MINRES
  // preconditioned with the multigrid V-cycle of the projected Hessian (positive definite),
  // until |b - J x| <= target. Leaves J holding the exact Hessian. Returns false if the
  // preconditioner could not be set up or MINRES did not converge.
  bool indefinite_multigrid_solve(const VectorXd& y, const Lag& lag, double h, const VectorXd& b,
                                  double target, VectorXd& xout) {
    assemble(y, lag, h, false);
    const bool ready = multigrid.setup(J, multigrid_coarse_stale);
    multigrid_coarse_stale = !ready;
    assemble(y, lag, h, true);
    if (!ready) return false;
    const Eigen::Index n = b.size();
    xout = VectorXd::Zero(n);
    if (b.norm() <= target) return true;
    // Preconditioned MINRES (Lanczos in the preconditioner's inner product, Givens QR),
    // after Elman, Silvester and Wathen, "Finite Elements and Fast Iterative Solvers", 2.4.
    VectorXd v_old = VectorXd::Zero(n), v = b, v_new, z, z_new, w_old = VectorXd::Zero(n),
             w = VectorXd::Zero(n), w_new, Az, res;
    multigrid.apply(v, z);
    double gamma_old = 1.0, gamma = std::sqrt(std::max(v.dot(z), 0.0));
    if (!(gamma > 0.0)) return false;
    double eta = gamma, c_old = 1.0, c = 1.0, s_old = 0.0, s = 0.0;
    for (int it = 1; it <= 5 * max_multigrid_iterations; ++it) {
      z /= gamma;
      spmv(z, Az);
      const double delta = Az.dot(z);
      v_new = Az - (delta / gamma) * v - (gamma / gamma_old) * v_old;
      multigrid.apply(v_new, z_new);
      const double gamma_new = std::sqrt(std::max(v_new.dot(z_new), 0.0));
      const double a0 = c * delta - c_old * s * gamma;
      const double a1 = std::hypot(a0, gamma_new);
      const double a2 = s * delta + c_old * c * gamma;
      const double a3 = s_old * gamma;
      if (!(a1 > 0.0)) return false;
      const double c_new = a0 / a1, s_new = gamma_new / a1;
      w_new = (z - a3 * w_old - a2 * w) / a1;
      xout += (c_new * eta) * w_new;
      eta = -s_new * eta;
      ++stats.cg_iterations;
      if (it % 5 == 0 || gamma_new == 0.0) {
        spmv(xout, res);
        if ((b - res).norm() <= target) return true;
        if (gamma_new == 0.0) return false;
      }
      v_old.swap(v);
      v.swap(v_new);
      z.swap(z_new);
      w_old.swap(w);
      w.swap(w_new);
      gamma_old = gamma;
      gamma = gamma_new;
      c_old = c;
      c = c_new;
      s_old = s;
      s = s_new;
    }
    return false;
  }

  // Largest per-node position-like size max_i |s_i| / m_i of a residual on free rows.
  double mass_scaled_inf(const VectorXd& s) const {
    double out = 0.0;
    for (size_t f = 0; f < model->free_nodes.size(); ++f)
      out = std::max(out, s.segment<3>(3 * static_cast<Eigen::Index>(f)).lpNorm<Eigen::Infinity>() /
                              model->mass[model->free_nodes[f]]);
    return out;
  }

  bool factorize(Solver& slot) {
    ++stats.factorizations;
    if (slot.chol.empty()) slot.chol = detail::SparseCholesky(analysis());
    slot.valid = slot.chol.factorize(J);
    return slot.valid;
  }

  // out = J_full(y) * lam on all nodes, with the exact Hessian (lam: 3N).
  // The blocks of the exact Jacobian (all nodes, anchored ones included) at y: one per node and
  // one per spring.
  struct ExactBlocks {
    std::vector<Matrix3d> node, spring;
  };
  void exact_blocks(const VectorXd& y, const Lag& lag, double h, ExactBlocks& out) const {
    const Model& m = *model;
    out.node.resize(static_cast<size_t>(N()));
    for (int i = 0; i < N(); ++i) out.node[static_cast<size_t>(i)] = node_block(i, y, lag, h);
    out.spring.resize(m.springs.size());
    for (size_t s = 0; s < m.springs.size(); ++s) {
      const Spring& sp = m.springs[s];
      out.spring[s] = spring_block(sp, y.segment<3>(3 * sp.b) - y.segment<3>(3 * sp.a), lag.dir[s],
                                   h, P().damping_beta, true);
    }
  }
  // out = J lam with the blocks of exact_blocks().
  void apply_blocks(const ExactBlocks& b, const VectorXd& lam, VectorXd& out) const {
    const Model& m = *model;
    out.resize(3 * N());
    for (int i = 0; i < N(); ++i)
      out.segment<3>(3 * i) = b.node[static_cast<size_t>(i)] * lam.segment<3>(3 * i);
    for (size_t s = 0; s < m.springs.size(); ++s) {
      const Spring& sp = m.springs[s];
      const Vector3d q = b.spring[s] * (lam.segment<3>(3 * sp.b) - lam.segment<3>(3 * sp.a));
      out.segment<3>(3 * sp.b) += q;
      out.segment<3>(3 * sp.a) -= q;
    }
  }
  void apply_exact(const VectorXd& y, const Lag& lag, double h, const VectorXd& lam,
                   VectorXd& out) const {
    ExactBlocks b;
    exact_blocks(y, lag, h, b);
    apply_blocks(b, lam, out);
  }

  VectorXd gather_free(const VectorXd& full) const {
    VectorXd f(3 * static_cast<Eigen::Index>(model->free_nodes.size()));
    for (size_t k = 0; k < model->free_nodes.size(); ++k)
      f.segment<3>(3 * static_cast<Eigen::Index>(k)) = full.segment<3>(3 * model->free_nodes[k]);
    return f;
  }

  // Moves y along a direction d of negative curvature c = d^T J d < 0 of the exact Hessian J
  // (free rows), met by conjugate gradients at the start of this Newton iteration (before its
  // projected step, so c is the curvature there). The sign of d is chosen downhill for the
  // gradient g at y. Lengths are tried from a largest coordinate move of a quarter edge,
  // halved down to 1/8192 of an edge, until the incremental potential falls by at least a
  // tenth of the decrease a g.d + a^2 c / 2 (both terms <= 0) that its quadratic model
  // predicts, and by more than its own rounding. Returns false (y unchanged) if none does.
  bool curvature_step(const VectorXd& d, double c, const VectorXd& xn, const VectorXd& vn,
                      const Lag& lag, double h, VectorXd& y, VectorXd& trial) {
    const Model& m = *model;
    const double scale = d.lpNorm<Eigen::Infinity>();
    if (!(scale > 0.0) || !(c < 0.0)) return false;
    VectorXd g;
    residual(y, xn, vn, lag, h, g);
    const double sign = g.dot(d) > 0.0 ? -1.0 / scale : 1.0 / scale;
    const double slope = sign * g.dot(d);  // per metre of the largest coordinate move
    const double bend = c / (scale * scale);
    const double e0 = potential(y, xn, vn, lag, h);
    const double noise = 1e3 * std::numeric_limits<double>::epsilon() * std::abs(e0);
    double a = 0.25 * m.char_length;
    for (int ls = 0; ls < 12; ++ls, a *= 0.5) {
      trial = y;
      for (size_t k = 0; k < m.free_nodes.size(); ++k)
        trial.segment<3>(3 * m.free_nodes[k]) +=
            (a * sign) * d.segment<3>(3 * static_cast<Eigen::Index>(k));
      const double de = potential(trial, xn, vn, lag, h) - e0;
      if (de <= 0.1 * (a * slope + 0.5 * a * a * bend) && de < -noise) {
        y.swap(trial);
        return true;
      }
    }
    return false;
  }

  // One backward Euler substep from (xn, vn) with anchors moved to ya (3 * #anchors); writes
  // y. vprev: the velocity before vn (the previous substep's start) or null. Returns Newton
  // iterations (negative when not converged).
  int substep(const VectorXd& xn, const VectorXd& vn, const VectorXd* vprev, const VectorXd& ya,
              const Lag& lag, double h, VectorXd& y) {
    const Model& m = *model;
    y = xn + h * vn;
    for (size_t k = 0; k < m.anchors.size(); ++k)
      y.segment<3>(3 * m.anchors[k]) = ya.segment<3>(3 * static_cast<Eigen::Index>(k));
    if (m.free_nodes.empty()) return 0;
    VectorXd rf, dy_free, trial;
    if (vprev) {
      // Start from the previous substep's acceleration carried on, x + h v + h^2 a with
      // a = (v - v_prev) / h, where that lowers the incremental potential (it does not across
      // a contact or a jerk): it halves the first Newton update of a swinging cloth.
      trial = y;
      for (int f : m.free_nodes)
        trial.segment<3>(3 * f) += h * (vn.segment<3>(3 * f) - vprev->segment<3>(3 * f));
      if (potential(trial, xn, vn, lag, h) < potential(y, xn, vn, lag, h)) y.swap(trial);
    }
    multigrid_coarse_stale = true;
    const double tol = P().newton_tolerance * m.char_length;
    bool exact = true;
    // Whether the last linear solve was on the exact Hessian, met no negative curvature and
    // reached its target (the iterate is then not taken for a saddle's neighbourhood).
    bool last_exact = false;
    // Inexact Newton: each linear solve runs to a fraction (the forcing term) of the current
    // residual, but at least to a tenth of the Newton tolerance (mass-scaled, i.e. in metres).
    // The forcing term follows Eisenstat and Walker's second choice, 0.9 (|r_k| / |r_k-1|)^2
    // with their safeguard, between 1e-4 (1e-3 with block Jacobi) and 0.1: tight where Newton
    // converges quadratically, looser while it does not (line searches, after a curvature step),
    // where a tight solve of the local model is wasted. A substep's first solve has no
    // previous ratio: it runs to the fraction of the residual that the last substep's first
    // update left as Newton remainder (the next residual is at least that, whatever the linear
    // residual), the tightest forcing in a step's first substep.
    const double min_forcing = use_block_jacobi() ? 1e-3 : 1e-4, max_forcing = 0.1;
    double last_norm = 0.0, forcing = std::clamp(newton_remainder, min_forcing, max_forcing);
    double linear_norm = 0.0;  // the last linear solve's final residual, mass-scaled
    bool full_first = false;   // the first update: an exact solve's full step
    for (int it = 1; it <= P().newton_iterations; ++it) {
      residual(y, xn, vn, lag, h, rf);
      const double norm = mass_scaled_inf(rf);
      if (it > 1 && last_norm > 0.0) {
        const double ratio = norm / last_norm;
        double eta = 0.9 * ratio * ratio;
        if (0.9 * forcing * forcing > 0.1) eta = std::max(eta, 0.9 * forcing * forcing);
        forcing = std::clamp(eta, min_forcing, max_forcing);
      }
      if (it == 2)
        newton_remainder =
            full_first && last_norm > 0.0 ? std::max(norm - linear_norm, 0.0) / last_norm : 0.0;
      last_norm = norm;
      // Also converged when the mass-scaled residual max_i |r_i| / m_i is below the tolerance
      // after an exact, positive definite solve: it bounds the next update. With a positive
      // semi-definite stiffness J >= (1 + h alpha) M, so in the mass norm the update J^-1 r is
      // at most M^-1 r; pointwise it is smaller still (the stiffness spreads a node's residual
      // over its neighbours): 40-70x on the swinging bench cloth. The test spares the solve
      // that would only confirm the update's size.
      if (it > 1 && last_exact && norm <= tol) return it - 1;
      const double target = std::max(forcing * norm, 0.1 * tol);
      auto stop = [&](const VectorXd& res) {
        linear_norm = mass_scaled_inf(res);
        return linear_norm <= target;
      };
      // The exact Hessian while conjugate gradients find it positive definite (quadratic
      // convergence; the solution is then a descent direction), else the one with compressed
      // springs' negative transverse stiffness dropped (positive semi-definite springs: always
      // a descent direction, linear convergence) and a step along the negative curvature met,
      // after which the exact Hessian is tried again (if no such step lowers the potential, the
      // projected Hessian for the rest of the substep).
      bool solved = false;
      const bool tried_exact = exact;
      // A direction of negative curvature of the exact Hessian that conjugate gradients met.
      // Taken from pcg()'s record right after the solve that met it.
      bool negative = false;
      VectorXd direction;
      double direction_curvature = 0.0;
      auto take_curvature = [&] {
        if (!curvature_found || !(curvature < 0.0)) return false;
        direction.swap(curvature_direction);
        direction_curvature = curvature;
        return true;
      };
      if (exact) {
        assemble(y, lag, h, true);
        curvature_found = false;
        solved = linear_solve(rf, dy_free, stop, true);
        negative = !solved && take_curvature();
        exact = solved;
      }
      if (!solved) {
        assemble(y, lag, h, false);
        if (!linear_solve(rf, dy_free, stop) && !use_block_jacobi()) return -it;
      }
      if (tried_exact && !solved && !negative && use_direct() && active) {
        // The exact matrix failed to factorize, which gives no direction: look for one with
        // conjugate gradients on it, preconditioned by the factorization just used, from a
        // fixed pseudo-random right side (the residual of a symmetric configuration may have no
        // component along the negative curvature that would break its symmetry).
        assemble(y, lag, h, true);
        curvature_found = false;
        VectorXd unused;
        pcg(
            detail::pseudo_random_vector(rf.size()), unused,
            [this](const VectorXd& in, VectorXd& out) { active->chol.solve(in, out); },
            [](const VectorXd&) { return false; }, max_reuse_iterations);
        negative = take_curvature();
      }
      last_exact = tried_exact && solved;
      dy_free = -dy_free;
      const double step_inf = dy_free.lpNorm<Eigen::Infinity>();
      if (!std::isfinite(step_inf)) return -it;
      double t = 1.0;
      if (step_inf > 1e-3 * m.char_length) {
        // Backtracking (Armijo) on the incremental potential (dy is a descent direction).
        const double e0 = potential(y, xn, vn, lag, h);
        const double slope = rf.dot(dy_free);
        for (int ls = 0; ls < 12; ++ls) {
          trial = y;
          for (size_t k = 0; k < m.free_nodes.size(); ++k)
            trial.segment<3>(3 * m.free_nodes[k]) +=
                t * dy_free.segment<3>(3 * static_cast<Eigen::Index>(k));
          if (potential(trial, xn, vn, lag, h) <= e0 + 1e-4 * t * slope) break;
          t *= 0.5;
        }
      }
      for (size_t k = 0; k < m.free_nodes.size(); ++k)
        y.segment<3>(3 * m.free_nodes[k]) +=
            t * dy_free.segment<3>(3 * static_cast<Eigen::Index>(k));
      // Projected Newton converges to a stationary point, which where the exact Hessian has
      // negative curvature is a saddle of the incremental potential, not a backward Euler step
      // (e.g. a symmetric sheet under compression, whose symmetry the projected Hessian keeps):
      // step along that curvature too, then try the exact Hessian again. Each such step lowers
      // the potential; the iteration limit bounds their number.
      if (negative && curvature_step(direction, direction_curvature, xn, vn, lag, h, y, trial)) {
        ++stats.curvature_steps;
        exact = true;
        continue;
      }
      if (it == 1) full_first = t == 1.0 && last_exact && !negative;
      if (t == 1.0 && step_inf <= tol) return it;
    }
    return -P().newton_iterations;
  }

  // ----- step ----------------------------------------------------------------------------

  void validate(const StepInput& in) const {
    if (!(in.dt > 0.0) || !std::isfinite(in.dt))
      throw std::invalid_argument("mass_spring: step dt must be positive and finite (got " +
                                  std::to_string(in.dt) + ")");
    const Eigen::Index nc = 3 * static_cast<Eigen::Index>(model->num_surface);
    if (in.control.size() != 0 && in.control.size() != nc)
      throw std::invalid_argument("mass_spring: control has " + std::to_string(in.control.size()) +
                                  " entries, expected " + std::to_string(nc) +
                                  " (3 per vertex) or 0");
    if (in.control.size() != 0 && !in.control.allFinite())
      throw std::invalid_argument("mass_spring: control contains non-finite values");
    const auto na = static_cast<Eigen::Index>(model->anchors.size());
    if (in.anchor_targets.rows() != 0 && in.anchor_targets.rows() != na)
      throw std::invalid_argument("mass_spring: anchor_targets has " +
                                  std::to_string(in.anchor_targets.rows()) + " rows, expected " +
                                  std::to_string(na) +
                                  (sheet ? " (one per anchors() vertex: the sheet nodes that "
                                           "carry the anchored vertices) or 0"
                                         : " (one per anchor) or 0"));
    if (in.anchor_targets.rows() != 0 && !in.anchor_targets.allFinite())
      throw std::invalid_argument("mass_spring: anchor_targets contain non-finite values");
  }

  // Prescribed anchor positions at substep s (1..S).
  VectorXd anchor_at(const VectorXd& a0, const StepInput& in, int s, int S) const {
    if (in.anchor_targets.rows() == 0) return a0;
    VectorXd target(a0.size());
    for (Eigen::Index k = 0; k < in.anchor_targets.rows(); ++k)
      target.segment<3>(3 * k) = in.anchor_targets.row(k).transpose();
    if (s == S) return target;
    const double t = static_cast<double>(s) / S;
    return a0 + t * (target - a0);
  }

  void step(const StepInput& in) {
    validate(in);
    const Model& m = *model;
    const int S = P().substeps;
    const double h = in.dt / S;
    VectorXd a0(3 * static_cast<Eigen::Index>(m.anchors.size()));
    for (size_t k = 0; k < m.anchors.size(); ++k)
      a0.segment<3>(3 * static_cast<Eigen::Index>(k)) = x.segment<3>(3 * m.anchors[k]);
    tape.valid = false;
    tape.before.resize(6 * N());
    tape.before << x, v;
    tape.in = in;
    tape.xs.assign(1, x);
    tape.vs.assign(1, v);
    stats = StepStats{};
    stats.substeps = S;
    begin_call(tape.before, in);
    phys.setZero(m.num_surface, 3);
    phys_norm.setZero(m.num_surface);
    Lag lag;
    VectorXd y;
    newton_remainder = 0.0;
    for (int s = 1; s <= S; ++s) {
      const VectorXd ya = anchor_at(a0, in, s, S);
      make_lag(x, v, in.control, lag);
      const int it = substep(x, v, s > 1 ? &tape.vs[tape.vs.size() - 2] : nullptr, ya, lag, h, y);
      stats.newton_iterations += std::abs(it);
      stats.max_newton_iterations = std::max(stats.max_newton_iterations, std::abs(it));
      if (it < 0) stats.converged = false;
      const VectorXd vnew = (y - x) / h;
      // Physical force = m a - u (the converged residual is zero to the Newton tolerance).
      for (int i = 0; i < m.num_surface; ++i) {
        if (m.free_index[static_cast<size_t>(i)] < 0) continue;
        Vector3d f = m.mass[i] * (vnew.segment<3>(3 * i) - v.segment<3>(3 * i)) / h;
        if (in.control.size() > 0) f -= in.control.segment<3>(3 * i);
        phys.row(i) += f.transpose() / S;
        const Vector3d weight = m.mass[i] * P().gravity;
        phys_norm[i] += (weight.norm() + (f - weight).norm()) / S;
      }
      x = y;
      v = vnew;
      tape.xs.push_back(x);
      tape.vs.push_back(v);
    }
    tape.valid = true;
  }

  // Transpose of one substep's linearization (from (xn, vn), control and anchors to y), given
  // the multiplier lam = J_ff^-T G on free rows (zero on anchored rows), Jlam = J_full lam,
  // G = dL/dy and gv = dL/dv' of the substep's end: writes dL/dxn and dL/dvn into gx_new and
  // gv_new, and adds dL/d(step-initial anchor positions) to ga0 (w_a0 = d y_a / d a0) and
  // dL/du to gu.
  void substep_transpose(const VectorXd& xn, const VectorXd& vn, const VectorXd& y, const Lag& lag,
                         double h, double w_a0, const VectorXd& G, const VectorXd& gv,
                         const VectorXd& lam, const VectorXd& Jlam, VectorXd& gx_new,
                         VectorXd& gv_new, VectorXd& ga0, VectorXd& gu) const {
    const Model& m = *model;
    const double alpha = P().damping_alpha, beta = P().damping_beta;
    const int np = static_cast<int>(P().planes.size());
    gx_new.resize(3 * N());
    gv_new.resize(3 * N());
    // Anchors: dL/dy_a, carried to the step's initial anchor positions.
    for (size_t k = 0; k < m.anchors.size(); ++k) {
      const Eigen::Index a = 3 * m.anchors[k];
      ga0.segment<3>(3 * static_cast<Eigen::Index>(k)) +=
          w_a0 * (G.segment<3>(a) - Jlam.segment<3>(a));
    }
    // Controls enter as -h^2 u in the residual.
    for (int i = 0; i < m.num_surface; ++i) gu.segment<3>(3 * i) += h * h * lam.segment<3>(3 * i);
    // gx_new = -gv/h - lam^T dr/dx ; gv_new = -lam^T dr/dv.
    for (int i = 0; i < N(); ++i) {
      const Vector3d li = lam.segment<3>(3 * i);
      gx_new.segment<3>(3 * i) = -gv.segment<3>(3 * i) / h + (1.0 + h * alpha) * m.mass[i] * li;
      gv_new.segment<3>(3 * i) = h * m.mass[i] * li;
    }
    for (size_t sidx = 0; sidx < m.springs.size(); ++sidx) {
      const Spring& sp = m.springs[sidx];
      const Vector3d& u = lag.dir[sidx];
      const Vector3d L = lam.segment<3>(3 * sp.b) - lam.segment<3>(3 * sp.a);
      const Vector3d w = relative_step(y, xn, sp);
      // -lam^T d/dx [h beta K(x) (y - x)] = +h beta K lam - h beta d/dx(lam^T K(x) w)|_w.
      const double uL = u.dot(L), uw = u.dot(w);
      Vector3d q = (h * beta * sp.k * uL) * u;
      const Vector3d PL = L - u * uL, Pw = w - u * uw;
      q -= (h * beta * sp.k * lag.inv_len[sidx]) * (PL * uw + Pw * uL);
      q += (h * beta * sp.iso) * L;  // through w in h beta iso w
      gx_new.segment<3>(3 * sp.b) += q;
      gx_new.segment<3>(3 * sp.a) -= q;
    }
    for (int p = 0; p < np; ++p) {
      const Plane& pl = P().planes[static_cast<size_t>(p)];
      const Vector3d n = pl.normal.normalized();
      for (int i = 0; i < N(); ++i) {
        const double c = lag.fric[static_cast<Eigen::Index>(i) * np + p];
        if (c <= 0.0) continue;
        const Vector3d li = lam.segment<3>(3 * i);
        const Vector3d w = y.segment<3>(3 * i) - xn.segment<3>(3 * i);
        const Vector3d Pl = li - n * n.dot(li);
        const double lPw = Pl.dot(w);
        // Through w = y - x: +h c P lam.
        gx_new.segment<3>(3 * i) += (h * c) * Pl;
        // Through c(x, v).
        const FrictionPartials dc = friction_partials(pl, n, xn, vn, i, c);
        gx_new.segment<3>(3 * i) -= (h * lPw) * dc.dx;
        gv_new.segment<3>(3 * i) -= (h * lPw) * dc.dv;
      }
    }
  }

  // Derivatives of the lagged friction coefficient c = mu kc (-phi(x)) / max(|v_t|, eps) of
  // node i on a plane (unit normal n) with respect to the node's position and velocity.
  struct FrictionPartials {
    Vector3d dx, dv;
  };
  FrictionPartials friction_partials(const Plane& pl, const Vector3d& n, const VectorXd& xn,
                                     const VectorXd& vn, int i, double c) const {
    const Vector3d vi = vn.segment<3>(3 * i);
    const Vector3d vt = vi - n * n.dot(vi);
    const double vtn = vt.norm();
    const double denom = std::max(vtn, P().friction_velocity);
    FrictionPartials out;
    out.dx = -(pl.friction * P().contact_stiffness / denom) * n;
    out.dv = vtn > P().friction_velocity ? Vector3d(-(c / (vtn * vtn)) * vt) : Vector3d::Zero();
    (void)xn;
    return out;
  }

  // The explicit part of one substep's tangent: dr = (dr/dxn) dxn + (dr/dvn) dvn + (dr/du) du
  // on all nodes (du: 3 per surface vertex, or empty).
  void substep_explicit_tangent(const VectorXd& xn, const VectorXd& vn, const VectorXd& y,
                                const Lag& lag, double h, const VectorXd& dxn, const VectorXd& dvn,
                                const VectorXd& du, VectorXd& dr) const {
    const Model& m = *model;
    const double alpha = P().damping_alpha, beta = P().damping_beta;
    const int np = static_cast<int>(P().planes.size());
    dr.resize(3 * N());
    for (int i = 0; i < N(); ++i)
      dr.segment<3>(3 * i) = -(1.0 + h * alpha) * m.mass[i] * dxn.segment<3>(3 * i) -
                             h * m.mass[i] * dvn.segment<3>(3 * i);
    if (du.size() > 0)
      for (int i = 0; i < m.num_surface; ++i) dr.segment<3>(3 * i) -= h * h * du.segment<3>(3 * i);
    for (size_t sidx = 0; sidx < m.springs.size(); ++sidx) {
      const Spring& sp = m.springs[sidx];
      const Vector3d& u = lag.dir[sidx];
      const Vector3d D = dxn.segment<3>(3 * sp.b) - dxn.segment<3>(3 * sp.a);
      const Vector3d w = relative_step(y, xn, sp);
      // g = h beta k (u . w) u with w = (y - xn)_b - (y - xn)_a and u = u(xn).
      const Vector3d du_dir = lag.inv_len[sidx] * (D - u * u.dot(D));
      const Vector3d dg =
          (h * beta * sp.k) * (-u.dot(D) * u + w.dot(du_dir) * u + u.dot(w) * du_dir) -
          (h * beta * sp.iso) * D;
      dr.segment<3>(3 * sp.b) += dg;
      dr.segment<3>(3 * sp.a) -= dg;
    }
    for (int p = 0; p < np; ++p) {
      const Plane& pl = P().planes[static_cast<size_t>(p)];
      const Vector3d n = pl.normal.normalized();
      for (int i = 0; i < N(); ++i) {
        const double c = lag.fric[static_cast<Eigen::Index>(i) * np + p];
        if (c <= 0.0) continue;
        const Vector3d w = y.segment<3>(3 * i) - xn.segment<3>(3 * i);
        const Vector3d Pw = w - n * n.dot(w);
        const Vector3d dx = dxn.segment<3>(3 * i);
        const FrictionPartials dc = friction_partials(pl, n, xn, vn, i, c);
        dr.segment<3>(3 * i) += -(h * c) * (dx - n * n.dot(dx)) +
                                (h * (dc.dx.dot(dx) + dc.dv.dot(dvn.segment<3>(3 * i)))) * Pw;
      }
    }
  }

  // ----- adjoint -------------------------------------------------------------------------

  // Makes the tape that of the step from `before` with `in`: kept when it already is (bitwise),
  // else the step is replayed.
  void record(const SimState& before, const StepInput& in) {
    const bool reuse = tape.valid &&
                       std::memcmp(tape.before.data(), before.values.data(),
                                   sizeof(double) * before.values.size()) == 0 &&
                       same_input(tape.in, in);
    if (reuse) return;
    std::copy(before.values.begin(), before.values.begin() + x.size(), x.begin());
    std::copy(before.values.begin() + x.size(), before.values.end(), v.begin());
    step(in);
  }

  StepVjp vjp(const StepInput& in, const VectorXd& g) {
    const Model& m = *model;
    const int S = P().substeps;
    const double h = in.dt / S;
    const int n3 = 3 * N();
    VectorXd gx = g.head(n3), gv = g.tail(n3);
    VectorXd ga0 = VectorXd::Zero(3 * static_cast<Eigen::Index>(m.anchors.size()));
    VectorXd gu = VectorXd::Zero(3 * static_cast<Eigen::Index>(m.num_surface));
    const bool moving = in.anchor_targets.rows() != 0;
    Lag lag;
    VectorXd G, lam(n3), Jlam, gx_new(n3), gv_new(n3);
    // Adjoint solves use `work` only: `base` (a projected Hessian at the step's start) is far
    // from the exact Hessians at its end.
    active = nullptr;
    last_reuse_iterations = 0;
    in_adjoint = true;
    struct Reset {
      bool& flag;
      ~Reset() { flag = false; }
    } reset{in_adjoint};
    for (int s = S - 1; s >= 0; --s) {
      const VectorXd& xn = tape.xs[static_cast<size_t>(s)];
      const VectorXd& vn = tape.vs[static_cast<size_t>(s)];
      const VectorXd& y = tape.xs[static_cast<size_t>(s + 1)];
      make_lag(xn, vn, in.control, lag);
      G = gx + gv / h;
      lam.setZero();
      if (!m.free_nodes.empty()) {
        assemble(y, lag, h, true);
        multigrid_coarse_stale = true;
        const VectorXd Gf = gather_free(G);
        VectorXd lf;
        const double target = P().adjoint_tolerance * Gf.norm();
        // CG preconditioned by the factorization of a later substep's matrix (refactorized
        // when that stalls). The exact Hessian may be indefinite (compressed springs): LL^T
        // then fails and the system is solved by LDL^T, else LU.
        // With the multigrid solver: MINRES on the exact (indefinite) matrix, preconditioned
        // by the multigrid of the projected one, before factorizing.
        if (!linear_solve(Gf, lf, [&](const VectorXd& res) { return res.norm() <= target; }) &&
            !(use_multigrid() && indefinite_multigrid_solve(y, lag, h, Gf, target, lf))) {
          if (!fallback.factor)
            fallback.factor = std::make_unique<detail::SymmetricFactor>(analysis());
          ++stats.factorizations;
          if (!fallback.factor->factorize(J))
            throw std::runtime_error("mass_spring: singular system in step_vjp");
          lf = fallback.factor->solve(Gf);
        }
        for (size_t k = 0; k < m.free_nodes.size(); ++k)
          lam.segment<3>(3 * m.free_nodes[k]) = lf.segment<3>(3 * static_cast<Eigen::Index>(k));
      }
      apply_exact(y, lag, h, lam, Jlam);
      const double w_a0 = moving ? 1.0 - static_cast<double>(s + 1) / S : 1.0;
      substep_transpose(xn, vn, y, lag, h, w_a0, G, gv, lam, Jlam, gx_new, gv_new, ga0, gu);
      gx.swap(gx_new);
      gv.swap(gv_new);
      gx_new.resize(n3);
      gv_new.resize(n3);
    }
    for (size_t k = 0; k < m.anchors.size(); ++k)
      gx.segment<3>(3 * m.anchors[k]) += ga0.segment<3>(3 * static_cast<Eigen::Index>(k));
    StepVjp out;
    out.state.resize(6 * N());
    out.state << gx, gv;
    for (int a : m.anchors) gu.segment<3>(3 * a).setZero();
    out.control = gu;
    return out;
  }

  class Linear;
};

// The linearization of the step recorded in a copy of the simulator's tape: one factorization
// of the exact free-free Jacobian per substep, so jvp() and vjp() cost one solve per substep.
class MassSpringSimulator::Impl::Linear final : public StepLinearization {
 public:
  Linear(const Impl& sim, const StepInput& in) : m_sim(sim), m_in(in) {
    if (m_sim.sheet) m_surface = m_sim.surface_jacobian(m_sim.tape.xs.back());
    const Model& m = *m_sim.model;
    const int S = m_sim.P().substeps;
    m_h = in.dt / S;
    m_lag.resize(static_cast<size_t>(S));
    m_blocks.resize(static_cast<size_t>(S));
    m_factor.resize(static_cast<size_t>(S));
    // The substeps' matrices are assembled in turn (into the simulator's J), then factorized
    // in parallel (each factorization is the same bits in any thread).
    std::vector<Eigen::SparseMatrix<double>> jacobians(static_cast<size_t>(S));
    for (int s = 0; s < S; ++s) {
      const auto k = static_cast<size_t>(s);
      m_sim.make_lag(m_sim.tape.xs[k], m_sim.tape.vs[k], in.control, m_lag[k]);
      m_sim.exact_blocks(m_sim.tape.xs[k + 1], m_lag[k], m_h, m_blocks[k]);
      if (m.free_nodes.empty()) continue;
      m_sim.assemble(m_sim.tape.xs[k + 1], m_lag[k], m_h, true);
      jacobians[k] = m_sim.J;
      m_factor[k] = m.factor_pool->take(m_sim.analysis());
    }
    if (m.free_nodes.empty()) return;
    std::vector<char> factorized(static_cast<size_t>(S), 0);
    tbb::parallel_for(size_t{0}, static_cast<size_t>(S), [&](size_t k) {
      factorized[k] = m_factor[k]->factorize(jacobians[k]) ? 1 : 0;
    });
    for (char ok : factorized)
      if (!ok) throw std::runtime_error("mass_spring: singular system in linearize_step");
  }

  ~Linear() override {
    for (auto& f : m_factor) m_sim.model->factor_pool->give(std::move(f));
  }
  Linear(const Linear&) = delete;
  Linear& operator=(const Linear&) = delete;

  VectorXd jvp(const VectorXd& d_state_before, const VectorXd& d_control) override {
    const Model& m = *m_sim.model;
    const int S = m_sim.P().substeps, n3 = 3 * m_sim.N();
    check_size(d_state_before, 2 * n3, "d_state_before");
    check_size(d_control, 3 * m.num_surface, "d_control");
    VectorXd dx = d_state_before.size() ? VectorXd(d_state_before.head(n3)) : VectorXd::Zero(n3);
    VectorXd dv = d_state_before.size() ? VectorXd(d_state_before.tail(n3)) : VectorXd::Zero(n3);
    VectorXd da0(3 * static_cast<Eigen::Index>(m.anchors.size()));
    for (size_t k = 0; k < m.anchors.size(); ++k)
      da0.segment<3>(3 * static_cast<Eigen::Index>(k)) = dx.segment<3>(3 * m.anchors[k]);
    VectorXd dr, dy(n3), Jd;
    for (int s = 0; s < S; ++s) {
      const auto k = static_cast<size_t>(s);
      const VectorXd& xn = m_sim.tape.xs[k];
      const VectorXd& vn = m_sim.tape.vs[k];
      const VectorXd& y = m_sim.tape.xs[k + 1];
      m_sim.substep_explicit_tangent(xn, vn, y, m_lag[k], m_h, dx, dv, d_control, dr);
      // Anchored rows follow their prescribed tangent; free rows solve J_ff dy = -(dr + J_fa dy_a).
      dy.setZero();
      const double w_a0 = anchor_weight(s);
      for (size_t a = 0; a < m.anchors.size(); ++a)
        dy.segment<3>(3 * m.anchors[a]) = w_a0 * da0.segment<3>(3 * static_cast<Eigen::Index>(a));
      if (!m.anchors.empty()) {
        m_sim.apply_blocks(m_blocks[k], dy, Jd);
        dr += Jd;
      }
      if (m_factor[k]) {
        const VectorXd dyf = m_factor[k]->solve(m_sim.gather_free(dr));
        for (size_t f = 0; f < m.free_nodes.size(); ++f)
          dy.segment<3>(3 * m.free_nodes[f]) = -dyf.segment<3>(3 * static_cast<Eigen::Index>(f));
      }
      dv = (dy - dx) / m_h;
      dx = dy;
    }
    VectorXd out(2 * n3);
    out << dx, dv;
    return out;
  }

  Vertices position_tangent(const VectorXd& d_state_after) const override {
    check_size(d_state_after, 6 * m_sim.N(), "d_state_after");
    if (d_state_after.size() == 0) return Vertices::Zero(m_sim.num_vertices(), 3);
    return m_sim.surface_tangent(m_sim.tape.xs.back(), d_state_after.head(3 * m_sim.N()),
                                 m_surface_ptr());
  }

  VectorXd position_cotangent(const Vertices& d_positions_after) const override {
    if (d_positions_after.rows() != m_sim.num_vertices())
      throw std::invalid_argument("mass_spring: linearization position_cotangent expects " +
                                  std::to_string(m_sim.num_vertices()) + " rows, got " +
                                  std::to_string(d_positions_after.rows()));
    VectorXd out = VectorXd::Zero(6 * m_sim.N());
    out.head(3 * m_sim.N()) =
        m_sim.surface_cotangent(m_sim.tape.xs.back(), d_positions_after, m_surface_ptr());
    return out;
  }

  StepVjp vjp(const VectorXd& d_state_after) override {
    const Model& m = *m_sim.model;
    const int S = m_sim.P().substeps, n3 = 3 * m_sim.N();
    if (d_state_after.size() != 2 * n3)  // (no empty form: a zero cotangent has a zero result)
      throw std::invalid_argument("mass_spring: linearization vjp: d_state_after has " +
                                  std::to_string(d_state_after.size()) + " entries, expected " +
                                  std::to_string(2 * n3));
    VectorXd gx = d_state_after.head(n3), gv = d_state_after.tail(n3);
    VectorXd ga0 = VectorXd::Zero(3 * static_cast<Eigen::Index>(m.anchors.size()));
    VectorXd gu = VectorXd::Zero(3 * static_cast<Eigen::Index>(m.num_surface));
    VectorXd G, lam(n3), Jlam, gx_new, gv_new;
    for (int s = S - 1; s >= 0; --s) {
      const auto k = static_cast<size_t>(s);
      const VectorXd& y = m_sim.tape.xs[k + 1];
      G = gx + gv / m_h;
      lam.setZero();
      if (m_factor[k]) {
        const VectorXd lf = m_factor[k]->solve(m_sim.gather_free(G));
        for (size_t f = 0; f < m.free_nodes.size(); ++f)
          lam.segment<3>(3 * m.free_nodes[f]) = lf.segment<3>(3 * static_cast<Eigen::Index>(f));
      }
      m_sim.apply_blocks(m_blocks[k], lam, Jlam);
      m_sim.substep_transpose(m_sim.tape.xs[k], m_sim.tape.vs[k], y, m_lag[k], m_h,
                              anchor_weight(s), G, gv, lam, Jlam, gx_new, gv_new, ga0, gu);
      gx.swap(gx_new);
      gv.swap(gv_new);
    }
    for (size_t a = 0; a < m.anchors.size(); ++a)
      gx.segment<3>(3 * m.anchors[a]) += ga0.segment<3>(3 * static_cast<Eigen::Index>(a));
    for (int a : m.anchors) gu.segment<3>(3 * a).setZero();
    StepVjp out;
    out.state.resize(2 * n3);
    out.state << gx, gv;
    out.control = std::move(gu);
    return out;
  }

 private:
  // d y_anchor / d (anchor position at the step's start) after substep s (0-based).
  double anchor_weight(int s) const {
    const int S = m_sim.P().substeps;
    return m_in.anchor_targets.rows() != 0 ? 1.0 - static_cast<double>(s + 1) / S : 1.0;
  }
  static void check_size(const VectorXd& v, Eigen::Index expected, const char* what) {
    if (v.size() != 0 && v.size() != expected)
      throw std::invalid_argument(std::string("mass_spring: linearization ") + what + " has " +
                                  std::to_string(v.size()) + " entries, expected " +
                                  std::to_string(expected) + " or 0");
  }

  const SurfaceJacobian* m_surface_ptr() const { return m_sim.sheet ? &m_surface : nullptr; }

  Impl m_sim;  // a copy holding the recorded trajectory (and scratch for assembly)
  StepInput m_in;
  SurfaceJacobian m_surface;  // with a sheet: surface_jacobian() at the step's end
  double m_h = 0.0;
  std::vector<Lag> m_lag;             // per substep
  std::vector<ExactBlocks> m_blocks;  // per substep, the exact Jacobian at its end
  std::vector<std::unique_ptr<detail::SymmetricFactor>> m_factor;  // per substep, exact J_ff
};

// ----- public API ------------------------------------------------------------------------

MassSpringSimulator::MassSpringSimulator(const Mesh& mesh, const Vertices& positions,
                                         std::vector<int> anchors, const Params& params)
    : m_impl(std::make_unique<Impl>()) {
  m_impl->user_params = params;
  std::optional<ThinSheet> sheet;
  if (params.material == Material::cloth && params.single_sheet != 0)
    sheet = detail::thin_sheet_of(mesh, positions, anchors, params);
  if (sheet) {
    // The model is the sheet: its nodes, its triangles, the whole surface's mass, and the
    // nodes that carry the anchored vertices held.
    const auto nn = static_cast<Eigen::Index>(sheet->node_vertex.size());
    Mesh sheet_mesh;
    sheet_mesh.triangles = sheet->triangles;
    Vertices nodes(nn, 3);
    for (Eigen::Index i = 0; i < nn; ++i)
      nodes.row(i) = positions.row(sheet->node_vertex[static_cast<size_t>(i)]);
    std::vector<int> held;
    for (int a : anchors) {
      const int node = sheet->vertex_node[static_cast<size_t>(a)];
      if (node >= 0) {
        held.push_back(node);
        continue;
      }
      const SheetAttachment& at = sheet->attachment[static_cast<size_t>(a)];
      for (int k = 0; k < 3; ++k)
        if (at.bary[k] > 1e-6) held.push_back(sheet->triangles(at.triangle, k));
    }
    std::sort(held.begin(), held.end());
    held.erase(std::unique(held.begin(), held.end()), held.end());
    Params sp = params;
    sp.layer_stiffness = 0.0;
    sp.density *= detail::surface_area(positions, mesh.triangles) /
                  detail::surface_area(nodes, sheet->triangles);
    m_impl->model = std::make_shared<const detail::Model>(
        detail::build_model(sheet_mesh, nodes, std::move(held), sp));
    m_impl->vertex_block.resize(sheet->vertex_node.size());
    for (size_t v = 0; v < sheet->vertex_node.size(); ++v) {
      int block = sheet->vertex_node[v];
      if (block < 0) {
        const SheetAttachment& at = sheet->attachment[v];
        Eigen::Index k = 0;
        at.bary.maxCoeff(&k);
        block = sheet->triangles(at.triangle, k);
      }
      m_impl->vertex_block[v] = block;
    }
    m_impl->sheet = std::make_shared<const ThinSheet>(std::move(*sheet));
  } else {
    m_impl->model = std::make_shared<const detail::Model>(
        detail::build_model(mesh, positions, std::move(anchors), params));
    m_impl->vertex_block.resize(static_cast<size_t>(m_impl->model->num_surface));
    std::iota(m_impl->vertex_block.begin(), m_impl->vertex_block.end(), 0);
  }
  m_impl->x = m_impl->model->rest;
  m_impl->v = VectorXd::Zero(m_impl->x.size());
  m_impl->phys = Vertices::Zero(m_impl->model->num_surface, 3);
  m_impl->phys_norm = Eigen::VectorXd::Zero(m_impl->model->num_surface);
}

MassSpringSimulator::MassSpringSimulator(const Mesh& mesh, std::vector<int> anchors,
                                         const Params& params)
    : MassSpringSimulator(mesh, mesh.vertices, std::move(anchors), params) {}

MassSpringSimulator::MassSpringSimulator(const MassSpringSimulator& other)
    : m_impl(std::make_unique<Impl>(*other.m_impl)) {}

MassSpringSimulator& MassSpringSimulator::operator=(const MassSpringSimulator& other) {
  if (this != &other) m_impl = std::make_unique<Impl>(*other.m_impl);
  return *this;
}

MassSpringSimulator::~MassSpringSimulator() = default;

int MassSpringSimulator::num_vertices() const {
  return m_impl->num_vertices();
}

Vertices MassSpringSimulator::positions() const {
  return m_impl->surface_positions(m_impl->x);
}

Vertices MassSpringSimulator::velocities() const {
  // Attached vertices of a sheet: the tangent of their position along the node velocities.
  return m_impl->surface_tangent(m_impl->x, m_impl->v);
}

ControlLayout MassSpringSimulator::control_layout() const {
  // One force per node (per surface vertex without a sheet; per sheet node with one, a force
  // on an attached vertex being one on the node that carries it most).
  ControlLayout l;
  l.space = ControlSpace::vertex_force;
  l.num_blocks = m_impl->model->num_surface;
  l.block_mass = m_impl->model->mass.head(l.num_blocks);
  l.vertex_block = m_impl->vertex_block;
  return l;
}

std::vector<int> MassSpringSimulator::anchors() const {
  if (!m_impl->sheet) return m_impl->model->anchors;
  std::vector<int> out;
  for (int node : m_impl->model->anchors)
    out.push_back(m_impl->sheet->node_vertex[static_cast<size_t>(node)]);
  return out;
}

void MassSpringSimulator::step(const StepInput& in) {
  m_impl->step(in);
}

Vertices MassSpringSimulator::physical_forces() const {
  return m_impl->scatter_rows(m_impl->phys);
}

Eigen::VectorXd MassSpringSimulator::physical_force_magnitudes() const {
  return m_impl->scatter_rows(m_impl->phys_norm);
}

SimState MassSpringSimulator::save() const {
  SimState s;
  s.values.resize(static_cast<size_t>(m_impl->x.size() + m_impl->v.size()));
  std::copy(m_impl->x.begin(), m_impl->x.end(), s.values.begin());
  std::copy(m_impl->v.begin(), m_impl->v.end(), s.values.begin() + m_impl->x.size());
  return s;
}

void MassSpringSimulator::restore(const SimState& state) {
  const auto n3 = static_cast<size_t>(m_impl->x.size());
  if (state.values.size() != 2 * n3)
    throw std::invalid_argument("mass_spring: restore() got a state of " +
                                std::to_string(state.values.size()) + " values, expected " +
                                std::to_string(2 * n3));
  std::copy(state.values.begin(), state.values.begin() + static_cast<std::ptrdiff_t>(n3),
            m_impl->x.begin());
  std::copy(state.values.begin() + static_cast<std::ptrdiff_t>(n3), state.values.end(),
            m_impl->v.begin());
}

std::unique_ptr<Simulator> MassSpringSimulator::clone() const {
  return std::make_unique<MassSpringSimulator>(*this);
}

int MassSpringSimulator::state_dim() const {
  return 6 * m_impl->model->num_nodes;
}

Eigen::VectorXd MassSpringSimulator::position_cotangent(const Vertices& d_positions) const {
  if (d_positions.rows() != num_vertices() || d_positions.cols() != 3)
    throw std::invalid_argument("mass_spring: position_cotangent expects " +
                                std::to_string(num_vertices()) + " by 3, got " +
                                std::to_string(d_positions.rows()) + " by " +
                                std::to_string(d_positions.cols()));
  VectorXd g = VectorXd::Zero(state_dim());
  g.head(3 * m_impl->N()) = m_impl->surface_cotangent(m_impl->x, d_positions);
  return g;
}

Vertices MassSpringSimulator::position_tangent(const Eigen::VectorXd& d_state) const {
  if (d_state.size() != state_dim())
    throw std::invalid_argument("mass_spring: position_tangent expects " +
                                std::to_string(state_dim()) + " entries, got " +
                                std::to_string(d_state.size()));
  return m_impl->surface_tangent(m_impl->x, d_state.head(3 * m_impl->N()));
}

StepVjp MassSpringSimulator::step_vjp(const SimState& before, const StepInput& in,
                                      const Eigen::VectorXd& d_state_after) {
  m_impl->validate(in);
  if (d_state_after.size() != state_dim())
    throw std::invalid_argument("mass_spring: step_vjp d_state_after has " +
                                std::to_string(d_state_after.size()) + " entries, expected " +
                                std::to_string(state_dim()));
  if (before.values.size() != static_cast<size_t>(state_dim()))
    throw std::invalid_argument("mass_spring: step_vjp state has " +
                                std::to_string(before.values.size()) + " values, expected " +
                                std::to_string(state_dim()));
  m_impl->record(before, in);
  return m_impl->vjp(in, d_state_after);
}

std::unique_ptr<StepLinearization> MassSpringSimulator::linearize_step(const SimState& before,
                                                                       const StepInput& in) {
  m_impl->validate(in);
  if (before.values.size() != static_cast<size_t>(state_dim()))
    throw std::invalid_argument("mass_spring: linearize_step state has " +
                                std::to_string(before.values.size()) + " values, expected " +
                                std::to_string(state_dim()));
  m_impl->record(before, in);
  return std::make_unique<Impl::Linear>(*m_impl, in);
}

int MassSpringSimulator::num_nodes() const {
  return m_impl->model->num_nodes;
}

Vertices MassSpringSimulator::node_positions() const {
  return Eigen::Map<const Vertices>(m_impl->x.data(), num_nodes(), 3);
}

Eigen::VectorXd MassSpringSimulator::node_masses() const {
  return m_impl->model->mass;
}

int MassSpringSimulator::num_springs() const {
  return static_cast<int>(m_impl->model->springs.size());
}

const Params& MassSpringSimulator::params() const {
  return m_impl->user_params;
}

bool MassSpringSimulator::single_sheet() const {
  return m_impl->sheet != nullptr;
}

const StepStats& MassSpringSimulator::last_stats() const {
  return m_impl->stats;
}

double MassSpringSimulator::kinetic_energy() const {
  double e = 0.0;
  for (int i = 0; i < num_nodes(); ++i)
    e += 0.5 * m_impl->model->mass[i] * m_impl->v.segment<3>(3 * i).squaredNorm();
  return e;
}

}  // namespace pbve::mass_spring
