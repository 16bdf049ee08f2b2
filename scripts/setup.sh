#!/usr/bin/env bash
# setup.sh — install what is missing, build, then run the service or the tests.
#
#   scripts/setup.sh run    install, build, render scenes/default.json to out/default.png,
#                           then serve the web page and API on http://127.0.0.1:8080
#   scripts/setup.sh test   install (test tools too), build with warnings as errors, run
#                           the GPU and browser tests (ctest), then the unit, HTTP and CLI
#                           tests on the sanitizer build, then each libFuzzer target for a
#                           bounded time (scripts/fuzz.sh)
#   scripts/setup.sh deps   only install what is missing
#   scripts/setup.sh build  install and build build/nscatter
#   scripts/setup.sh http-test-deps
#                           only install what the HTTP and CLI tests need (ctest -L 'http|cli'),
#                           Node.js and web/'s npm packages included: the Dockerfile's test stage
#   scripts/setup.sh bench-deps
#                           install the benchmarks' outside libraries (Embree 3, for
#                           bench/rays.c), then build build/bench/bench_rays: optional,
#                           never needed by the build, the tests or CI
#
# Works as root on a fresh Debian 12 (bookworm); as another user it uses sudo for apt.
set -euo pipefail
cd "$(dirname "$0")/.."

# Debian packages the build and the runtime need. Only missing ones are installed.
BUILD_PACKAGES=(
  build-essential cmake pkg-config
  mesa-vulkan-drivers libvulkan-dev glslang-tools
  libmicrohttpd-dev libjansson-dev zlib1g-dev
  libstb-dev libtinyexr-dev libtinygltf-dev nlohmann-json3-dev
  libopenblas-dev
  glmark2-data # the Stanford bunny of `nscatter bench` (read from /usr/share/glmark2/models)
)
# What only the tests need: validation layers, python3 for the HTTP tests (and the
# Prometheus client library, whose parser reads /metrics in tests/http_metrics.py; jsonschema,
# which checks answers against /openapi.json in tests/http_openapi.py), Chromium and Node.js
# for the browser test, nginx in front of three instances (tests/http_scaleout.py runs
# deploy/nginx.conf) and PyYAML, which reads the Kubernetes manifests of deploy/k8s/
# (tests/http_k8s.py).
# HTTP_TEST_PACKAGES are the ones the HTTP and CLI tests need (the Dockerfile's test stage
# installs these and Node.js, through `http-test-deps`); the GPU and browser tests add the rest.
HTTP_TEST_PACKAGES=(python3 python3-prometheus-client python3-jsonschema nginx-light python3-yaml)
TEST_PACKAGES=(vulkan-validationlayers chromium "${HTTP_TEST_PACKAGES[@]}")
# The fuzz step (scripts/fuzz.sh): clang and its libFuzzer runtime (libclang_rt.fuzzer,
# with the sanitizers' runtimes, is in libclang-rt-14-dev on Debian 12).
FUZZ_PACKAGES=(clang libclang-rt-14-dev)
# Test packages not every Debian release has, installed where the archive has them:
# python3-openapi-spec-validator (tests/http_openapi.py) is in Debian from trixie on; where it
# is missing that test relies on the npm validator alone (web/package.json,
# tests/openapi_validate.mjs), which it always runs.
OPTIONAL_TEST_PACKAGES=(python3-openapi-spec-validator)
# What only the benchmarks of bench/ need (`scripts/setup.sh bench-deps`): Embree 3, the CPU
# ray tracer bench_rays compares nscatter's traversal with (docs/bench.md, "Ray throughput
# against Embree"). Never in the lists above: the renderer stays Vulkan, and the build and
# the tests must not need it.
BENCH_PACKAGES=(libembree-dev)

as_root() { if [ "$(id -u)" -eq 0 ]; then "$@"; else sudo "$@"; fi; }

install_missing() {
  local missing=()
  for p in "$@"; do
    dpkg-query -W -f='${Status}' "$p" 2>/dev/null | grep -q "install ok installed" || missing+=("$p")
  done
  if [ ${#missing[@]} -gt 0 ]; then
    echo "setup: installing ${missing[*]}"
    as_root apt-get update -qq
    as_root env DEBIAN_FRONTEND=noninteractive apt-get install -y -qq --no-install-recommends "${missing[@]}"
  fi
}

# After install_missing, whose apt-get update (when anything was missing) makes the package
# lists current: the packages of the list that the archive has.
install_available() {
  local available=()
  for p in "$@"; do
    if apt-cache show "$p" >/dev/null 2>&1; then available+=("$p"); fi
  done
  if [ ${#available[@]} -gt 0 ]; then install_missing "${available[@]}"; fi
}

install_node() {
  # Any Node.js >= 18 will do (Debian 12 ships 18); keep one that is already there.
  if ! command -v node >/dev/null 2>&1; then install_missing nodejs; fi
  if ! command -v npm >/dev/null 2>&1; then install_missing npm; fi
  if [ -f web/package.json ]; then (cd web && npm ci --no-audit --no-fund --loglevel=error); fi
}

build() { # build DIR [cmake options...]
  local dir=$1; shift
  cmake -S . -B "$dir" -DCMAKE_BUILD_TYPE=RelWithDebInfo "$@" >/dev/null
  cmake --build "$dir" -j "$(nproc)"
}

mode=${1:-run}
case "$mode" in
  deps)
    install_missing "${BUILD_PACKAGES[@]}"
    ;;
  build)
    install_missing "${BUILD_PACKAGES[@]}"
    build build
    ;;
  bench-deps)
    install_missing "${BUILD_PACKAGES[@]}" "${BENCH_PACKAGES[@]}"
    build build
    echo "setup: built build/bench/bench_rays (docs/bench.md, \"Ray throughput against Embree\")"
    ;;
  run)
    install_missing "${BUILD_PACKAGES[@]}"
    build build
    mkdir -p out
    ./build/nscatter render scenes/default.json -o out/default.png --timings
    echo "setup: rendered out/default.png; serving http://127.0.0.1:8080/ (Ctrl-C stops)"
    exec ./build/nscatter serve --host 127.0.0.1 --port 8080
    ;;
  http-test-deps)
    install_missing "${HTTP_TEST_PACKAGES[@]}"
    install_available "${OPTIONAL_TEST_PACKAGES[@]}"
    install_node
    ;;
  test)
    install_missing "${BUILD_PACKAGES[@]}" "${TEST_PACKAGES[@]}" "${FUZZ_PACKAGES[@]}"
    install_available "${OPTIONAL_TEST_PACKAGES[@]}"
    install_node
    build build -DNS_WERROR=ON
    # One test per core at a time, four at most: every lavapipe render takes all the cores,
    # so dozens at once on a large machine would only contend (and stretch the tests' own
    # deadlines); a third slot on 2 cores was measured no faster (docs/development.md).
    test_jobs=$(nproc)
    [ "$test_jobs" -le 4 ] || test_jobs=4
    # The GPU and browser tests on the release build (the browser's server is the shipped
    # binary); the unit, HTTP and CLI tests once, on the sanitized build, which runs the same
    # code with ASan and UBSan checking it (lavapipe itself is not built with sanitizers).
    # Running those twice cost CI about two minutes (docs/development.md, *Each test
    # once*); the Dockerfile's test stage runs the HTTP and CLI tests on its release build.
    (cd build && ctest --output-on-failure --timeout 900 -j "$test_jobs" -LE 'unit|http|cli')
    build build-asan -DNS_WERROR=ON -DNS_SANITIZE=ON -DCMAKE_BUILD_TYPE=Debug -DNS_GPU_TESTS=OFF
    (cd build-asan && ASAN_OPTIONS=detect_leaks=1 ctest --output-on-failure --timeout 900 -j "$test_jobs" -L 'unit|http|cli')
    # The parsers that read untrusted bytes, fuzzed: 40 s per target, one per core at a time
    # (docs/development.md, "Fuzzing"); any crash, leak, UB report or timeout fails.
    scripts/fuzz.sh 40
    ;;
  *)
    echo "usage: scripts/setup.sh run|test|deps|build|bench-deps|http-test-deps" >&2
    exit 2
    ;;
esac
