// make bench, section "simulated": worlds made in-process by simulate() (seeded, reproducible),
// swept over the maps' scale drift, the overlap of the two agents and the semi-dense depth noise,
// several seeds per cell, each merged with depth images, with the keyframes' own semi-dense depth
// (as LSD-SLAM gives it) and with neither; a third agent that does not overlap checks false
// merges. Ours and Open3D in the same run, against the simulator's exact truth.
#include <algorithm>
#include <functional>
#include <memory>

#include "case_results.h"
#include "common/bench_worlds.h"
#include "bench_common.h"
#include "pcr_pro/sim/simulator.h"
#include "suite.h"

namespace pcr_pro {
namespace bench {
namespace {

// One cell of the sweep: overlap, scale drift, semi-dense inverse-depth noise (agent_b's own
// when source_noise >= 0); with both_orders each world is also merged the other way round
// (agent_a onto agent_b).
struct SimCell {
  double overlap, drift, noise;
  double source_noise = -1.0;
  bool both_orders = false;
};

// The cell texts of the two orders of a both_orders cell, which the noise grouping then tells apart.
constexpr const char* kForwardCell = ", b → a (the noisier map as source)";
constexpr const char* kReversedCell = ", a → b (the noisier map as target)";

struct SimSweep {
  std::vector<SimCell> cells;
  int first_seed = 0;  ///< seeds first_seed .. first_seed + seeds - 1 (benchWorldOptions())
  int seeds = 2;
  bool peers = true;   ///< Open3D on these worlds (when the suite runs peers at all)
  const char* stem = "simulated";  ///< the section's files: STEM.md, STEM.csv
  /// What the cells are (a sentence of STEM.md).
  const char* cells_text = "every overlap × drift at noise 0.01, and noise 0.03 at drift 2.5 % for every overlap";
  /// The headline's label of a sweep without peers.
  const char* label = "";
};

// Every overlap x drift at the simulator's default noise (0.01), and three times that noise at
// the middle drift for every overlap (the full factorial would take twice as long).
SimSweep simSweep(bool quick) {
  SimSweep s;
  if (quick) {
    s.cells = {{0.3, 0.05, 0.01}};
    s.seeds = 1;
    s.cells_text = "overlap 30 %, drift 5 %, noise 0.01 (quick mode)";
    return s;
  }
  for (double overlap : {0.15, 0.35, 0.6}) {
    for (double drift : {0.0, 0.025, 0.05}) s.cells.push_back({overlap, drift, 0.01});
    s.cells.push_back({overlap, 0.025, 0.03});
  }
  s.seeds = 2;
  return s;
}

// The same cells with the next four seeds (2-5), ours only: a sample three times as large that
// the simulated section's numbers can be checked against. The thresholds were chosen on the
// first two seeds, the real cases and the tests' worlds; these seeds keep what they show honest
// (a change that helps seeds 0-1 by luck shows here as no gain or a loss).
SimSweep heldOutSweep(bool quick) {
  SimSweep s = simSweep(quick);
  s.first_seed = 2;
  s.seeds = quick ? 1 : 4;
  s.peers = false;
  s.stem = "heldout";
  s.label = "Held-out simulated worlds";
  return s;
}

// Maps that are not equally noisy, as real pairs seldom are: agent_b at inverse-depth noise 0.03,
// agent_a at 0.01, drift 2.5 %, every overlap, seeds 0-5, ours only; each world merged b -> a (the
// noisier map as source) and a -> b (as target). The refinement finds a noisier map smaller, and
// fewer merges miss with it as target (README, Troubleshooting); the simulated section's cells
// give both maps of a world the same noise, where much of that cancels.
SimSweep unequalSweep(bool quick) {
  SimSweep s;
  for (double overlap : {0.15, 0.35, 0.6}) s.cells.push_back({overlap, 0.025, 0.01, 0.03, true});
  if (quick) s.cells.resize(1);
  s.seeds = quick ? 1 : 6;
  s.peers = false;
  s.stem = "unequal";
  s.cells_text = quick ? "agent_b's inverse-depth noise 0.03, agent_a's 0.01, drift 2.5 %, overlap 15 % (quick mode), "
                         "each world merged b → a and a → b"
                       : "agent_b's inverse-depth noise 0.03, agent_a's 0.01, drift 2.5 %, every overlap, each world "
                         "merged b → a (the noisier map as source) and a → b (as target)";
  s.label = "Unequal noise";
  return s;
}

// The pairs of merges of one world both ways: each b -> a case with its a -> b twin.
std::vector<std::pair<const CaseResult*, const CaseResult*>> bothWays(const std::vector<CaseResult>& results) {
  std::map<std::string, const CaseResult*> by_name;
  for (const CaseResult& c : results) by_name[c.name] = &c;
  std::vector<std::pair<const CaseResult*, const CaseResult*>> pairs;
  for (const CaseResult& ba : results) {
    const std::size_t slash = ba.name.rfind('/');
    if (slash == std::string::npos || ba.name.find("/reversed/") != std::string::npos) continue;
    const auto it = by_name.find(ba.name.substr(0, slash) + "/reversed" + ba.name.substr(slash));
    if (it != by_name.end()) pairs.emplace_back(&ba, it->second);
  }
  return pairs;
}

std::string cellName(const SimCell& c) {
  return "overlap " + fmt(100 * c.overlap, 0) + " %, drift " + fmt(100 * c.drift, 1) + " %, noise " + fmt(c.noise, 2) +
         (c.source_noise >= 0.0 ? " (agent_b " + fmt(c.source_noise, 2) + ")" : "");
}

// The three merges of a world (keyframe depth from depth images, from the keyframes' own
// semi-dense depth, from the map cloud), b -> a and with both_orders also a -> b, and, with a
// third agent, c -> a.
void runWorld(const Simulation& sim, const std::string& tag, const std::string& cell, bool both_orders,
              const CaseRunOptions& options, std::vector<CaseResult>& results,
              std::map<std::string, std::vector<PeerRun>>& peer_cache) {
  const AgentMap& a = sim.agents[0].map;
  const AgentMap& b = sim.agents[1].map;
  const AgentMap a_nodepth = test::withoutDepthImages(a), b_nodepth = test::withoutDepthImages(b);
  const AgentMap a_lsd = test::withLsdKeyframeDepth(sim.agents[0], sim.options.camera);
  const AgentMap b_lsd = test::withLsdKeyframeDepth(sim.agents[1], sim.options.camera);
  struct Variant {
    const char* name;
    const char* cell;
    const AgentMap *b, *a;
  };
  const Variant variants[] = {{"/depth", ", depth images", &b, &a},
                              {"/lsd", ", LSD keyframe depth", &b_lsd, &a_lsd},
                              {"/nodepth", ", no depth images", &b_nodepth, &a_nodepth}};
  // One pipeline for the merges: the images are the same, so the later ones take their SIFT
  // features from the cache (their time is then that of a warm merge).
  MergePipeline pipeline{MergeOptions()};
  for (const bool reversed : {false, true}) {
    if (reversed && !both_orders) break;
    const SimPairTruth& truth = reversed ? sim.pair(1, 0) : sim.pair(0, 1);
    for (const Variant& v : variants) {
      CaseInput in;
      in.name = tag + (reversed ? "/reversed" : "") + v.name;
      in.family = "simulated";
      in.cell = cell + (both_orders ? (reversed ? kReversedCell : kForwardCell) : "") + v.cell;
      in.overlap = truth.overlap;
      in.source = reversed ? v.a : v.b;
      in.target = reversed ? v.b : v.a;
      in.truth = truth.target_source;
      for (const SimKeyframePair& k : truth.keyframe_pairs) {
        in.local_truths[{k.target_id, k.source_id}] = k.target_source;
      }
      in.clouds_key = tag + (reversed ? "/reversed" : "");
      in.pipeline = &pipeline;
      results.push_back(runCase(in, options, peer_cache));
    }
  }
  if (sim.agents.size() > 2 && !sim.pair(0, 2).overlap) {
    CaseInput in;
    in.name = tag + "/apart";
    in.family = "simulated";
    in.cell = "apart (third agent)";
    in.overlap = false;
    in.source = &sim.agents[2].map;
    in.target = &a;
    in.truth = sim.pair(0, 2).target_source;
    in.clouds_key = tag + "/apart";
    results.push_back(runCase(in, options, peer_cache));
  }
}

void writeSimulated(Output& out, const SimSweep& s, const std::vector<CaseResult>& results,
                    const std::map<std::string, int>& best, double seconds, std::FILE* headline) {
  const std::string stem = s.stem;
  std::FILE* csv = out.open(stem + ".csv");
  writeCaseCsv(csv, results);
  std::fclose(csv);
  std::FILE* md = out.open(stem + ".md");
  std::fprintf(md, "Worlds made in this run by `simulate()` (seeds 1000+k, k = %d–%d; 2 agents at the cell's overlap, 30° "
                   "apart in view angle, 320×240 keyframes, about 5 per agent%s). Scale drift of either sign over each path with a map bend of "
                   "40° per unit of drift; semi-dense inverse-depth noise at the reference gradient as given; each "
                   "world merged three times%s: with its depth images (dense, exact), with each keyframe's own "
                   "semi-dense inverse depth and variance as LSD-SLAM publishes it (what the node merges), and with "
                   "neither (keyframe depth from the map cloud); one pipeline, so the second and third take their SIFT "
                   "features from the cache and their time is a warm merge's. "
                   "Cells: %s. "
                   "%s Truth: the simulator's least-squares similarity over the co-visible points of both maps "
                   "(exact; with drift it is what a merge of the overlap should find, and the truths of a→b and "
                   "b→a are inverses), so no truth uncertainty is added to "
                   "the NEES. Same columns and floors as the real cases; %zu merges in %.0f s.\n\n",
               s.first_seed, s.first_seed + s.seeds - 1,
               s.first_seed == 0 ? "; a third agent that does not overlap in seed k = 0 of each cell" : "",
               std::any_of(s.cells.begin(), s.cells.end(), [](const SimCell& c) { return c.both_orders; })
                   ? " in each order (b → a, then a → b: the same world, the roles of source and target exchanged)"
                   : "",
               s.cells_text,
               s.peers ? "Open3D runs every setting on the first seed of each cell and the best of those on the others."
                       : "No peer runs on these worlds (ours only).",
               results.size(), seconds);
  const Aggregate a = aggregate(results, best);
  {
    const NeesPool& nl = a.nees_local;
    const NeesPool& kl = a.nees_keyframe_local;
    const NeesPool& ko = a.nees_keyframe_same;
    std::fprintf(md, "The reported covariance stands for the similarity at the edge's anchor keyframe pair (the pose-graph "
                     "edge is attached there, and with drift it differs from the overlap's by the spread between keyframe "
                     "pairs). Against the simulator's local truth of that pair (rows `pcr_pro reported against the anchor pair's local "
                     "truth` of the CSV; n = %d merges whose anchor pair is a co-visible one): ANEES rotation %s, 6-DoF %s, "
                     "scale %s. The keyframe estimate stands for the same pair: against the same local truths (rows "
                     "`pcr_pro keyframe-only against the anchor pair's local truth`) its ANEES is rotation %s, 6-DoF %s, "
                     "scale %s, where on the same merges against the overlap's truth it is rotation %s, 6-DoF %s, scale %s.\n\n",
                 nl.n, neesCell(nl.anees_rot, nl.under_rot).c_str(), neesCell(nl.anees6, nl.under6).c_str(),
                 neesCell(nl.anees_scale, nl.under_scale).c_str(), neesCell(kl.anees_rot, kl.under_rot).c_str(),
                 neesCell(kl.anees6, kl.under6).c_str(), neesCell(kl.anees_scale, kl.under_scale).c_str(),
                 neesCell(ko.anees_rot, ko.under_rot).c_str(), neesCell(ko.anees6, ko.under6).c_str(),
                 neesCell(ko.anees_scale, ko.under_scale).c_str());
    const NeesPool& rl = a.nees_refined_local;
    std::fprintf(md, "The refinement's own covariance against the same local truths (rows `pcr_pro refined against the "
                     "anchor pair's local truth`, n = %d): ANEES rotation %s, 6-DoF %s, scale %s. Of the %d merges "
                     "above that report a kept refinement, those beyond the 6-DoF bound with no raise by the "
                     "disagreement with the keyframe estimate (`disagreement_scale` 1): %d. On those the disagreement "
                     "lies within the two estimates' covariances (docs/DESIGN.md, \"What the disagreement raise cannot see\").\n\n",
                 rl.n, neesCell(rl.anees_rot, rl.under_rot).c_str(), neesCell(rl.anees6, rl.under6).c_str(),
                 neesCell(rl.anees_scale, rl.under_scale).c_str(), a.kept_local, a.kept_local_beyond_unraised);
  }
  // One aggregate table per sweep dimension (the cases regrouped), and by the keyframe depth's source.
  const std::vector<std::pair<const char*, std::function<std::string(const CaseResult&)>>> groupings = {
      {"overlap", [](const CaseResult& c) { return c.cell.substr(0, c.cell.find(',')); }},
      {"drift", [](const CaseResult& c) { return c.cell.substr(c.cell.find("drift"), c.cell.find(", noise") - c.cell.find("drift")); }},
      {"noise and keyframe depth", [](const CaseResult& c) { return c.cell.substr(c.cell.find("noise")); }}};
  for (const auto& [title, key] : groupings) {
    std::vector<CaseResult> regrouped;
    for (const CaseResult& c : results) {
      if (!c.overlap) continue;
      regrouped.push_back(c);
      regrouped.back().cell = key(c);
    }
    std::fprintf(md, "By %s:\n\n", title);
    writeAggregateTable(md, regrouped, best);
  }
  std::vector<CaseResult> apart;
  for (const CaseResult& c : results) {
    if (!c.overlap) apart.push_back(c);
  }
  if (!apart.empty()) {
    std::fprintf(md, "Non-overlapping pairs (third agent):\n\n");
    writeAggregateTable(md, apart, best);
  }
  const Symmetry sym = symmetry(bothWays(results));
  const std::string symmetry_text = symmetryText(sym, "pairs of merges (each world and keyframe depth, both ways)");
  if (sym.pairs > 0) {
    std::fprintf(md, "**Symmetry** (issue 12: a → b must be the inverse of b → a within their uncertainties): %s. "
                     "The two merges share their data, so their errors are correlated and the sum of the "
                     "covariances overstates the difference's: the bound is lenient.\n\n",
                 symmetry_text.c_str());
  }
  writeIcpFromTruth(md, results);
  writeProjective(md, results);
  if (s.peers) writeOpen3dSweep(md, results, {"simulated"});
  std::fprintf(md, "<details><summary>Per case</summary>\n\n");
  writeCaseTable(md, results, best);
  std::fprintf(md, "</details>\n\n");
  std::fclose(md);
  const NeesPool& n = a.nees;
  const NeesPool& nl = a.nees_local;
  const double rate = a.overlapping ? 100.0 * a.success / a.overlapping : 0.0;
  // The covariance stands for the similarity at the edge's anchor keyframe pair (each map drifts,
  // so that differs from the overlap's by the between-pair spread): its NEES against that pair's
  // local truth, besides the overlap truth's above.
  const std::string local = "; against the anchor keyframe pair's local truth (what the covariance stands for, n = " +
                            std::to_string(nl.n) + ") rotation " + neesCell(nl.anees_rot, nl.under_rot) + ", 6-DoF " +
                            neesCell(nl.anees6, nl.under6) + ", scale " + neesCell(nl.anees_scale, nl.under_scale) +
                            " (floors: **" + (neesFloorsMet(nl) ? "met" : "NOT met") + "**)";
  if (!s.peers) {
    std::fprintf(headline,
                 "- **%s** (%zu cell%s: %s; seeds %d–%d, ours only): **%d / %d = %.1f %%** "
                 "within the floors (keyframe-only %d, refined %d), %d merged; ANEES reported rotation %s, 6-DoF %s, "
                 "scale %s (floors: **%s**)%s; refinement alone from the exact truth within the floors on %d / %d",
                 s.label, s.cells.size(), s.cells.size() == 1 ? "" : "s", s.cells_text, s.first_seed,
                 s.first_seed + s.seeds - 1, a.success,
                 a.overlapping, rate,
                 a.keyframe_success, a.refined_success, a.merged, neesCell(n.anees_rot, n.under_rot).c_str(),
                 neesCell(n.anees6, n.under6).c_str(), neesCell(n.anees_scale, n.under_scale).c_str(),
                 neesFloorsMet(n) ? "met" : "NOT met", local.c_str(), a.icp_from_truth_success, a.icp_from_truth_run);
    // Both orders of one world: each order's count, which the totals above pool.
    std::vector<CaseResult> order[2];
    for (const CaseResult& c : results) order[c.name.find("/reversed/") != std::string::npos].push_back(c);
    if (!order[1].empty()) {
      const Aggregate b_onto_a = aggregate(order[0], best), a_onto_b = aggregate(order[1], best);
      std::fprintf(headline, ". By order: b → a %d / %d (keyframe-only %d, refined %d), a → b %d / %d (%d, %d)",
                   b_onto_a.success, b_onto_a.overlapping, b_onto_a.keyframe_success, b_onto_a.refined_success,
                   a_onto_b.success, a_onto_b.overlapping, a_onto_b.keyframe_success, a_onto_b.refined_success);
    }
    if (sym.pairs > 0) std::fprintf(headline, ". Symmetry: %s", symmetry_text.c_str());
    std::fprintf(headline, ".\n");
    return;
  }
  std::fprintf(headline,
               "- **Simulated worlds** (%zu cell%s: %s; %d seed(s) per cell, each merged with depth images, with "
               "LSD-SLAM's keyframe depth and with neither): **%d / %d = %.1f %%** within the floors (keyframe-only "
               "%d, refined %d); floor ≥ 99 %%: **%s**; false merges %d / %d. ANEES reported rotation %s, 6-DoF %s, "
               "scale %s; floors: **%s**%s. Open3D (best setting): %d / %d, false merges %d / %d. Our refinement "
               "alone (no keyframes) started at the exact truth stays within the floors on %d / %d cases (it must "
               "stay there: **%s**).\n",
               s.cells.size(), s.cells.size() == 1 ? "" : "s", s.cells_text, s.seeds, a.success, a.overlapping, rate,
               a.keyframe_success,
               a.refined_success, rate >= 99.0 ? "met" : "NOT met", a.false_merges, a.apart,
               neesCell(n.anees_rot, n.under_rot).c_str(), neesCell(n.anees6, n.under6).c_str(),
               neesCell(n.anees_scale, n.under_scale).c_str(), neesFloorsMet(n) ? "met" : "NOT met", local.c_str(),
               a.open3d_success,
               a.overlapping, a.open3d_false, a.open3d_apart_ran, a.icp_from_truth_success, a.icp_from_truth_run,
               a.icp_from_truth_success == a.icp_from_truth_run ? "met" : "NOT met");
}

// Runs a sweep's worlds and writes its section.
void runSweep(Output& out, const SuiteConfig& config, const SimSweep& s, std::FILE* headline) {
  std::vector<CaseResult> results;
  std::map<std::string, std::vector<PeerRun>> peer_cache;
  const double t0 = nowMs();
  CaseRunOptions options;
  options.peers = s.peers && !config.ours_only;
  options.pcl = false;  // the PCL refiners are compared on the real cases only (time)
  // Open3D: every setting on the first seed of each cell, then the best of those on the others.
  std::map<std::string, int> best;
  for (int seed = s.first_seed; seed < s.first_seed + s.seeds; ++seed) {
    if (seed == s.first_seed + 1 && options.peers) {
      best["simulated"] = bestOpen3dSetting(results, "simulated");
      options.open3d_settings = {best["simulated"]};
    }
    for (const SimCell& c : s.cells) {
      const Simulation sim =
          simulate(test::benchWorldOptions(c.overlap, c.drift, c.noise, seed, seed == 0, c.source_noise));
      const std::string tag = "o" + fmt(c.overlap, 2) + "_d" + fmt(c.drift, 3) + "_n" + fmt(c.noise, 2) +
                              (c.source_noise >= 0.0 ? "+" + fmt(c.source_noise, 2) : "") + "_s" + std::to_string(seed);
      runWorld(sim, tag, cellName(c), c.both_orders, options, results, peer_cache);
    }
  }
  if (s.seeds == 1 && options.peers) best["simulated"] = bestOpen3dSetting(results, "simulated");
  writeSimulated(out, s, results, best, (nowMs() - t0) / 1000.0, headline);
}

}  // namespace

void sectionSimulated(Output& out, const SuiteConfig& config, std::FILE* headline) {
  runSweep(out, config, simSweep(config.quick), headline);
}

void sectionHeldOut(Output& out, const SuiteConfig& config, std::FILE* headline) {
  runSweep(out, config, heldOutSweep(config.quick), headline);
}

void sectionUnequal(Output& out, const SuiteConfig& config, std::FILE* headline) {
  runSweep(out, config, unequalSweep(config.quick), headline);
}

}  // namespace bench
}  // namespace pcr_pro
