#!/usr/bin/env bash
# make test-sanitize: builds the core, the offline tools, every unit test and the ROS-side tests
# that need no ROS master (message conversions, bad messages and store limits, the generated world's bags
# decoded and merged) with AddressSanitizer + UndefinedBehaviorSanitizer (g++,
# -DPCR_PRO_SANITIZE=ON) in build-asan/ and runs each test executable. Any sanitizer report is
# fatal (halt_on_error, and -fno-sanitize-recover at compile time), so a finding fails its test
# binary. The ROS libraries (roscpp, rosbag, ...) are Debian's, not instrumented: ASan checks our
# code's accesses and every malloc/free, LeakSanitizer the whole process.
#
# Usage: scripts/sanitize.sh [gtest filter]
#   SANITIZE_BUILD_DIR  build directory (default build-asan/ at the top of the package)
#   SANITIZE_SUITES     core | ros | all (default all): which test executables to build and run
#   JOBS                parallel compile jobs (default 2)
# Exit status: 0 every test binary passed clean, 1 otherwise. Summary in BUILD/sanitize_summary.txt.
set -euo pipefail
export PATH=/usr/bin:/bin:$PATH

root=$(cd "$(dirname "$0")/.." && pwd)
build=${SANITIZE_BUILD_DIR:-$root/build-asan}
jobs=${JOBS:-2}
filter=${1:-*}
suites=${SANITIZE_SUITES:-all}
case "$suites" in
  core) targets=(pcr_pro_unit_tests); pattern='pcr_pro_test_*'; exclude=(! -name 'pcr_pro_test_ros_*') ;;
  ros) targets=(pcr_pro_ros_unit_tests); pattern='pcr_pro_test_ros_*'; exclude=() ;;
  all) targets=(pcr_pro_unit_tests pcr_pro_ros_unit_tests); pattern='pcr_pro_test_*'; exclude=() ;;
  *) echo "sanitize: SANITIZE_SUITES must be core, ros or all, got '$suites'" >&2; exit 1 ;;
esac

if [ ! -f "$build/CMakeCache.txt" ]; then
  echo "sanitize: configuring $build"
  mkdir -p "$build"
  cmake -S "$root" -B "$build" -DCMAKE_BUILD_TYPE=Release -DPCR_PRO_SANITIZE=ON -DPCR_PRO_BUILD_BENCH=OFF \
    -DPCR_PRO_FUZZ_IN_CTEST=OFF -DCATKIN_DEVEL_PREFIX="$build/devel" >"$build/configure.log" 2>&1 ||
    { tail -30 "$build/configure.log" >&2; exit 1; }
fi
start=$(date +%s)
: >"$build/build.log"
for target in "${targets[@]}"; do
  cmake --build "$build" -j "$jobs" --target "$target" >>"$build/build.log" 2>&1 ||
    { grep -E 'error|Error' "$build/build.log" | head -30 >&2; exit 1; }
done
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
# pcr_pro_test_merge_node is the rostest driver (it needs a ROS master and the node): not run here.
done < <(find "$build" -type f -perm -u+x -name "$pattern" ! -name '*.cmake' ! -name 'pcr_pro_test_merge_node' \
           "${exclude[@]}" | sort)
echo "sanitize: $total_tests tests passed in total" | tee -a "$summary"
exit $failed
