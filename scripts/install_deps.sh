#!/usr/bin/env bash
# Installs the Debian 12 packages pcr_pro needs to build, test and run its demo.
# Idempotent: asks apt only for packages that are not installed yet, and runs
# `apt-get update` only when something is missing. Must run as root (or via sudo).
#
# Usage: scripts/install_deps.sh [build|bench|fuzz|sanitize|rviz]
#   build (default)  everything `make build`, `make test` and `make demo` need
#   bench            additionally what `make bench` needs
#   fuzz             additionally what `make fuzz` needs beyond the default (llvm-symbolizer)
#   sanitize         additionally what `make test-sanitize` needs beyond the default
#   rviz             additionally rviz and Xvfb (demo.launch rviz:=true, scripts/rviz_screenshot.sh)
set -euo pipefail

profile="${1:-build}"

packages=(
  # toolchain
  cmake g++ make pkg-config
  # catkin (devel space, package.xml handling) and its Python side
  catkin python3-catkin-pkg
  # core library
  libeigen3-dev libnanoflann-dev libyaml-cpp-dev libopencv-dev libopengv-dev
  # tests
  libgtest-dev
  # make test also runs each libFuzzer target briefly: clang 14, its libFuzzer/ASan/UBSan runtimes
  clang-14 libclang-rt-14-dev
  # ROS layer (merge node, nodelet, messages, bags, rostest, launch; Debian's ROS 1 under /usr)
  ros-base-dev ros-message-generation ros-message-runtime python3-genmsg python3-gencpp python3-genpy
  libroscpp-dev libstd-msgs-dev libsensor-msgs-dev libgeometry-msgs-dev libdiagnostic-msgs-dev
  ros-std-msgs ros-sensor-msgs ros-geometry-msgs ros-diagnostic-msgs
  libtf2-ros-dev libdiagnostic-updater-dev libnodelet-dev libnodeletlib-tools pluginlib-dev
  librosbag-dev python3-rosbag librostest-dev python3-rostest python3-roslaunch rosout rosbash
  # images through cv_bridge; pcr_pro/pcl.h, the published clouds (pcl_conversions) and the PCD
  # differential test (pcl::io)
  libcv-bridge-dev libpcl-dev libpcl-conversions-dev libpcl-msgs-dev
  # the README's command-line tools (rosrun, rosservice call, rostopic echo, rosmsg show, rosnode) and
  # the Python message classes they load: pcr_pro's messages need std/geometry/sensor_msgs, the
  # node's diagnostics diagnostic_msgs (test/ros/readme_commands.py runs them all)
  python3-rosservice python3-rostopic python3-rosmsg python3-rosnode python3-rospy
  python3-std-msgs python3-geometry-msgs python3-sensor-msgs python3-diagnostic-msgs python3-rosgraph-msgs
)
case "$profile" in
  build) ;;
  bench) packages+=(libopen3d-dev python3 python3-matplotlib python3-numpy) ;;
  # make fuzz: the default list has clang; llvm-14 adds llvm-symbolizer for readable reports
  fuzz) packages+=(llvm-14) ;;
  # make test-sanitize: g++'s ASan/UBSan runtimes come with g++; llvm-14 for symbolised reports
  sanitize) packages+=(llvm-14) ;;
  # demo.launch rviz:=true and scripts/rviz_screenshot.sh
  rviz) packages+=(rviz xvfb imagemagick) ;;
  *) echo "install_deps: unknown profile '$profile' (build|bench|fuzz|sanitize|rviz)" >&2; exit 2 ;;
esac

missing=()
for p in "${packages[@]}"; do
  if ! dpkg-query -W -f='${Status}' "$p" 2>/dev/null | grep -q "install ok installed"; then
    missing+=("$p")
  fi
done

if [ ${#missing[@]} -eq 0 ]; then
  echo "install_deps: all ${#packages[@]} Debian packages present"
  exit 0
fi

echo "install_deps: installing ${#missing[@]} missing package(s): ${missing[*]}"
SUDO=""
if [ "$(id -u)" -ne 0 ]; then
  if command -v sudo >/dev/null 2>&1; then SUDO="sudo"; else
    echo "install_deps: not root and no sudo; install these packages: ${missing[*]}" >&2
    exit 1
  fi
fi
export DEBIAN_FRONTEND=noninteractive
$SUDO apt-get update -qq
$SUDO apt-get install -y -qq --no-install-recommends "${missing[@]}"
