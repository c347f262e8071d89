// Images, depth images and pcr_pro/Keyframe <-> ROS messages, through cv_bridge (see msg_conversion.h).
#include "pcr_pro/ros/msg_conversion.h"

#include <cv_bridge/cv_bridge.h>
#include <opencv2/imgproc.hpp>
#include <sensor_msgs/image_encodings.h>

#include <cmath>
#include <limits>

#include "msg_checks.h"

namespace pcr_pro {
namespace ros_bridge {

using namespace detail;

// --- images -----------------------------------------------------------------------------------

namespace {

// The layout checks in front of cv_bridge: its own check of data size against height * step is
// done in 32 bits, so a message with a large step * height could pass it with too little data;
// here every product is 64-bit and each side is bounded.
void checkImageLayout(const sensor_msgs::Image& msg, std::size_t pixel_bytes, const std::string& field) {
  if (msg.width == 0 || msg.height == 0) {
    fail(field, "empty image (" + str(msg.width) + "x" + str(msg.height) + ")");
  }
  if (msg.width > kMaxImageSide || msg.height > kMaxImageSide) {
    fail(field, "image size " + str(msg.width) + "x" + str(msg.height) + " is beyond " + str(kMaxImageSide) +
                    " pixels a side");
  }
  const std::uint64_t min_step = static_cast<std::uint64_t>(msg.width) * pixel_bytes;
  if (msg.step < min_step) {
    fail(field,
         "step " + str(msg.step) + " < width * pixel size " + str(min_step) + " (" + printable(msg.encoding) + ")");
  }
  const std::uint64_t expected = static_cast<std::uint64_t>(msg.step) * msg.height;
  if (msg.data.size() != expected) {
    fail(field, "data size " + str(msg.data.size()) + " != step * height = " + str(expected));
  }
}

// cv_bridge::toCvCopy() of a message that passed checkImageLayout(); cv_bridge's own exceptions
// (none are expected after the checks) become InputError naming the field.
cv::Mat bridgeCopy(const sensor_msgs::Image& msg, const std::string& encoding, const std::string& field) {
  try {
    return cv_bridge::toCvCopy(msg, encoding)->image;
  } catch (const cv_bridge::Exception& e) {
    fail(field, std::string("cv_bridge: ") + printable(e.what()));
  } catch (const cv::Exception& e) {
    fail(field, std::string("cv_bridge: ") + printable(e.what()));
  }
}

// A message of `encoding` holding `image`, through cv_bridge (step = width * pixel size,
// little-endian as the host).
sensor_msgs::Image bridgeMsg(const cv::Mat& image, const std::string& encoding) {
  sensor_msgs::Image msg;
  cv_bridge::CvImage(std_msgs::Header(), encoding, image).toImageMsg(msg);
  return msg;
}

}  // namespace

cv::Mat greyImageFromMsg(const sensor_msgs::Image& msg, const std::string& field) {
  namespace enc = sensor_msgs::image_encodings;
  // cv_bridge converts many more encodings (16-bit, Bayer, YUV); the keyframe front end is
  // defined on 8-bit images, so only these are taken.
  std::size_t channels = 0;
  if (msg.encoding == enc::MONO8) {
    channels = 1;
  } else if (msg.encoding == enc::RGB8 || msg.encoding == enc::BGR8) {
    channels = 3;
  } else if (msg.encoding == enc::RGBA8 || msg.encoding == enc::BGRA8) {
    channels = 4;
  } else {
    fail(field, "unsupported encoding '" + printable(msg.encoding) + "' (mono8, rgb8, bgr8, rgba8, bgra8)");
  }
  checkImageLayout(msg, channels, field);
  return bridgeCopy(msg, enc::MONO8, field);
}

sensor_msgs::Image greyImageToMsg(const cv::Mat& image) {
  if (image.type() != CV_8UC1) throw InputError("greyImageToMsg: image must be CV_8UC1");
  return bridgeMsg(image, sensor_msgs::image_encodings::MONO8);
}

cv::Mat depthFromMsg(const sensor_msgs::Image& msg, const std::string& field) {
  namespace enc = sensor_msgs::image_encodings;
  const bool is_float = msg.encoding == enc::TYPE_32FC1;
  const bool is_mm = msg.encoding == enc::TYPE_16UC1 || msg.encoding == enc::MONO16;
  if (!is_float && !is_mm) fail(field, "unsupported encoding '" + printable(msg.encoding) + "' (32FC1, 16UC1)");
  if (msg.is_bigendian) fail(field, "big-endian depth data is not supported");
  checkImageLayout(msg, is_float ? 4 : 2, field);
  // The message's own encoding (no conversion): 32FC1 -> CV_32FC1, 16UC1 / mono16 -> CV_16UC1.
  cv::Mat depth = bridgeCopy(msg, "", field);
  if (is_mm) {
    depth.convertTo(depth, CV_32FC1, 1e-3);  // REP 118: millimetres, 0 = unknown
  } else {
    // NaN (every comparison false), +inf and non-positive depths: unknown (0)
    const cv::Mat known = (depth > 0.0f) & (depth < std::numeric_limits<float>::infinity());
    depth.setTo(0.0f, ~known);
  }
  return depth;
}

sensor_msgs::Image depthToMsg(const cv::Mat& depth) {
  if (depth.type() != CV_32FC1) throw InputError("depthToMsg: depth must be CV_32FC1");
  return bridgeMsg(depth, sensor_msgs::image_encodings::TYPE_32FC1);
}

sensor_msgs::Image depthToMsgMillimetres(const cv::Mat& depth) {
  if (depth.type() != CV_32FC1) throw InputError("depthToMsgMillimetres: depth must be CV_32FC1");
  cv::Mat mm(depth.size(), CV_16UC1);
  for (int r = 0; r < depth.rows; ++r) {
    const float* src = depth.ptr<float>(r);
    std::uint16_t* dst = mm.ptr<std::uint16_t>(r);
    for (int c = 0; c < depth.cols; ++c) {
      const double v = std::round(static_cast<double>(src[c]) * 1000.0);
      dst[c] = std::isfinite(v) && v > 0.0 && v <= 65535.0 ? static_cast<std::uint16_t>(v) : 0;
    }
  }
  return bridgeMsg(mm, sensor_msgs::image_encodings::TYPE_16UC1);
}

// --- keyframes --------------------------------------------------------------------------------

DecodedKeyframe keyframeFromMsg(const pcr_pro::Keyframe& msg) {
  DecodedKeyframe out;
  out.frame_id = msg.header.frame_id;
  out.keyframe.id = static_cast<long>(msg.id);
  out.camera = cameraFromMsg(msg.camera_info);
  out.keyframe.image = greyImageFromMsg(msg.image, "image");
  if (out.keyframe.image.cols != out.camera.width || out.keyframe.image.rows != out.camera.height) {
    fail("image", "size " + str(out.keyframe.image.cols) + "x" + str(out.keyframe.image.rows) +
                      " != camera_info size " + str(out.camera.width) + "x" + str(out.camera.height) +
                      (msg.camera_info.binning_x > 1 || msg.camera_info.binning_y > 1 || msg.camera_info.roi.width > 0
                           ? " (its roi at its binning)"
                           : ""));
  }
  out.keyframe.pose = sim3FromPose(msg.pose, msg.scale);
  const bool has_depth = msg.depth.width > 0 || msg.depth.height > 0 || !msg.depth.data.empty();
  if (has_depth) {
    out.keyframe.depth = depthFromMsg(msg.depth, "depth");
    if (out.keyframe.depth.size() != out.keyframe.image.size()) {
      fail("depth", "size " + str(out.keyframe.depth.cols) + "x" + str(out.keyframe.depth.rows) +
                        " != image size " + str(out.keyframe.image.cols) + "x" + str(out.keyframe.image.rows));
    }
  }
  return out;
}

pcr_pro::Keyframe keyframeToMsg(const MapKeyframe& keyframe, const PinholeCamera& camera, const std::string& frame_id,
                                const ros::Time& stamp, bool depth_millimetres) {
  pcr_pro::Keyframe msg;
  msg.header.frame_id = frame_id;
  msg.header.stamp = stamp;
  msg.id = keyframe.id;
  msg.image = greyImageToMsg(keyframe.image);
  msg.image.header = msg.header;
  msg.camera_info = cameraToMsg(camera);
  msg.camera_info.header = msg.header;
  msg.pose = poseFromSim3(keyframe.pose);
  msg.scale = keyframe.pose.scale();
  if (!keyframe.depth.empty()) {
    msg.depth = depth_millimetres ? depthToMsgMillimetres(keyframe.depth) : depthToMsg(keyframe.depth);
    msg.depth.header = msg.header;
  }
  return msg;
}

}  // namespace ros_bridge
}  // namespace pcr_pro
