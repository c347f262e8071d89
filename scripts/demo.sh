#!/usr/bin/env bash
# The demo: registers the two real car scans shipped in test/data with pcr_pro_icp (from identity)
# and prints the result YAML, then compares it with the ground truth gT of the data set.
# Usage: scripts/demo.sh BUILD_DIR
set -euo pipefail
build="${1:-build}"
here="$(cd "$(dirname "$0")/.." && pwd)"
bin="$build/devel/lib/pcr_pro/pcr_pro_icp"
data="$here/test/data/libpointmatcher_car"
out="$build/demo_output"
echo "== pcr_pro_icp: car_cloud401 (source) -> car_cloud400 (target), from identity"
"$bin" --source "$data/car_cloud401.csv" --target "$data/car_cloud400.csv" \
       --config "$here/config/icp.yaml" --output "$out"
echo "== wrote $out/result.yaml and $out/fused.pcd"
echo "== ground truth gT (carCloudList.csv, maps 401 into 400):"
grep '^car_cloud401' "$data/carCloudList.csv"
