#include <gtest/gtest.h>

#include "pcr_pro/registration/config.h"

namespace pcr_pro {
namespace {

const std::string kShipped = std::string(PCR_PRO_CONFIG_DIR) + "/icp.yaml";

std::string errorOf(const std::string& yaml) {
  try {
    parseRegistrationConfig(yaml, "test.yaml");
  } catch (const InputError& e) {
    return e.what();
  }
  return "";
}

TEST(Config, ShippedFileLoadsAndStatesTheStructDefaults) {
  // config/icp.yaml documents the defaults: its values must equal the option structs' defaults,
  // so that the defaults stay written once.
  const RegistrationOptions shipped = loadRegistrationConfig(kShipped);
  const RegistrationOptions d;
  EXPECT_EQ(shipped.scale_detection.trim_fraction, d.scale_detection.trim_fraction);
  EXPECT_EQ(shipped.scale_detection.ratio_threshold, d.scale_detection.ratio_threshold);
  EXPECT_EQ(shipped.filters.steps.size(), d.filters.steps.size());
  EXPECT_EQ(shipped.icp.max_source_points, d.icp.max_source_points);
  EXPECT_EQ(shipped.icp.coarse_source_points, d.icp.coarse_source_points);
  EXPECT_EQ(shipped.icp.extrapolation, d.icp.extrapolation);
  EXPECT_EQ(shipped.icp.normal_neighbors, d.icp.normal_neighbors);
  EXPECT_EQ(shipped.icp.max_correspondence_distance, d.icp.max_correspondence_distance);
  EXPECT_EQ(shipped.icp.trim_ratio, d.icp.trim_ratio);
  EXPECT_EQ(shipped.icp.min_correspondences, d.icp.min_correspondences);
  EXPECT_EQ(shipped.icp.error_metric, d.icp.error_metric);
  EXPECT_EQ(shipped.icp.estimate_scale, d.icp.estimate_scale);
  EXPECT_EQ(shipped.icp.max_scale_step, d.icp.max_scale_step);
  EXPECT_EQ(shipped.icp.min_scale_ratio, d.icp.min_scale_ratio);
  EXPECT_EQ(shipped.icp.max_scale_ratio, d.icp.max_scale_ratio);
  EXPECT_EQ(shipped.icp.max_iterations, d.icp.max_iterations);
  EXPECT_EQ(shipped.icp.min_relative_translation_change, d.icp.min_relative_translation_change);
  EXPECT_EQ(shipped.icp.min_rotation_change, d.icp.min_rotation_change);
  EXPECT_EQ(shipped.icp.min_scale_change, d.icp.min_scale_change);
  EXPECT_EQ(shipped.covariance.sensor_noise_stddev, d.covariance.sensor_noise_stddev);
  EXPECT_EQ(shipped.covariance.degeneracy_condition_threshold, d.covariance.degeneracy_condition_threshold);
  EXPECT_EQ(shipped.covariance.normal_neighbors, d.covariance.normal_neighbors);
}

TEST(Config, FilterChainIsReadInOrder) {
  const RegistrationOptions o = parseRegistrationConfig(
      "filters:\n"
      "  - crop: {axis: z, keep_fraction: 0.7, keep: upper}\n"
      "  - voxel_grid: {leaf_size: 0.1}\n"
      "  - outlier_removal: {mean_k: 5, stddev_multiplier: 1.5}\n"
      "  - random_sampling: {keep_ratio: 0.5, seed: 3}\n",
      "t");
  ASSERT_EQ(o.filters.steps.size(), 4u);
  EXPECT_EQ(o.filters.steps[0].type, FilterStep::Type::kCrop);
  EXPECT_EQ(o.filters.steps[0].crop.axis, 2);
  EXPECT_FALSE(o.filters.steps[0].crop.keep_lower);
  EXPECT_DOUBLE_EQ(o.filters.steps[0].crop.keep_fraction, 0.7);
  EXPECT_DOUBLE_EQ(o.filters.steps[1].voxel_grid.leaf_size, 0.1);
  EXPECT_EQ(o.filters.steps[2].outlier_removal.mean_k, 5);
  EXPECT_EQ(o.filters.steps[3].random_sampling.seed, 3u);
}

TEST(Config, ErrorsNameTheFileAndKey) {
  EXPECT_NE(errorOf("icp:\n  stop:\n    max_iterations: 0\n").find("max_iterations"), std::string::npos);
  EXPECT_NE(errorOf("icp:\n  stop:\n    max_iteration: 5\n").find("icp.stop.max_iteration: unknown key"),
            std::string::npos);
  EXPECT_NE(errorOf("icp:\n  outlier_rejection:\n    trim_ratio: abc\n").find("icp.outlier_rejection.trim_ratio"),
            std::string::npos);
  EXPECT_NE(errorOf("icp:\n  error_minimizer:\n    type: point_to_line\n").find("icp.error_minimizer.type"),
            std::string::npos);
  EXPECT_NE(errorOf("filters:\n  - blur: {}\n").find("filters[0]"), std::string::npos);
  EXPECT_NE(errorOf("filters:\n  - crop: {axis: w}\n").find("filters[0].crop.axis"), std::string::npos);
  EXPECT_NE(errorOf("covariance:\n  degeneracy_condition_threshold: 0.5\n").find("degeneracy_condition_threshold"),
            std::string::npos);
  EXPECT_NE(errorOf("scale_detection: {ratio_threshold: 1}\n").find("scale_detection.ratio_threshold"),
            std::string::npos);
  EXPECT_NE(errorOf("bogus: 1\n").find("bogus: unknown key"), std::string::npos);
  EXPECT_NE(errorOf("icp: [1, 2\n").find("invalid YAML"), std::string::npos);
  EXPECT_EQ(errorOf("icp: [1, 2\n").rfind("test.yaml", 0), 0u);
  EXPECT_THROW(loadRegistrationConfig("/nonexistent/icp.yaml"), InputError);
}

}  // namespace
}  // namespace pcr_pro
