// Benchmark helpers: medians, peak memory of a configuration measured in a child process, machine name,
// the render benchmark's procedural mesh and poses.
#pragma once

#include <signal.h>
#include <sys/prctl.h>
#include <sys/resource.h>
#include <sys/wait.h>
#include <unistd.h>

#include <Eigen/Geometry>
#include <algorithm>
#include <array>
#include <chrono>
#include <cmath>
#include <cstdio>
#include <fstream>
#include <functional>
#include <random>
#include <string>
#include <tuple>
#include <vector>

#include "perch2/core/mesh.hpp"
#include "perch2/render/render.hpp"

namespace perch2::bench {

inline double median(std::vector<double> v) {
  std::sort(v.begin(), v.end());
  return v.size() % 2 ? v[v.size() / 2] : 0.5 * (v[v.size() / 2 - 1] + v[v.size() / 2]);
}

/// Median wall time (seconds) of `runs` calls of f after one warm-up call.
inline double median_seconds(int runs, const std::function<void()>& f) {
  f();
  std::vector<double> t;
  for (int r = 0; r < runs; ++r) {
    const auto t0 = std::chrono::steady_clock::now();
    f();
    t.push_back(std::chrono::duration<double>(std::chrono::steady_clock::now() - t0).count());
  }
  return median(t);
}

/// printf-style formatting of one value into a string.
template <class T>
std::string format(const char* fmt, T value) {
  char buf[64];
  std::snprintf(buf, sizeof buf, fmt, value);
  return buf;
}

inline std::string cpu_model() {
  std::ifstream f("/proc/cpuinfo");
  for (std::string line; std::getline(f, line);)
    if (line.rfind("model name", 0) == 0) return line.substr(line.find(':') + 2);
  return "unknown CPU";
}

/// The 1-minute load average (other jobs sharing the cores), 0 if unknown.
inline double load_average() {
  double l = 0;
  std::ifstream("/proc/loadavg") >> l;
  return l;
}

/// A field of /proc/self/status in KiB (VmRSS: resident now, VmHWM: peak resident).
inline long status_kb(const char* field) {
  std::ifstream f("/proc/self/status");
  const std::string key = std::string(field) + ":";
  for (std::string line; std::getline(f, line);)
    if (line.rfind(key, 0) == 0) return std::stol(line.substr(key.size()));
  return 0;
}

/// CPU seconds (user + system, all threads) this process has used so far.
inline double cpu_seconds() {
  rusage u{};
  getrusage(RUSAGE_SELF, &u);
  return double(u.ru_utime.tv_sec + u.ru_stime.tv_sec) +
         1e-6 * double(u.ru_utime.tv_usec + u.ru_stime.tv_usec);
}

/// Runs f (returning std::array<double, N>) in a forked child; returns f's N results and the child's peak
/// resident memory (VmHWM, MiB), which includes what the parent held at the fork. Each configuration gets
/// its own process so one configuration's peak does not hide another's.
template <class F>
auto in_child(const F& f) {
  using Results = decltype(f());
  constexpr std::size_t N = std::tuple_size<Results>::value;
  std::array<double, N + 1> out{};
  int fd[2];
  if (pipe(fd) != 0) return out;
  const pid_t pid = fork();
  if (pid == 0) {
    close(fd[0]);
    const Results r = f();
    std::copy(r.begin(), r.end(), out.begin());
    out[N] = double(status_kb("VmHWM")) / 1024.0;
    (void)!write(fd[1], out.data(), sizeof(out));
    _exit(0);
  }
  close(fd[1]);
  (void)!read(fd[0], out.data(), sizeof(out));
  close(fd[0]);
  int status = 0;
  waitpid(pid, &status, 0);
  return out;
}

/// `n` busy processes spinning for this object's lifetime: the "shared CPU" condition of a robot, where
/// another process competes for the cores the estimator's threads expect (bench option --load N).
/// pause()/resume() stop and continue them, so quiet and loaded runs can alternate in one run.
class CompetingLoad {
 public:
  explicit CompetingLoad(int n) {
    const pid_t parent = getpid();
    for (int k = 0; k < n; ++k) {
      const pid_t pid = fork();
      if (pid == 0) {
        prctl(PR_SET_PDEATHSIG, SIGKILL);  // never outlive a benchmark that aborted
        if (getppid() != parent) _exit(0);
        for (volatile unsigned long spin = 0;; spin = spin + 1) {
        }
      }
      if (pid > 0) pids_.push_back(pid);
    }
  }
  ~CompetingLoad() {
    for (const pid_t pid : pids_) kill(pid, SIGKILL);
    for (const pid_t pid : pids_) waitpid(pid, nullptr, 0);
  }
  CompetingLoad(const CompetingLoad&) = delete;
  CompetingLoad& operator=(const CompetingLoad&) = delete;
  void pause() const { signal_all(SIGSTOP, 'T'); }
  void resume() const { signal_all(SIGCONT, 'R'); }

 private:
  /// Sends `sig` and waits (up to 0.1 s) until each process shows `state` in /proc: a run timed right after
  /// pause() must not share the CPU with a process that has not stopped yet.
  void signal_all(int sig, char state) const {
    for (const pid_t pid : pids_) {
      kill(pid, sig);
      for (int k = 0; k < 100 && process_state(pid) != state; ++k) usleep(1000);
    }
  }
  static char process_state(pid_t pid) {
    std::ifstream f("/proc/" + std::to_string(pid) + "/stat");
    std::string line;
    std::getline(f, line);
    const std::size_t at = line.rfind(')');  // "pid (comm) S ..."
    return at == std::string::npos || at + 2 >= line.size() ? '?' : line[at + 2];
  }
  std::vector<pid_t> pids_;
};

/// Wall times (seconds) of f on a quiet CPU and beside `load`'s busy processes, `runs` of each in
/// alternation (quiet, loaded, quiet, ...), so the host's speed drifting during the run hits both alike;
/// "kept" = quiet / loaded is then a ratio measured in one run. Leaves `load` running.
inline std::array<std::vector<double>, 2> seconds_quiet_loaded(int runs, const CompetingLoad& load,
                                                               const std::function<void()>& f) {
  std::array<std::vector<double>, 2> t;  // quiet, loaded
  for (int r = 0; r < runs; ++r)
    for (int loaded = 0; loaded < 2; ++loaded) {
      loaded ? load.resume() : load.pause();
      const auto t0 = std::chrono::steady_clock::now();
      f();
      t[std::size_t(loaded)].push_back(
          std::chrono::duration<double>(std::chrono::steady_clock::now() - t0).count());
    }
  load.resume();
  return t;
}

/// Median quiet and loaded wall times of seconds_quiet_loaded, after one warm-up call.
inline std::array<double, 2> median_seconds_quiet_loaded(int runs, const CompetingLoad& load,
                                                         const std::function<void()>& f) {
  f();
  const auto t = seconds_quiet_loaded(runs, load, f);
  return {median(t[0]), median(t[1])};
}

/// Tabletop-like poses: 0.5-1.0 m away, anywhere in the central part of the view, any rotation.
inline std::vector<Hypothesis> poses(int n, const Mesh& mesh) {
  std::mt19937 rng(42);
  std::uniform_real_distribution<float> u(-1.f, 1.f), z(0.5f, 1.0f);
  std::normal_distribution<float> g(0.f, 1.f);
  const Eigen::Vector3f centre = mesh.bounds().center();
  std::vector<Hypothesis> out;
  for (int k = 0; k < n; ++k) {
    Pose T = Pose::Identity();
    T.linear() = Eigen::Quaternionf{g(rng), g(rng), g(rng), g(rng)}.normalized().toRotationMatrix();
    const float depth = z(rng);
    T.translation() =
        Eigen::Vector3f{0.25f * depth * u(rng), 0.2f * depth * u(rng), depth} - T.linear() * centre;
    out.push_back({0, T});
  }
  return out;
}

}  // namespace perch2::bench
