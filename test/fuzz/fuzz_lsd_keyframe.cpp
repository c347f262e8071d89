// libFuzzer target: lsd_slam_viewer/keyframeMsg exactly as LSD-SLAM publishes it (X/lsd_slam/keyframes).
// The bytes are deserialized with ros::serialization; lsdKeyframeFromMsg() must give a keyframe
// consistent with the message or refuse with an InputError naming the field; then the LSD viewer
// filters (extractPoints) and the agent store (keyframe cap, map cloud voxelised to a small cap)
// must give finite points only. Any other exception, crash or sanitizer report is a finding.
#include <lsd_slam_viewer/keyframeMsg.h>

#include <cmath>
#include <cstddef>
#include <cstdint>

#include "fuzz_ros_common.h"
#include "pcr_pro/merge/agent_store.h"
#include "pcr_pro/ros/msg_conversion.h"

extern "C" int LLVMFuzzerTestOneInput(const std::uint8_t* data, std::size_t size) {
  using namespace pcr_pro;
  using namespace pcr_pro::ros_bridge;
  lsd_slam_viewer::keyframeMsg msg;
  if (!fuzz::deserializeMessage<lsd_slam_viewer::keyframeMsg_>(data, size, &msg)) return 0;
  LsdKeyframe kf;
  try {
    kf = lsdKeyframeFromMsg(msg);
  } catch (const InputError& e) {
    fuzz::requireFieldError(e.what(), {"width/height", "fx/fy/cx/cy", "pointcloud", "camToWorld"});
    return 0;
  }
  fuzz::require(kf.camera.valid(), "accepted invalid intrinsics");
  fuzz::require(kf.idepth.cols == static_cast<int>(msg.width) && kf.idepth.rows == static_cast<int>(msg.height) &&
                    kf.idepth_var.size() == kf.idepth.size() && kf.image.size() == kf.idepth.size(),
                "decoded sizes differ from the message's");
  const double s = kf.cam_to_world.scale();
  fuzz::require(std::isfinite(s) && s > 0.0 && kf.cam_to_world.matrix().allFinite(), "degenerate camToWorld accepted");

  // The viewer filters: defaults, and everything kept that has an inverse depth.
  LsdFilterOptions loose;
  loose.scaled_depth_var_th = loose.abs_depth_var_th = 1e30;
  loose.min_near_support = 0;
  loose.sparsify_factor = 1 + static_cast<int>(msg.id & 3);
  for (const LsdFilterOptions& o : {LsdFilterOptions(), loose}) {
    const LsdPoints p = extractPoints(kf, o);
    fuzz::require(p.camera_points.allFinite(), "extractPoints gave a non-finite point");
    fuzz::require(p.camera_points.cols() <= static_cast<Eigen::Index>(msg.width) * msg.height, "too many points");
    fuzz::require(p.depth.size() == kf.idepth.size(), "depth image size differs");
    const MapKeyframe m = toKeyframe(kf);
    fuzz::require(m.pose.matrix().allFinite(), "keyframe pose not finite");
    double lo = 0.0, hi = 0.0;
    cv::minMaxLoc(m.depth_stddev, &lo, &hi);
    fuzz::require(std::isfinite(lo) && std::isfinite(hi) && lo >= 0.0, "keyframe depth stddev not finite or negative");
  }

  // The store: a re-sent id replaces, the keyframe cap drops the oldest, the map cloud is capped.
  StoreLimits limits;
  limits.max_keyframes = 2;
  limits.max_cloud_points = 1000;
  AgentStore store("m", limits);
  std::vector<long> dropped;
  LsdKeyframe other = kf;
  for (long id : {kf.id, kf.id + 1, kf.id + 1, kf.id + 2}) {
    other.id = id;
    store.setLsdKeyframe(other, &dropped);
  }
  fuzz::require(store.keyframeCount() == 2 && dropped.size() == 1, "keyframe cap not kept");
  CloudCap cap;
  const AgentMap map = store.toAgentMap(loose, &cap);
  fuzz::require(map.cloud.cols() <= limits.max_cloud_points, "map cloud above the cap");
  fuzz::require(map.cloud.allFinite(), "map cloud has a non-finite point");
  fuzz::require(map.keyframes.size() == 2, "map keyframes lost");
  return 0;
}
