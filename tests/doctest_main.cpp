// doctest's main, plus one rule for perch2::cuda: when the tests are linked with it (an nvcc build) but this
// process sees no CUDA device, its test instances are not run. The run prints one "SKIPPED: perch2::cuda"
// line with the reason when it selected any of them, which ctest reports as a skip (tests/CMakeLists.txt).
#define DOCTEST_CONFIG_IMPLEMENT
#include <doctest/doctest.h>

#ifdef PERCH2_HAVE_CUDA
#include <cstdio>
#include <cstring>
#include <ostream>
#include <streambuf>
#include <string>
#include <vector>

#include "perch2/cuda/device.hpp"

namespace {

/// Test-case names of perch2::cuda instances contain this (doctest appends the template argument).
constexpr const char* kCudaInstance = "CudaSystem";

/// Counts the perch2::cuda instances among the test cases a --list-test-cases run selects.
struct CudaInstanceCounter : doctest::IReporter {
  static inline unsigned selected = 0;
  explicit CudaInstanceCounter(const doctest::ContextOptions&) {}
  void report_query(const doctest::QueryData& q) override {
    for (unsigned i = 0; i < q.num_data; ++i)
      if (std::strstr(q.data[i]->m_name, kCudaInstance)) ++selected;
  }
  void test_run_start() override {}
  void test_run_end(const doctest::TestRunStats&) override {}
  void test_case_start(const doctest::TestCaseData&) override {}
  void test_case_reenter(const doctest::TestCaseData&) override {}
  void test_case_end(const doctest::CurrentTestCaseStats&) override {}
  void test_case_exception(const doctest::TestCaseException&) override {}
  void subcase_start(const doctest::SubcaseSignature&) override {}
  void subcase_end() override {}
  void log_assert(const doctest::AssertData&) override {}
  void log_message(const doctest::MessageData&) override {}
  void test_case_skipped(const doctest::TestCaseData&) override {}
};
REGISTER_LISTENER("perch2_cuda_instances", 1, CudaInstanceCounter);

/// How many perch2::cuda instances the command line selects (a silent listing run with the same filters).
unsigned selected_cuda_instances(int argc, char** argv) {
  struct : std::streambuf {
    int overflow(int c) override { return c; }
  } discard;
  std::ostream nowhere(&discard);
  std::vector<const char*> args(argv, argv + argc);
  args.push_back("--dt-list-test-cases");  // a flag: setOption() cannot set it
  doctest::Context listing(int(args.size()), args.data());
  listing.setCout(&nowhere);
  CudaInstanceCounter::selected = 0;
  listing.run();
  return CudaInstanceCounter::selected;
}

}  // namespace
#endif

int main(int argc, char** argv) {
  doctest::Context context(argc, argv);
#ifdef PERCH2_HAVE_CUDA
  // Queries (--list-test-cases, --count, --help) list every instance: ctest registers them from that list.
  if (!context.shouldExit() && perch2::cuda::device_count() == 0) {
    context.addFilter("test-case-exclude", (std::string("*") + kCudaInstance + "*").c_str());
    if (const unsigned n = selected_cuda_instances(argc, argv))
      std::printf("SKIPPED: perch2::cuda: %u test case%s not run: %s\n", n, n == 1 ? "" : "s",
                  perch2::cuda::device_summary().c_str());
  }
#endif
  return context.run();
}
