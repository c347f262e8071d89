#!/usr/bin/env bash
# Builds the libFuzzer targets of test/fuzz (a standalone clang project: the reader sources with
# -fsanitize=fuzzer-no-link,address,undefined) and runs each for a bounded time.
#
# Usage: scripts/fuzz.sh [target ...]        targets: pcd csv bundle merge_config ros_cloud ros_keyframe
#                                            lsd_keyframe lsd_graph (default: all test/fuzz/fuzz_*.cpp)
#   FUZZ_SECONDS    time per target [s] (default 60)
#   FUZZ_BUILD_DIR  build directory (default build-fuzz/ at the top of the package)
#   JOBS            parallel compile jobs (default 2)
#   FUZZ_CXX        the clang++ to use (default clang++-14, else clang++)
#
# Each target starts from its seed corpus test/fuzz/corpus/<target>/ (read only) plus a working
# corpus FUZZ_BUILD_DIR/corpus/<target>/ that keeps what earlier runs found. A crash, a sanitizer
# report, a leak, an input slower than 10 s (a hang) or more than 2 GB of memory fails the run; the
# input is saved as FUZZ_BUILD_DIR/artifacts/<target>/crash-* (or leak-/timeout-/oom-), to be
# fixed in the core and added to the seed corpus as a regression input.
# Exit status: 0 all targets clean, 1 a finding or a build failure.
set -euo pipefail
export PATH=/usr/bin:/bin:$PATH

root=$(cd "$(dirname "$0")/.." && pwd)
seconds=${FUZZ_SECONDS:-60}
build=${FUZZ_BUILD_DIR:-$root/build-fuzz}
jobs=${JOBS:-2}
cxx=${FUZZ_CXX:-}
if [ -z "$cxx" ]; then
  if command -v clang++-14 >/dev/null 2>&1; then cxx=clang++-14; else cxx=clang++; fi
fi
if [ -z "${ASAN_SYMBOLIZER_PATH:-}" ] && [ -x /usr/bin/llvm-symbolizer-14 ]; then
  export ASAN_SYMBOLIZER_PATH=/usr/bin/llvm-symbolizer-14
fi

if ! command -v "$cxx" >/dev/null 2>&1; then
  echo "fuzz: $cxx not found (install it: scripts/install_deps.sh fuzz)" >&2
  exit 1
fi

if [ ! -f "$build/CMakeCache.txt" ]; then
  echo "fuzz: configuring $build"
  cmake -S "$root/test/fuzz" -B "$build" -DCMAKE_CXX_COMPILER="$cxx" >"$build.configure.log" 2>&1 ||
    { cat "$build.configure.log" >&2; exit 1; }
  rm -f "$build.configure.log"
fi
start=$(date +%s)
cmake --build "$build" -j "$jobs" >"$build/build.log" 2>&1 || { tail -50 "$build/build.log" >&2; exit 1; }
echo "fuzz: build up to date in $(( $(date +%s) - start )) s"

targets=("$@")
if [ ${#targets[@]} -eq 0 ]; then
  for f in "$root"/test/fuzz/fuzz_*.cpp; do
    t=$(basename "$f" .cpp)
    targets+=("${t#fuzz_}")
  done
fi

export ASAN_OPTIONS="${ASAN_OPTIONS:-halt_on_error=1:detect_leaks=1}"
export UBSAN_OPTIONS="${UBSAN_OPTIONS:-halt_on_error=1:print_stacktrace=1}"
summary="$build/fuzz_summary.txt"
: >"$summary"
failed=0
for t in "${targets[@]}"; do
  exe="$build/fuzz_$t"
  seeds="$root/test/fuzz/corpus/$t"
  if [ ! -x "$exe" ]; then echo "fuzz: no target $t ($exe)" >&2; failed=1; continue; fi
  mkdir -p "$build/corpus/$t" "$build/artifacts/$t" "$build/logs"
  args=(-max_total_time="$seconds" -timeout=10 -rss_limit_mb=2048 -print_final_stats=1
        -artifact_prefix="$build/artifacts/$t/")
  [ -f "$root/test/fuzz/$t.dict" ] && args+=(-dict="$root/test/fuzz/$t.dict")
  log="$build/logs/$t.log"
  set +e
  (cd "$build" && "$exe" "${args[@]}" "$build/corpus/$t" "$seeds") >"$log" 2>&1
  rc=$?
  set -e
  execs=$(awk '/stat::number_of_executed_units/ {print $2}' "$log" | tail -1)
  cov=$(grep -o 'cov: [0-9]*' "$log" | tail -1 | awk '{print $2}')
  corpus=$(ls "$build/corpus/$t" | wc -l)
  if [ $rc -eq 0 ]; then
    line="fuzz_$t: OK, ${execs:-?} executions in ${seconds} s, coverage ${cov:-?} edges, working corpus $corpus inputs"
  else
    failed=1
    line="fuzz_$t: FAILED (exit $rc) after ${execs:-?} executions; log $log; inputs in $build/artifacts/$t/"
    grep -E 'ERROR:|SUMMARY:|property violated|Test unit written' "$log" | head -8 >&2 || true
  fi
  echo "$line" | tee -a "$summary"
done
exit $failed
