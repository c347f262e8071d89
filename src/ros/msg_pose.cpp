// Camera intrinsics, poses and the merge edge <-> ROS messages (see msg_conversion.h).
#include "pcr_pro/ros/msg_conversion.h"

#include <ros/console.h>
#include <ros/time.h>

#include <algorithm>
#include <cstdint>
#include <mutex>
#include <vector>

#include "msg_checks.h"
#include "pcr_pro/io/plausibility.h"

namespace pcr_pro {
namespace ros_bridge {

using namespace detail;

// --- camera and poses -------------------------------------------------------------------------

namespace {

// Entries of a pinhole matrix (K, 3x3, or P, 3x4, row-major) that must be 0 or 1 for fx, fy, cx, cy
// to be the whole of it: skew and the bottom row. Skew is refused rather than dropped.
void checkPinholeLayout(const double* m, int cols, const std::string& field) {
  const auto at = [&](int r, int c) { return m[r * cols + c]; };
  if (at(0, 1) != 0.0) fail(field, "skew (element [1]) is " + str(at(0, 1)) + ": only zero skew is supported");
  if (at(1, 0) != 0.0 || at(2, 0) != 0.0 || at(2, 1) != 0.0 || at(2, 2) != 1.0 || (cols == 4 && at(2, 3) != 0.0)) {
    fail(field, "not a pinhole matrix: its last row must be [0 0 1" + std::string(cols == 4 ? " 0" : "") + "] and [1][0] 0");
  }
}

}  // namespace

PinholeCamera cameraFromMsg(const sensor_msgs::CameraInfo& msg) {
  // ROS convention (sensor_msgs/CameraInfo): K and D describe the raw camera; P holds the
  // intrinsics of the rectified image (image_rect). A P of zeros means none was given: the image
  // is then the raw one, which must have no distortion, and K is its intrinsics.
  const bool has_p = std::any_of(msg.P.begin(), msg.P.end(), [](double v) { return v != 0.0; });
  const std::string field = has_p ? "camera_info.P" : "camera_info.K";
  for (double v : has_p ? std::vector<double>(msg.P.begin(), msg.P.end()) : std::vector<double>(msg.K.begin(), msg.K.end())) {
    if (!finite(v)) fail(field, "must be finite");
  }
  PinholeCamera c;
  c.fx = has_p ? msg.P[0] : msg.K[0];
  c.fy = has_p ? msg.P[5] : msg.K[4];
  c.cx = has_p ? msg.P[2] : msg.K[2];
  c.cy = has_p ? msg.P[6] : msg.K[5];
  c.width = static_cast<int>(msg.width);
  c.height = static_cast<int>(msg.height);
  if (!(c.fx > 0.0 && c.fy > 0.0)) {
    fail(field, "focal lengths must be finite and > 0, got fx " + str(c.fx) + ", fy " + str(c.fy));
  }
  if (has_p) {
    checkPinholeLayout(msg.P.data(), 4, field);
  } else {
    checkPinholeLayout(msg.K.data(), 3, field);
  }
  if (msg.width == 0 || msg.height == 0 || msg.width > kMaxImageSide || msg.height > kMaxImageSide) {
    fail("camera_info", "image size must be > 0 and <= " + str(kMaxImageSide) + " a side, got " + str(msg.width) +
                            "x" + str(msg.height));
  }
  if (const auto problem = implausibleIntrinsics(c)) fail(field, problem->first + ": " + problem->second);
  if (!has_p) {
    for (std::size_t i = 0; i < msg.D.size(); ++i) {
      if (msg.D[i] != 0.0) {
        fail("camera_info.D", "distortion coefficient " + str(i) + " is " + str(msg.D[i]) +
                                  " and P is all zero: send the rectified image (image_rect) with P, or an "
                                  "undistorted image with D all zero");
      }
    }
  }
  // Binning and a region of interest (REP 104): K and P are the full sensor's, and the image is
  // the window roi (in full-resolution pixels; all zero = the whole sensor) at 1 / binning of its
  // size. The image's own intrinsics are then fx / bx, cx' = (cx - x_offset) / bx and the same in
  // y, as image_geometry's PinholeCameraModel takes them (without the half-pixel shift an averaging
  // bin makes: a quarter pixel at binning 2).
  const auto& roi = msg.roi;
  const bool no_roi = roi.x_offset == 0 && roi.y_offset == 0 &&
                      ((roi.width == 0 && roi.height == 0) || (roi.width == msg.width && roi.height == msg.height));
  if (!no_roi) {
    if (roi.width == 0 || roi.height == 0 || std::uint64_t{roi.x_offset} + roi.width > msg.width ||
        std::uint64_t{roi.y_offset} + roi.height > msg.height) {
      fail("camera_info.roi", "x_offset " + str(roi.x_offset) + ", y_offset " + str(roi.y_offset) + ", " +
                                  str(roi.width) + "x" + str(roi.height) + " is not a window of the " +
                                  str(msg.width) + "x" + str(msg.height) + " image");
    }
    // A window of the raw image is that window of the rectified one only where rectifying moves no
    // pixel: no distortion, R the identity and P's pinhole part equal to K.
    const bool identity_rectification =
        std::all_of(msg.D.begin(), msg.D.end(), [](double v) { return v == 0.0; }) &&
        (!has_p || (msg.R == sensor_msgs::CameraInfo::_R_type{1, 0, 0, 0, 1, 0, 0, 0, 1} && msg.P[0] == msg.K[0] &&
                    msg.P[2] == msg.K[2] && msg.P[5] == msg.K[4] && msg.P[6] == msg.K[5]));
    if (!identity_rectification) {
      fail("camera_info.roi", "a region of interest of a rectified image whose rectification moves pixels "
                              "(distortion, R or P other than K) is not supported: send the full image");
    }
  }
  const std::uint32_t bx = std::max<std::uint32_t>(1, msg.binning_x), by = std::max<std::uint32_t>(1, msg.binning_y);
  const std::uint32_t window_width = no_roi ? msg.width : roi.width, window_height = no_roi ? msg.height : roi.height;
  if (bx > window_width || by > window_height) {
    fail("camera_info.binning", "binning " + str(bx) + "x" + str(by) + " is larger than the " + str(window_width) +
                                    "x" + str(window_height) + " image");
  }
  c.fx /= bx;
  c.fy /= by;
  c.cx = (c.cx - (no_roi ? 0.0 : roi.x_offset)) / bx;
  c.cy = (c.cy - (no_roi ? 0.0 : roi.y_offset)) / by;
  c.width = static_cast<int>(window_width / bx);
  c.height = static_cast<int>(window_height / by);
  if (!c.valid()) fail("camera_info", "invalid pinhole camera");
  return c;
}

sensor_msgs::CameraInfo cameraToMsg(const PinholeCamera& camera) {
  sensor_msgs::CameraInfo msg;
  msg.width = static_cast<std::uint32_t>(camera.width);
  msg.height = static_cast<std::uint32_t>(camera.height);
  msg.distortion_model = "plumb_bob";
  msg.D.assign(5, 0.0);
  msg.K = {camera.fx, 0.0, camera.cx, 0.0, camera.fy, camera.cy, 0.0, 0.0, 1.0};
  msg.R = {1.0, 0.0, 0.0, 0.0, 1.0, 0.0, 0.0, 0.0, 1.0};
  msg.P = {camera.fx, 0.0, camera.cx, 0.0, 0.0, camera.fy, camera.cy, 0.0, 0.0, 0.0, 1.0, 0.0};
  return msg;
}

namespace {
// At most one warning per 10 s of wall time. ROS_WARN_THROTTLE reads ros::Time::now(), which
// throws where the conversions run without a node (rosbag API tools and tests, the fuzzers).
void warnThrottled(const std::string& text) {
  static std::mutex mutex;
  static double last = -1e300;
  const double now = ros::WallTime::now().toSec();
  std::lock_guard<std::mutex> lock(mutex);
  if (now - last < 10.0) return;
  last = now;
  ROS_WARN("%s", text.c_str());
}
}  // namespace

Sim3 sim3FromPose(const geometry_msgs::Pose& pose, double scale) {
  const auto& q = pose.orientation;
  const auto& p = pose.position;
  checkTranslation(p.x, p.y, p.z, "pose.position");
  const Eigen::Quaterniond quat(q.w, q.x, q.y, q.z);
  const double n = quat.norm();
  if (!finite(n) || n < 1e-9) fail("pose.orientation", "must be a finite, non-zero quaternion");
  const std::string norm_warning = quaternionNormWarning(n, "pose.orientation");
  if (!norm_warning.empty()) warnThrottled(norm_warning);
  if (!finite(scale) || !(scale > 0.0)) fail("scale", "must be finite and > 0, got " + str(scale));
  checkScale(scale, "scale");
  return Sim3(scale, quat.normalized(), Eigen::Vector3d(p.x, p.y, p.z));
}

geometry_msgs::Pose poseFromSim3(const Sim3& sim3) {
  geometry_msgs::Pose pose;
  pose.position.x = sim3.translation().x();
  pose.position.y = sim3.translation().y();
  pose.position.z = sim3.translation().z();
  Eigen::Quaterniond q = sim3.quaternion().normalized();
  if (q.w() < 0.0) q.coeffs() *= -1.0;
  pose.orientation.x = q.x();
  pose.orientation.y = q.y();
  pose.orientation.z = q.z();
  pose.orientation.w = q.w();
  return pose;
}

// --- merge result -----------------------------------------------------------------------------

pcr_pro::MapEdge edgeToMsg(const RegistrationReport& report, const EdgeNames& names, const ros::Time& stamp) {
  if (!report.transform || !report.covariance) {
    throw InputError("edgeToMsg: the report has no transform or covariance (status " +
                     std::string(statusName(report.status)) + ")");
  }
  pcr_pro::MapEdge msg;
  msg.header.frame_id = names.target_frame;
  msg.header.stamp = stamp;
  msg.source_agent = names.source_agent;
  msg.target_agent = names.target_agent;
  msg.source_frame = names.source_frame;
  msg.target_frame = names.target_frame;
  msg.source_keyframe = report.source_keyframe.value_or(-1);
  msg.target_keyframe = report.target_keyframe.value_or(-1);
  msg.pose.pose = poseFromSim3(*report.transform);
  const Matrix6d information = report.information ? *report.information : Matrix6d::Zero();
  for (int r = 0; r < 6; ++r) {
    for (int c = 0; c < 6; ++c) {
      msg.pose.covariance[6 * r + c] = (*report.covariance)(r, c);
      msg.information[6 * r + c] = information(r, c);
    }
  }
  msg.scale = report.transform->scale();
  msg.scale_stddev = report.scale_stddev.value_or(0.0);
  msg.fitness_rmse = report.fitness_rmse.value_or(0.0);
  msg.correspondences = report.correspondences.value_or(0);
  return msg;
}

EdgeData edgeFromMsg(const pcr_pro::MapEdge& msg) {
  EdgeData e;
  e.target_source = sim3FromPose(msg.pose.pose, msg.scale);
  for (int r = 0; r < 6; ++r) {
    for (int c = 0; c < 6; ++c) {
      e.covariance(r, c) = msg.pose.covariance[6 * r + c];
      e.information(r, c) = msg.information[6 * r + c];
    }
  }
  e.scale_stddev = msg.scale_stddev;
  e.fitness_rmse = msg.fitness_rmse;
  e.correspondences = msg.correspondences;
  e.source_keyframe = msg.source_keyframe;
  e.target_keyframe = msg.target_keyframe;
  e.names = {msg.source_agent, msg.target_agent, msg.source_frame, msg.target_frame};
  return e;
}

geometry_msgs::TransformStamped rigidTransformToMsg(const Sim3& target_source, const std::string& target_frame,
                                                    const std::string& source_frame, const ros::Time& stamp) {
  geometry_msgs::TransformStamped t;
  t.header.frame_id = target_frame;
  t.header.stamp = stamp;
  t.child_frame_id = source_frame;
  const geometry_msgs::Pose pose = poseFromSim3(target_source);
  t.transform.translation.x = pose.position.x;
  t.transform.translation.y = pose.position.y;
  t.transform.translation.z = pose.position.z;
  t.transform.rotation = pose.orientation;
  return t;
}

}  // namespace ros_bridge
}  // namespace pcr_pro
