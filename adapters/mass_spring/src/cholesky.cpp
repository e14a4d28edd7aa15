#include "cholesky.hpp"

#include <dlfcn.h>

#include <algorithm>
#include <array>
#include <cstring>
#include <mutex>
#include <stdexcept>
#include <string>
#include <vector>

#include <cholmod.h>
#include <tbb/parallel_invoke.h>

namespace pbve::mass_spring::detail {

namespace {

// ----- threads of the libraries under CHOLMOD ----------------------------------------------

// A symbol of a library the process has already loaded (or null).
void* loaded_symbol(std::initializer_list<const char*> libraries, const char* name) {
  if (void* s = dlsym(RTLD_DEFAULT, name)) return s;
  for (const char* lib : libraries)
    if (void* h = dlopen(lib, RTLD_LAZY | RTLD_NOLOAD)) {
      void* s = dlsym(h, name);
      dlclose(h);
      if (s) return s;
    }
  return nullptr;
}

// OpenBLAS runs its own thread pool: its threads would compete with the callers' (clones
// stepping in parallel) and may change the rounding of a factorization with the number of
// threads. One thread, set once for the process on first use (the reference BLAS and
// single-threaded builds have no such function).
void serial_blas_once() {
  static std::once_flag once;
  std::call_once(once, [] {
    using SetThreads = void (*)(int);
    if (auto set = reinterpret_cast<SetThreads>(
            loaded_symbol({"libopenblas.so.0", "libblas.so.3"}, "openblas_set_num_threads")))
      set(1);
  });
}

// CHOLMOD's supernodal factorization has OpenMP loops (element-wise copies and clears) with a
// fixed team of 4 threads. With dynamic adjustment on and one thread requested in the calling
// thread, libgomp runs them in the calling thread; both settings are the calling thread's own
// and are restored on exit.
class SerialOpenMP {
 public:
  SerialOpenMP() {
    const Api& api = get();
    if (!api.ok) return;
    m_dynamic = api.get_dynamic();
    m_threads = api.get_max_threads();
    api.set_dynamic(1);
    api.set_num_threads(1);
    m_active = true;
  }
  ~SerialOpenMP() {
    if (!m_active) return;
    const Api& api = get();
    api.set_num_threads(m_threads);
    api.set_dynamic(m_dynamic);
  }
  SerialOpenMP(const SerialOpenMP&) = delete;
  SerialOpenMP& operator=(const SerialOpenMP&) = delete;

 private:
  struct Api {
    int (*get_dynamic)() = nullptr;
    void (*set_dynamic)(int) = nullptr;
    int (*get_max_threads)() = nullptr;
    void (*set_num_threads)(int) = nullptr;
    bool ok = false;
  };
  static const Api& get() {
    static const Api api = [] {
      Api a;
      auto sym = [](const char* name) { return loaded_symbol({"libgomp.so.1"}, name); };
      a.get_dynamic = reinterpret_cast<int (*)()>(sym("omp_get_dynamic"));
      a.set_dynamic = reinterpret_cast<void (*)(int)>(sym("omp_set_dynamic"));
      a.get_max_threads = reinterpret_cast<int (*)()>(sym("omp_get_max_threads"));
      a.set_num_threads = reinterpret_cast<void (*)(int)>(sym("omp_set_num_threads"));
      a.ok = a.get_dynamic && a.set_dynamic && a.get_max_threads && a.set_num_threads;
      return a;
    }();
    return api;
  }
  int m_dynamic = 0, m_threads = 1;
  bool m_active = false;
};

// A CHOLMOD view of the lower triangle of a symmetric Eigen matrix (no copy).
cholmod_sparse view(const Eigen::SparseMatrix<double>& A) {
  if (!A.isCompressed())
    throw std::logic_error("mass_spring: CHOLMOD needs a compressed sparse matrix");
  cholmod_sparse S;
  std::memset(&S, 0, sizeof S);
  S.nrow = static_cast<size_t>(A.rows());
  S.ncol = static_cast<size_t>(A.cols());
  S.nzmax = static_cast<size_t>(A.nonZeros());
  S.p = const_cast<int*>(A.outerIndexPtr());
  S.i = const_cast<int*>(A.innerIndexPtr());
  S.x = const_cast<double*>(A.valuePtr());
  S.stype = -1;  // symmetric, the lower triangle is used (the upper one is ignored)
  S.itype = CHOLMOD_INT;
  S.xtype = CHOLMOD_REAL;
  S.dtype = CHOLMOD_DOUBLE;
  S.sorted = 1;
  S.packed = 1;
  return S;
}

void start(cholmod_common& c) {
  serial_blas_once();
  cholmod_start(&c);
  c.print = 0;  // failures are reported by return values
  c.quick_return_if_not_posdef = 1;
}

// ----- triangular solves with a supernodal factor ------------------------------------------

// Supernode J of a supernodal L holds columns [super[J], super[J+1]) as a dense column-major
// block of nsrow = pi[J+1] - pi[J] rows at x + px[J]; s[pi[J]...] lists the rows, the first
// nscol being the columns themselves, the others columns of J's ancestors in the elimination
// tree. Supernodes are postordered (the analysis asks for it), so a subtree is a contiguous
// range of supernodes ending at its root.
struct Supernodes {
  int nsuper = 0;
  const int *super = nullptr, *pi = nullptr, *px = nullptr, *s = nullptr;
  const double* x = nullptr;

  // Whether L is a real supernodal LL^T with int indices (what the analysis asks for).
  static bool usable(const cholmod_factor* L) {
    return L && L->is_super && L->is_ll && L->itype == CHOLMOD_INT && L->xtype != CHOLMOD_COMPLEX &&
           L->xtype != CHOLMOD_ZOMPLEX && L->dtype == CHOLMOD_DOUBLE && L->super && L->pi &&
           L->px && L->s;
  }
  explicit Supernodes(const cholmod_factor* L)
      : nsuper(static_cast<int>(L->nsuper)),
        super(static_cast<const int*>(L->super)),
        pi(static_cast<const int*>(L->pi)),
        px(static_cast<const int*>(L->px)),
        s(static_cast<const int*>(L->s)),
        x(static_cast<const double*>(L->x)) {}
  int columns(int J) const { return super[J + 1] - super[J]; }
  int rows(int J) const { return pi[J + 1] - pi[J]; }
};

// How a solve splits the elimination tree: two lists of disjoint subtrees (ranges [first,
// end) of supernodes), solved in parallel, and the remaining top supernodes (the separators
// above them), solved serially. It depends on the structure only, not on the number of
// threads, so a solve gives the same bits whether the parts run in parallel or in turn.
struct SolvePlan {
  std::array<std::vector<std::pair<int, int>>, 2> parts;
  std::vector<int> top;  // ascending
  // Columns of the top supernodes: top_columns[k] is one, slot[c] its k (-1 for the others).
  std::vector<int> top_columns, slot;
  int max_below = 0;   // the most rows of a supernode below its diagonal block
  bool split = false;  // false: CHOLMOD solves
};

// Below this many factor entries a solve does not split: example 1's board at 3 022 vertices
// (0.73 M entries) solves as fast in one part, at 8 090 vertices (2.05 M) 1.5x faster in two
// (bench_mass_spring, BM_BoardLinearJvpVjp).
constexpr double split_entries = 1e6;

SolvePlan make_plan(const cholmod_factor* L) {
  SolvePlan plan;
  if (!Supernodes::usable(L)) return plan;
  const Supernodes sn(L);
  const int ns = sn.nsuper, n = static_cast<int>(L->n);
  std::vector<int> owner(static_cast<size_t>(n));
  for (int J = 0; J < ns; ++J)
    for (int c = sn.super[J]; c < sn.super[J + 1]; ++c) owner[static_cast<size_t>(c)] = J;
  std::vector<int> parent(static_cast<size_t>(ns), -1), roots;
  std::vector<std::vector<int>> children(static_cast<size_t>(ns));
  // Per subtree: its work (factor entries), first supernode and number of supernodes.
  std::vector<double> work(static_cast<size_t>(ns));
  std::vector<int> first(static_cast<size_t>(ns)), count(static_cast<size_t>(ns), 1);
  double total = 0.0;
  for (int J = 0; J < ns; ++J) {
    const auto j = static_cast<size_t>(J);
    const int below = sn.rows(J) - sn.columns(J);
    plan.max_below = std::max(plan.max_below, below);
    work[j] = static_cast<double>(sn.rows(J)) * sn.columns(J);
    total += work[j];
    first[j] = J;
    if (below > 0) {
      parent[j] = owner[static_cast<size_t>(sn.s[sn.pi[J] + sn.columns(J)])];
      children[static_cast<size_t>(parent[j])].push_back(J);
    } else {
      roots.push_back(J);
    }
  }
  for (int J = 0; J < ns; ++J) {
    const auto j = static_cast<size_t>(J);
    const int P = parent[j];
    if (P < 0) continue;
    const auto p = static_cast<size_t>(P);
    work[p] += work[j];
    first[p] = std::min(first[p], first[j]);
    count[p] += count[j];
  }
  auto unsplit = [] { return SolvePlan{}; };  // (the parts may be partly filled)
  if (total < split_entries) return unsplit();
  // Move the largest subtree's root to the top until the subtrees below fill two parts within
  // 10% of each other (largest first, each into the lighter part), or give up when the top
  // would hold more than a quarter of the work.
  std::vector<int> candidates = roots;
  std::vector<int> top;
  double top_work = 0.0;
  auto subtree_work = [&](int J) { return work[static_cast<size_t>(J)]; };
  for (;;) {
    std::sort(candidates.begin(), candidates.end(), [&](int a, int b) {
      return subtree_work(a) != subtree_work(b) ? subtree_work(a) > subtree_work(b) : a < b;
    });
    std::array<double, 2> load{0.0, 0.0};
    std::array<std::vector<int>, 2> bins;
    for (int c : candidates) {
      const int b = load[0] <= load[1] ? 0 : 1;
      load[static_cast<size_t>(b)] += subtree_work(c);
      bins[static_cast<size_t>(b)].push_back(c);
    }
    const double below = load[0] + load[1];
    if (!bins[1].empty() && std::max(load[0], load[1]) <= 0.55 * below) {
      for (size_t b = 0; b < 2; ++b) {
        for (int c : bins[b]) {
          // A subtree is the range [first, root] only if the supernodes are postordered.
          const auto k = static_cast<size_t>(c);
          if (count[k] != c + 1 - first[k]) return unsplit();
          plan.parts[b].emplace_back(first[k], c + 1);
        }
        std::sort(plan.parts[b].begin(), plan.parts[b].end());
      }
      break;
    }
    const int largest = candidates.front();
    const double own = static_cast<double>(sn.rows(largest)) * sn.columns(largest);
    if (children[static_cast<size_t>(largest)].empty() || top_work + own > 0.25 * total)
      return unsplit();
    top_work += own;
    top.push_back(largest);
    candidates.erase(candidates.begin());
    for (int c : children[static_cast<size_t>(largest)]) candidates.push_back(c);
  }
  std::sort(top.begin(), top.end());
  plan.top = std::move(top);
  plan.slot.assign(static_cast<size_t>(n), -1);
  for (int J : plan.top)
    for (int c = sn.super[J]; c < sn.super[J + 1]; ++c) {
      plan.slot[static_cast<size_t>(c)] = static_cast<int>(plan.top_columns.size());
      plan.top_columns.push_back(c);
    }
  plan.split = true;
  return plan;
}

using ColumnBlock = Eigen::Map<const Eigen::MatrixXd>;

// Forward substitution L y = b in place over supernodes [J0, J1) (ascending). Updates of rows
// that have a slot go to `held` instead of y (null: every update goes to y).
void forward(const Supernodes& sn, int J0, int J1, double* y, const int* slot, double* held,
             double* tmp) {
  for (int J = J0; J < J1; ++J) {
    const int nscol = sn.columns(J), nsrow = sn.rows(J), below = nsrow - nscol;
    const ColumnBlock Lj(sn.x + sn.px[J], nsrow, nscol);
    Eigen::Map<Eigen::VectorXd> z(y + sn.super[J], nscol);
    Lj.topRows(nscol).triangularView<Eigen::Lower>().solveInPlace(z);
    if (below == 0) continue;
    Eigen::Map<Eigen::VectorXd> t(tmp, below);
    t.noalias() = Lj.bottomRows(below) * z;
    const int* rows = sn.s + sn.pi[J] + nscol;
    if (!held) {
      for (int i = 0; i < below; ++i) y[rows[i]] -= t[i];
    } else {
      for (int i = 0; i < below; ++i) {
        const int k = slot[rows[i]];
        (k < 0 ? y[rows[i]] : held[k]) -= t[i];
      }
    }
  }
}

// Back substitution L^T x = y in place over supernodes [J0, J1) (descending); reads x at rows
// of later supernodes, writes only its own columns.
void backward(const Supernodes& sn, int J0, int J1, double* y, double* tmp) {
  for (int J = J1 - 1; J >= J0; --J) {
    const int nscol = sn.columns(J), nsrow = sn.rows(J), below = nsrow - nscol;
    const ColumnBlock Lj(sn.x + sn.px[J], nsrow, nscol);
    Eigen::Map<Eigen::VectorXd> w(y + sn.super[J], nscol);
    if (below > 0) {
      const int* rows = sn.s + sn.pi[J] + nscol;
      Eigen::Map<Eigen::VectorXd> t(tmp, below);
      for (int i = 0; i < below; ++i) t[i] = y[rows[i]];
      w.noalias() -= Lj.bottomRows(below).transpose() * t;
    }
    Lj.topRows(nscol).triangularView<Eigen::Lower>().transpose().solveInPlace(w);
  }
}

}  // namespace

// ----- analysis ----------------------------------------------------------------------------

struct CholeskyAnalysis::Impl {
  cholmod_common common;
  cholmod_factor* supernodal = nullptr;  // symbolic
  // The simplicial symbolic factor with the same ordering (for LDL^T), made on first use.
  mutable std::once_flag simplicial_once;
  mutable cholmod_factor* simplicial = nullptr;
  mutable cholmod_common simplicial_common;
  // The analyzed pattern (for the simplicial analysis).
  Eigen::SparseMatrix<double> pattern;
  // How solves with the supernodal factor split.
  SolvePlan plan;

  const cholmod_factor* simplicial_symbolic() const {
    std::call_once(simplicial_once, [this] {
      SerialOpenMP serial;
      start(simplicial_common);
      simplicial_common.supernodal = CHOLMOD_SIMPLICIAL;
      simplicial_common.nmethods = 1;
      simplicial_common.method[0].ordering = CHOLMOD_GIVEN;
      simplicial_common.postorder = 0;
      cholmod_sparse S = view(pattern);
      simplicial = cholmod_analyze_p(&S, static_cast<int*>(supernodal->Perm), nullptr, 0,
                                     &simplicial_common);
      if (!simplicial)
        throw std::runtime_error("mass_spring: CHOLMOD simplicial analysis failed (status " +
                                 std::to_string(simplicial_common.status) + ")");
    });
    return simplicial;
  }

  ~Impl() {
    if (simplicial) {
      cholmod_free_factor(&simplicial, &simplicial_common);
      cholmod_finish(&simplicial_common);
    }
    cholmod_free_factor(&supernodal, &common);
    cholmod_finish(&common);
  }
};

CholeskyAnalysis::CholeskyAnalysis(const Eigen::SparseMatrix<double>& pattern)
    : m_impl(std::make_unique<Impl>()) {
  Impl& m = *m_impl;
  m.pattern = pattern;
  m.pattern.makeCompressed();
  start(m.common);
  m.common.supernodal = CHOLMOD_SUPERNODAL;
  // The better of AMD and METIS (nested dissection wins on the larger meshes); both are
  // deterministic (METIS uses a fixed seed).
  m.common.nmethods = 2;
  m.common.method[0].ordering = CHOLMOD_AMD;
  m.common.method[1].ordering = CHOLMOD_METIS;
  m.common.postorder = 1;
  // Coarser supernodes than CHOLMOD's defaults (columns {4, 16, 48}, fill {0.8, 0.1, 0.05}):
  // each supernode costs a few library calls (and an OpenMP region) whatever its size, which
  // dominates on the small systems of a frame-rate simulation; more explicit zeros in
  // fewer, larger dense blocks are cheaper there (measured in bench_mass_spring, BM_Board*).
  m.common.nrelax[0] = 16;
  m.common.nrelax[1] = 64;
  m.common.nrelax[2] = 192;
  m.common.zrelax[0] = 0.8;
  m.common.zrelax[1] = 0.4;
  m.common.zrelax[2] = 0.2;
  SerialOpenMP serial;
  cholmod_sparse S = view(m.pattern);
  m.supernodal = cholmod_analyze(&S, &m.common);
  if (!m.supernodal)
    throw std::runtime_error("mass_spring: CHOLMOD analysis failed (status " +
                             std::to_string(m.common.status) + ")");
  m.plan = make_plan(m.supernodal);
}

CholeskyAnalysis::~CholeskyAnalysis() = default;

Eigen::Index CholeskyAnalysis::size() const {
  return m_impl->pattern.rows();
}

double CholeskyAnalysis::factor_nonzeros() const {
  return m_impl->common.lnz;
}

double CholeskyAnalysis::factor_flops() const {
  return m_impl->common.fl;
}

bool CholeskyAnalysis::splits_solves() const {
  return m_impl->plan.split;
}

// ----- numeric factorization ---------------------------------------------------------------

struct SparseCholesky::Numeric {
  mutable cholmod_common common;
  cholmod_factor* L = nullptr;
  mutable cholmod_dense *X = nullptr, *Y = nullptr, *E = nullptr;  // solve workspace
  // Workspace of the supernodal solves: the permuted vector, one buffer per part for its
  // updates of top columns, one for a supernode's rows below its diagonal block per part.
  mutable Eigen::VectorXd y;
  mutable std::array<Eigen::VectorXd, 2> held, tmp;

  Numeric() { start(common); }
  ~Numeric() {
    cholmod_free_dense(&X, &common);
    cholmod_free_dense(&Y, &common);
    cholmod_free_dense(&E, &common);
    cholmod_free_factor(&L, &common);
    cholmod_finish(&common);
  }
  Numeric(const Numeric&) = delete;
  Numeric& operator=(const Numeric&) = delete;
};

SparseCholesky::SparseCholesky() = default;

SparseCholesky::SparseCholesky(std::shared_ptr<const CholeskyAnalysis> analysis, Kind kind)
    : m_analysis(std::move(analysis)), m_kind(kind) {}

SparseCholesky::SparseCholesky(const SparseCholesky& other)
    : m_analysis(other.m_analysis), m_kind(other.m_kind) {}

SparseCholesky& SparseCholesky::operator=(const SparseCholesky& other) {
  if (this != &other) {
    m_analysis = other.m_analysis;
    m_kind = other.m_kind;
    m_numeric.reset();
    m_valid = false;
  }
  return *this;
}

SparseCholesky::~SparseCholesky() = default;

bool SparseCholesky::factorize(const Eigen::SparseMatrix<double>& A) {
  if (!m_analysis) throw std::logic_error("mass_spring: factorization without an analysis");
  if (A.rows() != m_analysis->size() || A.cols() != m_analysis->size())
    throw std::logic_error("mass_spring: matrix size differs from the analyzed pattern");
  SerialOpenMP serial;
  if (!m_numeric) {
    m_numeric = std::make_unique<Numeric>();
    const CholeskyAnalysis::Impl& a = m_analysis->impl();
    cholmod_factor* symbolic =
        m_kind == Kind::llt ? a.supernodal : const_cast<cholmod_factor*>(a.simplicial_symbolic());
    m_numeric->L = cholmod_copy_factor(symbolic, &m_numeric->common);
    if (!m_numeric->L)
      throw std::runtime_error("mass_spring: CHOLMOD could not copy the symbolic factor");
  }
  Numeric& n = *m_numeric;
  cholmod_sparse S = view(A);
  const int ok = cholmod_factorize(&S, n.L, &n.common);
  m_valid = ok && n.common.status == CHOLMOD_OK && n.L->minor == n.L->n;
  return m_valid;
}

void SparseCholesky::solve(const Eigen::VectorXd& b, Eigen::VectorXd& x) const {
  if (!m_valid) throw std::logic_error("mass_spring: solve with an invalid factorization");
  Numeric& n = *m_numeric;
  if (m_kind == Kind::llt && m_analysis->splits_solves() && Supernodes::usable(n.L) &&
      b.size() == static_cast<Eigen::Index>(n.L->n)) {
    split_solve(b, x);
    return;
  }
  cholmod_dense B;
  std::memset(&B, 0, sizeof B);
  B.nrow = static_cast<size_t>(b.size());
  B.ncol = 1;
  B.nzmax = B.nrow;
  B.d = B.nrow;
  B.x = const_cast<double*>(b.data());
  B.xtype = CHOLMOD_REAL;
  B.dtype = CHOLMOD_DOUBLE;
  SerialOpenMP serial;
  if (!cholmod_solve2(CHOLMOD_A, n.L, &B, nullptr, &n.X, nullptr, &n.Y, &n.E, &n.common))
    throw std::runtime_error("mass_spring: CHOLMOD solve failed (status " +
                             std::to_string(n.common.status) + ")");
  x = Eigen::Map<const Eigen::VectorXd>(static_cast<const double*>(n.X->x), b.size());
}

// x = A^-1 b with P A P^T = L L^T (P = L->Perm): y = P b, L z = y, L^T w = z, x = P^T w, the
// triangular solves split as the analysis planned.
void SparseCholesky::split_solve(const Eigen::VectorXd& b, Eigen::VectorXd& x) const {
  Numeric& n = *m_numeric;
  const SolvePlan& plan = m_analysis->impl().plan;
  const Supernodes sn(n.L);
  const Eigen::Index size = b.size();
  const int* perm = static_cast<const int*>(n.L->Perm);
  Eigen::VectorXd& y = n.y;
  y.resize(size);
  for (Eigen::Index k = 0; k < size; ++k) y[k] = perm ? b[perm[k]] : b[k];
  for (size_t p = 0; p < 2; ++p) n.tmp[p].resize(std::max(plan.max_below, 1));
  double* yd = y.data();
  const auto top = static_cast<Eigen::Index>(plan.top_columns.size());
  // L z = y: the parts, each holding its updates of top columns, then those updates in part
  // order, then the top.
  auto forward_part = [&](size_t p) {
    n.held[p].setZero(top);
    for (const auto& [J0, J1] : plan.parts[p])
      forward(sn, J0, J1, yd, plan.slot.data(), n.held[p].data(), n.tmp[p].data());
  };
  tbb::parallel_invoke([&] { forward_part(0); }, [&] { forward_part(1); });
  for (Eigen::Index k = 0; k < top; ++k)
    yd[plan.top_columns[static_cast<size_t>(k)]] += n.held[0][k] + n.held[1][k];
  for (int J : plan.top) forward(sn, J, J + 1, yd, nullptr, nullptr, n.tmp[0].data());
  // L^T w = z: the top, then the parts (each reads the top and its own columns).
  for (auto J = plan.top.rbegin(); J != plan.top.rend(); ++J)
    backward(sn, *J, *J + 1, yd, n.tmp[0].data());
  auto backward_part = [&](size_t p) {
    for (const auto& [J0, J1] : plan.parts[p]) backward(sn, J0, J1, yd, n.tmp[p].data());
  };
  tbb::parallel_invoke([&] { backward_part(0); }, [&] { backward_part(1); });
  x.resize(size);
  for (Eigen::Index k = 0; k < size; ++k) (perm ? x[perm[k]] : x[k]) = y[k];
}

}  // namespace pbve::mass_spring::detail
