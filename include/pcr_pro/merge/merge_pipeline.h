/**
 * @file merge_pipeline.h
 * @brief The PCR-Pro merge of two agents' maps: keyframe matching (SIFT/FLANN), relative pose
 * (OpenGV RANSAC), keyframe depth, Kalman-filter scale, initial Sim(3), then scale detection,
 * filters, ICP with scale refinement and the closed-form covariance / information — with
 * quality gates so that maps that do not overlap are refused, not merged wrongly.
 */
#pragma once

#include <optional>
#include <string>

#include "pcr_pro/registration/config.h"
#include "pcr_pro/frontend/feature_matching.h"
#include "pcr_pro/io/input_limits.h"
#include "pcr_pro/frontend/keyframe_depth.h"
#include "pcr_pro/geometry/map_types.h"
#include "pcr_pro/frontend/relative_pose.h"
#include "pcr_pro/io/report.h"
#include "pcr_pro/frontend/scale_estimation.h"

namespace pcr_pro {

/// Keyframe pair selection and the quality gates against false merges (YAML block `merge`).
struct MergeGateOptions {
  /// Estimate the scale in the ICP refinement too (similarity ICP from the Kalman scale).
  bool refine_scale = true;
  /// When no keyframe ids are given and there are more keyframe pairs than this, only this many
  /// pairs, those with the most descriptor votes (keyframePairVotes()), get the full matching
  /// and relative pose [pairs], >= 0; 0 = every pair (cost grows with the product of the
  /// keyframe counts: 50 x 50 keyframes are 2500 pairs).
  int max_candidate_pairs = 10;
  /// Overlap check: a source point overlaps when its nearest target neighbour, after the
  /// merge, is closer than this many times the target's median point spacing [-], > 0.
  double overlap_distance_factor = 3.0;
  /// Fewest overlapping source points (fraction of the filtered source cloud) for a merge [-],
  /// in [0, 1].
  double min_overlap = 0.2;
  /// Largest relative disagreement between the ICP scale and the Kalman scale [-], > 0.
  double max_scale_disagreement = 0.2;
  /// Largest rotation the ICP may apply to the keyframe-based initial guess [deg], > 0.
  double max_icp_rotation_correction_deg = 15.0;
};

/// @throw InputError naming the option when out of range
void validate(const MergeGateOptions& options);

/// Configuration of every stage of the merge.
struct MergeOptions {
  FeatureMatchingOptions matching;
  RelativePoseOptions relative_pose;
  KeyframeDepthOptions keyframe_depth;
  ScaleEstimationOptions scale_estimation;
  MergeGateOptions merge;
  RegistrationOptions registration;  ///< scale_detection, filters, icp, covariance
  InputLimits limits;                ///< resource bounds on the inputs (block `limits`)
};

/// @throw InputError naming the first invalid option
void validate(const MergeOptions& options);

/**
 * @brief Parses a merge configuration (blocks matching, relative_pose, keyframe_depth,
 * scale_estimation, merge, scale_detection, filters, icp, covariance, limits; all optional).
 * @throw InputError "<origin>: <key>: <what>" on bad YAML, unknown keys, wrong types or ranges
 */
MergeOptions parseMergeConfig(const std::string& text, const std::string& origin);
/// @brief As parseMergeConfig() from a file. @throw InputError naming the file
MergeOptions loadMergeConfig(const std::string& path);

/// Which keyframes to use; unset = the pipeline chooses the pair with most verified inliers.
struct MergeRequest {
  std::optional<long> source_keyframe;
  std::optional<long> target_keyframe;
};

/// Diagnostics of the keyframe stages, beside the contract report.
struct MergeDiagnostics {
  int candidate_pairs = 0;         ///< keyframe pairs matched in full and tried
  int keyframe_pairs = 0;          ///< keyframe pairs there were (before the vote preselection)
  int feature_matches = 0;         ///< good SIFT matches of the chosen pair
  int relative_pose_inliers = 0;   ///< OpenGV inliers of the chosen pair
  int depth_matches = 0;           ///< inliers with depth on both sides
  double kalman_scale = 0.0;       ///< scale from the Kalman filter [-]
  double kalman_scale_stddev = 0.0;
  int kalman_inliers = 0;
  double overlap = 0.0;            ///< overlapping fraction of the filtered source cloud [-]
  Sim3 initial;                    ///< keyframe-based initial S_target_source
};

/// Result of a merge: the contract report plus diagnostics.
struct MergeResult {
  RegistrationReport report;
  MergeDiagnostics diagnostics;
};

/**
 * @brief Relative pose of one keyframe pair (the pipeline's relative pose stage): bearings of
 * the matched pixels (pixels_a in the target keyframe, pixels_b in the source keyframe), RANSAC
 * threshold from the mean focal length of the two cameras.
 * @throw InputError as estimateRelativePose()
 */
RelativePoseResult keyframePairPose(const FeatureMatches& matches, const PinholeCamera& target_camera,
                                    const PinholeCamera& source_camera, const RelativePoseOptions& options);

/// The keyframe-based guess of a verified keyframe pair (keyframeGuess()).
struct KeyframeGuess {
  ScaleEstimate scale;    ///< Kalman-filter scale (and translation magnitude) with its status
  int depth_matches = 0;  ///< relative pose inliers with depth on both sides
  Sim3 initial;           ///< S_target_source; meaningful when scale.status is kOk
};

/**
 * @brief The pipeline's keyframe depth, Kalman-filter scale and initial map-to-map similarity
 * for one keyframe pair and its relative pose.
 * @param[in] matches the pair's matches (pixels_a target, pixels_b source); pose.inliers index them
 * @throw InputError as the stages it runs
 */
KeyframeGuess keyframeGuess(const AgentMap& source, const MapKeyframe& source_keyframe, const AgentMap& target,
                            const MapKeyframe& target_keyframe, const FeatureMatches& matches,
                            const RelativePoseResult& pose, const MergeOptions& options);

/**
 * @brief Merges the source agent's map into the target agent's.
 * @param[in] source source agent (camera, keyframes, map cloud)
 * @param[in] target target agent
 * @param[in] request optional keyframe ids
 * @param[in] options configuration
 * @return report.status OK with S_target_source, covariance and information; otherwise the
 *         stage that failed (NOT_ENOUGH_MATCHES, RELATIVE_POSE_FAILED, SCALE_FAILED,
 *         ICP_NOT_CONVERGED, DEGENERATE, INVALID_INPUT) and why in report.message.
 * @throw InputError on invalid options
 */
MergeResult mergeMaps(const AgentMap& source, const AgentMap& target, const MergeRequest& request,
                      const MergeOptions& options);

}  // namespace pcr_pro
