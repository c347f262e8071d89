// pcr_pro_simulate: writes a synthetic multi-agent world (map bundles, truth, optionally the two
// ROS bags) made by the core simulator (include/pcr_pro/sim/simulator.h). Deterministic from the
// seed. See the README, section pcr_pro_simulate.
#include <cmath>
#include <cstdint>
#include <cstdlib>
#include <filesystem>
#include <fstream>
#include <iostream>
#include <sstream>

#include "pcr_pro/ros/sim_bags.h"
#include "pcr_pro/sim/simulator.h"
#include "tool_common.h"

namespace {

using pcr_pro::tools::UsageError;

const char* kUsage =
    "usage: pcr_pro_simulate --output DIR [--config FILE.yaml] [--seed N] [--agents N]\n"
    "                        [--overlap F] [--view-angle DEG] [--scale-drift F] [--bend-deg DEG]\n"
    "                        [--no-depth] [--nodepth-output DIR2] [--bags] [--quiet]\n"
    "Renders a textured room seen by N monocular-SLAM agents and writes DIR/<agent>/ (map bundles),\n"
    "DIR/truth.yaml (agent_a target, agent_b source), DIR/truth_<target>_<source>.yaml (every pair),\n"
    "DIR/simulation.yaml (the options), DIR/summary.yaml (also printed unless --quiet) and with --bags\n"
    "DIR/pcr_pro_two_agents.bag and DIR/lsd_slam_two_agents.bag. --nodepth-output also writes the same\n"
    "world without depth images (bundles, truth) to DIR2. Options override the config file\n"
    "(config/simulator.yaml documents every key). Exit: 0 written, 2 bad input.\n";

double parseNumber(const std::string& option, const std::string& text) {
  char* end = nullptr;
  const double v = std::strtod(text.c_str(), &end);
  if (text.empty() || *end != '\0' || !std::isfinite(v)) throw UsageError(option + ": not a number: '" + text + "'");
  return v;
}

std::uint64_t parseUnsigned(const std::string& option, const std::string& text) {
  char* end = nullptr;
  const unsigned long long v = std::strtoull(text.c_str(), &end, 10);
  if (text.empty() || *end != '\0' || text[0] == '-') throw UsageError(option + ": not an unsigned integer: '" + text + "'");
  return v;
}

// Command-line overrides; a value out of range is reported with the flag and the key it sets.
pcr_pro::SimulatorOptions options(const pcr_pro::tools::Arguments& args) {
  pcr_pro::SimulatorOptions o;
  if (const auto config = args.value("--config")) o = pcr_pro::loadSimulatorConfig(*config);
  struct Override {
    const char* flag;
    std::string key;
    void (*apply)(pcr_pro::SimulatorOptions*, double);
  };
  const Override overrides[] = {
      {"--agents", "agents", [](pcr_pro::SimulatorOptions* s, double v) { s->agents = static_cast<int>(v); }},
      {"--overlap", "layout.overlap", [](pcr_pro::SimulatorOptions* s, double v) { s->layout.overlap = v; }},
      {"--view-angle", "layout.view_angle_difference_deg",
       [](pcr_pro::SimulatorOptions* s, double v) { s->layout.view_angle_difference_deg = v; }},
      {"--scale-drift", "drift.scale_drift", [](pcr_pro::SimulatorOptions* s, double v) { s->drift.scale_drift = v; }},
      {"--bend-deg", "drift.bend_deg", [](pcr_pro::SimulatorOptions* s, double v) { s->drift.bend_deg = v; }},
  };
  for (const Override& ov : overrides) {
    const auto text = args.value(ov.flag);
    if (!text) continue;
    const double v = parseNumber(ov.flag, *text);
    if (std::string(ov.flag) == "--agents" && (v != std::floor(v) || v < 1 || v > 26)) {
      throw UsageError("--agents: must be an integer in [1, 26], got '" + *text + "'");
    }
    ov.apply(&o, v);
    // per_agent entries beyond --agents would be an error: --agents wins over the config.
    if (o.per_agent.size() > static_cast<std::size_t>(o.agents)) o.per_agent.resize(static_cast<std::size_t>(o.agents));
    try {  // the config was valid: an error now is this flag's
      pcr_pro::validate(o);
    } catch (const pcr_pro::InputError& e) {
      throw UsageError(std::string(ov.flag) + " " + *text + ": " + e.what());
    }
  }
  if (const auto seed = args.value("--seed")) o.seed = parseUnsigned("--seed", *seed);
  if (args.flag("--no-depth")) o.map.depth_images = "none";
  return o;
}

std::string summary(const pcr_pro::Simulation& sim, const std::string& dir, bool bags) {
  std::ostringstream y;
  y.precision(4);
  const pcr_pro::SimTimings& t = sim.timings;
  y << "output: " << dir << "\nseed: " << sim.options.seed << "\nagents:\n";
  for (const pcr_pro::SimAgent& a : sim.agents) {
    y << "  - {name: " << a.name << ", keyframes: " << a.keyframes.size() << ", cloud_points: " << a.map.cloud.cols()
      << ", scale: " << a.world_to_map.scale() << ", scale_drift: " << a.scale_drift << ", bend_deg: " << a.bend_deg << "}\n";
  }
  y << "pairs:\n";
  for (const pcr_pro::SimPairTruth& p : sim.pairs) {
    y << "  - {target: " << sim.agents[static_cast<std::size_t>(p.target)].name
      << ", source: " << sim.agents[static_cast<std::size_t>(p.source)].name << ", overlap_fraction: " << p.overlap_fraction
      << ", keyframe_pairs: " << p.keyframe_pairs.size() << ", scale: " << p.target_source.scale() << "}\n";
  }
  y << "bags: " << (bags ? "true" : "false") << "\n"
    << "timings_ms: {world: " << t.world << ", layout: " << t.layout << ", render: " << t.render
    << ", render_per_keyframe: " << (t.rendered > 0 ? t.render / t.rendered : 0.0) << ", maps: " << t.maps
    << ", truth: " << t.truth << ", total: " << t.total << "}\n";
  return y.str();
}

int run(int argc, char** argv) {
  if (pcr_pro::tools::printedHelp(argc, argv, kUsage)) return 0;
  const pcr_pro::tools::Arguments args(
      argc, argv,
      {"--output", "--nodepth-output", "--config", "--seed", "--agents", "--overlap", "--view-angle", "--scale-drift",
       "--bend-deg"},
      {"--no-depth", "--bags", "--quiet"});
  const std::string dir = args.required("--output");
  const pcr_pro::SimulatorOptions o = options(args);
  const pcr_pro::Simulation sim = pcr_pro::simulate(o);
  pcr_pro::writeSimulation(dir, sim);
  if (const auto nodepth = args.value("--nodepth-output")) pcr_pro::writeSimulation(*nodepth, sim, false);
  if (args.flag("--bags")) pcr_pro::ros_bridge::writeSimulationBags(dir, sim);
  const std::string text = summary(sim, dir, args.flag("--bags"));
  const std::string path = (std::filesystem::path(dir) / "summary.yaml").string();
  std::ofstream out(path);
  out << text;
  if (!out) throw pcr_pro::InputError(path + ": cannot write file");
  if (!args.flag("--quiet")) std::cout << text << std::flush;
  return 0;
}

}  // namespace

int main(int argc, char** argv) { return pcr_pro::tools::runTool("pcr_pro_simulate", argc, argv, run); }
