#!/usr/bin/env bash
# The demo, on the project's own generated world BUILD/sim/demo (the build simulates it with
# pcr_pro_simulate and config/sim_demo.yaml; nothing is read from ../shared/data):
#  1. pcr_pro_merge merges agent_b (source) into agent_a (target) and prints the result YAML with
#     its errors against the world's exact truth, beside the uncertainty it reports;
#  2. agent_c, which does not overlap agent_a, is refused (exit status 1, with its status);
#  3. the ROS node: launch/demo.launch headless, once on each of the world's bags (our messages,
#     LSD-SLAM's), prints the edge and its errors against the same truth.
# Usage: scripts/demo.sh BUILD_DIR
set -euo pipefail
build="${1:-build}"
here="$(cd "$(dirname "$0")/.." && pwd)"
bin="$build/devel/lib/pcr_pro/pcr_pro_merge"
world="$(cd "$build/sim/demo" && pwd)"  # nodes run in ROS_HOME: absolute paths only
out="$build/demo_output"

echo "== the generated world $world (config/sim_demo.yaml): agent_a and agent_b overlap by about half,"
echo "   seen 30 deg apart, scale ratio 2.5, with scale drift and bending; agent_c does not overlap agent_a"
echo "== pcr_pro_merge: agent_b (source) into agent_a (target), keyframe pair chosen automatically"
"$bin" --source "$world/agent_b" --target "$world/agent_a" --config "$here/config/merge.yaml" \
       --truth "$world/truth.yaml" --output "$out"
echo "== wrote $out/result.yaml and $out/fused.pcd"

echo
echo "== agent_c into agent_a: the maps do not overlap, the merge must be refused (exit status 1):"
set +e
"$bin" --source "$world/agent_c" --target "$world/agent_a" | sed -n '1,2p'
status=${PIPESTATUS[0]}
set -e
echo "== exit status $status"
[ "$status" -eq 1 ]

# --- ROS: launch/demo.launch headless, once per bag of the world --------------------------------
# Plays the bag into merge_node, calls ~merge when the bag is done and prints the edge as YAML.
# One master of its own on a free port for both launches, logs under BUILD_DIR, so that it runs
# beside anything else; the master is stopped when the demo ends.
(
  export PATH=/usr/bin:/bin:/usr/sbin:/sbin:$PATH
  set +u
  source "$build/devel/setup.bash"
  set -u
  port=$(/usr/bin/python3 -c 'import socket; s = socket.socket(); s.bind(("", 0)); print(s.getsockname()[1])')
  out="$(mkdir -p "$out" && cd "$out" && pwd)"
  export ROS_MASTER_URI="http://localhost:$port" ROS_HOME="$out/ros_home"
  roscore -p "$port" > "$out/roscore.log" 2>&1 &
  roscore_pid=$!
  trap 'kill -INT $roscore_pid 2>/dev/null; wait $roscore_pid 2>/dev/null || true' EXIT
  for _ in $(seq 100); do rosparam get /run_id > /dev/null 2>&1 && break; sleep 0.1; done
  for input in pcr_pro lsd_slam; do
    echo
    echo "== roslaunch pcr_pro demo.launch input:=$input (bag $world/${input}_two_agents.bag)"
    rm -f "$out/edge_$input.yaml"
    roslaunch pcr_pro demo.launch input:="$input" world:="$world" \
      output_file:="$out/edge_$input.yaml" > "$out/roslaunch_$input.log" 2>&1 || true
    if [ ! -s "$out/edge_$input.yaml" ]; then
      echo "demo.launch input:=$input printed no edge; log: $out/roslaunch_$input.log" >&2
      tail -n 30 "$out/roslaunch_$input.log" >&2
      exit 1
    fi
    if grep -q 'REQUIRED process' "$out/roslaunch_$input.log"; then
      echo "demo.launch input:=$input did not end cleanly; log: $out/roslaunch_$input.log" >&2
      exit 1
    fi
    cat "$out/edge_$input.yaml"
    grep -q '^status: OK' "$out/edge_$input.yaml"
    grep -q '^errors_vs_truth:' "$out/edge_$input.yaml"
  done
)
