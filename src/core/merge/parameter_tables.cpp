#include "pcr_pro/merge/parameter_tables.h"

#include "pcr_pro/merge/merge_options.h"

namespace pcr_pro {
namespace {

// Rows of a stage's schema, with their block prefix ("icp.stop.max_iterations").
template <typename O>
void addRows(std::vector<ParamRow>* rows, const std::string& prefix = "") {
  for (ParamRow row : paramRows(paramSchema<O>())) {
    row.key = prefix + row.key;
    rows->push_back(row);
  }
}

}  // namespace

std::vector<std::pair<std::string, std::string>> configParameterTables() {
  std::vector<ParamRow> icp;
  addRows<ScaleDetectionOptions>(&icp);
  addRows<CropOptions>(&icp, "filters[].");
  addRows<VoxelGridOptions>(&icp, "filters[].");
  addRows<OutlierRemovalOptions>(&icp, "filters[].");
  addRows<RandomSamplingOptions>(&icp, "filters[].");
  addRows<MaxPointsOptions>(&icp, "filters[].");
  addRows<IcpOptions>(&icp);
  addRows<CovarianceOptions>(&icp);
  std::vector<ParamRow> merge;
  addRows<FeatureMatchingOptions>(&merge);
  addRows<RelativePoseOptions>(&merge);
  addRows<KeyframeDepthOptions>(&merge);
  addRows<ScaleEstimationOptions>(&merge);
  addRows<MergeGateOptions>(&merge);
  addRows<ProjectiveOptions>(&merge);
  addRows<InputLimits>(&merge);
  return {{"icp_yaml", markdownTable(icp)}, {"merge_yaml", markdownTable(merge)}};
}

std::string withParameterTables(const std::string& text,
                                const std::vector<std::pair<std::string, std::string>>& sections) {
  std::string out = text;
  for (const auto& [name, body] : sections) {
    const std::string begin = "<!-- params:" + name + " -->\n";
    const std::string end = "<!-- /params:" + name + " -->";
    std::size_t at = 0;
    while ((at = out.find(begin, at)) != std::string::npos) {
      const std::size_t from = at + begin.size();
      const std::size_t to = out.find(end, from);
      if (to == std::string::npos) throw InputError("parameter table '" + name + "': no line " + end);
      out.replace(from, to - from, body);
      at = from + body.size() + end.size();
    }
  }
  return out;
}

}  // namespace pcr_pro
