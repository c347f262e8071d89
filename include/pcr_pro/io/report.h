/**
 * @file report.h
 * @brief The registration result as reported by the offline tools (result YAML contract).
 */
#pragma once

#include <optional>
#include <string>
#include <vector>

#include "pcr_pro/geometry/sim3.h"
#include "pcr_pro/geometry/types.h"

namespace pcr_pro {

/// Wall time of each stage [ms].
struct StageTimings {
  double features = 0.0;
  double relative_pose = 0.0;
  double scale = 0.0;  ///< scale detection (+ scale estimation in the merge pipeline)
  double filters = 0.0;
  double icp = 0.0;
  double covariance = 0.0;
  /// merge only: the keyframe pairs' camp arbitration (pooling, refining and judging the camps
  /// when the pairs split); the stages above are the first pass's alone
  double arbitration = 0.0;
  double total = 0.0;
};

/// One keyframe pair of a merge and what became of it.
struct KeyframePairReport {
  long source_keyframe = 0;
  long target_keyframe = 0;
  int inliers = 0;        ///< relative-pose inliers
  int depth_matches = 0;  ///< inliers with depth on both sides
  bool used = false;      ///< part of the keyframe estimate
  std::string note;       ///< how it was used, or why not
};

/**
 * @brief The merge as a Sim(3) constraint between two keyframes, the kind of edge LSD-SLAM's own
 * pose graph holds: S_target_source expressed between the anchor keyframes' cameras. A pose-graph
 * user attaches it to these two keyframes (not to the map origins): each monocular map's scale
 * drifts, so the similarity holds where the maps overlap, at these keyframes, and its covariance
 * includes how much it changes from one overlapping keyframe pair to the next.
 */
struct KeyframeEdge {
  long source_keyframe = 0;  ///< anchor keyframe of the source map
  long target_keyframe = 0;  ///< anchor keyframe of the target map
  /// target keyframe camera <- source keyframe camera, p_t = s R p_s + t in each keyframe's own
  /// camera units: pose_target⁻¹ ∘ S_target_source ∘ pose_source (poses camera -> map).
  Sim3 transform;
  /// 7x7 covariance of (x y z rot_x rot_y rot_z log-scale), left perturbation in the target
  /// keyframe's camera frame [target camera units², rad², -]: the map-frame covariance moved by
  /// the adjoint of pose_target⁻¹ (similarityAdjoint()).
  Matrix7d covariance = Matrix7d::Zero();
};

/// Everything a registration reports. Optional parts are absent when the run stopped early.
struct RegistrationReport {
  Status status = Status::kInvalidInput;
  std::string message;
  std::optional<long> source_keyframe;
  std::optional<long> target_keyframe;
  std::optional<Sim3> transform;  ///< S_target_source
  std::optional<Matrix6d> covariance;
  std::optional<Matrix6d> information;
  std::optional<double> scale_stddev;
  std::optional<double> condition_number;
  std::optional<double> noise_stddev;
  std::optional<double> fitness_rmse;
  std::optional<int> correspondences;
  std::optional<bool> scale_difference_detected;
  std::optional<double> detected_scale_ratio;
  int icp_iterations = 0;
  /// pcr_pro_icp (registerClouds()): the target cloud was registered onto the (noisier) source
  /// and the result inverted (icp.sampling.register_noisier_as_target); absent or false otherwise.
  std::optional<bool> reversed;
  // --- the merge's keyframe estimate and the refinement's verdict (pcr_pro_merge, node)
  std::optional<Sim3> keyframe_transform;           ///< keyframe-only S_target_source
  std::optional<Matrix6d> keyframe_covariance;      ///< its 6x6 covariance (same convention)
  std::optional<double> keyframe_scale_stddev;      ///< its scale's standard deviation [-]
  std::optional<bool> refinement_kept;              ///< the refined estimate is the result
  /// ... combined with the keyframe estimate (merge.combine_with_keyframe_estimate): the result is
  /// their information-weighted mean, not the refined estimate itself
  std::optional<bool> refinement_combined;
  std::optional<double> refinement_chi2;            ///< squared Mahalanobis distance refined vs keyframe [-]
  /// The refinement registered the target onto the source and inverted the result (the source
  /// map was the noisier one: icp.sampling.register_noisier_as_target); absent or false otherwise.
  std::optional<bool> refinement_reversed;
  std::optional<double> overlap;                    ///< overlap of the aligned maps [-]
  std::vector<KeyframePairReport> keyframe_pairs;   ///< every verified keyframe pair
  std::optional<KeyframeEdge> keyframe_edge;        ///< the result between the anchor keyframes (merge, OK)
  StageTimings timings;
};

/// @return the report as the contract's result YAML (one document, keys in contract order)
std::string toYaml(const RegistrationReport& report);

}  // namespace pcr_pro
