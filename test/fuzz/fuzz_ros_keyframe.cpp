// libFuzzer target: pcr_pro/Keyframe as the merge node receives it (X/keyframes), which carries the
// Image, depth Image and CameraInfo conversions. The bytes are deserialized with
// ros::serialization; then each conversion on its own (cameraFromMsg, greyImageFromMsg,
// depthFromMsg on both images) and the whole keyframeFromMsg() must give a consistent result or
// refuse with an InputError naming the field. Any other exception, crash or sanitizer report is a
// finding.
#include <pcr_pro/Keyframe.h>

#include <cmath>
#include <cstddef>
#include <cstdint>

#include "fuzz_ros_common.h"
#include "pcr_pro/ros/msg_conversion.h"

namespace {

using namespace pcr_pro;

void checkDepth(const cv::Mat& depth, const sensor_msgs::Image& msg) {
  fuzz::require(depth.type() == CV_32FC1, "depth is not CV_32FC1");
  fuzz::require(depth.cols == static_cast<int>(msg.width) && depth.rows == static_cast<int>(msg.height),
                "depth size differs from the message's");
  for (int r = 0; r < depth.rows; ++r) {
    const float* row = depth.ptr<float>(r);
    for (int c = 0; c < depth.cols; ++c) fuzz::require(std::isfinite(row[c]) && row[c] >= 0.0f, "bad depth value");
  }
}

}  // namespace

extern "C" int LLVMFuzzerTestOneInput(const std::uint8_t* data, std::size_t size) {
  using namespace pcr_pro::ros_bridge;
  pcr_pro::Keyframe msg;
  if (!fuzz::deserializeMessage<pcr_pro::Keyframe_>(data, size, &msg)) return 0;

  try {
    const PinholeCamera c = cameraFromMsg(msg.camera_info);
    fuzz::require(c.valid(), "accepted an invalid camera");
  } catch (const InputError& e) {
    fuzz::requireFieldError(e.what(), {"camera_info"});
  }
  try {
    const cv::Mat grey = greyImageFromMsg(msg.image);
    fuzz::require(grey.type() == CV_8UC1, "grey image is not CV_8UC1");
    fuzz::require(grey.cols == static_cast<int>(msg.image.width) && grey.rows == static_cast<int>(msg.image.height),
                  "grey image size differs from the message's");
  } catch (const InputError& e) {
    fuzz::requireFieldError(e.what(), {"image"});
  }
  for (const auto* image : {&msg.depth, &msg.image}) {
    try {
      checkDepth(depthFromMsg(*image, "depth"), *image);
    } catch (const InputError& e) {
      fuzz::requireFieldError(e.what(), {"depth"});
    }
  }
  try {
    const DecodedKeyframe k = keyframeFromMsg(msg);
    fuzz::require(k.camera.valid(), "keyframe with an invalid camera");
    fuzz::require(k.keyframe.image.cols == k.camera.width && k.keyframe.image.rows == k.camera.height,
                  "keyframe image size differs from its camera's");
    fuzz::require(k.keyframe.depth.empty() || k.keyframe.depth.size() == k.keyframe.image.size(),
                  "keyframe depth size differs from its image's");
    const double s = k.keyframe.pose.scale();
    fuzz::require(std::isfinite(s) && s > 0.0 && k.keyframe.pose.matrix().allFinite(), "degenerate pose accepted");
  } catch (const InputError& e) {
    fuzz::requireFieldError(e.what(), {"camera_info", "image", "depth", "pose.position", "pose.orientation", "scale"});
  }
  return 0;
}
