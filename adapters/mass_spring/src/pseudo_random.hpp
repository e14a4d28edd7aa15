#pragma once
// A fixed pseudo-random vector for the solvers' probes (start vectors of power iterations,
// right sides that break symmetries): reproducible on every platform and standard library.

#include <cstdint>

#include <Eigen/Core>

namespace pbve::mass_spring::detail {

/// n entries in [-1, 1) from the splitmix64 sequence of a fixed seed: the same for every call
/// with that size.
inline Eigen::VectorXd pseudo_random_vector(Eigen::Index n) {
  std::uint64_t state = 0x9e3779b97f4a7c15ULL;
  Eigen::VectorXd out(n);
  for (Eigen::Index i = 0; i < n; ++i) {
    std::uint64_t z = (state += 0x9e3779b97f4a7c15ULL);
    z = (z ^ (z >> 30)) * 0xbf58476d1ce4e5b9ULL;
    z = (z ^ (z >> 27)) * 0x94d049bb133111ebULL;
    z ^= z >> 31;
    out[i] = static_cast<double>(z >> 11) * 0x1.0p-52 - 1.0;
  }
  return out;
}

}  // namespace pbve::mass_spring::detail
