// A small, portable random source for the scene generator: the same seed gives the same dataset with any
// compiler and standard library (std::*_distribution are implementation-defined, so they are not used).
#pragma once

#include <cmath>
#include <cstdint>

namespace perch2::synth {

class Rng {
 public:
  explicit Rng(std::uint64_t seed) : state_(seed) {}

  /// A generator for a sub-stream (e.g. scene 7 of seed 3), independent of how many draws came before.
  static Rng stream(std::uint64_t seed, std::uint64_t a, std::uint64_t b = 0) {
    Rng r(seed ^ mix(a + 0x632be59bd9b4e019ull) ^ mix(mix(b) + 0x9e3779b97f4a7c15ull));
    r.next();
    return r;
  }

  /// splitmix64 (Steele, Lea, Flood 2014).
  std::uint64_t next() {
    state_ += 0x9e3779b97f4a7c15ull;
    return mix(state_);
  }
  /// Uniform in [0, 1).
  double uniform() { return double(next() >> 11) * (1.0 / 9007199254740992.0); }
  float uniform(float lo, float hi) { return lo + float(uniform()) * (hi - lo); }
  /// Uniform integer in [lo, hi]; lo when hi <= lo.
  int integer(int lo, int hi) { return hi <= lo ? lo : lo + int(next() % std::uint64_t(hi - lo + 1)); }
  bool chance(float p) { return uniform() < p; }
  /// Standard normal (Box-Muller; one value per call keeps the stream simple).
  float normal() {
    const double u1 = 1.0 - uniform(), u2 = uniform();
    return float(std::sqrt(-2.0 * std::log(u1)) * std::cos(6.283185307179586 * u2));
  }

 private:
  static std::uint64_t mix(std::uint64_t z) {
    z = (z ^ (z >> 30)) * 0xbf58476d1ce4e5b9ull;
    z = (z ^ (z >> 27)) * 0x94d049bb133111ebull;
    return z ^ (z >> 31);
  }
  std::uint64_t state_;
};

}  // namespace perch2::synth
