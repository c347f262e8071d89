// libFuzzer target: lsd_slam_viewer/keyframeGraphMsg exactly as LSD-SLAM publishes it
// (X/lsd_slam/graph). The bytes are deserialized with ros::serialization; lsdGraphFromMsg() must
// give numFrames poses and numConstraints constraints, every pose a proper similarity, or refuse
// with an InputError naming the field; applied to a store holding one of the ids, the moved
// keyframe's map points must stay finite. Any other exception, crash or sanitizer report is a finding.
#include <lsd_slam_viewer/keyframeGraphMsg.h>

#include <cmath>
#include <cstddef>
#include <cstdint>

#include "fuzz_ros_common.h"
#include "pcr_pro/merge/agent_store.h"
#include "pcr_pro/ros/msg_conversion.h"

namespace {

// A small LSD keyframe with depth everywhere.
pcr_pro::LsdKeyframe smallKeyframe(long id) {
  pcr_pro::LsdKeyframe kf;
  kf.id = id;
  kf.camera = {20.0, 20.0, 4.0, 3.0, 8, 6};
  kf.idepth = cv::Mat(6, 8, CV_32FC1, cv::Scalar(0.5f));
  kf.idepth_var = cv::Mat(6, 8, CV_32FC1, cv::Scalar(1e-6f));
  kf.image = cv::Mat(6, 8, CV_8UC1, cv::Scalar(80));
  return kf;
}

}  // namespace

extern "C" int LLVMFuzzerTestOneInput(const std::uint8_t* data, std::size_t size) {
  using namespace pcr_pro;
  using namespace pcr_pro::ros_bridge;
  lsd_slam_viewer::keyframeGraphMsg msg;
  if (!fuzz::deserializeMessage<lsd_slam_viewer::keyframeGraphMsg_>(data, size, &msg)) return 0;
  LsdGraph graph;
  try {
    graph = lsdGraphFromMsg(msg);
  } catch (const InputError& e) {
    fuzz::requireFieldError(e.what(), {"frameData", "constraintsData"});
    return 0;
  }
  fuzz::require(graph.poses.size() == msg.numFrames, "pose count differs from numFrames");
  fuzz::require(graph.constraints.size() == msg.numConstraints, "constraint count differs from numConstraints");
  for (const auto& [id, pose] : graph.poses) {
    const double s = pose.scale();
    fuzz::require(std::isfinite(s) && s > 0.0 && pose.matrix().allFinite(), "degenerate pose accepted");
  }
  if (graph.poses.empty()) return 0;
  AgentStore store("m");
  store.setLsdKeyframe(smallKeyframe(graph.poses.front().first));
  fuzz::require(store.updateLsdPoses(graph.poses) >= 1, "the known keyframe was not moved");
  LsdFilterOptions o;
  o.min_near_support = 0;
  const AgentMap map = store.toAgentMap(o);
  fuzz::require(map.cloud.allFinite(), "moved map points are not finite");
  return 0;
}
