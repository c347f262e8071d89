#!/usr/bin/env bash
# Builds and runs the benchmarks; prints a Markdown report. Usage: scripts/bench.sh BUILD_DIR [--quick]
set -euo pipefail
build="${1:-build}"
shift || true
export PATH=/usr/bin:$PATH
cmake --build "$build" -j 2 --target pcr_pro_bench
bin=$(find "$build" -name pcr_pro_bench -type f -perm -u+x | head -n 1)
"$bin" "$@"
