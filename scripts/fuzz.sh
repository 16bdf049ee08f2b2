#!/usr/bin/env bash
# fuzz.sh — build the libFuzzer targets and run each for a bounded time (docs/development.md,
# "Fuzzing"). CI runs it from scripts/setup.sh test; a longer campaign is the same script
# with more seconds.
#
#   scripts/fuzz.sh [SECONDS_PER_TARGET] [TARGET...]   default: 40 s each; every target
#       targets: scene gltf http sweep (tests/fuzz_<target>.c)
#
# Needs clang and the libFuzzer runtime (Debian: clang, libclang-rt-14-dev). Builds
# build-fuzz (ASan + UBSan + libFuzzer instrumentation), then runs each target on its
# committed seeds (tests/fuzz/corpus/<target>, read only) plus a working corpus in
# build-fuzz/corpus/<target>, where new inputs go (kept between runs, never in git).
# Exits non-zero when any target found a crash, a leak, undefined behaviour, a timeout or
# ran out of memory; the input that did it is written to build-fuzz/artifacts/ and its
# report is in build-fuzz/fuzz-<target>.log.
set -euo pipefail
cd "$(dirname "$0")/.."

seconds=${1:-40}
shift || true
targets=("$@")
[ ${#targets[@]} -gt 0 ] || targets=(scene gltf http sweep)
build=${NS_FUZZ_BUILD:-build-fuzz}

for t in "${targets[@]}"; do
  [ -f "tests/fuzz_$t.c" ] || { echo "fuzz: no target '$t' (tests/fuzz_$t.c)" >&2; exit 2; }
done
command -v clang >/dev/null || { echo "fuzz: needs clang (apt-get install clang libclang-rt-14-dev)" >&2; exit 2; }

# The fuzz build is its own tree: a sanitized, instrumented render library must not mix
# with build/'s objects. NS_TESTS=OFF: the tests are built and run elsewhere.
CC=clang CXX=clang++ cmake -S . -B "$build" -DNS_FUZZ=ON -DNS_TESTS=OFF -DNS_WERROR=ON \
  -DCMAKE_BUILD_TYPE=RelWithDebInfo >/dev/null
cmake --build "$build" -j "$(nproc)" --target "${targets[@]/#/fuzz_}" >/dev/null

mkdir -p "$build/artifacts"
# halt_on_error: UBSan's reports are errors, not warnings. detect_leaks: LeakSanitizer after
# inputs whose mallocs and frees do not balance, and at exit.
export ASAN_OPTIONS=${ASAN_OPTIONS:-detect_leaks=1:allocator_may_return_null=1}
export UBSAN_OPTIONS=${UBSAN_OPTIONS:-halt_on_error=1:print_stacktrace=1}
# One target per core at a time: libFuzzer runs an input at a time, so two targets on two
# cores take the time of one (the four at 40 s each: about 85 s instead of 164 on 2 cores).
jobs_max=${NS_FUZZ_JOBS:-$(nproc)}

# Runs target $1 and writes its summary line and status to $build/fuzz-$1.result; always
# returns 0 (the caller reads the result file).
run_target() {
  local t=$1 work="$build/corpus/$1" log="$build/fuzz-$1.log" dict=() status start last runs rate
  mkdir -p "$work"
  case $t in
    scene | sweep) dict=(-dict=tests/fuzz/scene.dict) ;;
    gltf | http) dict=(-dict="tests/fuzz/$t.dict") ;;
  esac
  start=$(date +%s)
  # -timeout: one input taking 10 s is a hang; -rss_limit_mb: a memory blow-up is a failure
  # too; -max_len: the seeds are at most 9 KiB, and the parsers' limits are not what is
  # being searched for here (each has its own test).
  if "$build/fuzz_$t" "$work" "tests/fuzz/corpus/$t" "${dict[@]}" \
      -max_total_time="$seconds" -timeout=10 -rss_limit_mb=2048 -max_len=16384 \
      -detect_leaks=1 -print_final_stats=1 -artifact_prefix="$build/artifacts/$t-" >"$log" 2>&1; then
    status=ok
  else
    status=FAILED
  fi
  # The figures of the run: the last status line (coverage, features, corpus) and the totals.
  last=$(grep -E '^#[0-9]+' "$log" | tail -1 || true)
  runs=$(sed -n 's/^stat::number_of_executed_units: *//p' "$log")
  rate=$(sed -n 's/^stat::average_exec_per_sec: *//p' "$log")
  printf '%s\nfuzz_%s: %s in %s s: %s executions (%s/s); %s\n' "$status" "$t" "$status" \
    "$(($(date +%s) - start))" "${runs:-?}" "${rate:-?}" "${last:-no status line}" >"$build/fuzz-$t.result"
}

for t in "${targets[@]}"; do
  rm -f "$build/fuzz-$t.result"
  while [ "$(jobs -rp | wc -l)" -ge "$jobs_max" ]; do wait -n || true; done
  run_target "$t" &
done
wait

failed=()
for t in "${targets[@]}"; do
  result="$build/fuzz-$t.result"
  status=$(head -1 "$result" 2>/dev/null || echo FAILED)
  tail -n +2 "$result" 2>/dev/null || echo "fuzz_$t: no result (the runner itself failed)"
  if [ "$status" != ok ]; then
    failed+=("$t")
    grep -E 'ERROR|SUMMARY|fuzz_[a-z]+:|Test unit written|==[0-9]+==' "$build/fuzz-$t.log" | head -20 >&2 || true
    echo "fuzz_$t: the whole report: $build/fuzz-$t.log" >&2
  fi
done
if [ ${#failed[@]} -gt 0 ]; then
  echo "fuzz: FAILED: ${failed[*]}" >&2
  exit 1
fi
