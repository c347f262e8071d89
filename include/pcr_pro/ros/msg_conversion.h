/**
 * @file msg_conversion.h
 * @brief Every conversion between ROS messages and pcr_pro core types (tested by
 * test/ros/test_msg_conversion.cpp). Decoding validates the message and throws
 * pcr_pro::InputError naming the field at fault; the node turns that into a throttled warning.
 * Sources by kind: src/ros/msg_image.cpp (images through cv_bridge, keyframes), msg_cloud.cpp
 * (PointCloud2; pcl_conversions for the published clouds), msg_pose.cpp (camera, poses, the
 * edge), msg_lsd.cpp (LSD-SLAM).
 */
#pragma once

#include <geometry_msgs/Pose.h>
#include <geometry_msgs/TransformStamped.h>
#include <lsd_slam_viewer/keyframeGraphMsg.h>
#include <lsd_slam_viewer/keyframeMsg.h>
#include <pcr_pro/Keyframe.h>
#include <pcr_pro/MapEdge.h>
#include <ros/time.h>
#include <sensor_msgs/CameraInfo.h>
#include <sensor_msgs/Image.h>
#include <sensor_msgs/PointCloud2.h>

#include <array>
#include <string>
#include <utility>
#include <vector>

#include "pcr_pro/geometry/map_types.h"
#include "pcr_pro/io/report.h"
#include "pcr_pro/geometry/sim3.h"
#include "pcr_pro/geometry/types.h"
#include "pcr_pro/io/lsd_keyframe.h"
#include "pcr_pro/io/text_escape.h"

namespace pcr_pro {
namespace ros_bridge {

// --- text from messages -----------------------------------------------------------------------

/// A string taken from a message (an encoding, a frame id, an agent name) made safe to quote in a
/// one-line log or error message (the core's pcr_pro::printable(), io/text_escape.h).
using pcr_pro::printable;

// --- camera and poses -------------------------------------------------------------------------

/**
 * @brief Intrinsics of a rectified image: fx = K[0], fy = K[4], cx = K[2], cy = K[5].
 * @throw InputError when K is not a valid pinhole matrix (zero / non-finite focal lengths, zero
 *   size) or a distortion coefficient is non-zero (the image must be rectified)
 */
PinholeCamera cameraFromMsg(const sensor_msgs::CameraInfo& msg);
/// @return CameraInfo with K, P (= [K | 0]), identity R, no distortion ("plumb_bob", D = 0)
sensor_msgs::CameraInfo cameraToMsg(const PinholeCamera& camera);

/// @return (scale, R(orientation), position). @throw InputError on a zero / non-finite
/// quaternion, a non-finite position or one with a component beyond 1e9, or a scale outside [1e-9, 1e9]
Sim3 sim3FromPose(const geometry_msgs::Pose& pose, double scale);
/// @return the rigid part of a similarity as a pose (position = t, orientation = R)
geometry_msgs::Pose poseFromSim3(const Sim3& sim3);

// --- images -----------------------------------------------------------------------------------

/// @return a CV_8UC1 grey copy of mono8 / rgb8 / bgr8 / rgba8 / bgra8 images.
/// @throw InputError on other encodings, zero size, a side beyond 100000 px, step < width * pixel size or
/// data size != step * height
cv::Mat greyImageFromMsg(const sensor_msgs::Image& msg, const std::string& field = "image");
/// @return a mono8 image message of a CV_8UC1 image
sensor_msgs::Image greyImageToMsg(const cv::Mat& image);

/// @return CV_32FC1 depth [camera units] of a 32FC1 [camera units] or 16UC1 [mm, REP 118: value / 1000]
/// image; 0 and non-finite values mean unknown. @throw InputError as greyImageFromMsg(), and on big-endian data
cv::Mat depthFromMsg(const sensor_msgs::Image& msg, const std::string& field = "depth");
/// @return a 32FC1 depth image message [camera units]
sensor_msgs::Image depthToMsg(const cv::Mat& depth);
/// @return a 16UC1 depth image message [mm] (REP 118; values rounded, out of range -> 0)
sensor_msgs::Image depthToMsgMillimetres(const cv::Mat& depth);

// --- keyframes and clouds ---------------------------------------------------------------------

/// A decoded pcr_pro/Keyframe.
struct DecodedKeyframe {
  MapKeyframe keyframe;
  PinholeCamera camera;
  std::string frame_id;  ///< header.frame_id (may be empty)
};

/// @throw InputError naming the field (image, camera_info, pose, scale, depth) and the
/// mismatch (e.g. image size vs. camera_info size)
DecodedKeyframe keyframeFromMsg(const pcr_pro::Keyframe& msg);
/// @param[in] depth_millimetres write the depth as 16UC1 [mm] instead of 32FC1
pcr_pro::Keyframe keyframeToMsg(const MapKeyframe& keyframe, const PinholeCamera& camera, const std::string& frame_id,
                                const ros::Time& stamp, bool depth_millimetres = false);

/**
 * @brief The x, y, z fields (FLOAT32 or FLOAT64) of a point cloud; points with a non-finite
 * coordinate are dropped. Stricter than pcl::fromROSMsg, which takes neither FLOAT64 nor a
 * malformed layout and keeps NaN points.
 * @throw InputError when width * height * point_step != data.size() (computed without overflow), row_step != width *
 *   point_step, a field x / y / z is missing, duplicated, of count != 1, of another type, or
 *   outside point_step, or the data is big-endian
 */
Cloud cloudFromMsg(const sensor_msgs::PointCloud2& msg);
/// @return a dense, unorganised FLOAT32 x y z cloud, 12 bytes a point (the bags' clouds)
sensor_msgs::PointCloud2 cloudToMsg(const Cloud& cloud, const std::string& frame_id, const ros::Time& stamp);
/**
 * @brief The cloud as PCL publishes it: pcl::toROSMsg of a pcl::PointCloud<pcl::PointXYZ> (x y z
 * FLOAT32, point_step 16), which pcl::fromROSMsg<pcl::PointXYZ> reads with one copy; the node's
 * fused and aligned clouds.
 * @throw InputError when a point is not finite or does not fit a float (toPcl())
 */
sensor_msgs::PointCloud2 cloudToPclMsg(const Cloud& cloud, const std::string& frame_id, const ros::Time& stamp);

// --- merge result -----------------------------------------------------------------------------

/// Names carried by a MapEdge.
struct EdgeNames {
  std::string source_agent, target_agent;
  std::string source_frame, target_frame;
};

/**
 * @brief The edge of a successful merge (S_target_source, covariance, information, scale stddev).
 * @throw InputError when the report has no transform or covariance
 */
pcr_pro::MapEdge edgeToMsg(const RegistrationReport& report, const EdgeNames& names, const ros::Time& stamp);

/// The numbers of a MapEdge back as core types.
struct EdgeData {
  Sim3 target_source;
  Matrix6d covariance = Matrix6d::Zero();
  Matrix6d information = Matrix6d::Zero();
  double scale_stddev = 0.0;
  double fitness_rmse = 0.0;
  int correspondences = 0;
  long source_keyframe = -1, target_keyframe = -1;
  EdgeNames names;
};
/// @throw InputError on a degenerate pose or scale
EdgeData edgeFromMsg(const pcr_pro::MapEdge& msg);

/// @return tf parent = target_frame, child = source_frame, the rigid part of S_target_source
geometry_msgs::TransformStamped rigidTransformToMsg(const Sim3& target_source, const std::string& target_frame,
                                                    const std::string& source_frame, const ros::Time& stamp);

// --- LSD-SLAM ---------------------------------------------------------------------------------

/**
 * @brief Sophus Sim3 as LSD-SLAM serialises it: [s*qx, s*qy, s*qz, s*qw, tx, ty, tz], the scale
 * being the norm of the quaternion part.
 * @throw InputError when non-finite, the quaternion part (scale) is (nearly) zero or outside [1e-9, 1e9], or a
 *   translation component is beyond 1e9
 */
Sim3 sim3FromLsd(const float* cam_to_world);
/// @return the 7 floats of a similarity in LSD-SLAM's layout
std::array<float, 7> sim3ToLsd(const Sim3& sim3);

/**
 * @brief Decodes an LSD-SLAM keyframe: pointcloud = width x height records {float idepth,
 * float idepth_var, uchar color[4]} (12 bytes), grey image = color[0].
 * @throw InputError on zero size, invalid intrinsics, a pointcloud of the wrong size (including
 *   empty: a keyframe without depth is of no use to the merge) or a degenerate camToWorld
 */
LsdKeyframe lsdKeyframeFromMsg(const lsd_slam_viewer::keyframeMsg& msg);
/// @return the message an LSD-SLAM keyframe is published as (isKeyframe = true)
lsd_slam_viewer::keyframeMsg lsdKeyframeToMsg(const LsdKeyframe& keyframe);

/// One constraint of an LSD-SLAM graph message.
struct LsdConstraint {
  int from = 0, to = 0;
  float error = 0.0f;
};
/// A decoded LSD-SLAM keyframe graph.
struct LsdGraph {
  std::vector<std::pair<long, Sim3>> poses;  ///< (keyframe id, camToWorld)
  std::vector<LsdConstraint> constraints;
};
/**
 * @brief Decodes frameData (numFrames x {int32 id, float[7] camToWorld}, 32 bytes) and
 * constraintsData (numConstraints x {int32 from, int32 to, float err}, 12 bytes).
 * @throw InputError when a data size does not match its count or a pose is degenerate
 */
LsdGraph lsdGraphFromMsg(const lsd_slam_viewer::keyframeGraphMsg& msg);
lsd_slam_viewer::keyframeGraphMsg lsdGraphToMsg(const LsdGraph& graph);

}  // namespace ros_bridge
}  // namespace pcr_pro
