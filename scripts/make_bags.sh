#!/usr/bin/env bash
# Regenerates the two shipped bags in test/data/bags from the real frames of the map bundle case
# test/data/bundles/depth (real NYU Depth V2 Kinect frames, see test/data/bundles/README.md):
#   pcr_pro_two_agents.bag   pcr_pro/Keyframe + sensor_msgs/PointCloud2 per agent
#   lsd_slam_two_agents.bag  lsd_slam_viewer/keyframeMsg + keyframeGraphMsg per agent
# Deterministic. Usage: scripts/make_bags.sh [BUILD_DIR]   (default build; builds the tool)
set -euo pipefail
export PATH=/usr/bin:/bin:/usr/sbin:/sbin:$PATH
here="$(cd "$(dirname "$0")/.." && pwd)"
build="${1:-build}"
case "$build" in /*) ;; *) build="$here/$build" ;; esac
if [ ! -f "$build/CMakeCache.txt" ]; then
  cmake -S "$here" -B "$build" -DCMAKE_BUILD_TYPE=Release -DCATKIN_DEVEL_PREFIX="$build/devel"
fi
cmake --build "$build" -j 2 --target pcr_pro_make_bags
"$build/devel/lib/pcr_pro/pcr_pro_make_bags" --case "$here/test/data/bundles/depth" --output "$here/test/data/bags"
ls -l "$here/test/data/bags"/*.bag
