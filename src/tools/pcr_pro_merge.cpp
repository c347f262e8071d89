// pcr_pro_merge: offline merge of two map bundles (command line, result YAML and exit statuses: docs/FORMATS.md).
#include <cstdlib>
#include <filesystem>
#include <iostream>
#include <optional>

#include "pcr_pro/io/bundle.h"
#include "pcr_pro/io/pose_graph.h"
#include "pcr_pro/io/truth_comparison.h"
#include "pcr_pro/merge/merge_pipeline.h"
#include "pcr_pro/merge/seed.h"
#include "image_check.h"
#include "tool_common.h"

namespace {

const char* kUsage =
    "usage: pcr_pro_merge --source DIR --target DIR [--config FILE] [--output DIR]\n"
    "                     [--source-keyframe ID] [--target-keyframe ID] [--seed N] [--truth FILE]\n"
    "                     [--g2o FILE] [--tum FILE]\n"
    "Merges the source agent's map bundle into the target agent's (PCR-Pro: SIFT/FLANN keyframe\n"
    "matching, OpenGV relative pose, Kalman-filter scale, ICP with scale, closed-form covariance)\n"
    "and prints the result YAML (S_target_source). --seed N (0 ... 2147483647, default 1) seeds every\n"
    "random stage: equal inputs and seeds give equal results, bit for bit. --truth FILE (a truth.yaml)\n"
    "adds the merge's errors against its S_target_source, beside the uncertainty it reports.\n"
    "--g2o FILE writes the merge as a g2o pose graph (every keyframe of both agents as a\n"
    "VERTEX_SIM3:EXPMAP in the target map frame, the merge as an EDGE_SIM3:EXPMAP between the anchor\n"
    "keyframes with its information); --tum FILE the fused keyframes as a TUM trajectory\n"
    "(timestamp = keyframe id: bundles carry no times). Written only when the maps merged.\n"
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

// The agent's name in the pose graph: its bundle directory's name.
std::string agentName(const std::string& dir, const std::string& fallback) {
  std::filesystem::path p(dir);
  if (!p.has_filename()) p = p.parent_path();
  const std::string name = p.filename().string();
  return name.empty() || name == "." || name == ".." ? fallback : name;
}

// --g2o / --tum: the pose graph of a successful merge (nothing written otherwise).
void writePoseGraph(const pcr_pro::tools::Arguments& args, const pcr_pro::MergeResult& result,
                    const pcr_pro::AgentMap& source, const std::string& source_dir, const pcr_pro::AgentMap& target,
                    const std::string& target_dir) {
  using namespace pcr_pro;
  const auto g2o_file = args.value("--g2o");
  const auto tum_file = args.value("--tum");
  if (!g2o_file && !tum_file) return;
  const std::optional<MergeEdge> edge = poseGraphEdge(result);
  if (!edge) {
    std::cerr << "pcr_pro_merge: not merged: no pose graph written\n";
    return;
  }
  std::string target_name = agentName(target_dir, "target"), source_name = agentName(source_dir, "source");
  if (target_name == source_name) {
    target_name = "target";
    source_name = "source";
  }
  const PoseGraph graph = mergePoseGraph(target, target_name, source, source_name, *edge);
  if (g2o_file) writeTextFileAtomically(*g2o_file, toG2o(graph));
  if (tum_file) writeTextFileAtomically(*tum_file, toTum(graph));
}

int run(int argc, char** argv) {
  using namespace pcr_pro;
  if (tools::printedHelp(argc, argv, kUsage)) return 0;
  const tools::Arguments args(
      argc, argv, {"--source", "--target", "--config", "--output", "--source-keyframe", "--target-keyframe", "--seed",
                   "--truth", "--g2o", "--tum"},
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

  std::vector<std::string> warnings;
  // The tools' reader: PNG chunk diagnostics and libjpeg's warnings as errors (image_check.h).
  const AgentMap source = loadBundle(source_dir, options.limits, &warnings, tools::readImageChecked);
  const AgentMap target = loadBundle(target_dir, options.limits, &warnings, tools::readImageChecked);
  for (const std::string& w : warnings) std::cerr << "pcr_pro_merge: warning: " << w << "\n";
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
  writePoseGraph(args, result, source, source_dir, target, target_dir);
  return tools::exitStatus(report);
}

}  // namespace

int main(int argc, char** argv) {
  return pcr_pro::tools::runTool("pcr_pro_merge", argc, argv, run);
}
