#!/usr/bin/env bash
# make test-sanitize: builds the core, the offline tools and every unit test with
# AddressSanitizer + UndefinedBehaviorSanitizer (g++, -DPCR_PRO_SANITIZE=ON) in build-asan/ and
# runs each unit-test executable. Any sanitizer report is fatal (halt_on_error, and
# -fno-sanitize-recover at compile time), so a finding fails its test binary.
#
# Usage: scripts/sanitize.sh [gtest filter]
#   SANITIZE_BUILD_DIR  build directory (default build-asan/ at the top of the package)
#   JOBS                parallel compile jobs (default 2)
# Exit status: 0 every test binary passed clean, 1 otherwise. Summary in BUILD/sanitize_summary.txt.
set -euo pipefail
export PATH=/usr/bin:/bin:$PATH

root=$(cd "$(dirname "$0")/.." && pwd)
build=${SANITIZE_BUILD_DIR:-$root/build-asan}
jobs=${JOBS:-2}
filter=${1:-*}

if [ ! -f "$build/CMakeCache.txt" ]; then
  echo "sanitize: configuring $build"
  mkdir -p "$build"
  cmake -S "$root" -B "$build" -DCMAKE_BUILD_TYPE=Release -DPCR_PRO_SANITIZE=ON -DPCR_PRO_BUILD_BENCH=OFF \
    -DPCR_PRO_FUZZ_IN_CTEST=OFF -DCATKIN_DEVEL_PREFIX="$build/devel" >"$build/configure.log" 2>&1 ||
    { tail -30 "$build/configure.log" >&2; exit 1; }
fi
start=$(date +%s)
cmake --build "$build" -j "$jobs" --target pcr_pro_unit_tests >"$build/build.log" 2>&1 ||
  { grep -E 'error|Error' "$build/build.log" | head -30 >&2; exit 1; }
echo "sanitize: build up to date in $(( $(date +%s) - start )) s"

# detect_leaks: LeakSanitizer too. The tools run by the CLI tests inherit these options.
export ASAN_OPTIONS="${ASAN_OPTIONS:-halt_on_error=1:detect_leaks=1:detect_stack_use_after_return=1:check_initialization_order=1:strict_init_order=1}"
export UBSAN_OPTIONS="${UBSAN_OPTIONS:-halt_on_error=1:print_stacktrace=1}"
if [ -z "${ASAN_SYMBOLIZER_PATH:-}" ] && [ -x /usr/bin/llvm-symbolizer-14 ]; then
  export ASAN_SYMBOLIZER_PATH=/usr/bin/llvm-symbolizer-14
fi

mkdir -p "$build/sanitize_logs"
summary="$build/sanitize_summary.txt"
: >"$summary"
failed=0
total_tests=0
while IFS= read -r exe; do
  name=$(basename "$exe")
  log="$build/sanitize_logs/$name.log"
  t0=$(date +%s)
  set +e
  (cd "$build" && "$exe" --gtest_filter="$filter") >"$log" 2>&1
  rc=$?
  set -e
  passed=$(grep -oE '\[  PASSED  \] [0-9]+' "$log" | awk '{print $4}' | tail -1)
  total_tests=$(( total_tests + ${passed:-0} ))
  reports=$(grep -cE 'ERROR: (AddressSanitizer|LeakSanitizer)|runtime error:' "$log" || true)
  if [ $rc -eq 0 ] && [ "$reports" -eq 0 ]; then
    line="$name: OK, ${passed:-0} tests passed, 0 sanitizer reports, $(( $(date +%s) - t0 )) s"
  else
    failed=1
    line="$name: FAILED (exit $rc, $reports sanitizer reports); log $log"
    grep -E 'ERROR: |runtime error:|SUMMARY:|\[  FAILED  \]' "$log" | head -10 >&2 || true
  fi
  echo "$line" | tee -a "$summary"
done < <(find "$build" -type f -perm -u+x -name 'pcr_pro_test_*' ! -name '*.cmake' | sort)
echo "sanitize: $total_tests tests passed in total" | tee -a "$summary"
exit $failed
