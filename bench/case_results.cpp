#include "case_results.h"

#include <algorithm>
#include <cmath>

#include "bench_common.h"
#include "pcr_pro/geometry/similarity_fit.h"
#include "pcr_pro/io/text_escape.h"
#include "pcr_pro/merge/map_registration.h"
#include "pcr_pro/merge/merge_options.h"
#include "pcr_pro/registration/projective_registration.h"
#include "suite.h"

namespace pcr_pro {
namespace bench {
namespace {

// The scores of our three estimates.
void scoreOurs(const MergeResult& r, const CaseInput& in, const Matrix7d& truth_cov, const Eigen::Vector3d& centroid,
               double extent, CaseResult& out) {
  const MergeDiagnostics& d = r.diagnostics;
  if (d.used_pairs > 0) out.keyframe = score(d.initial, d.keyframe_covariance, in.truth, truth_cov, centroid, extent);
  if (d.refinement_status == Status::kOk) {
    out.refined = score(d.refined, d.refined_covariance, in.truth, truth_cov, centroid, extent);
  }
  if (r.report.status == Status::kOk && r.report.transform) {
    out.reported = score(*r.report.transform, d.covariance, in.truth, truth_cov, centroid, extent);
    out.estimate = *r.report.transform;
    out.covariance = d.covariance;
    if (r.report.keyframe_edge) {
      const auto local = in.local_truths.find({r.report.keyframe_edge->target_keyframe, r.report.keyframe_edge->source_keyframe});
      if (local != in.local_truths.end()) {
        out.reported_local = score(*r.report.transform, d.covariance, local->second, truth_cov, centroid, extent);
        out.keyframe_local = score(d.initial, d.keyframe_covariance, local->second, truth_cov, centroid, extent);
        if (d.refinement_status == Status::kOk) {
          out.refined_local = score(d.refined, d.refined_covariance, local->second, truth_cov, centroid, extent);
        }
      }
    }
  }
}

std::vector<PeerRun> runOpen3dSettings(const CaseInput& in, const std::vector<int>& which,
                                       const Eigen::Vector3d& centroid, double extent) {
  std::vector<PeerRun> runs;
  PeerParams pp;
  pp.target_size = extent;
  pp.source_size = boxDiagonal(in.source->cloud);
  for (std::size_t k = 0; k < open3dSettings().size(); ++k) {
    PeerRun run;
    if (!which.empty() && std::find(which.begin(), which.end(), static_cast<int>(k)) == which.end()) {
      runs.push_back(run);
      continue;
    }
    const PeerResult p = runOpen3d(in.source->cloud, in.target->cloud, pp, open3dSettings()[k]);
    run.tried = true;
    run.ran = p.ran;
    run.ms = p.ms;
    if (p.ran) run.score = score(p.transform, Matrix7d::Zero(), in.truth, Matrix7d::Zero(), centroid, extent);
    runs.push_back(run);
  }
  return runs;
}

std::vector<PeerRun> runPclFrom(const CaseInput& in, const Sim3& start, const Eigen::Vector3d& centroid, double extent,
                                int max_points) {
  std::vector<PeerRun> runs;
  const Cloud source = capped(in.source->cloud, max_points), target = capped(in.target->cloud, max_points);
  PeerParams pp;
  pp.target_size = extent;
  pp.source_size = boxDiagonal(source);
  for (std::size_t k = 0; k < pclMethods().size(); ++k) {
    const PeerResult p = runPcl(static_cast<int>(k), source, target, pp, start);
    PeerRun run;
    run.ran = p.ran;
    run.ms = p.ms;
    if (p.ran) run.score = score(p.transform, Matrix7d::Zero(), in.truth, Matrix7d::Zero(), centroid, extent);
    runs.push_back(run);
  }
  return runs;
}

// Our refinement alone, without keyframe anchors, started at the exact truth: what the clouds
// alone do with a perfect start (the merge's MapRegistration with the default options and the
// scale estimated, as pcr_pro_icp --estimate-scale).
// With `local_noise`, IcpOptions::local_noise on instead of its default; `jackknife_blocks` sets
// covariance.jackknife_blocks.
PeerRun icpFromTruth(const CaseInput& in, const Matrix7d& truth_cov, const Eigen::Vector3d& centroid, double extent,
                     bool local_noise, int jackknife_blocks = CovarianceOptions().jackknife_blocks) {
  PeerRun run;
  run.tried = true;
  const double t0 = nowMs();
  RegistrationOptions options = MergeOptions().registration;
  options.icp.local_noise = local_noise;
  options.covariance.jackknife_blocks = jackknife_blocks;
  const MergeGateOptions gates;
  MapRegistration registration(options, true, gates.reweigh_keyframe_matches);
  if (!registration.setClouds(in.source->cloud, in.target->cloud).empty()) return run;
  const Refinement r = registration.refine(in.truth, {});
  run.ms = nowMs() - t0;
  run.ran = r.status == Status::kOk || r.status == Status::kDegenerate;
  run.score = score(r.estimate, r.covariance, in.truth, truth_cov, centroid, extent);
  return run;
}

// The projective registration of the keyframes' depth alone, on the whole maps, from `start`.
// With `gauss_newton`, the same estimate scored under the stage's Gauss-Newton covariance alone, and
// with `jackknifed`, whether the reported covariance holds the keyframe jackknife.
PeerRun projectiveFrom(const CaseInput& in, const Sim3& start, const Matrix7d& truth_cov,
                       const Eigen::Vector3d& centroid, double extent, PeerRun* gauss_newton = nullptr,
                       bool* jackknifed = nullptr) {
  PeerRun run;
  run.tried = true;
  const double t0 = nowMs();
  const ProjectiveResult r = registerProjective(*in.source, *in.target, start);
  run.ms = nowMs() - t0;
  run.ran = r.status == Status::kOk;
  run.status = statusName(r.status);
  // A run still moving at its iteration limit has an estimate so far: scored for the CSV, but not
  // counted as a result (ran is false).
  if (run.ran || r.status == Status::kIcpNotConverged) {
    run.score = score(r.estimate, r.covariance, in.truth, truth_cov, centroid, extent);
    if (gauss_newton != nullptr) {
      *gauss_newton = run;
      gauss_newton->ms = 0.0;
      gauss_newton->score = score(r.estimate, r.gauss_newton_covariance, in.truth, truth_cov, centroid, extent);
    }
  }
  if (jackknifed != nullptr) *jackknifed = r.jackknifed;
  return run;
}

std::string scoreCells(const Score& s) {
  if (!s.has) return "–";
  return fmt(s.rotation_deg, 2) + " / " + fmt(s.translation_pct, 2) + " / " + fmt(s.scale_pct, 2);
}

}  // namespace

CaseResult runCase(const CaseInput& in, const CaseRunOptions& options,
                   std::map<std::string, std::vector<PeerRun>>& peer_cache) {
  CaseResult out;
  out.name = in.name;
  out.family = in.family;
  out.cell = in.cell;
  out.overlap = in.overlap;
  const double extent = boxDiagonal(in.target->cloud);
  const Eigen::Vector3d centroid = in.source->cloud.rowwise().mean();
  TruthAccuracy accuracy = in.accuracy;
  accuracy.centre = in.truth.apply(centroid);
  const Matrix7d truth_cov = truthCovariance(accuracy);
  MergePipeline fresh{MergeOptions()};
  MergePipeline& pipeline = in.pipeline ? *in.pipeline : fresh;
  const double t0 = nowMs();
  const MergeResult r = pipeline.merge(*in.source, *in.target, MergeRequest(), "agent_b", "agent_a");
  out.ms = nowMs() - t0;
  out.status = statusName(r.report.status);
  out.refinement_kept = r.diagnostics.refinement_kept;
  out.disagreement_scale = r.diagnostics.disagreement_scale;
  out.used_pairs = r.diagnostics.used_pairs;
  scoreOurs(r, in, truth_cov, centroid, extent, out);
  if (options.peers && haveOpen3d()) {
    auto it = peer_cache.find(in.clouds_key);
    if (in.clouds_key.empty() || it == peer_cache.end()) {
      out.open3d = runOpen3dSettings(in, options.open3d_settings, centroid, extent);
      if (!in.clouds_key.empty()) peer_cache[in.clouds_key] = out.open3d;
    } else {
      out.open3d = it->second;
    }
  }
  if (options.icp_from_truth && in.overlap) {
    // Cases with the same clouds share the run (its inputs are the clouds and the truth).
    const std::string key = in.clouds_key.empty() ? "" : in.clouds_key + "#icp_from_truth";
    auto it = peer_cache.find(key);
    if (key.empty() || it == peer_cache.end()) {
      out.icp_from_truth = icpFromTruth(in, truth_cov, centroid, extent, IcpOptions().local_noise);
      out.icp_from_truth_local = icpFromTruth(in, truth_cov, centroid, extent, true);
      out.icp_from_truth_jackknife =
          icpFromTruth(in, truth_cov, centroid, extent, IcpOptions().local_noise, kBenchJackknifeBlocks);
      if (!key.empty()) {
        peer_cache[key] = {out.icp_from_truth, out.icp_from_truth_local, out.icp_from_truth_jackknife};
      }
    } else {
      out.icp_from_truth = it->second.at(0);
      out.icp_from_truth_local = it->second.at(1);
      out.icp_from_truth_jackknife = it->second.at(2);
    }
  }
  if (in.overlap && hasDepthUncertainty(*in.source) && hasDepthUncertainty(*in.target)) {
    out.projective_from_truth = projectiveFrom(in, in.truth, truth_cov, centroid, extent);
    if (r.diagnostics.used_pairs > 0) {
      out.projective_from_keyframes =
          projectiveFrom(in, r.diagnostics.initial, truth_cov, centroid, extent,
                         &out.projective_from_keyframes_gauss_newton, &out.projective_jackknifed);
    }
  }
  if (hasDepthUncertainty(*in.source) && hasDepthUncertainty(*in.target)) {
    MergeOptions with_projective;
    with_projective.merge.projective_refinement = true;
    MergePipeline projective_pipeline(with_projective);
    const double tp = nowMs();
    const MergeResult m = projective_pipeline.merge(*in.source, *in.target, MergeRequest(), "agent_b", "agent_a");
    out.merged_projective.tried = true;
    out.merged_projective.ms = nowMs() - tp;
    out.merged_projective.status = statusName(m.report.status);
    out.merged_projective.ran = m.report.status == Status::kOk && m.report.transform.has_value();
    if (out.merged_projective.ran) {
      out.merged_projective.score =
          score(*m.report.transform, m.diagnostics.covariance, in.truth, truth_cov, centroid, extent);
    }
    out.projective_used = m.diagnostics.projective_refinement;
    if (out.merged_projective.ran && m.report.keyframe_edge) {
      const auto local =
          in.local_truths.find({m.report.keyframe_edge->target_keyframe, m.report.keyframe_edge->source_keyframe});
      if (local != in.local_truths.end()) {
        out.merged_projective_local =
            score(*m.report.transform, m.diagnostics.covariance, local->second, truth_cov, centroid, extent);
      }
    }
    out.projective_stage_ms = m.diagnostics.ms_projective;
  }
  if (options.pcl && r.diagnostics.used_pairs > 0) {
    out.pcl = runPclFrom(in, r.diagnostics.initial, centroid, extent, options.pcl_max_points);
  }
  std::fprintf(stderr, "case %s: %s (%.0f ms)%s\n", in.name.c_str(), out.status.c_str(), out.ms,
               out.reported.has ? (out.reported.within_floors ? " within floors" : " outside floors") : "");
  return out;
}

int bestOpen3dSetting(const std::vector<CaseResult>& results, const std::string& family) {
  int best = 0, best_ok = -1;
  double best_rot = 1e300;
  for (std::size_t k = 0; k < open3dSettings().size(); ++k) {
    int ok = 0;
    std::vector<double> rot;
    for (const CaseResult& c : results) {
      if (c.family != family || !c.overlap || c.open3d.size() <= k || !c.open3d[k].tried) continue;
      const PeerRun& p = c.open3d[k];
      ok += p.ran && p.score.within_floors;
      rot.push_back(p.ran ? p.score.rotation_deg : 180.0);
    }
    const double m = median(rot);
    if (ok > best_ok || (ok == best_ok && m < best_rot)) {
      best = static_cast<int>(k);
      best_ok = ok;
      best_rot = m;
    }
  }
  return best;
}

Aggregate aggregate(const std::vector<CaseResult>& results, const std::map<std::string, int>& best_setting) {
  Aggregate a;
  a.pcl_success.assign(pclMethods().size(), 0);
  std::vector<Score> rep, kf, ref, local, keyframe_local, keyframe_same, refined_local;
  std::vector<double> ms, o3d_ms;
  for (const CaseResult& c : results) {
    ms.push_back(c.ms);
    const auto b = best_setting.find(c.family);
    const PeerRun* o3d = b != best_setting.end() && static_cast<std::size_t>(b->second) < c.open3d.size() &&
                                 c.open3d[static_cast<std::size_t>(b->second)].tried
                             ? &c.open3d[static_cast<std::size_t>(b->second)]
                             : nullptr;
    if (o3d) o3d_ms.push_back(o3d->ms);
    if (!c.overlap) {
      ++a.apart;
      a.false_merges += c.status == "OK";
      if (o3d) {
        ++a.open3d_apart_ran;
        a.open3d_false += o3d->ran;
      }
      continue;
    }
    ++a.overlapping;
    a.merged += c.reported.has;
    a.success += c.reported.has && c.reported.within_floors;
    a.keyframe_success += c.keyframe.has && c.keyframe.within_floors;
    a.refined_success += c.refined.has && c.refined.within_floors;
    if (o3d) a.open3d_success += o3d->ran && o3d->score.within_floors;
    for (std::size_t k = 0; k < c.pcl.size(); ++k) a.pcl_success[k] += c.pcl[k].ran && c.pcl[k].score.within_floors;
    if (c.icp_from_truth.tried) {
      ++a.icp_from_truth_run;
      a.icp_from_truth_success += c.icp_from_truth.ran && c.icp_from_truth.score.within_floors;
      a.icp_from_truth_local_success += c.icp_from_truth_local.ran && c.icp_from_truth_local.score.within_floors;
    }
    if (c.reported.has) rep.push_back(c.reported);
    if (c.reported_local.has) local.push_back(c.reported_local);
    if (c.refined_local.has) refined_local.push_back(c.refined_local);
    if (c.reported_local.has && c.reported_local.has_covariance && c.refinement_kept) {
      ++a.kept_local;
      a.kept_local_beyond_unraised += c.reported_local.nees6 > kChi2_95_6 && !(c.disagreement_scale > 1.0);
    }
    if (c.keyframe_local.has && c.keyframe.has) {
      keyframe_local.push_back(c.keyframe_local);
      keyframe_same.push_back(c.keyframe);
    }
    if (c.keyframe.has) kf.push_back(c.keyframe);
    if (c.refined.has) ref.push_back(c.refined);
  }
  a.nees = pool(rep);
  a.nees_keyframe = pool(kf);
  a.nees_refined = pool(ref);
  a.nees_local = pool(local);
  a.nees_keyframe_local = pool(keyframe_local);
  a.nees_keyframe_same = pool(keyframe_same);
  a.nees_refined_local = pool(refined_local);
  a.median_ms = median(ms);
  a.median_open3d_ms = o3d_ms.empty() ? 0.0 : median(o3d_ms);
  return a;
}

void writeCaseCsv(std::FILE* f, const std::vector<CaseResult>& results) {
  std::fprintf(f, "case,overlap,method,status,rotation_deg,translation_pct,scale_pct,within_floors,nees_rot,nees6,"
                  "nees_scale,raw_nees_rot,raw_nees6,raw_nees_scale,ms\n");
  // within_floors counts as the md tables do: only an estimate that was made (a peer that ran, a
  // refinement from the truth that converged), so that a count of the column matches them.
  const auto line = [f](const CaseResult& c, const std::string& method, const std::string& status, const Score& s,
                        bool made, double ms) {
    std::fprintf(f, "%s,%d,%s,%s,%.5g,%.5g,%.5g,%d,%.5g,%.5g,%.5g,%.5g,%.5g,%.5g,%.1f\n", csvField(c.name).c_str(),
                 c.overlap ? 1 : 0, csvField(method).c_str(), csvField(status).c_str(), s.rotation_deg,
                 s.translation_pct, s.scale_pct, made && s.within_floors ? 1 : 0, s.nees_rot, s.nees6, s.nees_scale,
                 s.raw_rot, s.raw6, s.raw_scale, ms);
  };
  for (const CaseResult& c : results) {
    line(c, "pcr_pro reported", c.status, c.reported, c.reported.has, c.ms);
    line(c, "pcr_pro keyframe-only", c.keyframe.has ? "ESTIMATE" : "NONE", c.keyframe, c.keyframe.has, 0.0);
    line(c, "pcr_pro refined", c.refined.has ? "ESTIMATE" : "NONE", c.refined, c.refined.has, 0.0);
    if (c.reported_local.has) {
      line(c, "pcr_pro reported against the anchor pair's local truth", c.status, c.reported_local, true, 0.0);
    }
    if (c.keyframe_local.has) {
      line(c, "pcr_pro keyframe-only against the anchor pair's local truth", "ESTIMATE", c.keyframe_local, true, 0.0);
    }
    if (c.refined_local.has) {
      line(c, "pcr_pro refined against the anchor pair's local truth", "ESTIMATE", c.refined_local, true, 0.0);
    }
    for (std::size_t k = 0; k < c.open3d.size(); ++k) {
      if (!c.open3d[k].tried) continue;
      line(c, "Open3D " + open3dSettings()[k].name(), c.open3d[k].ran ? "RAN" : "FAILED", c.open3d[k].score,
           c.open3d[k].ran, c.open3d[k].ms);
    }
    for (std::size_t k = 0; k < c.pcl.size(); ++k) {
      line(c, pclMethods()[k] + " from keyframe estimate", c.pcl[k].ran ? "RAN" : "FAILED", c.pcl[k].score,
           c.pcl[k].ran, c.pcl[k].ms);
    }
    if (c.icp_from_truth.tried) {
      line(c, "pcr_pro refinement alone from the truth", c.icp_from_truth.ran ? "CONVERGED" : "NOT_CONVERGED",
           c.icp_from_truth.score, c.icp_from_truth.ran, c.icp_from_truth.ms);
    }
    if (c.icp_from_truth_local.tried) {
      line(c, "pcr_pro refinement alone from the truth with local noise",
           c.icp_from_truth_local.ran ? "CONVERGED" : "NOT_CONVERGED", c.icp_from_truth_local.score,
           c.icp_from_truth_local.ran, c.icp_from_truth_local.ms);
    }
    if (c.icp_from_truth_jackknife.tried) {
      line(c, "pcr_pro refinement alone from the truth with jackknife covariance",
           c.icp_from_truth_jackknife.ran ? "CONVERGED" : "NOT_CONVERGED", c.icp_from_truth_jackknife.score,
           c.icp_from_truth_jackknife.ran, c.icp_from_truth_jackknife.ms);
    }
    for (const auto& [run, what] : {std::make_pair(&c.projective_from_truth, "from the truth"),
                                    std::make_pair(&c.projective_from_keyframes, "from the keyframe estimate")}) {
      if (!run->tried) continue;
      line(c, std::string("pcr_pro projective registration ") + what, run->status, run->score, run->ran, run->ms);
    }
    if (c.merged_projective.tried) {
      line(c, "pcr_pro reported with merge.projective_refinement", c.merged_projective.status,
           c.merged_projective.score, c.merged_projective.ran, c.merged_projective.ms);
    }
    if (c.projective_from_keyframes_gauss_newton.tried) {
      const PeerRun& run = c.projective_from_keyframes_gauss_newton;
      line(c, "pcr_pro projective registration from the keyframe estimate, Gauss-Newton covariance", run.status,
           run.score, run.ran, run.ms);
    }
  }
}

void writeIcpFromTruth(std::FILE* md, const std::vector<CaseResult>& results) {
  int run = 0, within = 0;
  std::string away;
  for (const CaseResult& c : results) {
    if (!c.icp_from_truth.tried) continue;
    ++run;
    const bool ok = c.icp_from_truth.ran && c.icp_from_truth.score.within_floors;
    within += ok;
    if (!ok) {
      away += "| " + c.name + " | " + (c.icp_from_truth.ran ? "converged" : "not converged") + " | " +
              scoreCells(c.icp_from_truth.score) + " |\n";
    }
  }
  if (run == 0) return;
  std::fprintf(md, "**Our refinement alone, started at the exact truth** (the merge's registration with the default "
                   "options, scale estimated, no keyframe matches as anchors: what `pcr_pro_icp --estimate-scale` "
                   "does from a perfect start; issue 12 asks that it stay there): within the floors on **%d / %d** "
                   "overlapping cases (cases with the same clouds share one run, and each counts).%s\n\n",
               within, run, away.empty() ? "" : " Where it did not stay:");
  if (!away.empty()) {
    std::fprintf(md, "| case | ICP | rot [deg] / trans [%% ext.] / scale [%%] |\n|---|---|---|\n%s\n", away.c_str());
  }
  int local = 0;
  for (const CaseResult& c : results) local += c.icp_from_truth_local.ran && c.icp_from_truth_local.score.within_floors;
  std::fprintf(md, "The same with `icp.error_minimizer.local_noise` on (each residual weighed by both clouds' local "
                   "surface thickness; off by default, README): within the floors on **%d / %d**.\n\n",
               local, run);
  std::vector<Score> blocks, jackknife;
  for (const CaseResult& c : results) {
    if (c.icp_from_truth.ran && c.icp_from_truth.score.has_covariance) blocks.push_back(c.icp_from_truth.score);
    if (c.icp_from_truth_jackknife.ran && c.icp_from_truth_jackknife.score.has_covariance) {
      jackknife.push_back(c.icp_from_truth_jackknife.score);
    }
  }
  const NeesPool b = pool(blocks), j = pool(jackknife);
  std::fprintf(md, "Its covariance against the truth (ANEES and fraction under the chi-square 95 %% bound, rotation / "
                   "6-DoF / scale, the truth's own uncertainty added), the default blocks model: %s / %s / %s (%d "
                   "runs); with `covariance.jackknife_blocks: %d` (off by default, README): %s / %s / %s (%d runs).\n\n",
               neesCell(b.anees_rot, b.under_rot).c_str(), neesCell(b.anees6, b.under6).c_str(),
               neesCell(b.anees_scale, b.under_scale).c_str(), b.n, kBenchJackknifeBlocks,
               neesCell(j.anees_rot, j.under_rot).c_str(), neesCell(j.anees6, j.under6).c_str(),
               neesCell(j.anees_scale, j.under_scale).c_str(), j.n);
}

void writeCaseTable(std::FILE* md, const std::vector<CaseResult>& results, const std::map<std::string, int>& best) {
  std::fprintf(md, "| case | status | keyframe-only: rot [deg] / trans [%% ext.] / scale [%%] | reported: rot / trans / "
                   "scale | refinement kept | NEES rot / 6-DoF / scale (reported) | floors | Open3D best: rot / trans "
                   "/ scale | time ours / Open3D [ms] |\n|---|---|---|---|---|---|---|---|---|\n");
  for (const CaseResult& c : results) {
    const auto b = best.find(c.family);
    const PeerRun* o3d = b != best.end() && static_cast<std::size_t>(b->second) < c.open3d.size() &&
                                 c.open3d[static_cast<std::size_t>(b->second)].tried
                             ? &c.open3d[static_cast<std::size_t>(b->second)]
                             : nullptr;
    const std::string nees = c.reported.has && c.reported.has_covariance
                                 ? fmt(c.reported.nees_rot, 1) + " / " + fmt(c.reported.nees6, 1) + " / " +
                                       fmt(c.reported.nees_scale, 1)
                                 : "–";
    const std::string floors = !c.overlap ? (c.status == "OK" ? "**false merge**" : "refused (right)")
                                          : (c.reported.has && c.reported.within_floors ? "yes" : "**no**");
    std::string peer = "–";
    if (o3d) {
      peer = o3d->ran ? (c.overlap ? scoreCells(o3d->score) + (o3d->score.within_floors ? " ✓" : "") : "merged (false)")
                      : "failed";
    }
    std::fprintf(md, "| %s | %s | %s | %s | %s | %s | %s | %s | %.0f / %s |\n", c.name.c_str(), c.status.c_str(),
                 scoreCells(c.keyframe).c_str(), scoreCells(c.reported).c_str(),
                 c.reported.has ? (c.refinement_kept ? "yes" : "no") : "–", nees.c_str(), floors.c_str(), peer.c_str(),
                 c.ms, o3d ? fmt(o3d->ms, 0).c_str() : "–");
  }
  std::fprintf(md, "\n");
}

void writeOpen3dSweep(std::FILE* md, const std::vector<CaseResult>& results, const std::vector<std::string>& families) {
  std::fprintf(md, "Open3D FPFH + RANSAC + ICP (with scaling), each cloud centred and divided by its own extent "
                   "before the features; successes within the floors on the overlapping cases per setting (lengths "
                   "in units of the normalised cloud), median time:\n\n| setting |");
  for (const std::string& f : families) std::fprintf(md, " %s |", f.c_str());
  std::fprintf(md, "\n|---|");
  for (std::size_t i = 0; i < families.size(); ++i) std::fprintf(md, "---|");
  std::fprintf(md, "\n");
  for (std::size_t k = 0; k < open3dSettings().size(); ++k) {
    std::fprintf(md, "| %s |", open3dSettings()[k].name().c_str());
    for (const std::string& f : families) {
      int ok = 0, n = 0;
      std::vector<double> ms;
      for (const CaseResult& c : results) {
        if (c.family != f || !c.overlap || c.open3d.size() <= k || !c.open3d[k].tried) continue;
        ++n;
        ok += c.open3d[k].ran && c.open3d[k].score.within_floors;
        ms.push_back(c.open3d[k].ms);
      }
      const bool is_best = static_cast<int>(k) == bestOpen3dSetting(results, f);
      std::fprintf(md, " %s%d / %d, %.0f ms%s |", is_best ? "**" : "", ok, n, ms.empty() ? 0.0 : median(ms),
                   is_best ? " (best)**" : "");
    }
    std::fprintf(md, "\n");
  }
  std::fprintf(md, "\n");
}

bool symmetryOf(const CaseResult& ba, const CaseResult& ab, double* rotation_deg, double* scale_pct, double* chi2) {
  if (!ba.reported.has || !ab.reported.has) return false;
  const Sim3 inverse = ab.estimate.inverse();
  const Matrix7d ad = similarityAdjoint(inverse);
  const Matrix7d joint = ba.covariance + ad * ab.covariance * ad.transpose();
  const Eigen::Matrix<double, 7, 1> d = similarityDifference(ba.estimate, inverse);
  *chi2 = d.dot(joint.ldlt().solve(d));
  *rotation_deg = d.segment<3>(3).norm() * 180.0 / M_PI;
  *scale_pct = 100.0 * std::abs(std::exp(d(6)) - 1.0);
  return true;
}

Symmetry symmetry(const std::vector<std::pair<const CaseResult*, const CaseResult*>>& pairs) {
  Symmetry out;
  for (const auto& [ba, ab] : pairs) {
    double rotation = 0.0, scale = 0.0, chi2 = 0.0;
    if (!symmetryOf(*ba, *ab, &rotation, &scale, &chi2)) continue;
    ++out.pairs;
    out.under += chi2 < kChi2_95_7 ? 1 : 0;
    out.rotation_deg.push_back(rotation);
    out.scale_pct.push_back(scale);
    out.chi2.push_back(chi2);
  }
  return out;
}

std::string symmetryText(const Symmetry& s, const std::string& what) {
  if (s.pairs == 0) return "";
  return "a → b inverted against b → a over " + std::to_string(s.pairs) + " " + what +
         ": rotation between them median " + fmt(median(s.rotation_deg), 2) + "°, largest " +
         fmt(*std::max_element(s.rotation_deg.begin(), s.rotation_deg.end()), 2) + "°; scale median " +
         fmt(median(s.scale_pct), 2) + " %, largest " +
         fmt(*std::max_element(s.scale_pct.begin(), s.scale_pct.end()), 2) +
         " %; squared Mahalanobis distance under the sum of their covariances median " + fmt(median(s.chi2), 2) +
         ", " + std::to_string(s.under) + " / " + std::to_string(s.pairs) +
         " under the χ² 95 % bound of 7 DoF (" + fmt(kChi2_95_7, 2) + ")";
}

void writeAggregateTable(std::FILE* md, const std::vector<CaseResult>& results, const std::map<std::string, int>& best) {
  std::vector<std::string> cells;
  for (const CaseResult& c : results) {
    if (std::find(cells.begin(), cells.end(), c.cell) == cells.end()) cells.push_back(c.cell);
  }
  cells.push_back("all");
  std::fprintf(md, "| cases | within floors: reported / keyframe-only / refined | merged | false merges (of apart) | "
                   "Open3D best: within floors / false merges |");
  for (const std::string& m : pclMethods()) std::fprintf(md, " %s from our keyframe estimate |", m.c_str());
  std::fprintf(md, " ANEES (under 95 %% bound) rot / 6-DoF / scale, reported | the same without the truth's "
                   "uncertainty (6-DoF / scale) | ANEES 6-DoF / scale keyframe-only; refined | median time ours, "
                   "Open3D / ours |\n|---|---|---|---|---|");
  for (std::size_t i = 0; i < pclMethods().size(); ++i) std::fprintf(md, "---|");
  std::fprintf(md, "---|---|---|---|\n");
  for (const std::string& cell : cells) {
    std::vector<CaseResult> sub;
    for (const CaseResult& c : results) {
      if (cell == "all" || c.cell == cell) sub.push_back(c);
    }
    const Aggregate a = aggregate(sub, best);
    std::fprintf(md, "| %s%s%s (%d + %d apart) | %d / %d / %d of %d | %d | %d / %d | %d / %d of %d |", cell == "all" ? "**" : "",
                 cell.c_str(), cell == "all" ? "**" : "", a.overlapping, a.apart, a.success, a.keyframe_success,
                 a.refined_success, a.overlapping, a.merged, a.false_merges, a.apart, a.open3d_success,
                 a.open3d_false, a.open3d_apart_ran);
    for (int s : a.pcl_success) std::fprintf(md, " %d |", s);
    const NeesPool& n = a.nees;
    std::fprintf(md, " %s / %s / %s (n = %d) | %s / %s | %s / %s; %s / %s | %.0f ms, %s |\n",
                 neesCell(n.anees_rot, n.under_rot).c_str(), neesCell(n.anees6, n.under6).c_str(),
                 neesCell(n.anees_scale, n.under_scale).c_str(), n.n, neesCell(n.raw_anees6, n.raw_under6).c_str(),
                 neesCell(n.raw_anees_scale, n.raw_under_scale).c_str(), fmt(a.nees_keyframe.anees6, 2).c_str(),
                 fmt(a.nees_keyframe.anees_scale, 2).c_str(), fmt(a.nees_refined.anees6, 2).c_str(),
                 fmt(a.nees_refined.anees_scale, 2).c_str(), a.median_ms,
                 a.median_open3d_ms > 0 ? (fmt(a.median_open3d_ms / a.median_ms, 2) + "×").c_str() : "–");
  }
  std::fprintf(md, "\n");
}

// The merge with merge.projective_refinement against the default merge, on the same cases.
void writeMergedProjective(std::FILE* md, const std::vector<CaseResult>& results) {
  int n = 0, within = 0, within_default = 0, used = 0, false_merges = 0, false_default = 0, apart = 0;
  std::vector<Score> with, without, with_local, without_local;
  std::vector<double> ms, ms_stage;
  for (const CaseResult& c : results) {
    if (!c.merged_projective.tried) continue;
    if (!c.overlap) {
      ++apart;
      false_merges += c.merged_projective.ran;
      false_default += c.reported.has;
      continue;
    }
    ++n;
    used += c.projective_used;
    within += c.merged_projective.ran && c.merged_projective.score.within_floors;
    within_default += c.reported.has && c.reported.within_floors;
    ms.push_back(c.merged_projective.ms);
    ms_stage.push_back(c.projective_stage_ms);
    if (c.merged_projective.ran && c.merged_projective.score.has_covariance) with.push_back(c.merged_projective.score);
    if (c.reported.has && c.reported.has_covariance) without.push_back(c.reported);
    if (c.merged_projective_local.has && c.merged_projective_local.has_covariance) {
      with_local.push_back(c.merged_projective_local);
    }
    if (c.reported_local.has && c.reported_local.has_covariance) without_local.push_back(c.reported_local);
  }
  if (n + apart == 0) return;
  // "rotation / 6-DoF / scale" cells of a pool.
  const auto cells = [](const std::vector<Score>& scores) {
    const NeesPool p = pool(scores);
    return neesCell(p.anees_rot, p.under_rot) + " / " + neesCell(p.anees6, p.under6) + " / " +
           neesCell(p.anees_scale, p.under_scale);
  };
  std::fprintf(md,
               "**The merge with `merge.projective_refinement`** (off by default; the refinement is the projective "
               "registration above, from the keyframe estimate, on the overlap's keyframes, whenever it "
               "converges and its keyframe jackknife is possible), on the same %d overlapping cases: within the "
               "floors on **%d / %d** (default merge: "
               "%d / %d); the projective refinement was the one reported on %d; false merges on the %d cases that "
               "do not overlap: %d (default: %d). ANEES rotation / 6-DoF / scale (fraction under the chi-square "
               "95 %% bound) over the merges reported OK, against the anchor keyframe pair's local truth (what the "
               "covariance stands for; n = %d): %s (default: %s); against the global truth: %s (default: %s). "
               "Median time per merge from a fresh pipeline: %s ms, of which the projective registration %s ms "
               "(rows `pcr_pro reported with merge.projective_refinement` of the CSV).\n\n",
               n, within, n, within_default, n, used, apart, false_merges, false_default,
               pool(with_local).n, cells(with_local).c_str(), cells(without_local).c_str(),
               cells(with).c_str(), cells(without).c_str(), fmt(median(ms), 0).c_str(),
               fmt(median(ms_stage), 0).c_str());
}

void writeProjective(std::FILE* md, const std::vector<CaseResult>& results) {
  int n = 0, truth_ok = 0, icp_ok = 0, kf_n = 0, kf_ok = 0, reported_ok = 0, truth_unconverged = 0,
      kf_unconverged = 0;
  std::vector<double> rot_p, rot_i, scale_p, scale_i, rot_k, rot_r, ms;
  for (const CaseResult& c : results) {
    if (!c.projective_from_truth.tried) continue;
    ++n;
    const Score& p = c.projective_from_truth.score;
    truth_ok += c.projective_from_truth.ran && p.within_floors;
    truth_unconverged += c.projective_from_truth.status == statusName(Status::kIcpNotConverged);
    icp_ok += c.icp_from_truth.ran && c.icp_from_truth.score.within_floors;
    if (c.projective_from_truth.ran) {
      rot_p.push_back(p.rotation_deg);
      scale_p.push_back(p.scale_pct);
      ms.push_back(c.projective_from_truth.ms);
    }
    if (c.icp_from_truth.ran) {
      rot_i.push_back(c.icp_from_truth.score.rotation_deg);
      scale_i.push_back(c.icp_from_truth.score.scale_pct);
    }
    if (c.projective_from_keyframes.tried) {
      ++kf_n;
      kf_ok += c.projective_from_keyframes.ran && c.projective_from_keyframes.score.within_floors;
      kf_unconverged += c.projective_from_keyframes.status == statusName(Status::kIcpNotConverged);
      reported_ok += c.reported.has && c.reported.within_floors;
      if (c.projective_from_keyframes.ran) rot_k.push_back(c.projective_from_keyframes.score.rotation_deg);
      if (c.reported.has) rot_r.push_back(c.reported.rotation_deg);
    }
  }
  if (n == 0) return;
  std::fprintf(md, "**Projective registration of the keyframes' depth** (registration/projective_registration.h: each "
                   "map's LSD keyframe pixels projected into the other map's keyframes, residuals in depth, across "
                   "the image edge and in grey level, both directions, the better-fitting one kept; the stage "
                   "alone on the whole maps, README), on the "
                   "%d overlapping cases whose keyframes carry LSD depth with its variance: from the exact truth within "
                   "the floors on **%d / %d** (our refinement from the truth on the same cases: %d / %d; %d not converged "
                   "within the stage's iteration limit, not counted), median "
                   "rotation error %s deg (refinement: %s), median scale error %s %% (refinement: %s), median time %s ms; "
                   "from our keyframe estimate: %d / %d (%d not converged; our reported estimate on the same merges: %d / "
                   "%d), median rotation error %s deg (reported: %s) (rows `pcr_pro projective registration ...` of the "
                   "CSV; an `ICP_NOT_CONVERGED` row holds the estimate where the stage stopped).\n\n",
               n, truth_ok, n, icp_ok, n, truth_unconverged, fmt(median(rot_p), 2).c_str(), fmt(median(rot_i), 2).c_str(),
               fmt(median(scale_p), 2).c_str(), fmt(median(scale_i), 2).c_str(), fmt(median(ms), 0).c_str(), kf_ok, kf_n,
               kf_unconverged, reported_ok, kf_n, fmt(median(rot_k), 2).c_str(), fmt(median(rot_r), 2).c_str());
  // The stage's covariance from our keyframe estimate: the keyframe jackknife (its default) against
  // the Gauss-Newton covariance alone, on the same converged runs.
  std::vector<Score> jackknifed, gauss_newton, all_reported, all_gauss_newton;
  for (const CaseResult& c : results) {
    if (!c.projective_from_keyframes.ran || !c.projective_from_keyframes.score.has_covariance) continue;
    all_reported.push_back(c.projective_from_keyframes.score);
    all_gauss_newton.push_back(c.projective_from_keyframes_gauss_newton.score);
    if (c.projective_jackknifed) {
      jackknifed.push_back(c.projective_from_keyframes.score);
      gauss_newton.push_back(c.projective_from_keyframes_gauss_newton.score);
    }
  }
  writeMergedProjective(md, results);
  if (all_reported.empty()) return;
  const NeesPool j = pool(jackknifed), g = pool(gauss_newton), a = pool(all_reported), ga = pool(all_gauss_newton);
  std::fprintf(md, "Its covariance from our keyframe estimate (ANEES and fraction under the chi-square 95 %% bound, "
                   "rotation / 6-DoF / scale): the Gauss-Newton covariance plus the keyframe jackknife "
                   "(`projective.jackknife`) and the two directions' difference (`projective.direction_spread`), both "
                   "on by default. The jackknife was possible on %d of the %d converged runs (each map needs two "
                   "keyframes with matches), and there the covariance gives %s / %s / %s, against %s / %s / %s under "
                   "the Gauss-Newton covariance alone; over all %d runs, as reported: %s / %s / %s (Gauss-Newton "
                   "alone: %s / %s / %s).\n\n",
               j.n, a.n, neesCell(j.anees_rot, j.under_rot).c_str(), neesCell(j.anees6, j.under6).c_str(),
               neesCell(j.anees_scale, j.under_scale).c_str(), neesCell(g.anees_rot, g.under_rot).c_str(),
               neesCell(g.anees6, g.under6).c_str(), neesCell(g.anees_scale, g.under_scale).c_str(), a.n,
               neesCell(a.anees_rot, a.under_rot).c_str(), neesCell(a.anees6, a.under6).c_str(),
               neesCell(a.anees_scale, a.under_scale).c_str(), neesCell(ga.anees_rot, ga.under_rot).c_str(),
               neesCell(ga.anees6, ga.under6).c_str(), neesCell(ga.anees_scale, ga.under_scale).c_str());
}

}  // namespace bench
}  // namespace pcr_pro
