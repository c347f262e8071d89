// Internal helper of the simulator: portable random draws from a 64-bit Mersenne twister. The
// standard distributions' algorithms are not fixed by the standard, so the same seed could give
// other data with another standard library; these draws are the same everywhere.
#pragma once

#include <algorithm>
#include <cmath>
#include <cstdint>
#include <random>

namespace pcr_pro {
namespace sim_detail {

/// Uniform in [0, 1), 53 random bits.
inline double uniform01(std::mt19937_64& rng) { return static_cast<double>(rng() >> 11) * (1.0 / 9007199254740992.0); }

/// Uniform in [lo, hi).
inline double uniform(std::mt19937_64& rng, double lo, double hi) { return lo + (hi - lo) * uniform01(rng); }

/// Integer uniform in [lo, hi] (modulo bias below 2^-40 for the small ranges used here).
inline int uniformInt(std::mt19937_64& rng, int lo, int hi) {
  return lo + static_cast<int>(rng() % static_cast<std::uint64_t>(hi - lo + 1));
}

/// Standard normal (Box-Muller, one draw of the pair).
inline double gaussian(std::mt19937_64& rng) {
  const double u1 = std::max(uniform01(rng), 1e-300);
  const double u2 = uniform01(rng);
  return std::sqrt(-2.0 * std::log(u1)) * std::cos(2.0 * M_PI * u2);
}

/// Two independent standard normals (both values of a Box-Muller draw: half the cost per value).
inline void gaussianPair(std::mt19937_64& rng, double* a, double* b) {
  const double u1 = std::max(uniform01(rng), 1e-300);
  const double u2 = uniform01(rng);
  const double r = std::sqrt(-2.0 * std::log(u1));
  *a = r * std::cos(2.0 * M_PI * u2);
  *b = r * std::sin(2.0 * M_PI * u2);
}

/// Log-uniform in [lo, hi], lo > 0.
inline double logUniform(std::mt19937_64& rng, double lo, double hi) {
  return lo * std::exp(uniform01(rng) * std::log(hi / lo));
}

/// A seed for a sub-stream: splitmix64 of (seed, stream), so that streams do not overlap in
/// practice and adding a stream does not change the others.
inline std::uint64_t subSeed(std::uint64_t seed, std::uint64_t stream) {
  std::uint64_t z = seed + 0x9E3779B97F4A7C15ULL * (stream + 1);
  z = (z ^ (z >> 30)) * 0xBF58476D1CE4E5B9ULL;
  z = (z ^ (z >> 27)) * 0x94D049BB133111EBULL;
  return z ^ (z >> 31);
}

}  // namespace sim_detail
}  // namespace pcr_pro
