// make bench, the suite: one section per table of docs/BENCHMARKS.md (section_*.cpp). Writes
// Markdown fragments and CSV files into an output directory; every number comes from this run.
//
// Usage: pcr_pro_bench_suite OUTPUT_DIR [--quick] [--ours-only] [--only SECTION[,SECTION...]]
//   SECTION: real, simulated, heldout, unequal, timing, consistency, sweep, car
//   pcr_pro_bench_suite --memory N merge|idle   (internal: the timing section's memory probe)
#include <omp.h>

#include <unistd.h>

#include <cstdio>
#include <functional>
#include <sstream>

#include "pcr_pro/geometry/types.h"
#include "common/data_dir.h"
#include "suite.h"

using namespace pcr_pro;
using namespace pcr_pro::bench;

namespace {

struct Section {
  const char* name;
  std::function<void(Output&, const SuiteConfig&, std::FILE*)> run;
};

const std::vector<Section>& sections() {
  static const std::vector<Section> list = {
      {"real", sectionRealCases},
      {"simulated", sectionSimulated},
      {"heldout", sectionHeldOut},
      {"unequal", sectionUnequal},
      {"timing", sectionTiming},
      {"consistency", sectionConsistency},
      {"sweep", sectionSweep},
      {"car", [](Output& out, const SuiteConfig& c, std::FILE*) { sectionCar(out, c); }},
  };
  return list;
}

bool wanted(const std::string& only, const std::string& name) {
  if (only.empty()) return true;
  std::stringstream ss(only);
  std::string item;
  while (std::getline(ss, item, ',')) {
    if (item == name) return true;
  }
  return false;
}

int usage() {
  std::fprintf(stderr, "usage: pcr_pro_bench_suite OUTPUT_DIR [--quick] [--ours-only] [--only SECTION[,SECTION...]]\n  sections:");
  for (const Section& s : sections()) std::fprintf(stderr, " %s", s.name);
  std::fprintf(stderr, "\n");
  return 2;
}

}  // namespace

int main(int argc, char** argv) {
  if (argc < 2) return usage();
  try {
    if (std::string(argv[1]) == "--memory" && argc == 4) {
      return memoryProbe(std::stoi(argv[2]), std::string(argv[3]) == "merge");
    }
    SuiteConfig config;
    std::string only;
    for (int i = 2; i < argc; ++i) {
      const std::string a = argv[i];
      if (a == "--quick") {
        config.quick = true;
      } else if (a == "--ours-only") {
        config.ours_only = true;
      } else if (a == "--only" && i + 1 < argc) {
        only = argv[++i];
      } else {
        return usage();
      }
    }
    for (std::stringstream ss(only); ss.good();) {
      std::string item;
      std::getline(ss, item, ',');
      bool known = item.empty();
      for (const Section& s : sections()) known |= item == s.name;
      if (!known) {
        std::fprintf(stderr, "pcr_pro_bench_suite: --only: unknown section '%s'\n", item.c_str());
        return usage();
      }
    }
    // The real cases are built from the data directory; without them most sections cannot run.
    if (const auto missing = test::missingRealCase("slambook2/depth")) {
      std::fprintf(stderr, "pcr_pro_bench_suite: %s\n", missing->c_str());
      return 2;
    }
    config.self = "/proc/" + std::to_string(getpid()) + "/exe";
    Output out(argv[1]);
    std::FILE* headline = out.open("headline.md");
    std::FILE* env = out.open("environment.md");
    std::fprintf(env, "Mode: %s. Machine: %d hardware threads. Peers: PCL %s, Open3D %s.\n",
                 config.quick ? "--quick" : "full", omp_get_num_procs(), pclVersion().c_str(), open3dVersion().c_str());
    std::FILE* times = out.open("section_times.md");
    std::fprintf(times, "| section | wall time [s] |\n|---|---|\n");
    for (const Section& s : sections()) {
      if (!wanted(only, s.name)) continue;
      const double t0 = nowMs();
      s.run(out, config, headline);
      const double seconds = (nowMs() - t0) / 1000.0;
      std::fprintf(stderr, "section %s: %.0f s\n", s.name, seconds);
      std::fprintf(times, "| %s | %.0f |\n", s.name, seconds);
      std::fflush(headline);
    }
    std::fclose(times);
    std::fclose(env);
    std::fclose(headline);
  } catch (const std::exception& e) {
    std::fprintf(stderr, "pcr_pro_bench_suite: %s\n", e.what());
    return 2;
  }
  return 0;
}
