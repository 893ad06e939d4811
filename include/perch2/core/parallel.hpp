// OpenMP scope helpers for the host code of the searches and the tracker.
#pragma once

#include <cctype>
#include <cstddef>
#include <cstdlib>
#include <string>

#ifdef _OPENMP
#include <omp.h>
#endif

namespace perch2 {

/// Whether OpenMP's idle threads sleep between parallel regions: OMP_WAIT_POLICY=passive (run.sh's
/// setting) without a GOMP_SPINCOUNT. Each region then wakes them through the kernel (about 10-50 us on
/// a 2-vCPU VM); spinning threads (libgomp's default for the first 3 ms of a wait) start at once. Read once,
/// as libgomp reads them once at start-up.
inline bool omp_waits_passively() {
  static const bool passive = [] {
    const char* policy = std::getenv("OMP_WAIT_POLICY");
    const char* spin = std::getenv("GOMP_SPINCOUNT");
    if (!policy || (spin && *spin && std::string(spin) != "0")) return false;
    std::string p;
    for (const char* c = policy; *c; ++c)
      if (!std::isspace(static_cast<unsigned char>(*c)))
        p += char(std::tolower(static_cast<unsigned char>(*c)));
    return p == "passive";
  }();
  return passive;
}

/// Runs the OpenMP parallel regions this thread starts within the scope on this thread alone, if `small`
/// and OpenMP waits passively (omp_waits_passively). For stages of many short launches over little data,
/// such as building the indexes of a few thousand observed points: under passive waiting each region's
/// wake-up costs more than its work, while spinning threads split it at no cost. It sets this thread's
/// thread count only (an OpenMP ICV per thread): a search running on another thread keeps its threads.
class SerialScope {
 public:
  explicit SerialScope(bool small) {
#ifdef _OPENMP
    if (small && omp_waits_passively() && omp_get_max_threads() > 1)
      saved_ = omp_get_max_threads(), omp_set_num_threads(1);
#else
    (void)small;
#endif
  }
  ~SerialScope() {
#ifdef _OPENMP
    if (saved_ > 0) omp_set_num_threads(saved_);
#endif
  }
  SerialScope(const SerialScope&) = delete;
  SerialScope& operator=(const SerialScope&) = delete;

 private:
  int saved_ = 0;
};

/// Observed points up to which an index is built on one thread under passive waiting (build_index).
/// 2-vCPU AMD EPYC VM, OMP_WAIT_POLICY=passive: the real cat frames' indexes (about 1,000 points) 6.9 ->
/// 2.7 ms per frame, bench_sixdof --masks gt (5 instances) 14 -> 10 ms per scene, bench_track's update
/// median 24.8 -> 21.3 ms (four runs each).
inline constexpr std::size_t kSerialIndexPoints = 20000;

/// make() (the construction of a backend's Registration or Cost over `points` observed points), on this
/// thread alone when they are few and OpenMP waits passively (SerialScope).
template <class Make>
auto build_index(std::size_t points, Make&& make) {
  const SerialScope serial(points <= kSerialIndexPoints);
  return make();
}

}  // namespace perch2
