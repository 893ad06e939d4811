#!/usr/bin/env bash
# perch2 entry point: installs missing Debian packages, configures, builds, runs.
#   ./run.sh demo [perch2 demo options]   build and run the built-in 3-DoF demo (writes demo_out/overlay.png)
#   ./run.sh test                         build and run every test (ctest: the C++ and the Python suites)
#   ./run.sh python                       set up .venv with the perch2 Python package (pip install -e .)
#   ./run.sh bench                        build and run the benchmarks (Release)
#   ./run.sh cuda                         compile and link the nvcc backend (perch2::cuda); needs nvcc
#   ./run.sh gpu                          nvcc build of everything; tests and benches include perch2::cuda
#                                         (its instances skip, with the reason, when no GPU is visible)
#   ./run.sh test-system-cccl             the tests, built against Debian's Thrust/CUB/libcu++ (not the toolkit's)
#   ./run.sh asan                         run the tests under AddressSanitizer + UndefinedBehaviorSanitizer
set -euo pipefail
cd "$(dirname "$0")"

DEPS=(cmake make g++ pkg-config libeigen3-dev libflann-dev liblz4-dev libopencv-dev libtinyobjloader-dev
      doctest-dev nlohmann-json3-dev ccache)
# Thrust/CUB/libcu++ for the CPU build of the Thrust backend: the CUDA toolkit ships them (CCCL); without a
# toolkit CMake takes Debian's copies.
SYSTEM_CCCL=(libthrust-dev libcub-dev libcu++-dev)
JOBS=$(nproc)
# The Python package's virtual environment and what it needs from PyPI (build: nanobind, scikit-build-core;
# run: numpy; tests: pytest). PyPI packages go only into it, never into the system Python.
VENV=${PERCH2_VENV:-.venv}
PY_REQUIREMENTS=(nanobind scikit-build-core numpy pytest)
# Ray, the optional dependency of perch2.distributed, for its tests (they skip, saying so, without it).
PY_TEST_REQUIREMENTS=(ray)
DEPS+=(python3-dev python3-venv)
# libgomp's default wait policy spins at every barrier; with other work on the cores (ctest -j, a robot's other
# processes) a descheduled thread then stalls each of the Thrust-OMP backend's many short parallel regions for
# a whole time slice (measured: 10x slower). Passive waiting gives the cores back (README, "Under load").
export OMP_WAIT_POLICY=${OMP_WAIT_POLICY:-passive}

have_toolkit() {
  command -v nvcc >/dev/null || [ -x /usr/local/cuda/bin/nvcc ] || [ -x "${CUDA_PATH:-/nonexistent}/bin/nvcc" ]
}
have_toolkit || DEPS+=("${SYSTEM_CCCL[@]}")

install_deps() {
  local missing=()
  for p in "${DEPS[@]}"; do
    dpkg-query -W -f='${Status}' "$p" 2>/dev/null | grep -q 'install ok installed' || missing+=("$p")
  done
  if ((${#missing[@]})); then
    echo "== installing Debian packages: ${missing[*]}"
    local sudo=""
    [ "$(id -u)" -eq 0 ] || sudo=sudo
    $sudo apt-get update -qq
    DEBIAN_FRONTEND=noninteractive $sudo apt-get install -y -qq --no-install-recommends "${missing[@]}" >/dev/null
  fi
}

# Optional benchmark peers (never needed to build or run the library): Embree and nanoflann from Debian,
# small_gicp's headers from its PyPI source package, unpacked under build/_peers. Prints small_gicp's include
# folder, or nothing when it cannot be had.
bench_peers() {
  local sudo=""
  [ "$(id -u)" -eq 0 ] || sudo=sudo
  dpkg-query -W -f='${Status}' libembree-dev 2>/dev/null | grep -q 'install ok installed' ||
    DEBIAN_FRONTEND=noninteractive $sudo apt-get install -y -qq --no-install-recommends libembree-dev \
      libnanoflann-dev >/dev/null 2>&1 || true
  local dir=build/_peers/small_gicp-1.0.1
  if [ ! -d "$dir/include" ]; then
    mkdir -p build/_peers
    (python3 -m pip download -q --no-deps --no-binary :all: small_gicp==1.0.1 -d build/_peers >/dev/null 2>&1 &&
      tar xzf build/_peers/small_gicp-1.0.1.tar.gz -C build/_peers) || true
  fi
  if [ -d "$dir/include" ]; then echo "$PWD/$dir/include"; fi
}

# Creates $VENV (once) with PY_REQUIREMENTS.
python_venv() {
  [ -x "$VENV/bin/python" ] || python3 -m venv "$VENV"
  "$VENV/bin/python" -c "import nanobind, scikit_build_core, numpy, pytest" 2>/dev/null || {
    echo "== installing into $VENV: ${PY_REQUIREMENTS[*]}"
    "$VENV/bin/python" -m pip install -q "${PY_REQUIREMENTS[@]}"
  }
}
# Adds PY_TEST_REQUIREMENTS to $VENV (once).
python_test_venv() {
  python_venv
  "$VENV/bin/python" -c "import ray" 2>/dev/null || {
    echo "== installing into $VENV: ${PY_TEST_REQUIREMENTS[*]}"
    "$VENV/bin/python" -m pip install -q "${PY_TEST_REQUIREMENTS[@]}"
  }
}
# The CMake options of a build with the Python package (the venv's Python and nanobind).
python_options() {
  echo "-DPERCH2_BUILD_PYTHON=ON -DPython_EXECUTABLE=$PWD/$VENV/bin/python"
}

use_nvcc() {
  command -v nvcc >/dev/null || export PATH=/usr/local/cuda/bin:$PATH
  command -v nvcc >/dev/null || { echo "this command needs nvcc (the CUDA toolkit)" >&2; exit 1; }
}

# A compiler cache shared by every build folder: CI's builds (build, build-system-cccl, build-gpu) compile
# most files with the same flags, and a rebuild after a change recompiles only what the change touched.
# Paths are hashed relative to the checkout, so clones in other folders share it too.
use_ccache() {
  command -v ccache >/dev/null || return 0
  export CMAKE_CXX_COMPILER_LAUNCHER=${CMAKE_CXX_COMPILER_LAUNCHER-ccache}
  export CMAKE_CUDA_COMPILER_LAUNCHER=${CMAKE_CUDA_COMPILER_LAUNCHER-ccache}
  export CCACHE_BASEDIR=${CCACHE_BASEDIR:-$PWD} CCACHE_NOHASHDIR=${CCACHE_NOHASHDIR-1}
}

build() {  # build DIR [cmake options...]
  local dir=$1
  shift
  use_ccache
  cmake -S . -B "$dir" -DCMAKE_BUILD_TYPE=Release "$@" | { grep '^-- perch2:' || true; }  # e.g. which CCCL
  cmake --build "$dir" -j"$JOBS"
}

cmd=${1:-}
[ $# -gt 0 ] && shift
case "$cmd" in
  demo)
    install_deps
    build build -DPERCH2_WITH_CUDA=OFF
    ./build/examples/perch2 demo --out demo_out "$@"
    ;;
  test)
    install_deps
    python_test_venv
    # shellcheck disable=SC2046
    build build -DPERCH2_WITH_CUDA=OFF $(python_options)
    ctest --test-dir build --output-on-failure -j"$JOBS" "$@"
    ;;
  python)
    install_deps
    python_venv
    echo "== pip install -e . into $VENV (builds the C++ libraries and the extension in build/py-*)"
    CMAKE_CXX_COMPILER_LAUNCHER=${CMAKE_CXX_COMPILER_LAUNCHER:-$(command -v ccache || true)} \
      "$VENV/bin/python" -m pip install -q --no-build-isolation -e .
    "$VENV/bin/python" -c "import perch2; print('perch2', perch2.__version__, 'backends', perch2.backends())"
    echo "== ready: source $VENV/bin/activate, then import perch2"
    ;;
  bench)
    install_deps
    build build -DPERCH2_WITH_CUDA=OFF -DPERCH2_SMALL_GICP_INCLUDE_DIR="$(bench_peers)"
    for b in build/bench/bench_*; do [ -x "$b" ] && "$b" "$@"; done
    # The Python call overhead, when the build has the Python package (./run.sh test configures it).
    if [ -x "$VENV/bin/python" ] && ls build/python/perch2/_perch2*.so >/dev/null 2>&1; then
      PYTHONPATH=build/python "$VENV/bin/python" bench/bench_python.py
      # perch2.distributed on a local Ray instance, when the venv has Ray (./run.sh test installs it).
      if "$VENV/bin/python" -c "import ray" 2>/dev/null; then
        PYTHONPATH=build/python "$VENV/bin/python" bench/bench_distributed.py
      fi
    fi
    ;;
  cuda)
    install_deps
    use_nvcc
    build build-cuda -DPERCH2_WITH_CUDA=ON -DPERCH2_BUILD_TESTS=OFF -DPERCH2_BUILD_BENCH=OFF \
      -DPERCH2_BUILD_EXAMPLES=OFF
    test -f build-cuda/backends/cuda/libperch2_cuda.so || { echo "perch2::cuda was not built" >&2; exit 1; }
    echo "== perch2::cuda compiled and linked: build-cuda/backends/cuda/libperch2_cuda.so (no GPU here to run it)"
    ;;
  gpu)
    install_deps
    use_nvcc
    build build-gpu -DPERCH2_WITH_CUDA=ON
    test -f build-gpu/backends/cuda/libperch2_cuda.so || { echo "perch2::cuda was not built" >&2; exit 1; }
    ctest --test-dir build-gpu --output-on-failure -j"$JOBS" "$@"
    if nvidia-smi -L 2>/dev/null | grep -q '^GPU'; then
      for b in build-gpu/bench/bench_*; do [ -x "$b" ] && "$b"; done
    else
      echo "== no GPU listed by nvidia-smi: benchmarks not run (the tests' perch2::cuda instances were skipped)"
    fi
    ;;
  test-system-cccl)
    DEPS+=("${SYSTEM_CCCL[@]}")
    install_deps
    build build-system-cccl -DPERCH2_WITH_CUDA=OFF -DPERCH2_FORCE_SYSTEM_CCCL=ON -DPERCH2_BUILD_BENCH=OFF \
      -DPERCH2_BUILD_EXAMPLES=OFF
    ctest --test-dir build-system-cccl --output-on-failure -j"$JOBS" "$@"
    ;;
  asan)
    install_deps
    use_ccache
    # -g1: line tables only, enough for the sanitizers' file:line reports (2-vCPU AMD EPYC VM, beside a
    # build: backends/cpu/src/knn.cpp compiles in 138 s instead of 169 s with -g, half the object size).
    cmake -S . -B build-asan -DCMAKE_BUILD_TYPE=RelWithDebInfo "-DCMAKE_CXX_FLAGS_RELWITHDEBINFO=-O2 -g1 -DNDEBUG" \
      -DPERCH2_SANITIZE=ON -DPERCH2_WITH_CUDA=OFF -DPERCH2_BUILD_BENCH=OFF -DPERCH2_BUILD_EXAMPLES=OFF >/dev/null
    cmake --build build-asan -j"$JOBS"
    # Not the search digest: it pins the poses bit for bit in the release builds (./run.sh test and
    # test-system-cccl); its code paths run under the sanitizers in test_runner and the search tests.
    UBSAN_OPTIONS=print_stacktrace=1 \
      ctest --test-dir build-asan --output-on-failure -j"$JOBS" -E "consumer|test_search_digest" "$@"
    ;;
  *)
    sed -n '2,11p' "$0"
    exit 2
    ;;
esac
