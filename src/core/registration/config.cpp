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

// The filter step of a given type, bound through its schema.
template <typename O>
void bindStep(FilterStep::Type type, Block* b, FilterStep* step, O FilterStep::*options) {
  step->type = type;
  bindParams(paramSchema<O>(), b, &(step->*options));
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
      bindStep(FilterStep::Type::kCrop, &b, &step, &FilterStep::crop);
    } else if (type == "voxel_grid") {
      bindStep(FilterStep::Type::kVoxelGrid, &b, &step, &FilterStep::voxel_grid);
    } else if (type == "outlier_removal") {
      bindStep(FilterStep::Type::kOutlierRemoval, &b, &step, &FilterStep::outlier_removal);
    } else if (type == "random_sampling") {
      bindStep(FilterStep::Type::kRandomSampling, &b, &step, &FilterStep::random_sampling);
    } else if (type == "max_points") {
      bindStep(FilterStep::Type::kMaxPoints, &b, &step, &FilterStep::max_points);
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
  o->scale_detection = loadStage<ScaleDetectionOptions>(top);
  o->filters = loadFilters(top->child("filters"), origin);
  o->icp = loadStage<IcpOptions>(top);
  o->covariance = loadStage<CovarianceOptions>(top);
}

}  // namespace config_detail

void validate(const RegistrationOptions& o) {
  validate(o.scale_detection);
  validate(o.filters);
  validate(o.icp);
  validate(o.covariance);
}

RegistrationOptions parseRegistrationConfig(const std::string& text, const std::string& origin) {
  RegistrationOptions o;
  config_detail::loadTopLevel(text, origin, [&o](config_detail::Block* top) { config_detail::loadRegistrationBlocks(top, &o); });
  return o;
}

RegistrationOptions loadRegistrationConfig(const std::string& path) {
  return parseRegistrationConfig(config_detail::readConfigFile(path), path);
}

}  // namespace pcr_pro
