#include "multigrid.hpp"

#include <algorithm>
#include <atomic>
#include <cmath>
#include <limits>
#include <stdexcept>

#include <Eigen/Cholesky>
#include <Eigen/LU>

#include <tbb/blocked_range.h>
#include <tbb/parallel_for.h>
#include <tbb/parallel_invoke.h>

#include "pseudo_random.hpp"

namespace pbve::mass_spring::detail {

namespace {

using Eigen::Matrix3d;
using Eigen::SparseMatrix;
using Eigen::Vector3d;
using Eigen::VectorXd;
using Blocks = MultigridHierarchy::Blocks;
using Level = MultigridHierarchy::Level;
using Real = Multigrid::Real;
using Block = Multigrid::Block;
using Vector = Multigrid::Vector;
using Vec3 = Eigen::Matrix<Real, 3, 1>;
// Per node: its (strong) connections, as (node, weight >= 0).
using Graph = std::vector<std::vector<std::pair<int, double>>>;

// Coarsening stops at this many nodes (the coarsest matrix is factorized dense) or when a level
// would keep more than `max_coarse_ratio` of its nodes.
constexpr int coarsest_nodes = 96;
constexpr double max_coarse_ratio = 0.6;
// Two nodes are strongly connected when their connection is at least this fraction of the
// geometric mean of their total connections (smoothed aggregation's usual criterion).
constexpr double strength_threshold = 0.08;
// Prolongator smoothing P = (I - omega D^-1 L_F) P_0 with the Laplacian L_F of the filtered
// stiffness graph (the strong connections) and D its diagonal: omega = 4 / (3 rho), rho the
// spectral radius of D^-1 L_F (at most 2; about 1.6 on triangle meshes), estimated by this
// many power iterations.
constexpr int spectral_iterations = 30;
// C/F interpolation (the finest level when rest positions are given): affine reproduction to
// this relative tolerance, and weights at most this large in magnitude.
// this relative tolerance, and weights at most this large in magnitude; the least-squares
// reproduction is a penalty of this weight. A node whose rest position its C neighbours miss
// by more than `outside` (relative to their distance; rounding and curvature miss by far
// less) or reproduce with a weight below `-outside` lies outside them (on a free edge):
// interpolated from farther C nodes.
constexpr double affine_penalty = 1e8;
constexpr double outside = 0.05;
constexpr double max_weight = 3.0;

// The spectral radius of D^-1 L_F by power iteration from a fixed pseudo-random vector. D^-1 L_F
// is similar to the normalized Laplacian D^-1/2 L_F D^-1/2, whose eigenvalues are real, in
// [0, 2], and the largest at least m / (m - 1) > 1 on a connected part of m >= 2 nodes: the
// estimate (from below) is clamped to [1, 2], so omega is in [2/3, 4/3] even if the iteration
// has not converged or the graph has no edge.
double laplacian_radius(const Graph& strong) {
  const size_t n = strong.size();
  VectorXd v = pseudo_random_vector(static_cast<Eigen::Index>(n));
  std::vector<double> w(n), d(n, 0.0);
  for (size_t i = 0; i < n; ++i)
    for (const auto& e : strong[i]) d[i] += e.second;
  double rho = 0.0;
  for (int it = 0; it < spectral_iterations; ++it) {
    double vv = 0.0, ww = 0.0;
    for (size_t i = 0; i < n; ++i) {
      double acc = 0.0;
      for (const auto& e : strong[i]) acc += e.second * v[e.first];
      w[i] = d[i] > 0.0 ? v[i] - acc / d[i] : 0.0;
      vv += v[i] * v[i];
      ww += w[i] * w[i];
    }
    if (!(ww > 0.0)) break;
    rho = std::sqrt(ww / vv);
    const double scale = 1.0 / std::sqrt(ww);
    for (size_t i = 0; i < n; ++i) v[i] = w[i] * scale;
  }
  return std::clamp(rho, 1.0, 2.0);
}

// Per node: the aggregate it belongs to. Greedy aggregation of the strong-connection graph:
// a node whose strong neighbours are all free starts an aggregate with them; the nodes left
// join the aggregate of their strongest aggregated neighbour; the rest (no aggregated strong
// neighbour) start aggregates with their free strong neighbours.
std::vector<int> aggregate(const Graph& strong, int& count) {
  const int n = static_cast<int>(strong.size());
  std::vector<int> agg(static_cast<size_t>(n), -1);
  count = 0;
  for (int i = 0; i < n; ++i) {
    const auto& nb = strong[static_cast<size_t>(i)];
    if (agg[static_cast<size_t>(i)] >= 0 || nb.empty()) continue;
    if (std::any_of(nb.begin(), nb.end(),
                    [&](const auto& e) { return agg[static_cast<size_t>(e.first)] >= 0; }))
      continue;
    agg[static_cast<size_t>(i)] = count;
    for (const auto& e : nb) agg[static_cast<size_t>(e.first)] = count;
    ++count;
  }
  const std::vector<int> first = agg;
  for (int i = 0; i < n; ++i) {
    if (agg[static_cast<size_t>(i)] >= 0) continue;
    double best = -1.0;
    for (const auto& e : strong[static_cast<size_t>(i)])
      if (first[static_cast<size_t>(e.first)] >= 0 && e.second > best) {
        best = e.second;
        agg[static_cast<size_t>(i)] = first[static_cast<size_t>(e.first)];
      }
  }
  for (int i = 0; i < n; ++i) {
    if (agg[static_cast<size_t>(i)] >= 0) continue;
    agg[static_cast<size_t>(i)] = count;
    for (const auto& e : strong[static_cast<size_t>(i)])
      if (agg[static_cast<size_t>(e.first)] < 0) agg[static_cast<size_t>(e.first)] = count;
    ++count;
  }
  return agg;
}

// The strong connections of the strength graph S (n x n, symmetric, off-diagonal entries the
// connection weights; the diagonal is ignored), and each node's total connection in `total`.
Graph strong_graph(const SparseMatrix<double>& S, std::vector<double>& total) {
  const int n = static_cast<int>(S.rows());
  total.assign(static_cast<size_t>(n), 0.0);
  for (int j = 0; j < n; ++j)
    for (SparseMatrix<double>::InnerIterator it(S, j); it; ++it)
      if (it.row() != j) total[static_cast<size_t>(j)] += std::abs(it.value());
  Graph strong(static_cast<size_t>(n));
  for (int j = 0; j < n; ++j)
    for (SparseMatrix<double>::InnerIterator it(S, j); it; ++it) {
      const int i = static_cast<int>(it.row());
      const double w = std::abs(it.value());
      if (i != j && w > 0.0 &&
          w >= strength_threshold *
                   std::sqrt(total[static_cast<size_t>(i)] * total[static_cast<size_t>(j)]))
        strong[static_cast<size_t>(j)].emplace_back(i, w);
    }
  return strong;
}

// Stores the prolongator P (n x count) in `level` and returns the next level's strength graph
// P^T L P, L the graph Laplacian of S (weights `total` on the diagonal).
SparseMatrix<double> finish_transfer(const SparseMatrix<double>& S,
                                     const std::vector<double>& total,
                                     const std::vector<Eigen::Triplet<double>>& entries, int count,
                                     Level& level) {
  const int n = static_cast<int>(S.rows());
  SparseMatrix<double> P(n, count);
  P.setFromTriplets(entries.begin(), entries.end());  // sums duplicates
  P.prune(0.0);
  level.coarse = count;
  const SparseMatrix<double, Eigen::RowMajor> Pr = P;
  level.p_row_start.assign(Pr.outerIndexPtr(), Pr.outerIndexPtr() + n + 1);
  level.p_row_col.assign(Pr.innerIndexPtr(), Pr.innerIndexPtr() + Pr.nonZeros());
  level.p_row_w.assign(Pr.valuePtr(), Pr.valuePtr() + Pr.nonZeros());
  level.p_col_start.assign(P.outerIndexPtr(), P.outerIndexPtr() + count + 1);
  level.p_col_row.assign(P.innerIndexPtr(), P.innerIndexPtr() + P.nonZeros());
  level.p_col_w.assign(P.valuePtr(), P.valuePtr() + P.nonZeros());
  std::vector<Eigen::Triplet<double>> lap;
  for (int j = 0; j < n; ++j) {
    lap.emplace_back(j, j, total[static_cast<size_t>(j)]);
    for (SparseMatrix<double>::InnerIterator it(S, j); it; ++it)
      if (it.row() != j) lap.emplace_back(static_cast<int>(it.row()), j, -std::abs(it.value()));
  }
  SparseMatrix<double> L(n, n);
  L.setFromTriplets(lap.begin(), lap.end());
  SparseMatrix<double> next = SparseMatrix<double>(P.transpose()) * L * P;
  next.prune(0.0);
  return next;
}

// Builds the transfer of `level` by smoothed aggregation from its strength graph S. Returns the
// next level's S, or an empty matrix when coarsening stops.
SparseMatrix<double> build_transfer(const SparseMatrix<double>& S, Level& level) {
  const int n = static_cast<int>(S.rows());
  std::vector<double> total;
  const Graph strong = strong_graph(S, total);
  int count = 0;
  const std::vector<int> agg = aggregate(strong, count);
  if (n <= coarsest_nodes || count > max_coarse_ratio * n || count == 0) return {};

  // P = (I - omega D^-1 L_F) P_0, row by row: P_0 puts node i in its aggregate with weight 1.
  const double smoothing_omega = 4.0 / (3.0 * laplacian_radius(strong));
  std::vector<Eigen::Triplet<double>> entries;
  for (int i = 0; i < n; ++i) {
    const auto& nb = strong[static_cast<size_t>(i)];
    double d = 0.0;
    for (const auto& e : nb) d += e.second;
    const int a = agg[static_cast<size_t>(i)];
    if (d <= 0.0) {
      entries.emplace_back(i, a, 1.0);
      continue;
    }
    entries.emplace_back(i, a, 1.0 - smoothing_omega);
    for (const auto& e : nb)
      entries.emplace_back(i, agg[static_cast<size_t>(e.first)], smoothing_omega * e.second / d);
  }
  return finish_transfer(S, total, entries, count, level);
}

// Interpolation weights w of the rest position x from the rest positions of `from`: summing
// to 1, and among those, reproducing x as an affine combination as closely as the points
// allow (least squares), and among those the least norm with each point's weight scaled by
// its inverse squared distance (near points first). Returns the distance between x and that
// combination relative to the farthest point.
double affine_weights(const Vector3d& x, const std::vector<int>& from, const Eigen::MatrixX3d& rest,
                      std::vector<double>& w) {
  const auto k = static_cast<Eigen::Index>(from.size());
  double scale = 0.0;
  for (const int c : from) scale = std::max(scale, (rest.row(c).transpose() - x).norm());
  if (!(scale > 0.0)) {
    w.assign(from.size(), 1.0 / static_cast<double>(k));
    return 0.0;
  }
  Eigen::MatrixX3d D(k, 3);
  for (Eigen::Index q = 0; q < k; ++q)
    D.row(q) = (rest.row(from[static_cast<size_t>(q)]) - x.transpose()) / scale;
  // min w^T Q w subject to sum(w) = 1, Q = mu D D^T + diag(|d_q|^2): w = Q^-1 1 / 1^T Q^-1 1.
  Eigen::MatrixXd Q = affine_penalty * (D * D.transpose());
  for (Eigen::Index q = 0; q < k; ++q) Q(q, q) += std::max(D.row(q).squaredNorm(), 1e-12);
  const VectorXd y = Q.ldlt().solve(VectorXd::Ones(k));
  const VectorXd wv = y / y.sum();
  w.assign(wv.data(), wv.data() + k);
  if (!wv.allFinite()) return std::numeric_limits<double>::infinity();
  return (D.transpose() * wv).norm();
}

// Builds the transfer of `level` by C/F splitting, from its strength graph S and its nodes'
// rest positions `rest` (replaced by the next level's): the coarse (C) nodes are a maximal
// independent set of the strong graph (greedy, in node order: on a triangle mesh about one node
// in four), and each other (F) node interpolates from its strong C neighbours with weights
// reproducing affine functions of the rest position (linear interpolation between them); where
// they cannot (a node on a free edge with C neighbours on one side only), from the C nodes
// within two, then three strong links (linear extrapolation towards the edge). Against smoothed
// aggregation (about nine nodes per aggregate): a coarse space twice as fine whose matrix has
// about 13 blocks per row instead of 22, and a free edge's bending modes represented up to the
// edge. Returns the next level's S, or an empty matrix (level.coarse 0) when this does not
// coarsen.
SparseMatrix<double> build_cf_transfer(const SparseMatrix<double>& S, Eigen::MatrixX3d& rest,
                                       Level& level) {
  const int n = static_cast<int>(S.rows());
  std::vector<double> total;
  const Graph strong = strong_graph(S, total);
  std::vector<int> coarse(static_cast<size_t>(n), -2);  // C index, -1 F, -2 unassigned
  int count = 0;
  for (int i = 0; i < n; ++i) {
    if (coarse[static_cast<size_t>(i)] != -2) continue;
    coarse[static_cast<size_t>(i)] = count++;
    for (const auto& e : strong[static_cast<size_t>(i)])
      if (coarse[static_cast<size_t>(e.first)] == -2) coarse[static_cast<size_t>(e.first)] = -1;
  }
  if (n <= coarsest_nodes || count > max_coarse_ratio * n) return {};
  std::vector<Eigen::Triplet<double>> entries;
  std::vector<int> from, frontier, next_frontier, seen(static_cast<size_t>(n), 0);
  int stamp = 0;
  std::vector<double> w;
  for (int i = 0; i < n; ++i) {
    const auto& nb = strong[static_cast<size_t>(i)];
    if (coarse[static_cast<size_t>(i)] >= 0) {
      entries.emplace_back(i, coarse[static_cast<size_t>(i)], 1.0);
      continue;
    }
    const Vector3d x = rest.row(i).transpose();
    from.clear();
    for (const auto& e : nb)
      if (coarse[static_cast<size_t>(e.first)] >= 0) from.push_back(e.first);
    const auto nearest = from.size();
    double miss = affine_weights(x, from, rest, w);
    // Not reproduced, or not by interpolation: the C nodes two, then three links away too.
    for (int depth = 2;
         depth <= 3 &&
         (miss > outside || std::any_of(w.begin(), w.end(), [](double v) { return v < -outside; }));
         ++depth) {
      const size_t before = from.size();
      ++stamp;
      frontier.assign(1, i);
      seen[static_cast<size_t>(i)] = stamp;
      for (int d = 0; d < depth; ++d) {
        next_frontier.clear();
        for (const int u : frontier)
          for (const auto& e : strong[static_cast<size_t>(u)])
            if (seen[static_cast<size_t>(e.first)] != stamp) {
              seen[static_cast<size_t>(e.first)] = stamp;
              next_frontier.push_back(e.first);
              if (coarse[static_cast<size_t>(e.first)] >= 0 &&
                  std::find(from.begin(), from.end(), e.first) == from.end())
                from.push_back(e.first);
            }
        frontier.swap(next_frontier);
      }
      if (from.size() > before) miss = affine_weights(x, from, rest, w);
    }
    // Large weights (extrapolation from points nearly coincident or far): direct
    // interpolation, by connection.
    const bool usable =
        std::all_of(w.begin(), w.end(), [](double v) { return std::abs(v) <= max_weight; });
    if (!usable) {
      from.resize(nearest);
      double sum = 0.0;
      for (const auto& e : nb)
        if (coarse[static_cast<size_t>(e.first)] >= 0) sum += e.second;
      w.clear();
      for (const auto& e : nb)
        if (coarse[static_cast<size_t>(e.first)] >= 0) w.push_back(e.second / sum);
    }
    for (size_t q = 0; q < from.size(); ++q)
      if (std::abs(w[q]) > 1e-12)
        entries.emplace_back(i, coarse[static_cast<size_t>(from[q])], w[q]);
  }
  Eigen::MatrixX3d next_rest(count, 3);
  for (int i = 0; i < n; ++i)
    if (coarse[static_cast<size_t>(i)] >= 0)
      next_rest.row(coarse[static_cast<size_t>(i)]) = rest.row(i);
  SparseMatrix<double> next = finish_transfer(S, total, entries, count, level);
  rest = std::move(next_rest);
  return next;
}

// The Galerkin plans of `level` (whose A pattern and transfer are set) and the next level's
// pattern.
Blocks build_plans(Level& level) {
  const Blocks& A = level.A;
  const int n = A.rows(), nc = level.coarse;
  // T = P^T A: row b sums w * (row i of A) over the nodes i of P's column b.
  Blocks& T = level.T;
  T.start.assign(1, 0);
  level.t_plan.assign(1, 0);
  std::vector<int> mark(static_cast<size_t>(n), -1);
  for (int b = 0; b < nc; ++b) {
    const int row_begin = static_cast<int>(T.col.size());
    for (int k = level.p_col_start[static_cast<size_t>(b)];
         k < level.p_col_start[static_cast<size_t>(b) + 1]; ++k) {
      const int i = level.p_col_row[static_cast<size_t>(k)];
      const double w = level.p_col_w[static_cast<size_t>(k)];
      for (int e = A.start[static_cast<size_t>(i)]; e < A.start[static_cast<size_t>(i) + 1]; ++e) {
        const int j = A.col[static_cast<size_t>(e)];
        int& t = mark[static_cast<size_t>(j)];
        if (t < row_begin) {
          t = static_cast<int>(T.col.size());
          T.col.push_back(j);
        }
        level.to_t.push_back({t, e, w});
      }
    }
    T.start.push_back(static_cast<int>(T.col.size()));
    level.t_plan.push_back(static_cast<int>(level.to_t.size()));
  }
  // A_next = T P: block (b, c) sums w * T(b, j) over the entries (j, c) of P.
  Blocks next;
  next.start.assign(1, 0);
  level.next_plan.assign(1, 0);
  std::vector<int> cmark(static_cast<size_t>(nc), -1);
  for (int b = 0; b < nc; ++b) {
    const int row_begin = static_cast<int>(next.col.size());
    for (int t = T.start[static_cast<size_t>(b)]; t < T.start[static_cast<size_t>(b) + 1]; ++t) {
      const int j = T.col[static_cast<size_t>(t)];
      for (int k = level.p_row_start[static_cast<size_t>(j)];
           k < level.p_row_start[static_cast<size_t>(j) + 1]; ++k) {
        const int c = level.p_row_col[static_cast<size_t>(k)];
        int& dst = cmark[static_cast<size_t>(c)];
        if (dst < row_begin) {
          dst = static_cast<int>(next.col.size());
          next.col.push_back(c);
        }
        level.to_next.push_back({dst, t, level.p_row_w[static_cast<size_t>(k)]});
      }
    }
    next.start.push_back(static_cast<int>(next.col.size()));
    level.next_plan.push_back(static_cast<int>(level.to_next.size()));
  }
  next.diag.assign(static_cast<size_t>(nc), -1);
  for (int b = 0; b < nc; ++b)
    for (int e = next.start[static_cast<size_t>(b)]; e < next.start[static_cast<size_t>(b) + 1];
         ++e)
      if (next.col[static_cast<size_t>(e)] == b) next.diag[static_cast<size_t>(b)] = e;
  return next;
}

// A finest level of at least this many nodes is smoothed by two threads, a coarser one (not
// the coarsest) of at least parallel_coarse_nodes.
constexpr int parallel_nodes = 2048;
constexpr int parallel_coarse_nodes = 1024;

// Whether threads run `level` (a split level).
bool threaded(const Level& level) {
  return level.part[0] > 0 && level.part[1] < level.U.rows();
}

// f(k) for k in [0, n), in parallel on a split level.
template <class F>
void for_rows(const Level& level, int n, F f) {
  if (!threaded(level)) {
    for (int k = 0; k < n; ++k) f(k);
    return;
  }
  tbb::parallel_for(tbb::blocked_range<int>(0, n, 2048), [&](const tbb::blocked_range<int>& r) {
    for (int k = r.begin(); k != r.end(); ++k) f(k);
  });
}

// f(begin, end) over ranges of the next level's nodes [0, level.coarse), in parallel on a
// split level (the next level's nodes are too few for for_rows' grain).
template <class F>
void coarse_ranges(const Level& level, F f) {
  if (!threaded(level)) {
    f(0, level.coarse);
    return;
  }
  tbb::parallel_for(tbb::blocked_range<int>(0, level.coarse, 64),
                    [&](const tbb::blocked_range<int>& r) { f(r.begin(), r.end()); });
}

// f(c) for each of the next level's nodes, as coarse_ranges().
template <class F>
void coarse_rows(const Level& level, F f) {
  coarse_ranges(level, [&](int begin, int end) {
    for (int c = begin; c < end; ++c) f(c);
  });
}

// The V-cycle order of `level` (see Level::order) and everything kept in that order; `next`:
// the next level, already ordered (null on the coarsest). Splits the level in two parts from
// min_split nodes.
void order_level(Level& level, int min_split, const Level* next) {
  const Blocks& A = level.A;
  const int n = A.rows();
  level.order.clear();
  level.part[0] = level.part[1] = n;
  if (level.coarse > 0 && n >= min_split) {
    // The halves of the node numbering (meshes number their nodes with some locality), and
    // the first half's nodes coupled to the second as the separator.
    const int half = n / 2;
    std::vector<int> separator, first;
    for (int i = 0; i < half; ++i) {
      bool coupled = false;
      for (int e = A.start[static_cast<size_t>(i)]; e < A.start[static_cast<size_t>(i) + 1]; ++e)
        coupled = coupled || A.col[static_cast<size_t>(e)] >= half;
      (coupled ? separator : first).push_back(i);
    }
    // Threads pay only with a thin separator (a few grid lines): else one part.
    if (separator.size() <= static_cast<size_t>(n / 8)) {
      level.order = first;
      for (int i = half; i < n; ++i) level.order.push_back(i);
      level.order.insert(level.order.end(), separator.begin(), separator.end());
      level.part[0] = static_cast<int>(first.size());
      level.part[1] = level.part[0] + (n - half);
    }
  }
  if (level.order.empty())
    for (int i = 0; i < n; ++i) level.order.push_back(i);
  std::vector<int> rank(static_cast<size_t>(n));
  for (int k = 0; k < n; ++k) rank[static_cast<size_t>(level.order[static_cast<size_t>(k)])] = k;
  Blocks& U = level.U;
  U.start.assign(1, 0);
  U.col.clear();
  level.u_src.clear();
  level.d_src.clear();
  for (int k = 0; k < n; ++k) {
    const int i = level.order[static_cast<size_t>(k)];
    level.d_src.push_back(A.diag[static_cast<size_t>(i)]);
    for (int e = A.start[static_cast<size_t>(i)]; e < A.start[static_cast<size_t>(i) + 1]; ++e) {
      const int c = rank[static_cast<size_t>(A.col[static_cast<size_t>(e)])];
      if (c <= k) continue;
      // A part's rows couple only to their own part and the separator.
      if (k < level.part[0] && c >= level.part[0] && c < level.part[1])
        throw std::logic_error("multigrid: the separator does not separate");
      U.col.push_back(c);
      level.u_src.push_back(e);
    }
    U.start.push_back(static_cast<int>(U.col.size()));
  }
  level.c_row_start.assign(1, 0);
  level.c_row_col.clear();
  level.c_row_w.clear();
  level.c_col_start.assign(1, 0);
  level.c_col_row.clear();
  level.c_col_w.clear();
  if (level.coarse == 0 || !next) return;
  std::vector<int> next_rank(static_cast<size_t>(level.coarse));
  for (int k = 0; k < level.coarse; ++k)
    next_rank[static_cast<size_t>(next->order[static_cast<size_t>(k)])] = k;
  for (int k = 0; k < n; ++k) {
    const auto i = static_cast<size_t>(level.order[static_cast<size_t>(k)]);
    for (int q = level.p_row_start[i]; q < level.p_row_start[i + 1]; ++q) {
      level.c_row_col.push_back(
          next_rank[static_cast<size_t>(level.p_row_col[static_cast<size_t>(q)])]);
      level.c_row_w.push_back(level.p_row_w[static_cast<size_t>(q)]);
    }
    level.c_row_start.push_back(static_cast<int>(level.c_row_col.size()));
  }
  for (int k = 0; k < level.coarse; ++k) {
    const auto c = static_cast<size_t>(next->order[static_cast<size_t>(k)]);
    for (int q = level.p_col_start[c]; q < level.p_col_start[c + 1]; ++q) {
      level.c_col_row.push_back(rank[static_cast<size_t>(level.p_col_row[static_cast<size_t>(q)])]);
      level.c_col_w.push_back(level.p_col_w[static_cast<size_t>(q)]);
    }
    level.c_col_start.push_back(static_cast<int>(level.c_col_row.size()));
  }
}

}  // namespace

MultigridHierarchy::MultigridHierarchy(const SparseMatrix<double>& pattern,
                                       const SparseMatrix<double>& strength,
                                       const Eigen::MatrixX3d& rest) {
  const int n = static_cast<int>(strength.rows());
  if (pattern.rows() != 3 * n || pattern.cols() != 3 * n || strength.cols() != n ||
      (rest.rows() != 0 && rest.rows() != n))
    throw std::logic_error("multigrid: pattern, strength graph and rest positions sizes differ");
  // Level 0's blocks from the symmetric pattern: block row i = block column i, read from
  // columns 3i .. 3i + 2, which must hold the same rows in groups of three.
  Level fine;
  Blocks& A = fine.A;
  A.start.assign(1, 0);
  A.diag.assign(static_cast<size_t>(n), -1);
  const int* outer = pattern.outerIndexPtr();
  const int* inner = pattern.innerIndexPtr();
  for (int i = 0; i < n; ++i) {
    const int len = outer[3 * i + 1] - outer[3 * i];
    if (len % 3 != 0 || outer[3 * i + 2] - outer[3 * i + 1] != len ||
        outer[3 * i + 3] - outer[3 * i + 2] != len)
      throw std::logic_error("multigrid: the pattern is not made of full 3x3 blocks");
    for (int p = 0; p < len / 3; ++p) {
      const int row = inner[outer[3 * i] + 3 * p];
      for (int r = 0; r < 3; ++r)
        for (int c = 0; c < 3; ++c)
          if (inner[outer[3 * i + r] + 3 * p + c] != row + c || row % 3 != 0)
            throw std::logic_error("multigrid: the pattern is not made of full 3x3 blocks");
      const int j = row / 3;
      if (j == i) A.diag[static_cast<size_t>(i)] = static_cast<int>(A.col.size());
      A.col.push_back(j);
      for (int r = 0; r < 3; ++r) m_fine_offset.push_back(outer[3 * i + r] + 3 * p);
    }
    if (A.diag[static_cast<size_t>(i)] < 0)
      throw std::logic_error("multigrid: the pattern lacks a diagonal block");
    A.start.push_back(static_cast<int>(A.col.size()));
  }
  m_levels.push_back(std::move(fine));
  SparseMatrix<double> S = strength;
  // C/F splitting while there are positions and it coarsens (a coarse node is a fine node,
  // with its position), smoothed aggregation below.
  Eigen::MatrixX3d positions = rest;
  for (;;) {
    Level& level = m_levels.back();
    SparseMatrix<double> next_s;
    if (positions.rows() > 0) next_s = build_cf_transfer(S, positions, level);
    if (level.coarse == 0) {
      positions.resize(0, 3);  // aggregates below: no positions
      next_s = build_transfer(S, level);
    }
    S = std::move(next_s);
    if (level.coarse == 0) break;
    Blocks next = build_plans(level);
    Level coarse;
    coarse.A = std::move(next);
    m_levels.push_back(std::move(coarse));
  }
  // From the coarsest level up: each level's transfer indexes the next level's order.
  for (size_t l = m_levels.size(); l-- > 0;)
    order_level(m_levels[l], l == 0 ? parallel_nodes : parallel_coarse_nodes,
                l + 1 < m_levels.size() ? &m_levels[l + 1] : nullptr);
}

Multigrid::Multigrid(std::shared_ptr<const MultigridHierarchy> hierarchy)
    : m_h(std::move(hierarchy)) {
  const size_t L = m_h->levels().size();
  m_A.resize(L);
  m_U.resize(L);
  m_D.resize(L);
  m_Dinv.resize(L);
  m_b.resize(L);
  m_x.resize(L);
  m_r.resize(L);
  for (size_t l = 0; l < L; ++l) {
    const Blocks& A = m_h->levels()[l].A;
    m_A[l].resize(A.col.size());
    m_U[l].resize(m_h->levels()[l].U.col.size());
    m_D[l].resize(static_cast<size_t>(A.rows()));
    m_Dinv[l].resize(static_cast<size_t>(A.rows()));
    m_b[l].resize(3 * A.rows());
    m_x[l].resize(3 * A.rows());
    m_r[l].resize(3 * A.rows());
  }
}

bool Multigrid::setup(const SparseMatrix<double>& J, bool coarse) {
  coarse = coarse || !m_coarse_ready;
  m_coarse_ready = false;
  const auto& levels = m_h->levels();
  const double* val = J.valuePtr();
  const std::vector<int>& off = m_h->fine_offsets();
  // Level 0's block e of J (all of them only when the coarse levels are made from it).
  auto fine = [&](int e) {
    Block B;
    for (int r = 0; r < 3; ++r)
      for (int c = 0; c < 3; ++c)
        B(r, c) =
            static_cast<Real>(val[off[3 * static_cast<size_t>(e) + static_cast<size_t>(r)] + c]);
    return B;
  };
  if (coarse)
    for_rows(levels[0], static_cast<int>(m_A[0].size()),
             [&](int e) { m_A[0][static_cast<size_t>(e)] = fine(e); });
  for (size_t l = 0; l < levels.size(); ++l) {
    const Level& level = levels[l];
    const Blocks& U = level.U;
    auto block = [&](int e) { return l == 0 ? fine(e) : m_A[l][static_cast<size_t>(e)]; };
    std::atomic<bool> definite{true};
    for_rows(level, U.rows(), [&](int k) {
      const Matrix3d D = block(level.d_src[static_cast<size_t>(k)]).cast<double>();
      // Positive definite by Sylvester's criterion (leading minors; no absolute threshold:
      // a light node's block at a short step is legitimately tiny), and a finite inverse.
      const double minor2 = D(0, 0) * D(1, 1) - D(0, 1) * D(1, 0);
      const Matrix3d inv = D.inverse();
      if (!(D(0, 0) > 0.0) || !(minor2 > 0.0) || !(D.determinant() > 0.0) || !inv.allFinite())
        definite = false;
      m_Dinv[l][static_cast<size_t>(k)] = inv.cast<Real>();
      m_D[l][static_cast<size_t>(k)] = D.cast<Real>();
      for (int e = U.start[static_cast<size_t>(k)]; e < U.start[static_cast<size_t>(k) + 1]; ++e)
        m_U[l][static_cast<size_t>(e)] = block(level.u_src[static_cast<size_t>(e)]);
    });
    if (!definite) return false;
    if (l + 1 == levels.size()) break;
    if (!coarse) {
      m_coarse_ready = true;
      return true;
    }
    m_T.resize(level.T.col.size());
    coarse_ranges(level, [&](int b0, int b1) {
      std::fill(m_T.begin() + level.T.start[static_cast<size_t>(b0)],
                m_T.begin() + level.T.start[static_cast<size_t>(b1)], Block::Zero());
      for (int q = level.t_plan[static_cast<size_t>(b0)]; q < level.t_plan[static_cast<size_t>(b1)];
           ++q) {
        const auto& p = level.to_t[static_cast<size_t>(q)];
        m_T[static_cast<size_t>(p.dst)].noalias() +=
            static_cast<Real>(p.w) * m_A[l][static_cast<size_t>(p.src)];
      }
    });
    std::vector<Block>& next = m_A[l + 1];
    coarse_ranges(level, [&](int b0, int b1) {
      const Blocks& N = levels[l + 1].A;
      std::fill(next.begin() + N.start[static_cast<size_t>(b0)],
                next.begin() + N.start[static_cast<size_t>(b1)], Block::Zero());
      for (int q = level.next_plan[static_cast<size_t>(b0)];
           q < level.next_plan[static_cast<size_t>(b1)]; ++q) {
        const auto& p = level.to_next[static_cast<size_t>(q)];
        next[static_cast<size_t>(p.dst)].noalias() +=
            static_cast<Real>(p.w) * m_T[static_cast<size_t>(p.src)];
      }
    });
  }
  // The coarsest level, dense.
  const Blocks& C = levels.back().A;
  Eigen::MatrixXd dense = Eigen::MatrixXd::Zero(3 * C.rows(), 3 * C.rows());
  for (int i = 0; i < C.rows(); ++i)
    for (int e = C.start[static_cast<size_t>(i)]; e < C.start[static_cast<size_t>(i) + 1]; ++e)
      dense.block<3, 3>(3 * i, 3 * C.col[static_cast<size_t>(e)]) =
          m_A.back()[static_cast<size_t>(e)].cast<double>();
  m_coarsest.compute(dense);
  m_coarse_ready = m_coarsest.info() == Eigen::Success;
  return m_coarse_ready;
}

// The smoother and the product read the symmetric A = L + D + U from U and D only: row i's
// lower blocks are the transposes of the blocks (j, i) of U, used by scattering from row j.
// With two parts (Level::order), each part scatters into its own rows and, for the separator's
// rows, into its own buffer: the parts run in parallel, and the result is that of the serial
// sweep in the same order.
namespace {

struct Sweeps {
  const Level& level;
  const std::vector<Block>& u;
  const std::vector<Block>& dinv;
  bool parallel() const { return threaded(level); }
  // f(begin, end) over the two parts, in parallel when the level is split.
  template <class F>
  void parts(F f) const {
    if (parallel())
      tbb::parallel_invoke([&] { f(0, level.part[0]); }, [&] { f(level.part[0], level.part[1]); });
    else
      f(0, level.part[1]);
  }
  // f(k) for every position, in parallel when the level is split.
  template <class F>
  void rows(F f) const {
    for_rows(level, level.U.rows(), f);
  }
  // s = b - L x in the scatter form (b = 0 when null); with `solve`, x is the forward
  // Gauss-Seidel sweep from x = 0 (x_k = D_k^-1 s_k as each s_k is complete) instead of an
  // input.
  void lower(const Vector* b, Vector& x, Vector& s, Vector* sep, bool solve) const {
    const Blocks& U = level.U;
    const int n = U.rows(), s0 = level.part[1];
    const Eigen::Index ns = 3 * static_cast<Eigen::Index>(n - s0);
    auto run = [&](int begin, int end, Vector& buf) {
      if (b)
        s.segment(3 * begin, 3 * (end - begin)) = b->segment(3 * begin, 3 * (end - begin));
      else
        s.segment(3 * begin, 3 * (end - begin)).setZero();
      buf.setZero(ns);
      for (int k = begin; k < end; ++k) {
        if (solve) x.segment<3>(3 * k) = dinv[static_cast<size_t>(k)] * s.segment<3>(3 * k);
        const Vec3 xk = x.segment<3>(3 * k);
        for (int e = U.start[static_cast<size_t>(k)]; e < U.start[static_cast<size_t>(k) + 1];
             ++e) {
          const int c = U.col[static_cast<size_t>(e)];
          if (c < s0)
            s.segment<3>(3 * c).noalias() -= u[static_cast<size_t>(e)].transpose() * xk;
          else
            buf.segment<3>(3 * (c - s0)).noalias() += u[static_cast<size_t>(e)].transpose() * xk;
        }
      }
    };
    parts([&](int begin, int end) { run(begin, end, sep[begin == 0 ? 0 : 1]); });
    if (s0 == n) return;
    if (b)
      s.tail(ns) = b->tail(ns) - sep[0];
    else
      s.tail(ns) = -sep[0];
    if (parallel()) s.tail(ns) -= sep[1];
    for (int k = s0; k < n; ++k) {
      if (solve) x.segment<3>(3 * k) = dinv[static_cast<size_t>(k)] * s.segment<3>(3 * k);
      const Vec3 xk = x.segment<3>(3 * k);
      for (int e = U.start[static_cast<size_t>(k)]; e < U.start[static_cast<size_t>(k) + 1]; ++e)
        s.segment<3>(3 * U.col[static_cast<size_t>(e)]).noalias() -=
            u[static_cast<size_t>(e)].transpose() * xk;
    }
  }
  // (U x)_k.
  Vec3 upper(const Vector& x, int k) const {
    const Blocks& U = level.U;
    Vec3 acc = Vec3::Zero();
    for (int e = U.start[static_cast<size_t>(k)]; e < U.start[static_cast<size_t>(k) + 1]; ++e)
      acc.noalias() += u[static_cast<size_t>(e)] * x.segment<3>(3 * U.col[static_cast<size_t>(e)]);
    return acc;
  }
  // Backward Gauss-Seidel from s = b - L x: the separator first, then the parts.
  void backward(const Vector& s, Vector& x) const {
    const int n = level.U.rows();
    auto run = [&](int begin, int end) {
      for (int k = end - 1; k >= begin; --k)
        x.segment<3>(3 * k) = dinv[static_cast<size_t>(k)] * (s.segment<3>(3 * k) - upper(x, k));
    };
    run(level.part[1], n);
    parts(run);
  }
};

}  // namespace

void Multigrid::cycle(size_t l) const {
  const auto& levels = m_h->levels();
  if (l + 1 == levels.size()) {
    m_x[l] = m_coarsest.solve(m_b[l].cast<double>()).cast<Real>();
    return;
  }
  const Level& level = levels[l];
  const Sweeps sw{level, m_U[l], m_Dinv[l]};
  Vector& x = m_x[l];
  Vector& s = m_r[l];
  const Vector& b = m_b[l];
  // Forward Gauss-Seidel from x = 0. Its residual b - A x is -U x (the sweep zeroed
  // b - (L + D) x), restricted by the columns of P.
  sw.lower(&b, x, s, m_sep, true);
  sw.rows([&](int k) { s.segment<3>(3 * k) = -sw.upper(x, k); });
  Vector& bc = m_b[l + 1];
  coarse_rows(level, [&](int c) {
    Vec3 acc = Vec3::Zero();
    for (int q = level.c_col_start[static_cast<size_t>(c)];
         q < level.c_col_start[static_cast<size_t>(c) + 1]; ++q)
      acc += static_cast<Real>(level.c_col_w[static_cast<size_t>(q)]) *
             s.segment<3>(3 * level.c_col_row[static_cast<size_t>(q)]);
    bc.segment<3>(3 * c) = acc;
  });
  cycle(l + 1);
  // Coarse correction, then s = b - L x and the backward sweep.
  const Vector& xc = m_x[l + 1];
  sw.rows([&](int k) {
    Vec3 xk = x.segment<3>(3 * k);
    for (int q = level.c_row_start[static_cast<size_t>(k)];
         q < level.c_row_start[static_cast<size_t>(k) + 1]; ++q)
      xk += static_cast<Real>(level.c_row_w[static_cast<size_t>(q)]) *
            xc.segment<3>(3 * level.c_row_col[static_cast<size_t>(q)]);
    x.segment<3>(3 * k) = xk;
  });
  sw.lower(&b, x, s, m_sep, false);
  sw.backward(s, x);
}

void Multigrid::multiply(const VectorXd& x, VectorXd& y) const {
  // y = (D + U) x + L x: L x as in the smoother's lower sweep, (D + U) x row by row.
  const Level& level = m_h->levels()[0];
  const Sweeps sw{level, m_U[0], m_Dinv[0]};
  const std::vector<Block>& d = m_D[0];
  const int n = level.U.rows();
  m_in.resize(x.size());
  for (int k = 0; k < n; ++k)
    m_in.segment<3>(3 * k) = x.segment<3>(3 * level.order[static_cast<size_t>(k)]);
  m_out.resize(x.size());
  sw.lower(nullptr, m_in, m_out, m_sep, false);  // m_out = -L x
  y.resize(x.size());
  sw.rows([&](int k) {
    y.segment<3>(3 * level.order[static_cast<size_t>(k)]) =
        d[static_cast<size_t>(k)] * m_in.segment<3>(3 * k) + sw.upper(m_in, k) -
        m_out.segment<3>(3 * k);
  });
}

void Multigrid::apply(const VectorXd& r, VectorXd& z) const {
  const std::vector<int>& order = m_h->levels()[0].order;
  const auto n = static_cast<Eigen::Index>(order.size());
  for (Eigen::Index k = 0; k < n; ++k)
    m_b[0].segment<3>(3 * k) = r.segment<3>(3 * order[static_cast<size_t>(k)]);
  cycle(0);
  z.resize(r.size());
  for (Eigen::Index k = 0; k < n; ++k)
    z.segment<3>(3 * order[static_cast<size_t>(k)]) = m_x[0].segment<3>(3 * k);
}

}  // namespace pbve::mass_spring::detail
