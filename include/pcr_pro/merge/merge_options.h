/**
 * @file merge_options.h
 * @brief Configuration of every stage of the merge (config/merge.yaml) and what a caller asks
 * of one merge.
 */
#pragma once

#include <optional>
#include <string>

#include "pcr_pro/frontend/feature_matching.h"
#include "pcr_pro/frontend/keyframe_depth.h"
#include "pcr_pro/frontend/relative_pose.h"
#include "pcr_pro/frontend/scale_estimation.h"
#include "pcr_pro/io/input_limits.h"
#include "pcr_pro/registration/config.h"
#include "pcr_pro/registration/projective_registration.h"
#include "pcr_pro/io/param_schema.h"

namespace pcr_pro {

/// Keyframe pair selection and the quality gates against false merges (YAML block `merge`).
struct MergeGateOptions {
  /// Scale policy of the refinement: estimate the scale there too (similarity ICP from the
  /// keyframe estimate's scale); false keeps the keyframe estimate's scale and its stddev.
  bool refine_scale = true;
  /// The refinement weighs the keyframe matches against the map clouds by how far the clouds'
  /// own covariance understates their estimate's spread between spatial blocks of the overlap
  /// (the ICP's block spread factor f): one Gauss-Newton step at the ICP's final correspondences
  /// gives the matches f times their information. Maps that one similarity does not fit (scale
  /// drift, bending) pull a point-to-plane ICP along their distorted surfaces; the matches' 3D
  /// residuals measure the similarity of the overlap itself. On the bench's simulated worlds 61
  /// of 72 merges within the floors instead of 58, on its held-out seeds 137 of 144 instead of
  /// 136; costs the step and a second covariance (about 30 ms on the 70k-point merge).
  bool reweigh_keyframe_matches = true;
  /// A refinement kept is combined with the keyframe estimate instead of replacing it: the
  /// keyframe estimate acts as a prior. The reported estimate is the information-weighted mean
  /// of the keyframe estimate (its covariance, between-pair spread included) and the refinement,
  /// whose covariance R is raised by the agreement gate's excess g = max(1, χ² / 7) to
  /// g R + (g − 1) K: while the two agree as their covariances say, the plain information-
  /// weighted mean (the refinement, where the clouds are the more precise); beyond that the
  /// refinement counts g times less, since a noisy map's clouds share errors that their own
  /// covariance misses. Measured on the bench's merges (2026-12-04, against the refinement
  /// alone): simulated semi-dense worlds 69 of 72 within the floors instead of 67, held-out seeds
  /// 144 of 144 instead of 143, unequal noise 102 of 108 instead of 99, real cases 7 of 27 as
  /// before (their changes lie within the 7-Scenes truth's own accuracy). Off: the refined
  /// estimate is reported as it is (depth-camera clouds, where the keyframe pairs are the worse
  /// evidence: on 7-Scenes the mean scale error of the 18 merges was 0.46 % without and 0.62 %
  /// with, against a truth good to about 2.7 % in scale; docs/DESIGN.md).
  bool combine_with_keyframe_estimate = true;
  /// After the ICP refinement, the map clouds are re-noised this many times along their
  /// keyframes' rays, at the depth noise each map's cloud shows (ray_noise.h), and registered
  /// again from the refined estimate with the same keyframe matches; the spread of those
  /// estimates is added to the refinement's covariance R (MapRegistration::setRayNoise()),
  /// before the gates and the combination with the keyframe estimate [draws], >= 0; 0 = off.
  /// The closed form holds the normals and correspondences fixed and misses what re-fitting them
  /// does: started at the exact truth on the bench's worlds without drift, the refinement's
  /// rotation ANEES was 3.9 (inverse-depth noise 0.01) and 36 (0.03) with its covariance alone,
  /// 0.5 and 0.3 with the spread of four draws. Off by default: the combination reports the kept
  /// refinement's covariance, so with the spread in it the edges are conservative (on the bench,
  /// 2026-12-08, against the anchor pair's local truth: 6-DoF ANEES 0.57 simulated, 0.32
  /// held-out and 0.25 with unequal noise, 99-100 % under the χ² 95 % bound, against 1.17, 0.80
  /// and 0.71 off), and two draws cost about 140 ms of the 70k-point merge (about one ICP run
  /// each, on a core each). For a pose graph that must not be over-confident on noisy semi-dense
  /// maps. Not for the projective refinement, nor for pcr_pro_icp (no keyframes, no rays).
  /// docs/DESIGN.md, "Re-noising in the merge".
  int renoise_draws = 0;
  /// When no keyframe ids are given and there are more keyframe pairs than this, only this many
  /// pairs, those with the most descriptor votes (keyframePairVotes()), get the full matching
  /// and relative pose; every verified one of them contributes evidence [pairs], >= 0; 0 = every
  /// pair (cost grows with the product of the keyframe counts: 50 x 50 keyframes are 2500 pairs).
  int max_candidate_pairs = 10;
  /// A verified keyframe pair whose own estimate differs from the pooled one by more than this
  /// squared Mahalanobis distance (7 DoF, covariance of both) is dropped and reported [-], > 0
  /// (χ² with 7 DoF: 24.32 = 99.9 %).
  double pair_consistency_chi2 = 24.32;
  /// Locality of the edge: only keyframe pairs whose keyframes lie within this many keyframes
  /// (in id order, the order along each agent's path) of the best pair's contribute to it
  /// [keyframes], >= 0; 0 = every verified pair. Each monocular map's scale and orientation drift
  /// along its path, so distant pairs measure a different local similarity; on the real LSD-SLAM
  /// maps of lsd_slam_7scenes, 3 keyframes on either side cover the region where the two paths
  /// overlap (6 x 3 keyframes) and leave out the pairs where one map's start overlaps the other's
  /// middle (20-26 deg and 25-40 % away).
  int local_keyframes = 3;
  /// The refined estimate is kept only when it differs from the keyframe estimate by at most
  /// this squared Mahalanobis distance (7 DoF, both covariances); otherwise the keyframe
  /// estimate is reported, with the refinement's verdict [-], > 0 (24.32 = 99.9 %).
  double refinement_agreement_chi2 = 24.32;
  /// Overlap check: a point overlaps when its nearest neighbour in the other cloud, after the
  /// merge, is closer than this many times the larger of the two clouds' median point spacings
  /// [-], > 0.
  double overlap_distance_factor = 3.0;
  /// Fewest overlapping points for a merge: the larger of the source's overlapping fraction and
  /// the target's (so that a→b and b→a agree) [-], in [0, 1]. Below it: NO_OVERLAP.
  double min_overlap = 0.2;
  /// Largest relative disagreement between the refined scale and the keyframe scale [-], > 0.
  double max_scale_disagreement = 0.2;
  /// Largest rotation the refinement may apply to the keyframe estimate [deg], > 0.
  double max_icp_rotation_correction_deg = 15.0;
  /// When both maps' keyframes carry depth with a per-pixel standard deviation (LSD-SLAM
  /// keyframes: hasDepthUncertainty()), the refinement is the projective registration of the
  /// keyframes' depth (projective_registration.h, options in block `projective`) from the keyframe
  /// estimate, on the keyframes of the used pairs and those within local_keyframes of the anchor
  /// pair, instead of the ICP on the map clouds. Its estimate and covariance (keyframe jackknife
  /// plus the two directions' difference) then go through the same gates. When it does not
  /// converge, when its keyframe jackknife is not possible (a map's overlap holds fewer than two
  /// keyframes with matches, with projective.jackknife on: its covariance would then hold no
  /// keyframe's error), or the maps carry no depth uncertainty, the ICP refinement is used, and the
  /// message says why. Off by default for its cost: each keyframe with matches costs one more
  /// registration for the jackknife (docs/DESIGN.md: measured on the bench's worlds and on
  /// the real LSD-SLAM bags).
  bool projective_refinement = false;
};

/// Every parameter of MergeGateOptions (YAML block `merge`): key, type, default (the member initialiser), range, unit, doc.
template <>
const ParamSchema<MergeGateOptions>& paramSchema<MergeGateOptions>();

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
  ProjectiveOptions projective;      ///< the projective refinement (merge.projective_refinement)
  InputLimits limits;                ///< resource bounds on the inputs (block `limits`)
};

/// @throw InputError naming the first invalid option
void validate(const MergeOptions& options);

/**
 * @brief Parses a merge configuration (blocks matching, relative_pose, keyframe_depth,
 * scale_estimation, merge, scale_detection, filters, icp, covariance, projective, limits; all
 * optional).
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

}  // namespace pcr_pro
