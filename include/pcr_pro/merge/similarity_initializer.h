/**
 * @file similarity_initializer.h
 * @brief The merge's fast estimate, stage 2: for every verified keyframe pair, the keyframe
 * depth, the Kalman-filter scale and the pair's own initial Sim(3); then one robust Sim(3) from
 * the 3D-3D matches of all pairs pooled (with each pair's relative-pose rotation), a consistency
 * check of the pairs against each other (a pair that disagrees beyond its uncertainty is
 * dropped and reported), and a covariance that holds the pairs' disagreement. When no pair has
 * the depth matches for a scale of its own, their depth matches pooled give one joint estimate
 * (see SimilarityInitializer::run()).
 */
#pragma once

#include <string>
#include <vector>

#include "pcr_pro/frontend/scale_estimation.h"
#include "pcr_pro/geometry/map_types.h"
#include "pcr_pro/geometry/similarity_fit.h"
#include "pcr_pro/merge/keyframe_front_end.h"
#include "pcr_pro/merge/merge_options.h"

namespace pcr_pro {

/// The evidence of one verified keyframe pair.
struct PairEvidence {
  long source_keyframe = 0;
  long target_keyframe = 0;
  int feature_matches = 0;
  int inliers = 0;        ///< relative-pose inliers
  int depth_matches = 0;  ///< inliers with depth on both sides
  ScaleEstimate scale;    ///< the pair's Kalman-filter scale
  /// Distance between the two keyframes' cameras over the median distance of the target
  /// keyframe's matched points (both in target units), when the scale filter succeeded [-]: how
  /// far apart the two keyframes see the overlap from (0 = from the same place).
  double baseline_ratio = 0.0;
  bool has_estimate = false;  ///< the scale filter succeeded: estimate and covariance are set
  Sim3 estimate;              ///< the pair's own S_target_source
  Matrix7d covariance = Matrix7d::Zero();  ///< of estimate (similarity_fit.h convention)
  bool used = false;     ///< part of the pooled (or joint) estimate
  /// has an estimate and lies within merge.local_keyframes of the best pair: a candidate for pooling
  bool in_neighbourhood = false;
  std::string note;      ///< why not used, or how it was used
  double consistency_chi2 = 0.0;  ///< squared Mahalanobis distance to the pooled estimate
  /// The pair's Kalman-inlier matches as map points (source map, target map) with covariances.
  std::vector<PointMatch3> matches;
  /// The relative pose's rotation as a map-to-map rotation measurement.
  RotationMeasurement rotation;
};

/// The keyframe estimate of S_target_source.
struct KeyframeEstimate {
  /// kOk; or the status of the best pair's failure (NOT_ENOUGH_MATCHES, SCALE_FAILED, ...).
  Status status = Status::kScaleFailed;
  std::string message;
  /// S_target_source: one robust fit over the used pairs' matches and relative-pose rotations,
  /// started from the random-effects mean of the pairs' own estimates.
  Sim3 estimate;
  /**
   * Covariance of estimate against the local truth at one keyframe pair, such as the anchor
   * pair the edge is attached to (similarity_fit.h convention): mean_covariance + between, the
   * predictive covariance of the random-effects model. Each map's scale drift and distortion
   * make the similarity differ from place to place; between measures by how much.
   */
  Matrix7d covariance = Matrix7d::Zero();
  /// Of the estimate alone: covers both the fit's and the pooled mean's standard error.
  Matrix7d mean_covariance = Matrix7d::Zero();
  /// Between-pair covariance T (DerSimonian-Laird): how much the pairs' own similarities differ
  /// beyond their noise; zero with one pair. Its scale row and column are then rescaled to the
  /// anchor pair's own: the random-effects posterior of its local scale given its own estimate
  /// (the anchor is chosen close to the pooled estimate, so it deviates less than a random pair).
  Matrix7d between = Matrix7d::Zero();
  SimilarityFit fit;                       ///< of the pooled matches
  std::vector<PairEvidence> pairs;         ///< every verified pair, in the front end's order
  /// index in pairs of the edge's anchor pair: of the used pairs with at least half the most pooled
  /// inlier matches, the one whose own estimate lies closest to `estimate` (see selectPooledMatches)
  int anchor = -1;
  /// The pooled inlier matches (group = index in pairs), for the refinement.
  std::vector<PointMatch3> matches;
  int used_pairs = 0;
  int dropped_pairs = 0;  ///< set aside as inconsistent with the others
  int distant_pairs = 0;  ///< set aside as too far along a path from the best pair (merge.local_keyframes)
  double ms = 0.0;
};

/// Stage 2 of the merge (see the file comment).
class SimilarityInitializer {
 public:
  /// @throw InputError when the options are invalid
  explicit SimilarityInitializer(const MergeOptions& options);

  /**
   * @brief The keyframe estimate. When no verified pair has the depth matches (relative-pose
   * inliers with depth on both sides) for a Kalman scale of its own, the depth matches of the
   * pairs near the best one (merge.local_keyframes) are pooled instead: the similarity through
   * three of them that the most fit within their noise, then one robust fit over those. It needs
   * scale_estimation.min_inliers of them from two pairs at least, and a scale within
   * scale_estimation.max_relative_stddev; its pairs are then used with has_estimate false and a
   * note that says "used jointly", and its covariance is the fit's.
   * @param[in] source source map (cloud used for keyframes without depth images)
   * @param[in] target target map
   * @param[in] front the front end's pairs (only the verified ones are used)
   */
  KeyframeEstimate run(const AgentMap& source, const AgentMap& target, const FrontEndResult& front) const;

  /**
   * @brief The keyframe estimate pooled again around a hypothesis that other evidence supports
   * (the refinement on the map clouds), for when the pairs split into camps: the pairs kept are
   * those within four times the second-closest pair's distance of the hypothesis, or within
   * their own noise of it (merge.pair_consistency_chi2); the others are dropped with the reason.
   * The hypothesis only chooses the pairs: the estimate and its covariance are theirs alone.
   * @param[in] keyframes a result of run() with status kOk
   * @param[in] hypothesis S_target_source
   */
  KeyframeEstimate poolAround(const KeyframeEstimate& keyframes, const Sim3& hypothesis) const;

 private:
  /// Pools out's candidate pairs (used): consensus around the medoid pair, or around hypothesis.
  void pool(const Sim3* hypothesis, KeyframeEstimate* out) const;

  MergeOptions options_;
};

/**
 * @brief The edge's scale variance from the between-pair spread, conditioned on its anchor pair.
 * keyframes->between describes a pair taken at random; the anchor is chosen close to the pooled
 * estimate. With r the anchor's own log-scale deviation from keyframes->estimate, S its variance
 * and T = between(6, 6), the anchor's local deviation has the random-effects posterior
 * N(g r, g S), g = T / (T + S), and between's scale row and column are rescaled so that
 * between(6, 6) = g² r² + g S; covariance is then mean_covariance + between. Unchanged without
 * an anchor with an estimate of its own, or with T or S not positive.
 */
void conditionScaleOnAnchor(KeyframeEstimate* keyframes);

}  // namespace pcr_pro
