/**
 * @file lsd_keyframe.h
 * @brief An LSD-SLAM keyframe as the node keeps it (per-pixel inverse depth, its variance and
 * the grey image), and the LSD viewer's point filters that turn it into map points. ROS-free:
 * the message side is in msg_conversion.h.
 */
#pragma once

#include <opencv2/core.hpp>

#include <vector>

#include "pcr_pro/geometry/map_types.h"
#include "pcr_pro/geometry/sim3.h"
#include "pcr_pro/io/param_schema.h"

namespace pcr_pro {

/// The LSD-SLAM viewer's filters of keyframe points (parameters `lsd/...` of the merge node);
/// the defaults are the viewer's defaults (its dynamic-reconfigure values).
struct LsdFilterOptions {
  /// A point is kept when idepth_var * depth^4 <= this [keyframe depth units^2], > 0
  /// (viewer: scaledDepthVarTH = 10^-3).
  double scaled_depth_var_th = 1e-3;
  /// A point is kept when idepth_var * depth^4 * scale^2 <= this [map units^2], > 0
  /// (viewer: absDepthVarTH = 10^-1).
  double abs_depth_var_th = 1e-1;
  /// A point is kept when at least this many pixels of its 3x3 neighbourhood (itself included)
  /// have an inverse depth within sqrt(2 * idepth_var) of its own; 0 or 1 = no check, <= 9
  /// (viewer: minNearSupport = 7).
  int min_near_support = 7;
  /// Keep one point in this many, chosen at random with a fixed seed per keyframe id [-], >= 1
  /// (viewer: sparsifyFactor = 1).
  int sparsify_factor = 1;
};

/// Every parameter of LsdFilterOptions (ROS parameters `~lsd/...`): key, type, default (the member initialiser), range, unit, doc.
template <>
const ParamSchema<LsdFilterOptions>& paramSchema<LsdFilterOptions>();

/// @throw InputError naming the option ("lsd.min_near_support: must be in [0, 9], got 12")
void validate(const LsdFilterOptions& options);

/// One LSD-SLAM keyframe (lsd_slam_viewer/keyframeMsg, decoded).
struct LsdKeyframe {
  long id = 0;
  double time = 0.0;      ///< LSD-SLAM's frame time stamp [s]
  PinholeCamera camera;   ///< fx fy cx cy, width, height of the keyframe
  Sim3 cam_to_world;      ///< camToWorld: p_map = s * R * p_cam + t, p_cam in keyframe depth units
  cv::Mat idepth;         ///< CV_32FC1, inverse depth [1 / keyframe depth units], <= 0 = none
  cv::Mat idepth_var;     ///< CV_32FC1, variance of the inverse depth
  cv::Mat image;          ///< CV_8UC1, grey image (colour byte 0 of each pixel)
};

/// Points of an LSD keyframe that pass the filters.
struct LsdPoints {
  Cloud camera_points;  ///< in the keyframe's camera frame [keyframe depth units]
  cv::Mat depth;        ///< CV_32FC1 depth of the kept pixels, 0 elsewhere [keyframe depth units]
};

/**
 * @brief Applies the LSD viewer's filters to every pixel with a positive inverse depth (the
 * one-pixel image border is skipped, as the viewer does) and back-projects the kept ones. A
 * threshold test that is NaN (e.g. zero variance at a denormal inverse depth) fails, and points
 * whose back-projection is not finite are skipped: every returned point is finite.
 * @param[in] keyframe decoded keyframe
 * @param[in] options filter thresholds
 */
LsdPoints extractPoints(const LsdKeyframe& keyframe, const LsdFilterOptions& options);

/**
 * @brief The pipeline's keyframe: grey image, camToWorld as pose, and the keyframe's whole
 * semi-dense depth with its uncertainty. Every pixel with a finite inverse depth > 0 and a finite
 * variance > 0 gets depth = 1 / idepth and depth_stddev = sqrt(idepth_var) / idepth² (first-order
 * propagation) [keyframe depth units]; the others stay 0 (unknown). The viewer's filters are not
 * applied here: they are for display (and for the map cloud, extractPoints()); the keyframe depth
 * lookup weighs every pixel by its own variance instead (KeyframeDepth).
 * @param[in] keyframe decoded keyframe
 */
MapKeyframe toKeyframe(const LsdKeyframe& keyframe);

}  // namespace pcr_pro
