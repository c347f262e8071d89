// The project's own generated worlds, for the self-contained tests.
//
// The build simulates the standard worlds into BUILD/sim (CMakeLists.txt, config/sim_demo.yaml):
//   demo/     agents agent_a, agent_b (about 50 % overlap, scale ratio 2.5, 30 deg apart) and
//             agent_c (no overlap with agent_a); depth images; small drift; truth_<t>_<s>.yaml for
//             every ordered pair; pcr_pro_two_agents.bag and lsd_slam_two_agents.bag
//   nodepth/  the same world without depth images
// Tests get the directory compiled in (PCR_PRO_SIM_DIR; the environment variable of the same name
// overrides it) and depend on the target that generates it, so the worlds are always there: a
// missing world is a failure, never a skip.
//
// pairTolerance() derives how far a merge of a generated pair may be from its truth from the
// world itself (see there); compare with compareWithTruth() (pcr_pro/io/truth_comparison.h).
#pragma once

#include <yaml-cpp/yaml.h>

#include <algorithm>
#include <cstdlib>
#include <string>
#include <vector>

#include "pcr_pro/geometry/similarity_fit.h"
#include "pcr_pro/io/truth_comparison.h"
#include "common/yaml_sim3.h"

#ifndef PCR_PRO_SIM_DIR
#error "PCR_PRO_SIM_DIR must be defined by the build (pcr_pro_use_sim_worlds in CMakeLists.txt)"
#endif

namespace pcr_pro {
namespace test {

/// @return the generated worlds' directory: $PCR_PRO_SIM_DIR, else BUILD/sim
inline std::string simDir() {
  const char* value = std::getenv("PCR_PRO_SIM_DIR");
  return (value != nullptr && *value != '\0') ? std::string(value) : std::string(PCR_PRO_SIM_DIR);
}

/// @return simDir() + "/" + relative, e.g. simPath("demo/agent_a")
inline std::string simPath(const std::string& relative) { return simDir() + "/" + relative; }

/// Largest errors a merge of a generated pair may have against its truth (compareWithTruth()'s terms).
struct PairTolerance {
  double rotation_deg = 0.0;
  double translation = 0.0;    ///< [target units]
  double scale_percent = 0.0;  ///< of |scale_percent|
};

/**
 * The tolerance of a generated pair, from its truth file. The truth S_target_source is the
 * least-squares similarity over the co-visible points of both maps; with drift, the similarity local to each
 * overlapping keyframe pair (keyframe_pairs: exact for the points both keyframes see) differs
 * from it by the maps' distortion there. A merge estimates from keyframe pairs and refines over
 * the overlap, so a correct estimate lies within the spread of these local truths around the
 * global one; `factor` (2) leaves as much again for the estimate's own noise (pixel and depth
 * noise, the refinement's pull over the whole overlap); the translation bound is at least the
 * truth fit's own residual (fit_rms). The standard worlds have drift (config/sim_demo.yaml), so
 * the spread is not zero; a world without drift would need a noise floor instead. With the exact
 * truth these bounds are far tighter than the real data's (whose truth is itself good to about
 * 1 deg and a few cm): for the demo world 0.74 deg, 0.028 target units (agent_a's metres) and
 * 1.2 % scale, where its merges are off by 0.06-0.26 deg, 2-6 mm and 0.2-0.4 %.
 */
inline PairTolerance pairTolerance(const std::string& truth_file, double factor = 2.0) {
  const YAML::Node truth = YAML::LoadFile(truth_file);
  const Sim3 global = sim3FromYaml(truth["S_target_source"]);
  PairTolerance spread;
  for (const YAML::Node& pair : truth["keyframe_pairs"]) {
    const Sim3 local = sim3FromYaml(pair["S_target_source"]);
    const TruthErrors e = compareWithTruth(local, global, std::nullopt, std::nullopt);
    spread.rotation_deg = std::max(spread.rotation_deg, e.rotation_deg);
    spread.translation = std::max(spread.translation, e.translation);
    spread.scale_percent = std::max(spread.scale_percent, std::abs(e.scale_percent));
  }
  const double fit_rms = truth["fit_rms"].as<double>(0.0);
  return {factor * spread.rotation_deg, factor * std::max(spread.translation, fit_rms),
          factor * spread.scale_percent};
}

/// @return whether every error is within the tolerance
inline bool within(const TruthErrors& e, const PairTolerance& t) {
  return e.rotation_deg < t.rotation_deg && e.translation < t.translation && std::abs(e.scale_percent) < t.scale_percent;
}

}  // namespace test
}  // namespace pcr_pro
