/**
 * @file map_types.h
 * @brief One agent's map as the merge pipeline sees it: camera, keyframes, map cloud.
 */
#pragma once

#include <opencv2/core.hpp>

#include <map>
#include <string>
#include <vector>

#include "pcr_pro/geometry/sim3.h"
#include "pcr_pro/geometry/types.h"

namespace pcr_pro {

/// Pinhole camera of rectified images (REP-103 optical frame: x right, y down, z forward).
struct PinholeCamera {
  double fx = 0.0, fy = 0.0;  ///< focal lengths [px]
  double cx = 0.0, cy = 0.0;  ///< principal point [px]
  int width = 0, height = 0;  ///< image size [px]

  /// @return true when fx, fy > 0, width, height > 0 and all finite
  bool valid() const;
  /// @return the unit bearing vector normalize(K⁻¹ [u v 1]ᵀ)
  Eigen::Vector3d bearing(double u, double v) const;
  /// Projects a camera-frame point; @return false when z <= 0. (u, v) may lie outside the image.
  bool project(const Eigen::Vector3d& p, double* u, double* v) const;
  /// @return mean focal length (fx + fy) / 2 [px]
  double focal() const { return 0.5 * (fx + fy); }
};

/// A keyframe of one agent. (Not named `Keyframe`: the ROS message pcr_pro/Keyframe is the C++
/// type pcr_pro::Keyframe, and both must compile in one translation unit of the ROS layer.)
/// A copy shares its images' pixels with the original (cv::Mat copies are shallow): replace an
/// image (assign a new cv::Mat, or clone() first) rather than writing into a copy's pixels.
struct MapKeyframe {
  long id = 0;
  cv::Mat image;  ///< 8-bit grey (CV_8UC1), the camera's rectified image
  /// Depth along the optical axis (CV_32FC1) in camera units (before the pose scale), 0 or
  /// non-finite = unknown; empty when the keyframe has no depth image.
  cv::Mat depth;
  /// Standard deviation of `depth` per pixel (CV_32FC1) [camera units], 0 or non-finite =
  /// unknown; empty when the depth has no per-pixel uncertainty (depth images of bundles and of
  /// pcr_pro/Keyframe messages): the scale stage's noise model (ScaleEstimationOptions) then
  /// applies. LSD-SLAM keyframes carry it from their inverse-depth variance (toKeyframe()).
  cv::Mat depth_stddev;
  /// camera -> map similarity: p_map = scale * R * p_cam + position
  Sim3 pose;
};

/// One agent's map: the input of the merge pipeline (from a bundle or from ROS messages).
struct AgentMap {
  std::string frame_id = "map";
  Cloud cloud;  ///< map point cloud in the map frame [map units]
  PinholeCamera camera;
  std::vector<MapKeyframe> keyframes;
};

/// Each keyframe id of `map` -> its rank along the path: how many of the map's keyframes have a
/// smaller id. Ids grow along the path in LSD-SLAM and in the simulator, so |rank difference| is
/// the distance along the path that merge.local_keyframes bounds (the front end's extra pairs,
/// the initializer's neighbourhood, the projective refinement's keyframes).
std::map<long, long> keyframeRanks(const AgentMap& map);

}  // namespace pcr_pro
