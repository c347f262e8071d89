#include "pcr_pro/registration/config.h"

#include "io/yaml_block.h"

#include <yaml-cpp/yaml.h>

#include <filesystem>
#include <fstream>
#include <sstream>

#include "pcr_pro/io/text_escape.h"

namespace pcr_pro {
namespace config_detail {
namespace {

// The filter step of a given type, bound through its schema.
template <typename O>
void bindStep(FilterStep::Type type, Block* b, FilterStep* step, O FilterStep::*options) {
  step->type = type;
  bindParams(paramSchema<O>(), b, &(step->*options));
}

// The filter chain: a list of one-key maps, the key naming the filter type.
FilterChainOptions loadFilters(Block* top) {
  FilterChainOptions chain;
  const YAML::Node node = top->child("filters");
  if (!node || node.IsNull()) return chain;
  const yaml_detail::FieldReader& reader = top->reader();
  reader.list(node, "filters", "filter steps");
  for (std::size_t i = 0; i < node.size(); ++i) {
    const std::string where = yaml_detail::elementKey("filters", i);
    if (!node[i].IsMap() || node[i].size() != 1) {
      reader.fail(where, node[i], "must be a map with one key (the filter type), got " + yaml_detail::describe(node[i]));
    }
    const yaml_detail::Fields one_key = reader.fields(node[i], where);
    const yaml_detail::Entry& entry = one_key.entries.front();
    Block b(reader, entry.value, yaml_detail::childKey(where, entry.key));
    FilterStep step;
    if (entry.key == "crop") {
      bindStep(FilterStep::Type::kCrop, &b, &step, &FilterStep::crop);
    } else if (entry.key == "voxel_grid") {
      bindStep(FilterStep::Type::kVoxelGrid, &b, &step, &FilterStep::voxel_grid);
    } else if (entry.key == "outlier_removal") {
      bindStep(FilterStep::Type::kOutlierRemoval, &b, &step, &FilterStep::outlier_removal);
    } else if (entry.key == "random_sampling") {
      bindStep(FilterStep::Type::kRandomSampling, &b, &step, &FilterStep::random_sampling);
    } else if (entry.key == "max_points") {
      bindStep(FilterStep::Type::kMaxPoints, &b, &step, &FilterStep::max_points);
    } else {
      reader.fail(where, entry.key_node, "unknown filter type '" + printable(entry.key) +
                                             "' (crop, voxel_grid, outlier_removal, random_sampling, max_points)");
    }
    b.finish();
    try {
      FilterChainOptions one;
      one.steps.push_back(step);
      validate(one);
    } catch (const InputError& e) {
      throw InputError(reader.origin() + ": " + where + ": " + e.what());
    }
    chain.steps.push_back(step);
  }
  return chain;
}

}  // namespace

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
  o->scale_detection = loadStage<ScaleDetectionOptions>(top);
  o->filters = loadFilters(top);
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
