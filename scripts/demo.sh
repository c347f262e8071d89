#!/usr/bin/env bash
# The demo: merges the two real agents' maps shipped in test/data/bundles/depth (built from real
# Kinect frames, each agent in its own frame and scale) with pcr_pro_merge, prints the result
# YAML, and compares it with the known ground truth. Then shows the refusal of a pair of maps
# that do not overlap.
# Usage: scripts/demo.sh BUILD_DIR
set -euo pipefail
build="${1:-build}"
here="$(cd "$(dirname "$0")/.." && pwd)"
bin="$build/devel/lib/pcr_pro/pcr_pro_merge"
data="$here/test/data/bundles"
out="$build/demo_output"

echo "== pcr_pro_merge: agent_b (source) into agent_a (target), keyframe pair chosen automatically"
"$bin" --source "$data/depth/agent_b" --target "$data/depth/agent_a" \
       --config "$here/config/merge.yaml" --output "$out"
echo "== wrote $out/result.yaml and $out/fused.pcd"
echo "== ground truth (test/data/bundles/depth/truth.yaml):"
sed -n '/^S_target_source:/,/translation/p' "$data/depth/truth.yaml"

echo
echo "== maps that do not overlap must be refused (exit status 1):"
set +e
"$bin" --source "$data/nooverlap/agent_b" --target "$data/nooverlap/agent_a" | sed -n '1,2p'
status=${PIPESTATUS[0]}
set -e
echo "== exit status $status"
[ "$status" -eq 1 ]
