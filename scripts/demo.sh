#!/usr/bin/env bash
# The demo: merges the two real agents' maps shipped in test/data/bundles/depth (built from real
# Kinect frames, each agent in its own frame and scale) with pcr_pro_merge, prints the result
# YAML, and compares it with the known ground truth. Then shows the refusal of a pair of maps
# that do not overlap. Then the ROS node: launch/demo.launch headless on both shipped bags.
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

# --- ROS (issue 4): launch/demo.launch headless, once per shipped bag ----------------------------
# Plays the bag into merge_node, calls ~merge when the bag is done and prints the edge as YAML.
# Its own master on a free port, logs under BUILD_DIR, so it runs beside anything else.
(
  export PATH=/usr/bin:/bin:/usr/sbin:/sbin:$PATH
  set +u
  source "$build/devel/setup.bash"
  set -u
  port=$(/usr/bin/python3 -c 'import socket; s = socket.socket(); s.bind(("", 0)); print(s.getsockname()[1])')
  out="$(mkdir -p "$out" && cd "$out" && pwd)"  # nodes run in ROS_HOME: absolute paths only
  export ROS_MASTER_URI="http://localhost:$port" ROS_HOME="$out/ros_home"
  for input in pcr_pro lsd_slam; do
    echo
    echo "== roslaunch pcr_pro demo.launch input:=$input (bag test/data/bags/$([ $input = lsd_slam ] && echo lsd_slam || echo pcr_pro)_two_agents.bag)"
    rm -f "$out/edge_$input.yaml"
    roslaunch -p "$port" pcr_pro demo.launch input:="$input" output_file:="$out/edge_$input.yaml" > "$out/roslaunch_$input.log" 2>&1 || true
    if [ ! -s "$out/edge_$input.yaml" ]; then
      echo "demo.launch input:=$input printed no edge; log: $out/roslaunch_$input.log" >&2
      tail -n 30 "$out/roslaunch_$input.log" >&2
      exit 1
    fi
    cat "$out/edge_$input.yaml"
    grep -q '^status: OK' "$out/edge_$input.yaml"
  done
)
