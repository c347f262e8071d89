// make bench, the suite: one section per table of docs/BENCHMARKS.md, each in its own file
// (section_*.cpp), run by bench_suite.cpp. Shared here: the result rows of the older tables,
// formatting, and the section entry points.
#pragma once

#include <cstdio>
#include <string>
#include <vector>

#include "bench_common.h"
#include "peers.h"
#include "pcr_pro/io/report.h"

namespace pcr_pro {
namespace bench {

/// One run of the robustness sweep or the car scans.
struct Row {
  std::string method, variant;
  double ratio = 1, roll = 0, sparsity = 1;
  std::string status;
  Errors err;
  bool ok = false;
  double ms = 0;
};

/// A number with `prec` decimals.
std::string fmt(double v, int prec = 2);
/// "42 %" (or "n/a" for den = 0).
std::string pct(int num, int den);
/// Result row of a pcr_pro report (success: status OK and within the older 1° / 1 % / 1 % criterion).
Row fromReport(const RegistrationReport& rep, const Sim3& truth, double extent, double ms);
/// Result row of a peer.
Row fromPeer(const PeerResult& p, const Sim3& truth, double extent);
/// CSV of rows, with a header line.
void writeRows(std::FILE* f, const std::vector<Row>& rows);

/// What the run does: full, or --quick (a reduced version of every section).
struct SuiteConfig {
  bool quick = false;
  /// `--ours-only`: the real and simulated sections run no peer (a quick look at our own numbers
  /// while developing; BENCHMARKS.md is always made with the peers).
  bool ours_only = false;
  std::string self;  ///< this executable (for the memory probes)
};

/// Robustness sweep on the slambook2 two-agent cases (scale ratio, roll, sparsity, noise, outliers, ablations).
void sectionSweep(Output& out, const SuiteConfig& config, std::FILE* headline);
/// The real car scans with a known scale.
void sectionCar(Output& out, const SuiteConfig& config);
/// Speed: per stage vs point count, the 70k-point floor, memory, the pair search and the warm cache.
void sectionTiming(Output& out, const SuiteConfig& config, std::FILE* headline);
/// `--memory N merge|idle`: prints the peak RSS [MiB] of this process after (optionally) one merge.
int memoryProbe(int points, bool merge);
/// Monte-Carlo covariance consistency (closed_form / calibrated / blocks).
void sectionConsistency(Output& out, const SuiteConfig& config, std::FILE* headline);
/// Every real two-agent case of BUILD/real_cases: ours (keyframe, refined, reported) and the peers.
void sectionRealCases(Output& out, const SuiteConfig& config, std::FILE* headline);
/// Simulated worlds swept over drift, overlap and depth noise, with and without depth images.
void sectionSimulated(Output& out, const SuiteConfig& config, std::FILE* headline);
/// The simulated worlds' cells with the next four seeds, ours only (heldout.md, heldout.csv).
void sectionHeldOut(Output& out, const SuiteConfig& config, std::FILE* headline);
/// Maps of unequal noise (agent_b 0.03, agent_a 0.01), seeds 0-5, ours only (unequal.md, unequal.csv).
void sectionUnequal(Output& out, const SuiteConfig& config, std::FILE* headline);

}  // namespace bench
}  // namespace pcr_pro
