/**
 * @file merge_pipeline.h
 * @brief The PCR-Pro merge of two agents' maps as four stage objects, in the shape of a
 * constraint builder (fast estimate, prune, refine):
 *   1. KeyframeFrontEnd: SIFT once per keyframe (cached), vote preselection, FLANN matching and
 *      OpenGV relative pose of the candidate keyframe pairs;
 *   2. SimilarityInitializer: keyframe depth, Kalman-filter scale and Sim(3) per verified pair,
 *      pooled into one robust keyframe estimate; disagreeing pairs dropped;
 *   3. MapRegistration: filters once, one target k-d tree, overlap-aware similarity ICP with the
 *      keyframe matches as anchors, covariance with the spatial-block spread;
 *   4. MergeGates: the refinement only when it agrees with the keyframes; overlap check.
 */
#pragma once

#include <optional>
#include <string>

#include "pcr_pro/io/pose_graph.h"
#include "pcr_pro/io/report.h"
#include "pcr_pro/merge/keyframe_front_end.h"
#include "pcr_pro/merge/map_registration.h"
#include "pcr_pro/merge/merge_gates.h"
#include "pcr_pro/merge/merge_options.h"
#include "pcr_pro/merge/similarity_initializer.h"

namespace pcr_pro {

/// Diagnostics of a merge, beside the contract report.
struct MergeDiagnostics {
  int keyframe_pairs = 0;          ///< keyframe pairs there were (before the vote preselection)
  int candidate_pairs = 0;         ///< keyframe pairs matched in full and given a relative pose
  int verified_pairs = 0;          ///< candidate pairs with a verified relative pose
  int used_pairs = 0;              ///< verified pairs in the keyframe estimate
  int dropped_pairs = 0;           ///< verified pairs dropped as inconsistent with the others
  int distant_pairs = 0;           ///< verified pairs set aside as too far from the best pair (merge.local_keyframes)
  int features_computed = 0;       ///< keyframes whose SIFT features were computed by this merge
  int features_cached = 0;         ///< keyframes whose features came from the cache
  int pairs_cached = 0;            ///< candidate pairs whose matches and relative pose came from the cache
  /// candidate pairs that verified in an earlier merge, added because no preselected pair verified
  /// (FrontEndResult::earlier_pairs)
  int earlier_pairs = 0;
  int vote_rows_computed = 0;      ///< source keyframes whose votes were computed (KeyframeFrontEnd, PairCache)
  int feature_matches = 0;         ///< good SIFT matches of the anchor pair
  int relative_pose_inliers = 0;   ///< OpenGV inliers of the anchor pair
  int depth_matches = 0;           ///< inliers of the anchor pair with depth on both sides
  int keyframe_matches = 0;        ///< pooled 3D-3D inlier matches of the keyframe estimate
  double kalman_scale = 0.0;       ///< scale of the keyframe estimate [-]
  double kalman_scale_stddev = 0.0;  ///< its standard deviation [-]
  double overlap = 0.0;            ///< overlap of the aligned maps [-]
  bool refinement_kept = false;    ///< the reported estimate is the refined one ...
  /// ... combined with the keyframe estimate (GateVerdict::combined; `refined` holds the refinement's own)
  bool combined = false;
  double refinement_chi2 = 0.0;    ///< refined vs keyframe estimate, squared Mahalanobis [-]
  double disagreement_scale = 1.0;  ///< GateVerdict::disagreement_scale [-]
  double block_spread_factor = 1.0;  ///< enlargement of the covariance by the block spread [-]
  double anchor_weight = 1.0;        ///< Refinement::anchor_weight [-]
  bool refinement_reversed = false;  ///< Refinement::reversed
  double noise_ratio = 1.0;          ///< Refinement::noise_ratio [-]
  /// Re-noised registrations whose spread is in refined_covariance (Refinement::renoise_draws;
  /// 0 = none: merge.renoise_draws off, or no spread formed)
  int renoise_draws = 0;
  Matrix7d renoise_spread = Matrix7d::Zero();  ///< that spread (Refinement::renoise_spread)
  Sim3 initial;                    ///< the keyframe estimate of S_target_source
  Matrix7d keyframe_covariance = Matrix7d::Zero();  ///< its (predictive) covariance (similarity_fit.h)
  /// The keyframe estimate's covariance as the pooled mean's standard error alone (without the
  /// between-pair spread), for comparison (KeyframeEstimate::mean_covariance).
  Matrix7d keyframe_mean_covariance = Matrix7d::Zero();
  Matrix7d between_pairs = Matrix7d::Zero();  ///< between-pair covariance T (KeyframeEstimate::between)
  Matrix7d covariance = Matrix7d::Zero();           ///< the reported estimate's (similarity_fit.h)
  Status refinement_status = Status::kIcpNotConverged;  ///< of the refinement, whatever the gates did
  Sim3 refined;                                     ///< the refined estimate, also when not kept
  Matrix7d refined_covariance = Matrix7d::Zero();   ///< its covariance (similarity_fit.h)
  /// The refinement is the projective registration of the keyframes' depth
  /// (merge.projective_refinement), not the ICP on the map clouds.
  bool projective_refinement = false;
  /// With merge.projective_refinement: what the projective registration did (its keyframes,
  /// matches, jackknife and time), or why the ICP refinement was used instead; empty when off.
  std::string projective_note;
  int projective_keyframes_source = 0, projective_keyframes_target = 0;  ///< keyframes it registered
  double ms_projective = 0.0;  ///< its time [ms]
};

/// Result of a merge: the contract report plus diagnostics.
struct MergeResult {
  RegistrationReport report;
  MergeDiagnostics diagnostics;
};

/**
 * @brief The merge, built once from its options. Keeps the front end's feature cache across
 * merges (the node holds one pipeline; a re-sent keyframe is recomputed, see FeatureCache).
 */
class MergePipeline {
 public:
  /// @throw InputError naming the first invalid option (a caller's mistake: error rule, pcr_pro.h)
  explicit MergePipeline(const MergeOptions& options);

  /**
   * @brief Merges the source agent's map into the target agent's.
   *
   * Error rule (pcr_pro.h): the two maps and the requested keyframe ids describe data as a SLAM
   * system produced it, so every defect of theirs is a status, INVALID_INPUT with the reason:
   * an empty map cloud, no keyframes, invalid camera intrinsics, a keyframe image missing, not
   * 8-bit grey or of another size than the camera's, a non-finite pose, a requested keyframe
   * that is not (or no longer, for a streaming agent) in its map, a cloud the filters empty. An
   * agent that has not mapped anything yet is a normal state of a live system, not a bug of
   * the caller. The options, the caller's own choice, were checked (thrown) at construction.
   *
   * @param[in] source source agent (camera, keyframes, map cloud)
   * @param[in] target target agent
   * @param[in] request optional keyframe ids
   * @param[in] source_key, target_key feature-cache keys of the two maps (e.g. agent names)
   * @return report.status OK with S_target_source, covariance and information; otherwise the
   *   stage that refused (NOT_ENOUGH_MATCHES, RELATIVE_POSE_FAILED, SCALE_FAILED, NO_OVERLAP,
   *   INCONSISTENT, DEGENERATE, INVALID_INPUT for what the data does) and why in
   *   report.message. Never NaN or infinite numbers with OK.
   * @throw nothing for what the maps hold (see above); std::bad_alloc when memory runs out
   */
  MergeResult merge(const AgentMap& source, const AgentMap& target, const MergeRequest& request,
                    const std::string& source_key = "source", const std::string& target_key = "target");

  FeatureCache& featureCache() { return front_end_.cache(); }
  const MergeOptions& options() const { return options_; }

 private:
  MergeOptions options_;
  KeyframeFrontEnd front_end_;
  SimilarityInitializer initializer_;
  MergeGates gates_;
};

/**
 * @brief The merge's edge as the pose-graph export takes it (io/pose_graph.h): S_target_source,
 * its 7x7 covariance (MergeDiagnostics::covariance) and the anchor keyframe pair.
 * @return the edge when the merge is OK (report.status OK with a keyframe edge); empty otherwise
 */
std::optional<MergeEdge> poseGraphEdge(const MergeResult& result);

/**
 * @brief One merge with a pipeline of its own (no cache kept): MergePipeline(options).merge().
 * Error rule as MergePipeline::merge(): defects of the maps are a status (INVALID_INPUT), only
 * invalid options throw.
 * @return as MergePipeline::merge()
 * @throw InputError naming the first invalid option (the caller's mistake)
 */
MergeResult mergeMaps(const AgentMap& source, const AgentMap& target, const MergeRequest& request,
                      const MergeOptions& options);

}  // namespace pcr_pro
