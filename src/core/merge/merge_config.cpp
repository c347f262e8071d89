#include <string>

#include "pcr_pro/merge/merge_options.h"
#include "io/yaml_block.h"

namespace pcr_pro {

using config_detail::Block;
using config_detail::loadStage;

template <>
const ParamSchema<MergeGateOptions>& paramSchema<MergeGateOptions>() {
  using O = MergeGateOptions;
  using R = ParamRange;
  static const ParamSchema<O> schema{"merge", {
      {"refine_scale", &O::refine_scale, R::any(), "",
       "scale policy: the refinement estimates the scale too (else the keyframe estimate's scale is kept)"},
      {"reweigh_keyframe_matches", &O::reweigh_keyframe_matches, R::any(), "",
       "one Gauss-Newton step at the ICP's final correspondences with the keyframe matches weighed up by its block "
       "spread factor (how many times the clouds' own covariance is too small)"},
      {"combine_with_keyframe_estimate", &O::combine_with_keyframe_estimate, R::any(), "",
       "the keyframe estimate is a prior: a refinement kept is combined with it (information-weighted mean, the "
       "refinement's covariance raised by the agreement gate's excess max(1, chi2 / 7)); off = the refined estimate "
       "as it is (depth-camera clouds, where the keyframe pairs are the worse evidence)"},
      {"renoise_draws", &O::renoise_draws, R::atLeast(0), "draws",
       "after the ICP refinement, the map clouds re-noised along their keyframes' rays (at the noise each map's cloud "
       "shows) and registered again this many times; their spread is added to the refinement's covariance "
       "(conservative edges); 0 = off (about one ICP run per draw, on a core of its own)"},
      {"max_candidate_pairs", &O::max_candidate_pairs, R::atLeast(0), "pairs",
       "without keyframe ids, only the keyframe pairs with the most descriptor votes are matched in full; 0 = every "
       "pair (cost grows with the product of the keyframe counts)"},
      {"pair_consistency_chi2", &O::pair_consistency_chi2, R::above(0), "-",
       "a keyframe pair farther from the pooled estimate (squared Mahalanobis, 7 DoF; 24.32 = 99.9 %) is dropped"},
      {"local_keyframes", &O::local_keyframes, R::atLeast(0), "keyframes",
       "only pairs within this many keyframes (id order, along each path) of the best pair make the edge; 0 = all"},
      {"refinement_agreement_chi2", &O::refinement_agreement_chi2, R::above(0), "-",
       "a refinement farther from the keyframe estimate (squared Mahalanobis, 7 DoF) is not kept"},
      {"overlap_distance_factor", &O::overlap_distance_factor, R::above(0), "median point spacings",
       "overlap radius"},
      {"min_overlap", &O::min_overlap, R::closed(0, 1), "-",
       "the larger of the source's and the target's overlapping fraction below this: NO_OVERLAP"},
      {"max_scale_disagreement", &O::max_scale_disagreement, R::above(0), "-",
       "a refinement that changes the keyframe scale by more (relative) is ignored, or refused when the clouds fit it clearly better"},
      {"max_icp_rotation_correction_deg", &O::max_icp_rotation_correction_deg, R::above(0), "deg",
       "a refinement that rotates the keyframe estimate by more is ignored, or refused when the clouds fit it clearly better"},
      {"projective_refinement", &O::projective_refinement, R::any(), "",
       "when both maps' keyframes carry depth with a per-pixel standard deviation (LSD-SLAM), refine by the projective "
       "registration of the keyframes' depth (block projective) instead of the ICP on the map clouds, when it "
       "converges and its keyframe jackknife is possible; costs one more registration per keyframe with matches"},
  }};
  return schema;
}

void validate(const MergeGateOptions& o) { checkRanges(paramSchema<MergeGateOptions>(), o); }

void validate(const MergeOptions& o) {
  validate(o.matching);
  validate(o.relative_pose);
  validate(o.keyframe_depth);
  validate(o.scale_estimation);
  validate(o.merge);
  validate(o.registration);
  validate(o.projective);
  validate(o.limits);
}

MergeOptions parseMergeConfig(const std::string& text, const std::string& origin) {
  MergeOptions o;
  config_detail::loadTopLevel(text, origin, [&o](Block* top) {
    o.matching = loadStage<FeatureMatchingOptions>(top);
    o.relative_pose = loadStage<RelativePoseOptions>(top);
    o.keyframe_depth = loadStage<KeyframeDepthOptions>(top);
    o.scale_estimation = loadStage<ScaleEstimationOptions>(top);
    o.merge = loadStage<MergeGateOptions>(top);
    config_detail::loadRegistrationBlocks(top, &o.registration);
    o.projective = loadStage<ProjectiveOptions>(top);
    o.limits = loadStage<InputLimits>(top);
  });
  return o;
}

MergeOptions loadMergeConfig(const std::string& path) {
  return parseMergeConfig(config_detail::readConfigFile(path), path);
}

}  // namespace pcr_pro
