#include <cmath>
#include <string>

#include "pcr_pro/merge/merge_options.h"
#include "io/yaml_block.h"

namespace pcr_pro {
namespace {

using config_detail::Block;
using config_detail::validateIn;

FeatureMatchingOptions loadMatching(const YAML::Node& node, const std::string& origin) {
  FeatureMatchingOptions o;
  Block b(node, "matching", origin);
  b.get("image_scale", &o.image_scale);
  b.get("nfeatures", &o.nfeatures);
  b.get("n_octave_layers", &o.n_octave_layers);
  b.get("contrast_threshold", &o.contrast_threshold);
  b.get("edge_threshold", &o.edge_threshold);
  b.get("sigma", &o.sigma);
  b.get("flann_trees", &o.flann_trees);
  b.get("flann_checks", &o.flann_checks);
  b.get("ratio_test", &o.ratio_test);
  b.get("symmetric", &o.symmetric);
  b.get("min_matches", &o.min_matches);
  b.finish();
  validateIn(o, origin);
  return o;
}

RelativePoseOptions loadRelativePose(const YAML::Node& node, const std::string& origin) {
  RelativePoseOptions o;
  Block b(node, "relative_pose", origin);
  std::string algorithm = relativePoseAlgorithmName(o.algorithm);
  b.get("algorithm", &algorithm);
  if (!parseRelativePoseAlgorithm(algorithm, &o.algorithm)) {
    b.fail("relative_pose.algorithm", "must be NISTER, STEWENIUS, SEVENPT or EIGHTPT");
  }
  b.get("pixel_error", &o.pixel_error);
  b.get("max_iterations", &o.max_iterations);
  b.get("probability", &o.probability);
  b.get("nonlinear_refinement", &o.nonlinear_refinement);
  b.get("min_inliers", &o.min_inliers);
  b.get("min_inlier_ratio", &o.min_inlier_ratio);
  b.get("min_spread_px", &o.min_spread_px);
  b.finish();
  validateIn(o, origin);
  return o;
}

KeyframeDepthOptions loadKeyframeDepth(const YAML::Node& node, const std::string& origin) {
  KeyframeDepthOptions o;
  Block b(node, "keyframe_depth", origin);
  b.get("neighborhood_radius_px", &o.neighborhood_radius_px);
  b.get("min_depth", &o.min_depth);
  b.get("max_depth", &o.max_depth);
  b.get("max_cloud_points_projected", &o.max_cloud_points_projected);
  b.get("depth_consistency", &o.depth_consistency);
  b.get("spatial_sigma_px", &o.spatial_sigma_px);
  b.get("max_relative_stddev", &o.max_relative_stddev);
  b.finish();
  validateIn(o, origin);
  return o;
}

ScaleEstimationOptions loadScaleEstimation(const YAML::Node& node, const std::string& origin) {
  ScaleEstimationOptions o;
  Block b(node, "scale_estimation", origin);
  b.get("relative_depth_noise", &o.relative_depth_noise);
  b.get("relative_lateral_noise", &o.relative_lateral_noise);
  b.get("gating_chi2", &o.gating_chi2);
  b.get("min_inliers", &o.min_inliers);
  b.get("min_inlier_ratio", &o.min_inlier_ratio);
  b.get("max_relative_stddev", &o.max_relative_stddev);
  b.get("passes", &o.passes);
  b.get("prior_relative_stddev", &o.prior_relative_stddev);
  b.finish();
  validateIn(o, origin);
  return o;
}

MergeGateOptions loadGates(const YAML::Node& node, const std::string& origin) {
  MergeGateOptions o;
  Block b(node, "merge", origin);
  b.get("refine_scale", &o.refine_scale);
  b.get("max_candidate_pairs", &o.max_candidate_pairs);
  b.get("pair_consistency_chi2", &o.pair_consistency_chi2);
  b.get("local_keyframes", &o.local_keyframes);
  b.get("refinement_agreement_chi2", &o.refinement_agreement_chi2);
  b.get("overlap_distance_factor", &o.overlap_distance_factor);
  b.get("min_overlap", &o.min_overlap);
  b.get("max_scale_disagreement", &o.max_scale_disagreement);
  b.get("max_icp_rotation_correction_deg", &o.max_icp_rotation_correction_deg);
  b.finish();
  validateIn(o, origin);
  return o;
}

InputLimits loadLimits(const YAML::Node& node, const std::string& origin) {
  InputLimits o;
  Block b(node, "limits", origin);
  b.get("max_cloud_points", &o.max_cloud_points);
  b.get("max_keyframes", &o.max_keyframes);
  b.get("max_image_pixels", &o.max_image_pixels);
  b.finish();
  validateIn(o, origin);
  return o;
}

}  // namespace

void validate(const MergeGateOptions& o) {
  if (!(o.max_candidate_pairs >= 0)) throw InputError("merge.max_candidate_pairs must be >= 0");
  if (o.local_keyframes < 0) throw InputError("merge.local_keyframes must be >= 0");
  if (!(o.pair_consistency_chi2 > 0.0) || !std::isfinite(o.pair_consistency_chi2)) {
    throw InputError("merge.pair_consistency_chi2 must be > 0");
  }
  if (!(o.refinement_agreement_chi2 > 0.0) || !std::isfinite(o.refinement_agreement_chi2)) {
    throw InputError("merge.refinement_agreement_chi2 must be > 0");
  }
  if (!(o.overlap_distance_factor > 0.0)) throw InputError("merge.overlap_distance_factor must be > 0");
  if (!(o.min_overlap >= 0.0 && o.min_overlap <= 1.0)) throw InputError("merge.min_overlap must be in [0, 1]");
  if (!(o.max_scale_disagreement > 0.0)) throw InputError("merge.max_scale_disagreement must be > 0");
  if (!(o.max_icp_rotation_correction_deg > 0.0)) {
    throw InputError("merge.max_icp_rotation_correction_deg must be > 0");
  }
}

void validate(const MergeOptions& o) {
  validate(o.matching);
  validate(o.relative_pose);
  validate(o.keyframe_depth);
  validate(o.scale_estimation);
  validate(o.merge);
  validate(o.registration);
  validate(o.limits);
}

MergeOptions parseMergeConfig(const std::string& text, const std::string& origin) {
  const YAML::Node root = config_detail::parseYaml(text, origin);
  MergeOptions o;
  if (!root || root.IsNull()) return o;
  if (!root.IsMap()) throw InputError(origin + ": top level must be a map");
  try {
    Block top(root, "", origin);
    o.matching = loadMatching(top.child("matching"), origin);
    o.relative_pose = loadRelativePose(top.child("relative_pose"), origin);
    o.keyframe_depth = loadKeyframeDepth(top.child("keyframe_depth"), origin);
    o.scale_estimation = loadScaleEstimation(top.child("scale_estimation"), origin);
    o.merge = loadGates(top.child("merge"), origin);
    config_detail::loadRegistrationBlocks(&top, &o.registration);
    o.limits = loadLimits(top.child("limits"), origin);
    top.finish();
  } catch (const YAML::Exception& e) {
    throw InputError(origin + ": malformed configuration: " + e.msg);
  }
  return o;
}

MergeOptions loadMergeConfig(const std::string& path) {
  return parseMergeConfig(config_detail::readConfigFile(path), path);
}

}  // namespace pcr_pro
