// pcr_pro_make_real_cases: builds the real two-agent test cases from the real-data directory into
// a build-tree directory (never into the source tree). Run by the build (target
// pcr_pro_real_cases) when the data directory exists; see docs/FORMATS.md for what it writes.
#include <chrono>
#include <cstdio>
#include <filesystem>
#include <fstream>
#include <iostream>

#include "real_cases/cases.h"
#include "tool_common.h"

namespace {

namespace fs = std::filesystem;

const char* kUsage =
    "usage: pcr_pro_make_real_cases --data DIR --output DIR\n"
    "Builds the real two-agent cases (map bundles with and without depth images, and their truth)\n"
    "from DIR/7scenes_redkitchen and DIR/slambook2_ch5_rgbd into OUTPUT/{7scenes,slambook2}, with\n"
    "OUTPUT/index.yaml and OUTPUT/stamp. A data set that is absent is skipped with a message.\n"
    "Exit: 0 built, 2 bad usage or input.\n";

void writeText(const fs::path& path, const std::string& text) {
  std::ofstream out(path);
  out << text;
  if (!out) throw pcr_pro::InputError(path.string() + ": cannot write file");
}

// Removes what an earlier run wrote (and nothing else in OUTPUT).
void clearOutput(const fs::path& output) {
  for (const char* name : {"7scenes", "slambook2", "index.yaml", "stamp"}) fs::remove_all(output / name);
  fs::create_directories(output);
}

void printSummary(const pcr_pro::real_cases::CaseSummary& c) {
  std::printf(
      "%-34s overlap %-5s ref %4ld-%-4ld %5.1f deg %5.2f m  scales %.3g / %.3g  drift %+.1f / %+.1f %%  "
      "points %ld / %ld  seen %.0f / %.0f %%\n",
      c.path.c_str(), c.overlap ? "yes" : "no", c.reference_target, c.reference_source, c.angle_deg, c.distance_m,
      c.target_scale, c.source_scale, 100.0 * c.target_drift, 100.0 * c.source_drift, c.target_points, c.source_points,
      100.0 * c.target_seen_by_source, 100.0 * c.source_seen_by_target);
}

int run(int argc, char** argv) {
  using namespace pcr_pro;
  if (tools::printedHelp(argc, argv, kUsage)) return 0;
  const tools::Arguments args(argc, argv, {"--data", "--output"}, {});
  const fs::path data = args.required("--data"), output = args.required("--output");
  const fs::path seven = data / "7scenes_redkitchen", slambook = data / "slambook2_ch5_rgbd";
  if (!fs::is_directory(seven) && !fs::is_directory(slambook)) {
    throw InputError(data.string() + ": holds neither 7scenes_redkitchen nor slambook2_ch5_rgbd");
  }
  const auto start = std::chrono::steady_clock::now();
  clearOutput(output);
  std::vector<real_cases::CaseSummary> cases;
  for (const auto& [dir, build] :
       {std::pair{seven, &real_cases::buildSevenScenesCases}, std::pair{slambook, &real_cases::buildSlambook2Cases}}) {
    if (!fs::is_directory(dir)) {
      std::printf("pcr_pro_make_real_cases: %s absent: its cases are skipped\n", dir.string().c_str());
      continue;
    }
    real_cases::RgbdSequence sequence =
        dir == seven ? real_cases::openSevenScenes(dir.string()) : real_cases::openSlambook2(dir.string());
    for (const real_cases::CaseSummary& c : build(sequence, output.string())) {
      printSummary(c);
      cases.push_back(c);
    }
  }
  writeText(output / "index.yaml", real_cases::indexYaml(cases, data.string()));
  const double seconds = std::chrono::duration<double>(std::chrono::steady_clock::now() - start).count();
  // Written last: the build takes the cases as complete when the stamp exists.
  writeText(output / "stamp",
            "built " + std::to_string(cases.size()) + " case directories in " + std::to_string(seconds) + " s\n");
  std::printf("pcr_pro_make_real_cases: %zu case directories in %s (%.1f s)\n", cases.size(), output.string().c_str(),
              seconds);
  return 0;
}

}  // namespace

int main(int argc, char** argv) { return pcr_pro::tools::runTool("pcr_pro_make_real_cases", argc, argv, run); }
