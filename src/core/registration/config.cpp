#include "pcr_pro/registration/config.h"

#include "io/yaml_block.h"

#include <yaml-cpp/yaml.h>

#include <filesystem>
#include <fstream>
#include <set>
#include <sstream>
#include <utility>

namespace pcr_pro {
namespace config_detail {
namespace {

ScaleDetectionOptions loadScaleDetection(const YAML::Node& node, const std::string& origin) {
  ScaleDetectionOptions o;
  Block b(node, "scale_detection", origin);
  b.get("trim_fraction", &o.trim_fraction);
  b.get("ratio_threshold", &o.ratio_threshold);
  b.finish();
  if (!(o.trim_fraction >= 0.0 && o.trim_fraction <= 0.45)) b.fail("scale_detection.trim_fraction", "must be in [0, 0.45]");
  if (!(o.ratio_threshold > 1.0)) b.fail("scale_detection.ratio_threshold", "must be > 1");
  return o;
}

FilterChainOptions loadFilters(const YAML::Node& node, const std::string& origin) {
  FilterChainOptions chain;
  if (!node || node.IsNull()) return chain;
  if (!node.IsSequence()) throw InputError(origin + ": filters: must be a list of filter steps");
  for (std::size_t i = 0; i < node.size(); ++i) {
    const std::string where = "filters[" + std::to_string(i) + "]";
    const YAML::Node item = node[i];
    if (!item.IsMap() || item.size() != 1) {
      throw InputError(origin + ": " + where + ": must be a map with one key (the filter type)");
    }
    const std::string type = item.begin()->first.as<std::string>();
    Block b(item.begin()->second, where + "." + type, origin);
    FilterStep step;
    if (type == "crop") {
      step.type = FilterStep::Type::kCrop;
      std::string axis = "y", keep = "lower";
      b.get("axis", &axis);
      b.get("keep_fraction", &step.crop.keep_fraction);
      b.get("keep", &keep);
      if (axis == "x") step.crop.axis = 0;
      else if (axis == "y") step.crop.axis = 1;
      else if (axis == "z") step.crop.axis = 2;
      else b.fail(b.path() + ".axis", "must be x, y or z");
      if (keep == "lower") step.crop.keep_lower = true;
      else if (keep == "upper") step.crop.keep_lower = false;
      else b.fail(b.path() + ".keep", "must be lower or upper");
    } else if (type == "voxel_grid") {
      step.type = FilterStep::Type::kVoxelGrid;
      b.get("leaf_size", &step.voxel_grid.leaf_size);
    } else if (type == "outlier_removal") {
      step.type = FilterStep::Type::kOutlierRemoval;
      b.get("mean_k", &step.outlier_removal.mean_k);
      b.get("stddev_multiplier", &step.outlier_removal.stddev_multiplier);
    } else if (type == "random_sampling") {
      step.type = FilterStep::Type::kRandomSampling;
      b.get("keep_ratio", &step.random_sampling.keep_ratio);
      b.get("seed", &step.random_sampling.seed);
    } else if (type == "max_points") {
      step.type = FilterStep::Type::kMaxPoints;
      b.get("max_points", &step.max_points.max_points);
      b.get("seed", &step.max_points.seed);
    } else {
      throw InputError(origin + ": " + where + ": unknown filter type '" + type +
                       "' (crop, voxel_grid, outlier_removal, random_sampling, max_points)");
    }
    b.finish();
    try {
      FilterChainOptions one;
      one.steps.push_back(step);
      validate(one);
    } catch (const InputError& e) {
      throw InputError(origin + ": " + where + ": " + e.what());
    }
    chain.steps.push_back(step);
  }
  return chain;
}

IcpOptions loadIcp(const YAML::Node& node, const std::string& origin) {
  IcpOptions o;
  Block icp(node, "icp", origin);
  {
    Block b(icp.child("sampling"), "icp.sampling", origin);
    b.get("max_source_points", &o.max_source_points);
    b.get("coarse_source_points", &o.coarse_source_points);
    b.finish();
  }
  {
    Block b(icp.child("matcher"), "icp.matcher", origin);
    b.get("normal_neighbors", &o.normal_neighbors);
    b.finish();
  }
  {
    Block b(icp.child("outlier_rejection"), "icp.outlier_rejection", origin);
    b.get("max_correspondence_distance", &o.max_correspondence_distance);
    b.get("reciprocal", &o.reciprocal);
    b.get("symmetric", &o.symmetric);
    b.get("reciprocal_tolerance", &o.reciprocal_tolerance);
    b.get("adaptive_distance_factor", &o.adaptive_distance_factor);
    b.get("trim_ratio", &o.trim_ratio);
    std::string kernel = robustKernelName(o.robust_kernel);
    b.get("robust_kernel", &kernel);
    if (!parseRobustKernel(kernel, &o.robust_kernel)) b.fail("icp.outlier_rejection.robust_kernel", "must be none or cauchy");
    b.get("kernel_width", &o.kernel_width);
    b.get("min_correspondences", &o.min_correspondences);
    b.finish();
  }
  {
    Block b(icp.child("error_minimizer"), "icp.error_minimizer", origin);
    std::string metric = errorMetricName(o.error_metric);
    b.get("type", &metric);
    if (!parseErrorMetric(metric, &o.error_metric)) b.fail("icp.error_minimizer.type", "must be point_to_point or point_to_plane");
    b.get("estimate_scale", &o.estimate_scale);
    b.get("max_scale_step", &o.max_scale_step);
    b.get("min_scale_ratio", &o.min_scale_ratio);
    b.get("max_scale_ratio", &o.max_scale_ratio);
    b.get("extrapolation", &o.extrapolation);
    b.finish();
  }
  {
    Block b(icp.child("stop"), "icp.stop", origin);
    b.get("max_iterations", &o.max_iterations);
    b.get("min_relative_translation_change", &o.min_relative_translation_change);
    b.get("min_rotation_change", &o.min_rotation_change);
    b.get("min_scale_change", &o.min_scale_change);
    b.finish();
  }
  icp.finish();
  validateIn(o, origin);
  return o;
}

CovarianceOptions loadCovariance(const YAML::Node& node, const std::string& origin) {
  CovarianceOptions o;
  Block b(node, "covariance", origin);
  std::string model = covarianceModelName(o.model);
  b.get("model", &model);
  if (!parseCovarianceModel(model, &o.model)) b.fail("covariance.model", "must be closed_form, calibrated or blocks");
  b.get("calibration_splits", &o.calibration_splits);
  b.get("calibration_max_points", &o.calibration_max_points);
  b.get("sensor_noise_stddev", &o.sensor_noise_stddev);
  b.get("degeneracy_condition_threshold", &o.degeneracy_condition_threshold);
  b.get("normal_neighbors", &o.normal_neighbors);
  b.finish();
  validateIn(o, origin);
  return o;
}

}  // namespace

YAML::Node parseYaml(const std::string& text, const std::string& origin) {
  try {
    return YAML::Load(text);
  } catch (const YAML::Exception& e) {
    throw InputError(origin + ": invalid YAML at line " + std::to_string(e.mark.line + 1) + ": " + e.msg);
  }
}

std::string readConfigFile(const std::string& path) {
  // Only a regular file: a device or FIFO (--config /dev/zero) would never end.
  std::error_code ec;
  const auto status = std::filesystem::status(path, ec);
  if (std::filesystem::exists(status) && !std::filesystem::is_regular_file(status)) {
    throw InputError(path + ": configuration file is not a regular file");
  }
  std::ifstream in(path);
  if (!in) throw InputError(path + ": cannot open configuration file");
  std::stringstream ss;
  ss << in.rdbuf();
  return ss.str();
}

void loadRegistrationBlocks(Block* top, RegistrationOptions* o) {
  const std::string& origin = top->origin();
  o->scale_detection = loadScaleDetection(top->child("scale_detection"), origin);
  o->filters = loadFilters(top->child("filters"), origin);
  o->icp = loadIcp(top->child("icp"), origin);
  o->covariance = loadCovariance(top->child("covariance"), origin);
}

}  // namespace config_detail

void validate(const RegistrationOptions& o) {
  if (!(o.scale_detection.trim_fraction >= 0.0 && o.scale_detection.trim_fraction <= 0.45)) {
    throw InputError("scale_detection.trim_fraction must be in [0, 0.45]");
  }
  if (!(o.scale_detection.ratio_threshold > 1.0)) throw InputError("scale_detection.ratio_threshold must be > 1");
  validate(o.filters);
  validate(o.icp);
  validate(o.covariance);
}

RegistrationOptions parseRegistrationConfig(const std::string& text, const std::string& origin) {
  using namespace config_detail;
  const YAML::Node root = parseYaml(text, origin);
  RegistrationOptions o;
  if (!root || root.IsNull()) return o;
  if (!root.IsMap()) throw InputError(origin + ": top level must be a map");
  try {
    Block top(root, "", origin);
    loadRegistrationBlocks(&top, &o);
    top.finish();
  } catch (const YAML::Exception& e) {
    throw InputError(origin + ": malformed configuration: " + e.msg);
  }
  return o;
}

RegistrationOptions loadRegistrationConfig(const std::string& path) {
  return parseRegistrationConfig(config_detail::readConfigFile(path), path);
}

}  // namespace pcr_pro
