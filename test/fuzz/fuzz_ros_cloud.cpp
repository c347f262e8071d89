// libFuzzer target: sensor_msgs/PointCloud2 as the merge node receives it (X/cloud). The bytes are
// deserialized with ros::serialization, then cloudFromMsg() must give finite points, no more than
// width * height, or refuse with an InputError naming "cloud"; the store's cap (capCloud, voxel
// grid) must then bring the cloud under a small cap with finite points. Any other exception,
// crash or sanitizer report is a finding.
#include <sensor_msgs/PointCloud2.h>

#include <cstddef>
#include <cstdint>

#include "fuzz_ros_common.h"
#include "pcr_pro/merge/agent_store.h"
#include "pcr_pro/ros/msg_conversion.h"

extern "C" int LLVMFuzzerTestOneInput(const std::uint8_t* data, std::size_t size) {
  using namespace pcr_pro;
  sensor_msgs::PointCloud2 msg;
  if (!fuzz::deserializeMessage<sensor_msgs::PointCloud2_>(data, size, &msg)) return 0;
  Cloud cloud;
  try {
    cloud = ros_bridge::cloudFromMsg(msg);
  } catch (const InputError& e) {
    fuzz::requireFieldError(e.what(), {"cloud"});
    return 0;
  }
  fuzz::require(cloud.rows() == 3, "cloud does not have 3 rows");
  fuzz::require(static_cast<std::uint64_t>(cloud.cols()) <= static_cast<std::uint64_t>(msg.width) * msg.height,
                "more points than width * height");
  fuzz::require(cloud.allFinite(), "a non-finite point was kept");
  constexpr std::int64_t kCap = 16;
  CloudCap cap;
  const Cloud kept = capCloud(cloud, kCap, &cap);
  fuzz::require(kept.cols() <= std::max<Eigen::Index>(kCap, 0) && kept.cols() <= cloud.cols(), "cap not kept");
  fuzz::require(cloud.cols() == 0 || kept.cols() >= 1, "the cap removed every point");
  fuzz::require(kept.allFinite(), "the cap made a non-finite point");
  fuzz::require(cap.input_points == cloud.cols() && cap.kept_points == kept.cols(), "cap report is wrong");
  return 0;
}
