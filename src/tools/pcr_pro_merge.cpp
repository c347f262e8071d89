// pcr_pro_merge: offline merge of two map bundles (command line, result YAML and exit statuses: docs/FORMATS.md).
#include <cstdlib>
#include <optional>
#include <iostream>

#include "pcr_pro/io/bundle.h"
#include "pcr_pro/io/truth_comparison.h"
#include "pcr_pro/merge/merge_pipeline.h"
#include "pcr_pro/merge/seed.h"
#include "tool_common.h"

namespace {

const char* kUsage =
    "usage: pcr_pro_merge --source DIR --target DIR [--config FILE] [--output DIR]\n"
    "                     [--source-keyframe ID] [--target-keyframe ID] [--seed N] [--truth FILE]\n"
    "Merges the source agent's map bundle into the target agent's (PCR-Pro: SIFT/FLANN keyframe\n"
    "matching, OpenGV relative pose, Kalman-filter scale, ICP with scale, closed-form covariance)\n"
    "and prints the result YAML (S_target_source). --seed N (0 ... 2147483647, default 1) seeds every\n"
    "random stage: equal inputs and seeds give equal results, bit for bit. --truth FILE (a truth.yaml)\n"
    "adds the merge's errors against its S_target_source, beside the uncertainty it reports.\n"
    "Exit: 0 merged, 1 not merged, 2 bad input.\n";

long parseId(const std::string& option, const std::string& text) {
  try {
    std::size_t pos = 0;
    const long v = std::stol(text, &pos);
    if (pos == text.size()) return v;
  } catch (const std::exception&) {
  }
  throw pcr_pro::tools::UsageError(option + ": not an integer keyframe id: '" + text + "'");
}

int run(int argc, char** argv) {
  using namespace pcr_pro;
  for (int i = 1; i < argc; ++i) {
    if (std::string(argv[i]) == "--help" || std::string(argv[i]) == "-h") {
      std::cout << kUsage;
      return 0;
    }
  }
  const tools::Arguments args(argc, argv,
                              {"--source", "--target", "--config", "--output", "--source-keyframe",
                               "--target-keyframe", "--seed", "--truth"},
                              {});
  const std::string source_dir = args.required("--source");
  const std::string target_dir = args.required("--target");
  MergeOptions options;
  if (const auto config = args.value("--config")) options = loadMergeConfig(*config);
  setSeed(&options, tools::seedOption(args));
  MergeRequest request;
  if (const auto id = args.value("--source-keyframe")) request.source_keyframe = parseId("--source-keyframe", *id);
  if (const auto id = args.value("--target-keyframe")) request.target_keyframe = parseId("--target-keyframe", *id);

  // Read before the merge, so that a bad truth file ends the run at once.
  const auto truth_file = args.value("--truth");
  std::optional<BundleTruth> truth;
  if (truth_file) truth = loadBundleTruth(*truth_file);

  const AgentMap source = loadBundle(source_dir, options.limits);
  const AgentMap target = loadBundle(target_dir, options.limits);
  for (const auto& [id, map, dir] : {std::tuple{request.source_keyframe, &source, source_dir},
                                     std::tuple{request.target_keyframe, &target, target_dir}}) {
    if (!id) continue;
    bool found = false;
    for (const MapKeyframe& kf : map->keyframes) found = found || kf.id == *id;
    if (!found) throw InputError(dir + "/bundle.yaml: keyframes: no keyframe with id " + std::to_string(*id));
  }
  const MergeResult result = mergeMaps(source, target, request, options);
  std::string yaml = toYaml(result.report);
  const RegistrationReport& report = result.report;
  if (truth && report.status == Status::kOk && report.transform) {
    yaml += truthErrorsYaml(
        compareWithTruth(*report.transform, truth->target_source, report.covariance, report.scale_stddev), *truth_file);
  }
  std::cout << yaml << std::flush;
  if (const auto out = args.value("--output")) {
    const bool merged = report.status == Status::kOk && report.transform;
    Cloud fused(3, target.cloud.cols() + (merged ? source.cloud.cols() : 0));
    if (merged) {
      fused << target.cloud, report.transform->apply(source.cloud);
    } else {
      fused = target.cloud;  // nothing merged: the target map alone
    }
    tools::writeOutputs(*out, yaml, fused);
  }
  return tools::exitStatus(report);
}

}  // namespace

int main(int argc, char** argv) {
  return pcr_pro::tools::runTool("pcr_pro_merge", argc, argv, run);
}
