#include <gtest/gtest.h>

#include <yaml-cpp/yaml.h>

#include <fstream>
#include <set>
#include <sstream>

#include "pcr_pro/merge/merge_options.h"
#include "pcr_pro/merge/parameter_tables.h"
#include "pcr_pro/registration/config.h"

namespace pcr_pro {
namespace {

std::string errorOf(const std::string& yaml) {
  try {
    parseRegistrationConfig(yaml, "test.yaml");
  } catch (const InputError& e) {
    return e.what();
  }
  return "";
}

// Expects the configuration to be refused with a message that contains part.
void expectError(const std::string& yaml, const std::string& part) {
  const std::string message = errorOf(yaml);
  EXPECT_NE(message.find(part), std::string::npos) << "'" << message << "' lacks '" << part << "'";
}

std::string readText(const std::string& path) {
  std::ifstream in(path);
  std::stringstream s;
  s << in.rdbuf();
  return s.str();
}

// Every parameter of a stage: the shipped file states it (so it documents every default), and its
// value there equals the struct default, except the keys the file deliberately changes.
template <typename O>
void expectShippedDefaults(const std::string& file, const YAML::Node& root, const O& shipped,
                           const std::set<std::string>& changed = {}) {
  const ParamSchema<O>& schema = paramSchema<O>();
  const O defaults{};
  for (const Param<O>& p : schema.params) {
    const std::string key = schema.fullKey(p, '.');
    YAML::Node node = root;  // reset(), not =: assigning a YAML::Node writes into the tree
    std::string rest = key;
    for (std::size_t dot; node.IsMap() && (dot = rest.find('.')) != std::string::npos; rest = rest.substr(dot + 1)) {
      node.reset(node[rest.substr(0, dot)]);
    }
    EXPECT_TRUE(node.IsMap() && node[rest]) << file << " does not state " << key;
    EXPECT_EQ(paramEqual(p, shipped, defaults), changed.count(key) == 0)
        << file << ": " << key << " = " << paramValueText(p, shipped) << ", default " << paramValueText(p, defaults);
  }
}

TEST(Config, ShippedFilesStateEveryParameterWithItsDefault) {
  // Neither shipped file changes a default: they document them (a file that means to change one
  // lists it in `changed`, with the reason).
  const std::string icp = std::string(PCR_PRO_CONFIG_DIR) + "/icp.yaml";
  const YAML::Node icp_yaml = YAML::LoadFile(icp);
  const RegistrationOptions r = loadRegistrationConfig(icp);
  expectShippedDefaults(icp, icp_yaml, r.scale_detection);
  expectShippedDefaults(icp, icp_yaml, r.icp);
  expectShippedDefaults(icp, icp_yaml, r.covariance);
  EXPECT_TRUE(r.filters.steps.empty());
  const std::string merge = std::string(PCR_PRO_CONFIG_DIR) + "/merge.yaml";
  const YAML::Node merge_yaml = YAML::LoadFile(merge);
  const MergeOptions m = loadMergeConfig(merge);
  expectShippedDefaults(merge, merge_yaml, m.matching);
  expectShippedDefaults(merge, merge_yaml, m.relative_pose);
  expectShippedDefaults(merge, merge_yaml, m.keyframe_depth);
  expectShippedDefaults(merge, merge_yaml, m.scale_estimation);
  expectShippedDefaults(merge, merge_yaml, m.merge);
  expectShippedDefaults(merge, merge_yaml, m.projective);
  expectShippedDefaults(merge, merge_yaml, m.limits);
}

TEST(Config, ReadmeTablesAreTheSchemaTables) {
  // The README's parameter tables are printed from the schemas (pcr_pro_params --update README.md):
  // each generated section is present once and holds exactly what the schemas print now.
  const std::string readme = readText(std::string(PCR_PRO_CONFIG_DIR) + "/../README.md");
  const auto tables = configParameterTables();
  ASSERT_EQ(tables.size(), 2u);
  for (const auto& [name, body] : tables) {
    EXPECT_NE(readme.find("<!-- params:" + name + " -->\n" + body + "<!-- /params:" + name + " -->"), std::string::npos)
        << "README.md: the section " << name << " differs from the schema: run pcr_pro_params --update README.md";
  }
  EXPECT_EQ(withParameterTables(readme, tables), readme);
}

TEST(Config, SchemaRowsCoverEveryStageWithTypesRangesAndDefaults) {
  const std::vector<ParamRow> rows = paramRows(paramSchema<IcpOptions>());
  ASSERT_FALSE(rows.empty());
  const auto row = [&](const std::string& key) {
    for (const ParamRow& r : rows) {
      if (r.key == key) return r;
    }
    return ParamRow{};
  };
  EXPECT_EQ(row("icp.stop.max_iterations").type, "int");
  EXPECT_EQ(row("icp.stop.max_iterations").default_value, std::to_string(IcpOptions().max_iterations));
  EXPECT_EQ(row("icp.stop.max_iterations").range, ">= 1");
  EXPECT_EQ(row("icp.outlier_rejection.trim_ratio").range, "in (0, 1]");
  EXPECT_EQ(row("icp.error_minimizer.type").default_value, errorMetricName(IcpOptions().error_metric));
  EXPECT_EQ(paramRows(paramSchema<CovarianceOptions>())[2].range, "0 or >= 100");
  const auto complete = [](const std::vector<ParamRow>& stage) {
    for (const ParamRow& r : stage) {
      EXPECT_FALSE(r.type.empty() || r.default_value.empty() || r.doc.empty()) << r.key << ": incomplete";
    }
    return !stage.empty();
  };
  EXPECT_TRUE(complete(paramRows(paramSchema<FeatureMatchingOptions>())));
  EXPECT_TRUE(complete(paramRows(paramSchema<RelativePoseOptions>())));
  EXPECT_TRUE(complete(paramRows(paramSchema<KeyframeDepthOptions>())));
  EXPECT_TRUE(complete(paramRows(paramSchema<ScaleEstimationOptions>())));
  EXPECT_TRUE(complete(paramRows(paramSchema<MergeGateOptions>())));
  EXPECT_TRUE(complete(paramRows(paramSchema<InputLimits>())));
  EXPECT_TRUE(complete(paramRows(paramSchema<ScaleDetectionOptions>())));
  EXPECT_TRUE(complete(paramRows(paramSchema<CropOptions>())));
  EXPECT_TRUE(complete(rows));
  EXPECT_TRUE(complete(paramRows(paramSchema<CovarianceOptions>())));
}

TEST(Config, DuplicateKeysAreRejectedWithBothLines) {
  // yaml-cpp keeps the first of two equal keys silently: the binder refuses them.
  const std::string e = errorOf("icp:\n  stop:\n    max_iterations: 5\n    max_iterations: 90\n");
  EXPECT_NE(e.find("test.yaml: icp.stop.max_iterations: duplicate key (lines 3 and 4)"), std::string::npos) << e;
  expectError("icp: {}\nicp: {}\n", "icp: duplicate key (lines 1 and 2)");
  expectError("filters:\n  - crop: {axis: x, axis: y}\n", "filters[0].crop.axis: duplicate key");
}

TEST(Config, BinderErrorsGiveTheLine) {
  const std::string unknown = errorOf("icp:\n  stop:\n    max_iteration: 5\n");
  EXPECT_NE(unknown.find("icp.stop.max_iteration: unknown key (allowed: max_iterations, "), std::string::npos) << unknown;
  EXPECT_NE(unknown.find(") (line 3)"), std::string::npos) << unknown;
  expectError("\ncovariance:\n  normal_neighbors: x\n", "covariance.normal_neighbors: must be an integer, got 'x' (line 3)");
  expectError("icp:\n  stop: {max_iterations: 0}\n", "icp.stop.max_iterations: must be >= 1, got 0 (line 2)");
  expectError("scale_detection: {ratio_threshold: .inf}\n", "scale_detection.ratio_threshold: must be finite, got '.inf'");
  expectError("scale_detection: {ratio_threshold: 1}\n", "scale_detection.ratio_threshold: must be > 1, got 1 (line 1)");
}

// The binder is the bundle reader's: a quoted number is a string, an integer must fit its type.
TEST(Config, BinderReadsTypesStrictly) {
  expectError("icp:\n  stop: {max_iterations: \"5\"}\n", "icp.stop.max_iterations: must be an integer, got the string '5' (line 2)");
  expectError("icp:\n  stop: {max_iterations: 99999999999}\n", "icp.stop.max_iterations: is too large (99999999999) (line 2)");
  expectError("filters:\n  - random_sampling: {seed: -1}\n", "filters[0].random_sampling.seed: must be >= 0, got -1 (line 2)");
  expectError("icp: {stop: {max_iterations: 5}, stop: {}}\n", "icp.stop: duplicate key (lines 1 and 1)");
}

TEST(Config, ScaleDetectionHasItsOwnValidate) {
  EXPECT_NO_THROW(validate(ScaleDetectionOptions()));
  // trim_fraction beyond 0.45, ratio_threshold not above 1
  for (const ScaleDetectionOptions& bad : {ScaleDetectionOptions{0.5, 1.2}, ScaleDetectionOptions{0.05, 1.0}}) {
    EXPECT_THROW(validate(bad), InputError);
    RegistrationOptions r;
    r.scale_detection = bad;
    EXPECT_THROW(validate(r), InputError) << "the registration's validate() runs it";
  }
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
  expectError("icp:\n  stop:\n    max_iterations: 0\n", "max_iterations");
  expectError("icp:\n  stop:\n    max_iteration: 5\n", "icp.stop.max_iteration: unknown key");
  expectError("icp:\n  outlier_rejection:\n    trim_ratio: abc\n", "icp.outlier_rejection.trim_ratio");
  expectError("icp:\n  error_minimizer:\n    type: point_to_line\n", "icp.error_minimizer.type");
  expectError("filters:\n  - blur: {}\n", "filters[0]");
  expectError("filters:\n  - crop: {axis: w}\n", "filters[0].crop.axis");
  expectError("covariance:\n  degeneracy_condition_threshold: 0.5\n", "degeneracy_condition_threshold");
  expectError("scale_detection: {ratio_threshold: 1}\n", "scale_detection.ratio_threshold");
  expectError("bogus: 1\n", "bogus: unknown key");
  expectError("icp: [1, 2\n", "YAML syntax error at line 2");
  EXPECT_EQ(errorOf("icp: [1, 2\n").rfind("test.yaml", 0), 0u);
  EXPECT_THROW(loadRegistrationConfig("/nonexistent/icp.yaml"), InputError);
}

}  // namespace
}  // namespace pcr_pro
