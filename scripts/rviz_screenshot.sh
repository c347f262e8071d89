#!/usr/bin/env bash
# Renders an rviz screenshot of the demo merge under Xvfb into BUILD_DIR/rviz_merge.png (the README's
# docs/images/rviz_merge.png is a copy of one, looked at before it is committed).
# Usage: scripts/rviz_screenshot.sh [BUILD_DIR] [demo.launch arguments ...]
#   (needs the `rviz` profile: scripts/install_deps.sh rviz)
set -euo pipefail
here="$(cd "$(dirname "$0")/.." && pwd)"
build="$(cd "${1:-$here/build}" && pwd)"
shift || true
out="$build/rviz_merge.png"
export PATH=/usr/bin:/bin:/usr/sbin:/sbin:$PATH
for tool in Xvfb import rviz; do
  command -v "$tool" >/dev/null || { echo "rviz_screenshot: $tool missing: run scripts/install_deps.sh rviz" >&2; exit 2; }
done
work="$(mktemp -d)"
display=":$((90 + RANDOM % 9))"
Xvfb "$display" -screen 0 1280x800x24 >"$work/xvfb.log" 2>&1 &
xvfb_pid=$!
launch_pid=""
cleanup() {
  [ -n "$launch_pid" ] && kill -INT "$launch_pid" 2>/dev/null && wait "$launch_pid" 2>/dev/null || true
  kill "$xvfb_pid" 2>/dev/null || true
}
trap cleanup EXIT
set +u
source "$build/devel/setup.bash"
set -u
port=$(/usr/bin/python3 -c 'import socket; s = socket.socket(); s.bind(("", 0)); print(s.getsockname()[1])')
export DISPLAY="$display" ROS_MASTER_URI="http://localhost:$port" ROS_HOME="$work/ros_home" LIBGL_ALWAYS_SOFTWARE=1
roslaunch -p "$port" pcr_pro demo.launch rviz:=true output_file:="$work/edge.yaml" "$@" >"$work/roslaunch.log" 2>&1 &
launch_pid=$!
for _ in $(seq 1 180); do
  [ -s "$work/edge.yaml" ] && break
  sleep 1
done
if [ ! -s "$work/edge.yaml" ]; then
  echo "rviz_screenshot: the demo merge printed no edge; log: $work/roslaunch.log" >&2
  exit 1
fi
sleep 15  # let rviz receive the latched clouds and render
mkdir -p "$(dirname "$out")"
import -display "$display" -window root "$out"
echo "rviz_screenshot: wrote $out"
