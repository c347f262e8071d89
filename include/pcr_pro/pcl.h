/**
 * @file pcl.h
 * @brief The C++ API for PCL and OpenCV users: pcl::PointCloud<PointT> to and from the core cloud,
 * keyframes from cv::Mat images, and one call that merges two agents' maps (README, "C++ API
 * for PCL users"). Header-only: link pcr_pro_core and PCL's common library.
 *
 * Example (the README's, compiled and run by test/pcl/test_pcl_api.cpp on a generated world):
 * @code
 * const pcr_pro::AgentMap a = pcr_pro::agentFromPcl(cloud_a, camera_a, images_a, depths_a, poses_a);
 * const pcr_pro::AgentMap b = pcr_pro::agentFromPcl(cloud_b, camera_b, images_b, depths_b, poses_b);
 * const pcr_pro::MergeResult merged = pcr_pro::mergeAgents(b, a);  // b's map into a's frame: S_a_b
 * @endcode
 */
#pragma once

#include <pcl/point_cloud.h>
#include <pcl/point_types.h>

#include <opencv2/core.hpp>
#include <opencv2/imgproc.hpp>

#include <cmath>
#include <limits>
#include <string>
#include <vector>

#include "pcr_pro/geometry/map_types.h"
#include "pcr_pro/geometry/sim3.h"
#include "pcr_pro/geometry/types.h"
#include "pcr_pro/merge/merge_options.h"
#include "pcr_pro/merge/merge_pipeline.h"

namespace pcr_pro {

/**
 * @brief The core cloud of a PCL cloud: the x, y, z of every point (any PointT with float x, y,
 * z: PointXYZ, PointXYZI, PointXYZRGB, PointNormal, ...); points with a non-finite coordinate
 * (PCL's NaN of organised clouds) are dropped, as the ROS cloud reader does.
 * @param[in] cloud PCL cloud [map units]
 * @return 3 x N cloud of the finite points, in order [map units]
 */
template <typename PointT>
Cloud fromPcl(const pcl::PointCloud<PointT>& cloud) {
  Cloud out(3, static_cast<Eigen::Index>(cloud.size()));
  Eigen::Index kept = 0;
  for (const PointT& p : cloud) {
    const Eigen::Vector3d v(p.x, p.y, p.z);
    if (v.allFinite()) out.col(kept++) = v;
  }
  out.conservativeResize(3, kept);
  return out;
}

/**
 * @brief A PCL cloud of the core cloud: x, y, z as float, the point type's other fields at their
 * defaults (intensity 0, colour black); unorganised (height 1) and dense.
 * @param[in] cloud 3 x N cloud [map units]
 * @return a new PCL cloud of N points (PointT: any point type with x, y, z)
 * @throw InputError when a coordinate does not fit a float (beyond about 3.4e38) or is not finite
 */
template <typename PointT = pcl::PointXYZ>
typename pcl::PointCloud<PointT>::Ptr toPcl(const Cloud& cloud) {
  typename pcl::PointCloud<PointT>::Ptr out(new pcl::PointCloud<PointT>);
  out->resize(static_cast<std::size_t>(cloud.cols()));
  constexpr double kFloatMax = static_cast<double>(std::numeric_limits<float>::max());
  for (Eigen::Index i = 0; i < cloud.cols(); ++i) {
    if (!cloud.col(i).allFinite() || cloud.col(i).cwiseAbs().maxCoeff() > kFloatMax) {
      throw InputError("toPcl: point " + std::to_string(i) + " is not finite or does not fit a float");
    }
    PointT& p = (*out)[static_cast<std::size_t>(i)];
    p.x = static_cast<float>(cloud(0, i));
    p.y = static_cast<float>(cloud(1, i));
    p.z = static_cast<float>(cloud(2, i));
  }
  return out;
}

/**
 * @brief A keyframe of images: the grey image the front end uses and, when given, a depth image.
 * @param[in] id keyframe id (reported as the merge's anchor keyframe)
 * @param[in] image rectified image: CV_8UC1 grey, CV_8UC3 BGR or CV_8UC4 BGRA (OpenCV's order)
 * @param[in] depth empty (no depth), CV_32FC1 [camera units] or CV_16UC1 [mm, REP 118]; depth
 *   along the optical axis, 0 or non-finite = unknown; the size of `image`
 * @param[in] camera the image's pinhole intrinsics [px]; its size must be the image's
 * @param[in] camera_to_map the keyframe's pose: p_map = s R p_cam + t [map units]
 * @return the keyframe (its images are copies)
 * @throw InputError naming the argument: another image type, a size mismatch, invalid intrinsics,
 *   a non-finite or non-positive pose scale
 */
inline MapKeyframe keyframeFromImages(long id, const cv::Mat& image, const cv::Mat& depth, const PinholeCamera& camera,
                                      const Sim3& camera_to_map) {
  const auto size = [](const cv::Mat& m) { return std::to_string(m.cols) + "x" + std::to_string(m.rows); };
  if (!camera.valid() || !std::isfinite(camera.cx) || !std::isfinite(camera.cy)) {
    throw InputError("keyframeFromImages: camera: invalid intrinsics");
  }
  if (image.cols != camera.width || image.rows != camera.height) {
    throw InputError("keyframeFromImages: image: size " + size(image) + " != camera size " +
                     std::to_string(camera.width) + "x" + std::to_string(camera.height));
  }
  MapKeyframe kf;
  kf.id = id;
  if (image.type() == CV_8UC1) {
    kf.image = image.clone();
  } else if (image.type() == CV_8UC3 || image.type() == CV_8UC4) {
    cv::cvtColor(image, kf.image, image.type() == CV_8UC3 ? cv::COLOR_BGR2GRAY : cv::COLOR_BGRA2GRAY);
  } else {
    throw InputError("keyframeFromImages: image: type must be CV_8UC1, CV_8UC3 (BGR) or CV_8UC4 (BGRA)");
  }
  if (!depth.empty()) {
    if (depth.size() != image.size()) {
      throw InputError("keyframeFromImages: depth: size " + size(depth) + " != image size " + size(image));
    }
    if (depth.type() == CV_16UC1) {
      depth.convertTo(kf.depth, CV_32FC1, 1e-3);  // REP 118 millimetres
    } else if (depth.type() == CV_32FC1) {
      kf.depth = depth.clone();
    } else {
      throw InputError("keyframeFromImages: depth: type must be CV_32FC1 or CV_16UC1 [mm]");
    }
    // NaN (every comparison false), +inf and non-positive depths: unknown (0)
    const cv::Mat known = (kf.depth > 0.0f) & (kf.depth < std::numeric_limits<float>::infinity());
    kf.depth.setTo(0.0f, ~known);
  }
  const double s = camera_to_map.scale();
  if (!std::isfinite(s) || !(s > 0.0) || !camera_to_map.translation().allFinite() ||
      !camera_to_map.rotation().allFinite()) {
    throw InputError("keyframeFromImages: camera_to_map: scale must be finite and > 0, all entries finite");
  }
  kf.pose = camera_to_map;
  return kf;
}

/**
 * @brief One agent's map from a PCL cloud and its keyframes' images (keyframe i gets id i).
 * @param[in] cloud the agent's map cloud [map units] (non-finite points dropped)
 * @param[in] camera the intrinsics of every image [px]
 * @param[in] images one image per keyframe (keyframeFromImages())
 * @param[in] depths empty (no depth), or one depth image per keyframe (each may be empty)
 * @param[in] poses one camera -> map similarity per keyframe
 * @param[in] frame_id the map's frame name
 * @return the map as the merge takes it
 * @throw InputError when the vectors' sizes differ, or as keyframeFromImages() naming the keyframe
 */
template <typename PointT>
AgentMap agentFromPcl(const pcl::PointCloud<PointT>& cloud, const PinholeCamera& camera, const std::vector<cv::Mat>& images,
                      const std::vector<cv::Mat>& depths, const std::vector<Sim3>& poses,
                      const std::string& frame_id = "map") {
  if (poses.size() != images.size() || (!depths.empty() && depths.size() != images.size())) {
    throw InputError("agentFromPcl: " + std::to_string(images.size()) + " images, " + std::to_string(depths.size()) +
                     " depths and " + std::to_string(poses.size()) + " poses: one each per keyframe (depths may be none)");
  }
  AgentMap map;
  map.frame_id = frame_id;
  map.cloud = fromPcl(cloud);
  map.camera = camera;
  for (std::size_t i = 0; i < images.size(); ++i) {
    try {
      map.keyframes.push_back(keyframeFromImages(static_cast<long>(i), images[i], depths.empty() ? cv::Mat() : depths[i],
                                                 camera, poses[i]));
    } catch (const InputError& e) {
      throw InputError("agentFromPcl: keyframe " + std::to_string(i) + ": " + e.what());
    }
  }
  return map;
}

/**
 * @brief Merges the source agent's map into the target's, as pcr_pro_merge does: one
 * MergePipeline built from `options` (mergeMaps()), keyframe pair chosen automatically.
 * @param[in] source the map to align (e.g. agentFromPcl())
 * @param[in] target the map it is aligned to
 * @param[in] options the merge's options (default: MergeOptions())
 * @return report.status OK with S_target_source (report.transform), its covariance and
 *   information; otherwise the stage that refused and why (report.message)
 * @throw InputError on invalid options
 */
inline MergeResult mergeAgents(const AgentMap& source, const AgentMap& target,
                               const MergeOptions& options = MergeOptions()) {
  return mergeMaps(source, target, MergeRequest(), options);
}

}  // namespace pcr_pro
