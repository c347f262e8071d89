// pcr_pro_icp: register two point clouds (command line, result YAML and exit statuses: docs/FORMATS.md).
#include <cmath>
#include <cstdlib>
#include <iostream>
#include <sstream>

#include "pcr_pro/io/cloud_io.h"
#include "pcr_pro/registration/cloud_registration.h"
#include "pcr_pro/registration/config.h"
#include "pcr_pro/merge/merge_pipeline.h"
#include "pcr_pro/merge/seed.h"
#include "tool_common.h"

namespace {

const char* kUsage =
    "usage: pcr_pro_icp --source A.pcd --target B.pcd [--config FILE] [--initial \"16 numbers row-major\"]\n"
    "                   [--estimate-scale] [--output DIR] [--seed N]\n"
    "Registers the source cloud onto the target cloud (PCD, or CSV/text x,y,z[,...]) and prints the\n"
    "result YAML (S_target_source, covariance, information). --seed N (0 ... 2147483647, default 1)\n"
    "seeds the configuration's random filter steps (the ICP sampling and the covariance calibration\n"
    "use fixed seeds of their own). Exit: 0 OK, 1 not merged, 2 bad input.\n";

pcr_pro::Sim3 parseInitial(const std::string& text) {
  std::istringstream in(text);
  Eigen::Matrix4d m;
  for (int i = 0; i < 16; ++i) {
    std::string token;
    if (!(in >> token)) {
      throw pcr_pro::tools::UsageError("--initial: expected 16 numbers (row-major 4x4), got " + std::to_string(i));
    }
    char* end = nullptr;
    const double value = std::strtod(token.c_str(), &end);
    if (end != token.c_str() + token.size() || !std::isfinite(value)) {
      throw pcr_pro::tools::UsageError("--initial: number " + std::to_string(i + 1) + " is '" + token +
                                       "', not a finite number");
    }
    m(i / 4, i % 4) = value;
  }
  std::string extra;
  if (in >> extra) throw pcr_pro::tools::UsageError("--initial: more than 16 numbers");
  try {
    return pcr_pro::Sim3::fromMatrix(m);
  } catch (const pcr_pro::InputError& e) {
    throw pcr_pro::tools::UsageError(std::string("--initial: ") + e.what());
  }
}

int run(int argc, char** argv) {
  using namespace pcr_pro;
  if (tools::printedHelp(argc, argv, kUsage)) return 0;
  const tools::Arguments args(argc, argv, {"--source", "--target", "--config", "--initial", "--output", "--seed"},
                              {"--estimate-scale"});
  const std::string source_path = args.required("--source");
  const std::string target_path = args.required("--target");
  RegistrationOptions options;
  InputLimits limits;
  // The merge configuration schema is accepted too (its front-end blocks are validated, unused).
  if (const auto config = args.value("--config")) {
    const MergeOptions merge_options = loadMergeConfig(*config);
    options = merge_options.registration;
    limits = merge_options.limits;
  }
  setSeed(&options.filters, tools::seedOption(args));
  if (args.flag("--estimate-scale")) options.icp.estimate_scale = true;
  std::optional<Sim3> initial;
  if (const auto init = args.value("--initial")) initial = parseInitial(*init);

  const Cloud source = readCloud(source_path, limits);
  const Cloud target = readCloud(target_path, limits);
  const RegistrationReport report = registerClouds(source, target, initial, options);
  const std::string yaml = toYaml(report);
  std::cout << yaml << std::flush;
  if (const auto out = args.value("--output")) {
    Cloud fused(3, target.cols() + source.cols());
    fused << target, report.transform ? report.transform->apply(source) : source;
    tools::writeOutputs(*out, yaml, fused);
  }
  return tools::exitStatus(report);
}

}  // namespace

int main(int argc, char** argv) {
  return pcr_pro::tools::runTool("pcr_pro_icp", argc, argv, run);
}
