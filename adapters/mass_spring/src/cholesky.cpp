#include "cholesky.hpp"

#include <dlfcn.h>

#include <cstring>
#include <mutex>
#include <stdexcept>
#include <string>
#include <vector>

#include <cholmod.h>

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

// ----- numeric factorization ---------------------------------------------------------------

struct SparseCholesky::Numeric {
  mutable cholmod_common common;
  cholmod_factor* L = nullptr;
  mutable cholmod_dense *X = nullptr, *Y = nullptr, *E = nullptr;  // solve workspace

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

}  // namespace pbve::mass_spring::detail
