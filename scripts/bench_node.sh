#!/usr/bin/env bash
# make bench, the node section: the real LSD-SLAM bags ($PCR_PRO_DATA_DIR/lsd_slam_7scenes) merged
# THROUGH merge_node as a user runs it (bench/node_timing.launch: launch/merge_node.launch
# input:=lsd_slam and the client pcr_pro_bench_node), cold and warm; writes OUT/node.md (the
# section) and OUT/node_headline.md (its headline line). Called by scripts/bench.sh; alone:
#   scripts/bench_node.sh BUILD_DIR OUT_DIR     (the targets merge_node and pcr_pro_bench_node built)
# Without the data the section says so (skipped, not an error). A failed run is written into the
# section and makes the script exit 1.
set -euo pipefail
here="$(cd "$(dirname "$0")/.." && pwd)"
build="$(cd "${1:?usage: bench_node.sh BUILD_DIR OUT_DIR}" && pwd)"
out="$(mkdir -p "${2:?usage: bench_node.sh BUILD_DIR OUT_DIR}" && cd "$2" && pwd)"
export PATH=/usr/bin:/bin:/usr/sbin:/sbin:$PATH
section="$out/node.md"
headline="$out/node_headline.md"
rm -f "$section" "$headline"

data_dir="${PCR_PRO_DATA_DIR:-$(sed -n 's/^PCR_PRO_DATA_DIR:PATH=//p' "$build/CMakeCache.txt")}"
if [ ! -f "$data_dir/lsd_slam_7scenes/agent_a.bag" ] || [ ! -f "$data_dir/lsd_slam_7scenes/agent_b.bag" ]; then
  reason="Skipped: the real LSD-SLAM bags are absent ($data_dir/lsd_slam_7scenes/agent_{a,b}.bag; set PCR_PRO_DATA_DIR)"
  echo "$reason." > "$section"
  echo "- Warm merge through the node (issue 13): $reason." > "$headline"
  echo "bench_node: $reason" >&2
  exit 0
fi

# One master of roslaunch's own on a free port, logs under the build directory, so that it runs
# beside anything else; bounded in time (a hung node must not hang make bench).
set +u
source "$build/devel/setup.bash"
set -u
log_dir="$build/bench_node"
mkdir -p "$log_dir"
port=$(/usr/bin/python3 -c 'import socket; s = socket.socket(); s.bind(("", 0)); print(s.getsockname()[1])')
export ROS_MASTER_URI="http://localhost:$port" ROS_HOME="$log_dir/ros_home" PCR_PRO_DATA_DIR="$data_dir"
status=0
timeout -s INT -k 10 240 roslaunch -p "$port" "$here/bench/node_timing.launch" output:="$section" \
  headline:="$headline" > "$log_dir/roslaunch.log" 2>&1 || status=$?
# The client is required: its exit ends the launch, and roslaunch says whether it exited with 0.
ended=$(grep -A1 'REQUIRED process \[pcr_pro_bench_node' "$log_dir/roslaunch.log" || true)
clean=0
[[ "$ended" == *"finished cleanly"* ]] && clean=1
if [ "$clean" -ne 1 ] || [ ! -s "$section" ] || [ ! -s "$headline" ]; then
  echo "bench_node: the node benchmark failed (roslaunch status $status); log: $log_dir/roslaunch.log" >&2
  tail -n 20 "$log_dir/roslaunch.log" >&2
  {
    [ -s "$section" ] && cat "$section" && echo
    echo "**The node benchmark failed** (roslaunch status $status); the end of its log:"
    echo
    echo '```'
    grep 'pcr_pro_bench_node' "$log_dir/roslaunch.log" | tail -n 10
    echo '```'
  } > "$section.tmp"
  mv "$section.tmp" "$section"
  [ -s "$headline" ] || echo "- **Warm merge through the node** (issue 13): **the benchmark failed** (see its section)." > "$headline"
  exit 1
fi
echo "bench_node: wrote $section" >&2
