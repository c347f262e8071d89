// All ROS message <-> pcr_pro core conversions (see msg_conversion.h).
#include "pcr_pro/ros/msg_conversion.h"

#include <opencv2/imgproc.hpp>
#include <ros/console.h>
#include <ros/time.h>
#include <sensor_msgs/image_encodings.h>

#include <algorithm>
#include <cmath>
#include <cstring>
#include <map>
#include <mutex>
#include <sstream>

#include "pcr_pro/io/plausibility.h"

namespace pcr_pro {
namespace ros_bridge {

namespace {

[[noreturn]] void fail(const std::string& field, const std::string& what) { throw InputError(field + ": " + what); }

template <typename T>
std::string str(const T& v) {
  std::ostringstream s;
  s << v;
  return s.str();
}

// Largest image side accepted [px] (also for CameraInfo and LSD keyframes): keeps every size
// product in range of int and of the 64-bit arithmetic below.
constexpr std::uint32_t kMaxImageSide = 100000;
// Similarity poses: scale in [1/kMaxScale, kMaxScale], |translation| components <= kMaxTranslation;
// beyond that a pose is degenerate (it would put map points at infinity or on one point).
constexpr double kMaxScale = 1e9;
constexpr double kMaxTranslation = 1e9;

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

bool finite(double v) { return std::isfinite(v); }

// A translation within the pose bounds. @throw InputError naming `field`
void checkTranslation(double x, double y, double z, const std::string& field) {
  if (!finite(x) || !finite(y) || !finite(z)) fail(field, "must be finite");
  if (std::abs(x) > kMaxTranslation || std::abs(y) > kMaxTranslation || std::abs(z) > kMaxTranslation) {
    fail(field, "degenerate: a component beyond " + str(kMaxTranslation) + " map units");
  }
}

// A similarity scale within the pose bounds. @throw InputError naming `field`
void checkScale(double s, const std::string& field) {
  if (!finite(s) || !(s >= 1.0 / kMaxScale) || s > kMaxScale) {
    fail(field, "degenerate similarity: scale must be finite and in [1e-9, 1e9], got " + str(s));
  }
}

}  // namespace

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
  if (msg.binning_x > 1 || msg.binning_y > 1) {
    fail("camera_info.binning", "binning " + str(msg.binning_x) + "x" + str(msg.binning_y) + " is not supported (0 or 1)");
  }
  const auto& roi = msg.roi;
  const bool full_roi = (roi.width == 0 && roi.height == 0 && roi.x_offset == 0 && roi.y_offset == 0) ||
                        (roi.x_offset == 0 && roi.y_offset == 0 && roi.width == msg.width && roi.height == msg.height);
  if (!full_roi) fail("camera_info.roi", "a region of interest is not supported (the full image only)");
  if (!has_p) {
    for (std::size_t i = 0; i < msg.D.size(); ++i) {
      if (msg.D[i] != 0.0) {
        fail("camera_info.D", "distortion coefficient " + str(i) + " is " + str(msg.D[i]) +
                                  " and P is all zero: send the rectified image (image_rect) with P, or an "
                                  "undistorted image with D all zero");
      }
    }
  }
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

// --- images -----------------------------------------------------------------------------------

cv::Mat greyImageFromMsg(const sensor_msgs::Image& msg, const std::string& field) {
  namespace enc = sensor_msgs::image_encodings;
  int channels = 0, code = -1;
  if (msg.encoding == enc::MONO8) {
    channels = 1;
  } else if (msg.encoding == enc::RGB8) {
    channels = 3, code = cv::COLOR_RGB2GRAY;
  } else if (msg.encoding == enc::BGR8) {
    channels = 3, code = cv::COLOR_BGR2GRAY;
  } else if (msg.encoding == enc::RGBA8) {
    channels = 4, code = cv::COLOR_RGBA2GRAY;
  } else if (msg.encoding == enc::BGRA8) {
    channels = 4, code = cv::COLOR_BGRA2GRAY;
  } else {
    fail(field, "unsupported encoding '" + printable(msg.encoding) + "' (mono8, rgb8, bgr8, rgba8, bgra8)");
  }
  checkImageLayout(msg, static_cast<std::size_t>(channels), field);
  const cv::Mat view(static_cast<int>(msg.height), static_cast<int>(msg.width), CV_8UC(channels),
                     const_cast<std::uint8_t*>(msg.data.data()), msg.step);
  cv::Mat grey;
  if (channels == 1) {
    grey = view.clone();
  } else {
    cv::cvtColor(view, grey, code);
  }
  return grey;
}

sensor_msgs::Image greyImageToMsg(const cv::Mat& image) {
  if (image.type() != CV_8UC1) throw InputError("greyImageToMsg: image must be CV_8UC1");
  sensor_msgs::Image msg;
  msg.width = static_cast<std::uint32_t>(image.cols);
  msg.height = static_cast<std::uint32_t>(image.rows);
  msg.encoding = sensor_msgs::image_encodings::MONO8;
  msg.is_bigendian = 0;
  msg.step = msg.width;
  msg.data.resize(static_cast<std::size_t>(msg.step) * msg.height);
  for (int r = 0; r < image.rows; ++r) std::memcpy(&msg.data[r * msg.step], image.ptr(r), msg.width);
  return msg;
}

cv::Mat depthFromMsg(const sensor_msgs::Image& msg, const std::string& field) {
  namespace enc = sensor_msgs::image_encodings;
  const bool is_float = msg.encoding == enc::TYPE_32FC1;
  const bool is_mm = msg.encoding == enc::TYPE_16UC1 || msg.encoding == enc::MONO16;
  if (!is_float && !is_mm) fail(field, "unsupported encoding '" + printable(msg.encoding) + "' (32FC1, 16UC1)");
  if (msg.is_bigendian) fail(field, "big-endian depth data is not supported");
  checkImageLayout(msg, is_float ? 4 : 2, field);
  const int rows = static_cast<int>(msg.height), cols = static_cast<int>(msg.width);
  cv::Mat depth(rows, cols, CV_32FC1);
  for (int r = 0; r < rows; ++r) {
    const std::uint8_t* src = &msg.data[static_cast<std::size_t>(r) * msg.step];
    float* dst = depth.ptr<float>(r);
    for (int c = 0; c < cols; ++c) {
      if (is_float) {
        float v;
        std::memcpy(&v, src + 4 * c, 4);
        dst[c] = std::isfinite(v) && v > 0.0f ? v : 0.0f;
      } else {
        std::uint16_t v;
        std::memcpy(&v, src + 2 * c, 2);
        dst[c] = static_cast<float>(v) * 1e-3f;
      }
    }
  }
  return depth;
}

sensor_msgs::Image depthToMsg(const cv::Mat& depth) {
  if (depth.type() != CV_32FC1) throw InputError("depthToMsg: depth must be CV_32FC1");
  sensor_msgs::Image msg;
  msg.width = static_cast<std::uint32_t>(depth.cols);
  msg.height = static_cast<std::uint32_t>(depth.rows);
  msg.encoding = sensor_msgs::image_encodings::TYPE_32FC1;
  msg.is_bigendian = 0;
  msg.step = msg.width * 4;
  msg.data.resize(static_cast<std::size_t>(msg.step) * msg.height);
  for (int r = 0; r < depth.rows; ++r) std::memcpy(&msg.data[r * msg.step], depth.ptr(r), msg.step);
  return msg;
}

sensor_msgs::Image depthToMsgMillimetres(const cv::Mat& depth) {
  if (depth.type() != CV_32FC1) throw InputError("depthToMsgMillimetres: depth must be CV_32FC1");
  sensor_msgs::Image msg;
  msg.width = static_cast<std::uint32_t>(depth.cols);
  msg.height = static_cast<std::uint32_t>(depth.rows);
  msg.encoding = sensor_msgs::image_encodings::TYPE_16UC1;
  msg.is_bigendian = 0;
  msg.step = msg.width * 2;
  msg.data.resize(static_cast<std::size_t>(msg.step) * msg.height);
  for (int r = 0; r < depth.rows; ++r) {
    const float* src = depth.ptr<float>(r);
    for (int c = 0; c < depth.cols; ++c) {
      const double mm = std::round(static_cast<double>(src[c]) * 1000.0);
      const std::uint16_t v = std::isfinite(mm) && mm > 0.0 && mm <= 65535.0 ? static_cast<std::uint16_t>(mm) : 0;
      std::memcpy(&msg.data[r * msg.step + 2 * c], &v, 2);
    }
  }
  return msg;
}

// --- keyframes and clouds ---------------------------------------------------------------------

DecodedKeyframe keyframeFromMsg(const pcr_pro::Keyframe& msg) {
  DecodedKeyframe out;
  out.frame_id = msg.header.frame_id;
  out.keyframe.id = static_cast<long>(msg.id);
  out.camera = cameraFromMsg(msg.camera_info);
  out.keyframe.image = greyImageFromMsg(msg.image, "image");
  if (out.keyframe.image.cols != out.camera.width || out.keyframe.image.rows != out.camera.height) {
    fail("image", "size " + str(out.keyframe.image.cols) + "x" + str(out.keyframe.image.rows) +
                      " != camera_info size " + str(out.camera.width) + "x" + str(out.camera.height));
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

Cloud cloudFromMsg(const sensor_msgs::PointCloud2& msg) {
  // width * height * point_step can exceed 64 bits (3 x 32 bits): compare without overflow.
  const std::uint64_t points = static_cast<std::uint64_t>(msg.width) * msg.height;
  const bool fits = msg.point_step == 0 || points <= msg.data.size() / msg.point_step;
  const std::uint64_t expected = fits ? points * msg.point_step : 0;
  if (!fits || expected != msg.data.size()) {
    fail("cloud", "width * height * point_step = " + str(msg.width) + " * " + str(msg.height) + " * " +
                      str(msg.point_step) + (fits ? " = " + str(expected) : std::string()) + " != data size " +
                      str(msg.data.size()));
  }
  if (msg.height > 0 && static_cast<std::uint64_t>(msg.row_step) != static_cast<std::uint64_t>(msg.width) * msg.point_step) {
    fail("cloud", "row_step " + str(msg.row_step) + " != width * point_step " +
                      str(static_cast<std::uint64_t>(msg.width) * msg.point_step));
  }
  if (msg.is_bigendian) fail("cloud", "big-endian data is not supported");
  int offsets[3] = {-1, -1, -1};
  bool is_double[3] = {false, false, false};
  const char* names[3] = {"x", "y", "z"};
  for (const auto& f : msg.fields) {
    for (int k = 0; k < 3; ++k) {
      if (f.name != names[k]) continue;
      if (f.datatype != sensor_msgs::PointField::FLOAT32 && f.datatype != sensor_msgs::PointField::FLOAT64) {
        fail("cloud", std::string("field ") + names[k] + " must be FLOAT32 or FLOAT64, got datatype " +
                          str(static_cast<int>(f.datatype)));
      }
      is_double[k] = f.datatype == sensor_msgs::PointField::FLOAT64;
      if (static_cast<std::uint64_t>(f.offset) + (is_double[k] ? 8 : 4) > msg.point_step) {
        fail("cloud", std::string("field ") + names[k] + " at offset " + str(f.offset) + " lies outside point_step " +
                          str(msg.point_step));
      }
      offsets[k] = static_cast<int>(f.offset);
    }
  }
  for (int k = 0; k < 3; ++k) {
    if (offsets[k] < 0) fail("cloud", std::string("no field '") + names[k] + "'");
  }
  const std::size_t n = static_cast<std::size_t>(msg.width) * msg.height;
  Cloud cloud(3, static_cast<Eigen::Index>(n));
  Eigen::Index kept = 0;
  for (std::size_t i = 0; i < n; ++i) {
    const std::uint8_t* p = &msg.data[i * msg.point_step];
    Eigen::Vector3d v;
    for (int k = 0; k < 3; ++k) {
      if (is_double[k]) {
        double d;
        std::memcpy(&d, p + offsets[k], 8);
        v[k] = d;
      } else {
        float f;
        std::memcpy(&f, p + offsets[k], 4);
        v[k] = f;
      }
    }
    if (v.allFinite()) cloud.col(kept++) = v;
  }
  cloud.conservativeResize(3, kept);
  return cloud;
}

sensor_msgs::PointCloud2 cloudToMsg(const Cloud& cloud, const std::string& frame_id, const ros::Time& stamp) {
  sensor_msgs::PointCloud2 msg;
  msg.header.frame_id = frame_id;
  msg.header.stamp = stamp;
  msg.height = 1;
  msg.width = static_cast<std::uint32_t>(cloud.cols());
  const char* names[3] = {"x", "y", "z"};
  for (int k = 0; k < 3; ++k) {
    sensor_msgs::PointField f;
    f.name = names[k];
    f.offset = static_cast<std::uint32_t>(4 * k);
    f.datatype = sensor_msgs::PointField::FLOAT32;
    f.count = 1;
    msg.fields.push_back(f);
  }
  msg.is_bigendian = false;
  msg.point_step = 12;
  msg.row_step = msg.point_step * msg.width;
  msg.is_dense = true;
  msg.data.resize(static_cast<std::size_t>(msg.row_step));
  for (Eigen::Index i = 0; i < cloud.cols(); ++i) {
    const float xyz[3] = {static_cast<float>(cloud(0, i)), static_cast<float>(cloud(1, i)),
                          static_cast<float>(cloud(2, i))};
    std::memcpy(&msg.data[static_cast<std::size_t>(i) * 12], xyz, 12);
  }
  return msg;
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

// --- LSD-SLAM ---------------------------------------------------------------------------------

namespace {
constexpr std::size_t kLsdPointBytes = 12;  // float idepth, float idepth_var, uchar color[4]
constexpr std::size_t kLsdFramePoseBytes = 32;  // int32 id, float camToWorld[7]
constexpr std::size_t kLsdConstraintBytes = 12;  // int32 from, int32 to, float err
}  // namespace

Sim3 sim3FromLsd(const float* v) {
  for (int i = 0; i < 7; ++i) {
    if (!std::isfinite(v[i])) fail("camToWorld", "element " + str(i) + " is not finite");
  }
  const Eigen::Quaterniond q(v[3], v[0], v[1], v[2]);
  const double s = q.norm();
  if (!(s > 1e-9)) fail("camToWorld", "degenerate similarity: quaternion part (scale) is zero");
  checkScale(s, "camToWorld");
  checkTranslation(v[4], v[5], v[6], "camToWorld");
  return Sim3(s, q.normalized(), Eigen::Vector3d(v[4], v[5], v[6]));
}

std::array<float, 7> sim3ToLsd(const Sim3& sim3) {
  const Eigen::Quaterniond q = sim3.quaternion().normalized();
  const double s = sim3.scale();
  return {static_cast<float>(s * q.x()), static_cast<float>(s * q.y()), static_cast<float>(s * q.z()),
          static_cast<float>(s * q.w()), static_cast<float>(sim3.translation().x()),
          static_cast<float>(sim3.translation().y()), static_cast<float>(sim3.translation().z())};
}

LsdKeyframe lsdKeyframeFromMsg(const lsd_slam_viewer::keyframeMsg& msg) {
  LsdKeyframe kf;
  kf.id = msg.id;
  kf.time = msg.time;
  if (msg.width == 0 || msg.height == 0 || msg.width > kMaxImageSide || msg.height > kMaxImageSide) {
    fail("width/height", "image size must be > 0 and <= " + str(kMaxImageSide) + " a side, got " + str(msg.width) +
                             "x" + str(msg.height));
  }
  kf.camera.fx = msg.fx;
  kf.camera.fy = msg.fy;
  kf.camera.cx = msg.cx;
  kf.camera.cy = msg.cy;
  kf.camera.width = static_cast<int>(msg.width);
  kf.camera.height = static_cast<int>(msg.height);
  if (!kf.camera.valid() || !std::isfinite(msg.cx) || !std::isfinite(msg.cy)) {
    fail("fx/fy/cx/cy", "invalid intrinsics (fx " + str(msg.fx) + ", fy " + str(msg.fy) + ", cx " + str(msg.cx) +
                            ", cy " + str(msg.cy) + ")");
  }
  const std::size_t n = static_cast<std::size_t>(msg.width) * msg.height;
  if (msg.pointcloud.size() != n * kLsdPointBytes) {
    fail("pointcloud", "size " + str(msg.pointcloud.size()) + " != width * height * 12 = " + str(n * kLsdPointBytes) +
                           (msg.pointcloud.empty() ? " (a keyframe without depth)" : ""));
  }
  kf.cam_to_world = sim3FromLsd(msg.camToWorld.data());
  const int rows = static_cast<int>(msg.height), cols = static_cast<int>(msg.width);
  kf.idepth.create(rows, cols, CV_32FC1);
  kf.idepth_var.create(rows, cols, CV_32FC1);
  kf.image.create(rows, cols, CV_8UC1);
  const std::uint8_t* p = msg.pointcloud.data();
  for (int r = 0; r < rows; ++r) {
    float* id_row = kf.idepth.ptr<float>(r);
    float* var_row = kf.idepth_var.ptr<float>(r);
    std::uint8_t* img_row = kf.image.ptr<std::uint8_t>(r);
    for (int c = 0; c < cols; ++c, p += kLsdPointBytes) {
      std::memcpy(&id_row[c], p, 4);
      std::memcpy(&var_row[c], p + 4, 4);
      img_row[c] = p[8];
    }
  }
  return kf;
}

lsd_slam_viewer::keyframeMsg lsdKeyframeToMsg(const LsdKeyframe& kf) {
  lsd_slam_viewer::keyframeMsg msg;
  msg.id = static_cast<std::int32_t>(kf.id);
  msg.time = kf.time;
  msg.isKeyframe = true;
  const std::array<float, 7> c = sim3ToLsd(kf.cam_to_world);
  std::copy(c.begin(), c.end(), msg.camToWorld.begin());
  msg.fx = static_cast<float>(kf.camera.fx);
  msg.fy = static_cast<float>(kf.camera.fy);
  msg.cx = static_cast<float>(kf.camera.cx);
  msg.cy = static_cast<float>(kf.camera.cy);
  msg.width = static_cast<std::uint32_t>(kf.idepth.cols);
  msg.height = static_cast<std::uint32_t>(kf.idepth.rows);
  msg.pointcloud.resize(static_cast<std::size_t>(msg.width) * msg.height * kLsdPointBytes);
  std::uint8_t* p = msg.pointcloud.data();
  for (int r = 0; r < kf.idepth.rows; ++r) {
    for (int c2 = 0; c2 < kf.idepth.cols; ++c2, p += kLsdPointBytes) {
      const float idepth = kf.idepth.at<float>(r, c2);
      const float var = kf.idepth_var.at<float>(r, c2);
      const std::uint8_t grey = kf.image.empty() ? 0 : kf.image.at<std::uint8_t>(r, c2);
      std::memcpy(p, &idepth, 4);
      std::memcpy(p + 4, &var, 4);
      p[8] = p[9] = p[10] = p[11] = grey;
    }
  }
  return msg;
}

LsdGraph lsdGraphFromMsg(const lsd_slam_viewer::keyframeGraphMsg& msg) {
  if (msg.frameData.size() != static_cast<std::size_t>(msg.numFrames) * kLsdFramePoseBytes) {
    fail("frameData", "size " + str(msg.frameData.size()) + " != numFrames * 32 = " + str(msg.numFrames) + " * 32");
  }
  if (msg.constraintsData.size() != static_cast<std::size_t>(msg.numConstraints) * kLsdConstraintBytes) {
    fail("constraintsData",
         "size " + str(msg.constraintsData.size()) + " != numConstraints * 12 = " + str(msg.numConstraints) + " * 12");
  }
  LsdGraph graph;
  std::map<std::int32_t, std::uint32_t> first_of;  // keyframe id -> its first frameData entry
  for (std::uint32_t i = 0; i < msg.numFrames; ++i) {
    const std::uint8_t* p = &msg.frameData[i * kLsdFramePoseBytes];
    std::int32_t id;
    float v[7];
    std::memcpy(&id, p, 4);
    std::memcpy(v, p + 4, 28);
    // Two poses for one keyframe: which one holds is undefined, so the message is refused.
    const auto [it, fresh] = first_of.emplace(id, i);
    if (!fresh) {
      fail("frameData[" + str(i) + "]", "duplicate keyframe id " + str(id) + " (also frameData[" + str(it->second) + "])");
    }
    try {
      graph.poses.emplace_back(id, sim3FromLsd(v));
    } catch (const InputError& e) {
      fail("frameData[" + str(i) + "] (keyframe " + str(id) + ")", e.what());
    }
  }
  for (std::uint32_t i = 0; i < msg.numConstraints; ++i) {
    const std::uint8_t* p = &msg.constraintsData[i * kLsdConstraintBytes];
    LsdConstraint c;
    std::int32_t from, to;
    std::memcpy(&from, p, 4);
    std::memcpy(&to, p + 4, 4);
    std::memcpy(&c.error, p + 8, 4);
    c.from = from;
    c.to = to;
    graph.constraints.push_back(c);
  }
  return graph;
}

lsd_slam_viewer::keyframeGraphMsg lsdGraphToMsg(const LsdGraph& graph) {
  lsd_slam_viewer::keyframeGraphMsg msg;
  msg.numFrames = static_cast<std::uint32_t>(graph.poses.size());
  msg.frameData.resize(graph.poses.size() * kLsdFramePoseBytes);
  for (std::size_t i = 0; i < graph.poses.size(); ++i) {
    const std::int32_t id = static_cast<std::int32_t>(graph.poses[i].first);
    const std::array<float, 7> v = sim3ToLsd(graph.poses[i].second);
    std::memcpy(&msg.frameData[i * kLsdFramePoseBytes], &id, 4);
    std::memcpy(&msg.frameData[i * kLsdFramePoseBytes + 4], v.data(), 28);
  }
  msg.numConstraints = static_cast<std::uint32_t>(graph.constraints.size());
  msg.constraintsData.resize(graph.constraints.size() * kLsdConstraintBytes);
  for (std::size_t i = 0; i < graph.constraints.size(); ++i) {
    const std::int32_t from = graph.constraints[i].from, to = graph.constraints[i].to;
    std::memcpy(&msg.constraintsData[i * kLsdConstraintBytes], &from, 4);
    std::memcpy(&msg.constraintsData[i * kLsdConstraintBytes + 4], &to, 4);
    std::memcpy(&msg.constraintsData[i * kLsdConstraintBytes + 8], &graph.constraints[i].error, 4);
  }
  return msg;
}

}  // namespace ros_bridge
}  // namespace pcr_pro
