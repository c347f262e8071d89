#!/usr/bin/env bash
# Builds and runs the benchmarks; prints a Markdown report.
# Usage: scripts/bench.sh BUILD_DIR [--quick]
set -euo pipefail
here="$(cd "$(dirname "$0")/.." && pwd)"
build="${1:-build}"
shift || true
export PATH=/usr/bin:$PATH
# Re-configure: PCL (the reference) may have been installed after the first configure.
cmake -S "$here" -B "$build" -DPCR_PRO_BUILD_BENCH=ON >/dev/null
cmake --build "$build" -j 2 --target pcr_pro_bench
"$build/devel/lib/pcr_pro/pcr_pro_bench" "$@"
