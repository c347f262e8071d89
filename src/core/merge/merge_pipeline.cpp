#include "pcr_pro/merge/merge_pipeline.h"

#include <Eigen/Cholesky>

#include <algorithm>
#include <chrono>
#include <cmath>
#include <sstream>
#include <stdexcept>
#include <utility>

#include "pcr_pro/merge/ray_noise.h"
#include "pcr_pro/registration/covariance.h"
#include "pcr_pro/registration/scale_detection.h"

namespace pcr_pro {
namespace {

using Clock = std::chrono::steady_clock;

double msSince(Clock::time_point start) {
  return std::chrono::duration<double, std::milli>(Clock::now() - start).count();
}

std::string fmt(double v, int precision = 3) {
  std::ostringstream os;
  os.precision(precision);
  os << v;
  return os.str();
}

// What the data does that the pipeline cannot use (a caller's mistake would be an exception).
std::string checkMap(const AgentMap& map, const char* which) {
  if (!map.camera.valid()) return std::string(which) + " map: invalid camera intrinsics or image size";
  if (map.cloud.cols() == 0) return std::string(which) + " map: empty cloud";
  for (const MapKeyframe& kf : map.keyframes) {
    const std::string name = std::string(which) + " keyframe " + std::to_string(kf.id);
    if (kf.image.empty() || kf.image.type() != CV_8UC1) return name + ": image missing or not 8-bit grey";
    if (kf.image.cols != map.camera.width || kf.image.rows != map.camera.height) {
      return name + ": image size differs from the camera's";
    }
    if (!(kf.pose.scale() > 0.0) || !kf.pose.matrix().allFinite()) return name + ": invalid pose";
  }
  return "";
}

// The 6x6 pose covariance: the marginal of the 7x7, made symmetric.
Matrix6d poseCovariance(const Matrix7d& cov7) {
  return 0.5 * (cov7.topLeftCorner<6, 6>() + cov7.topLeftCorner<6, 6>().transpose());
}

// Its information; false when the covariance is not finite or not positive definite.
bool poseInformation(const Matrix6d& cov, Matrix6d* info) {
  if (!cov.allFinite()) return false;
  const Eigen::LDLT<Matrix6d> ldlt(cov);
  if (ldlt.info() != Eigen::Success || !ldlt.isPositive()) return false;
  *info = ldlt.solve(Matrix6d::Identity());
  *info = 0.5 * (*info + info->transpose()).eval();
  return info->allFinite();
}

void reportPairs(const KeyframeEstimate& kf, RegistrationReport* rep) {
  rep->keyframe_pairs.clear();
  for (const PairEvidence& e : kf.pairs) {
    KeyframePairReport p;
    p.source_keyframe = e.source_keyframe;
    p.target_keyframe = e.target_keyframe;
    p.inliers = e.inliers;
    p.depth_matches = e.depth_matches;
    p.used = e.used;
    p.note = e.note;
    rep->keyframe_pairs.push_back(p);
  }
}

// The reported similarity between the anchor keyframes (see KeyframeEdge).
KeyframeEdge keyframeEdge(const AgentMap& source, const AgentMap& target, const PairEvidence& anchor,
                          const Sim3& target_source, const Matrix7d& covariance) {
  const auto pose = [](const AgentMap& map, long id) {
    for (const MapKeyframe& kf : map.keyframes) {
      if (kf.id == id) return kf.pose;
    }
    throw std::logic_error("anchor keyframe " + std::to_string(id) + " is not in its map");
  };
  KeyframeEdge e;
  e.source_keyframe = anchor.source_keyframe;
  e.target_keyframe = anchor.target_keyframe;
  const Sim3 target_inverse = pose(target, anchor.target_keyframe).inverse();
  e.transform = target_inverse * target_source * pose(source, anchor.source_keyframe);
  const Matrix7d ad = similarityAdjoint(target_inverse);
  e.covariance = ad * covariance * ad.transpose();
  e.covariance = 0.5 * (e.covariance + e.covariance.transpose()).eval();
  return e;
}

// The front end's timings and counts into the report and diagnostics.
void recordFrontEnd(const FrontEndResult& front, RegistrationReport* rep, MergeDiagnostics* diag) {
  rep->timings.features = front.features_ms;
  rep->timings.relative_pose = front.relative_pose_ms;
  diag->keyframe_pairs = front.keyframe_pairs;
  diag->candidate_pairs = static_cast<int>(front.pairs.size());
  diag->verified_pairs = front.verified;
  diag->features_computed = front.features_computed;
  diag->features_cached = front.features_cached;
  diag->pairs_cached = front.pairs_cached;
  diag->earlier_pairs = front.earlier_pairs;
  diag->vote_rows_computed = front.vote_rows_computed;
}

// No keyframe pair verified: the best pair into the report, and the status and message why.
Status noPairVerified(const FrontEndResult& front, RegistrationReport* rep, MergeDiagnostics* diag,
                      std::string* message) {
  const CandidatePair& c = front.pairs.front();
  Status status = c.pose.status == Status::kOk ? Status::kRelativePoseFailed : c.pose.status;
  if (status == Status::kDegenerate) status = Status::kRelativePoseFailed;
  rep->source_keyframe = c.source->id;
  rep->target_keyframe = c.target->id;
  diag->feature_matches = static_cast<int>(c.matches.size());
  *message = "no keyframe pair verified (" + std::to_string(front.pairs.size()) + " tried); best pair source " +
             std::to_string(c.source->id) + " / target " + std::to_string(c.target->id) + ": " + c.pose.message;
  return status;
}

// The keyframe estimate's anchor pair, initial similarity and Kalman scale into the report and
// diagnostics.
void recordKeyframeEstimate(const KeyframeEstimate& kf, const PairEvidence& anchor, RegistrationReport* rep,
                            MergeDiagnostics* diag) {
  rep->source_keyframe = anchor.source_keyframe;
  rep->target_keyframe = anchor.target_keyframe;
  diag->feature_matches = anchor.feature_matches;
  diag->relative_pose_inliers = anchor.inliers;
  diag->depth_matches = anchor.depth_matches;
  diag->keyframe_matches = static_cast<int>(kf.matches.size());
  diag->initial = kf.estimate;
  diag->keyframe_covariance = kf.covariance;
  diag->keyframe_mean_covariance = kf.mean_covariance;
  diag->between_pairs = kf.between;
  diag->kalman_scale = kf.estimate.scale();
  diag->kalman_scale_stddev = kf.estimate.scale() * std::sqrt(std::max(0.0, kf.covariance(6, 6)));
  rep->keyframe_transform = kf.estimate;
  rep->keyframe_covariance = kf.covariance.topLeftCorner<6, 6>();
  rep->keyframe_scale_stddev = diag->kalman_scale_stddev;
}

// Scale detection on the filtered clouds (reported beside the keyframe scale; timed as scale).
void recordScaleDetection(const MapRegistration& registration, const ScaleDetectionOptions& options,
                          RegistrationReport* rep) {
  auto t = Clock::now();
  const ScaleDetectionResult detection = detectScale(registration.source(), registration.target(), options);
  rep->timings.scale += msSince(t);
  rep->scale_difference_detected = detection.scale_difference_detected;
  rep->detected_scale_ratio = detection.ratio;
}

// The refinement's timings, ICP figures and estimate into the report and diagnostics.
void recordRefinement(const Refinement& refinement, RegistrationReport* rep, MergeDiagnostics* diag) {
  rep->timings.icp = refinement.ms_icp;
  rep->timings.covariance = refinement.ms_covariance;
  rep->icp_iterations = refinement.icp.iterations;
  if (!refinement.projective && (refinement.status == Status::kOk || refinement.status == Status::kDegenerate)) {
    // (The ICP's figures: none when the projective registration was the refinement.)
    rep->fitness_rmse = refinement.icp.fitness_rmse;
    rep->correspondences = refinement.icp.correspondences;
    rep->condition_number = refinement.closed_form.condition_number;
    rep->noise_stddev = refinement.closed_form.noise_stddev;
  }
  diag->block_spread_factor = refinement.block_spread_factor;
  diag->anchor_weight = refinement.anchor_weight;
  diag->refinement_reversed = refinement.reversed;
  diag->noise_ratio = refinement.noise_ratio;
  diag->renoise_draws = refinement.renoise_draws;
  diag->renoise_spread = refinement.renoise_spread;
  rep->refinement_reversed = refinement.reversed;
  diag->refinement_status = refinement.status;
  diag->refined = refinement.estimate;
  diag->refined_covariance = refinement.covariance;
}

// The gates' overlap and refinement decision into the report and diagnostics.
void recordVerdict(const GateVerdict& verdict, RegistrationReport* rep, MergeDiagnostics* diag) {
  diag->overlap = verdict.overlap;
  diag->refinement_kept = verdict.refinement_kept;
  diag->combined = verdict.combined;
  diag->refinement_chi2 = verdict.refinement_chi2;
  diag->disagreement_scale = verdict.disagreement_scale;
  rep->overlap = verdict.overlap;
  rep->refinement_kept = verdict.refinement_kept;
  rep->refinement_combined = verdict.combined;
  rep->refinement_chi2 = verdict.refinement_chi2;
}

// The keyframe estimate's pairs, counts, anchor and similarity into the report and diagnostics.
void recordKeyframes(const KeyframeEstimate& kf, RegistrationReport* rep, MergeDiagnostics* diag) {
  reportPairs(kf, rep);
  diag->used_pairs = kf.used_pairs;
  diag->dropped_pairs = kf.dropped_pairs;
  diag->distant_pairs = kf.distant_pairs;
  if (kf.status == Status::kOk) recordKeyframeEstimate(kf, kf.pairs[static_cast<std::size_t>(kf.anchor)], rep, diag);
}

// The keyframes of `map` that the projective refinement registers: those of the used pairs and
// those within `k` keyframes (in id order, along the path) of the anchor pair's, the region where
// the two maps overlap and whose local similarity the edge measures (merge.local_keyframes; 0 = all).
AgentMap overlapKeyframes(const AgentMap& map, const KeyframeEstimate& kf, bool source_side, int k) {
  if (k <= 0) return map;
  const std::map<long, long> rank = keyframeRanks(map);
  const auto idOf = [source_side](const PairEvidence& e) {
    return source_side ? e.source_keyframe : e.target_keyframe;
  };
  const long centre = rank.at(idOf(kf.pairs[static_cast<std::size_t>(kf.anchor)]));
  AgentMap out;
  out.frame_id = map.frame_id;
  out.camera = map.camera;
  for (const MapKeyframe& f : map.keyframes) {
    bool keep = std::abs(rank.at(f.id) - centre) <= k;
    for (const PairEvidence& e : kf.pairs) keep = keep || (e.used && idOf(e) == f.id);
    if (keep) out.keyframes.push_back(f);
  }
  return out;
}

// merge.projective_refinement: the projective registration of the keyframes' depth from the
// keyframe estimate, on the overlap's keyframes (overlapKeyframes()), is the refinement when it
// converged and (projective.jackknife on) its keyframe jackknife was possible: `refinement` is then
// set and the ICP on the map clouds does not run. Otherwise the note says why, and the caller runs
// the ICP. @return whether `refinement` was set
bool refineProjectively(const AgentMap& source, const AgentMap& target, const KeyframeEstimate& kf,
                        const MergeOptions& options, Refinement* refinement, MergeDiagnostics* diag) {
  const bool source_ok = hasDepthUncertainty(source);
  if (!source_ok || !hasDepthUncertainty(target)) {
    diag->projective_note = std::string("not run: the ") + (source_ok ? "target" : "source") +
                            " map's keyframes carry no depth with a per-pixel standard deviation; ICP refinement";
    return false;
  }
  const auto t = Clock::now();
  const AgentMap s = overlapKeyframes(source, kf, true, options.merge.local_keyframes);
  const AgentMap g = overlapKeyframes(target, kf, false, options.merge.local_keyframes);
  diag->projective_keyframes_source = static_cast<int>(s.keyframes.size());
  diag->projective_keyframes_target = static_cast<int>(g.keyframes.size());
  const ProjectiveResult p = registerProjective(s, g, kf.estimate, options.projective);
  diag->ms_projective = msSince(t);
  const std::string where = std::to_string(s.keyframes.size()) + " + " + std::to_string(g.keyframes.size()) +
                            " keyframes, " + std::to_string(std::lround(diag->ms_projective)) + " ms";
  if (p.status != Status::kOk || !p.estimate.matrix().allFinite() || !p.covariance.allFinite()) {
    diag->projective_note = "failed (" + p.message + "; " + where + "); ICP refinement";
    return false;
  }
  if (options.projective.jackknife && !p.jackknifed) {
    // Without the jackknife its covariance holds no keyframe's error: the Gauss-Newton covariance
    // (plus the directions' difference, one direction of seven) was 150-1,300 times too confident
    // on the bench's LSD maps (ProjectiveOptions::jackknife), and the gates would take it at its word.
    diag->projective_note = "not used (no keyframe jackknife: " + std::to_string(p.jackknife_moving_keyframes) +
                            " moving and " + std::to_string(p.jackknife_fixed_keyframes) +
                            " fixed keyframes with matches left out, 2 of each needed; " + where + "); ICP refinement";
    return false;
  }
  diag->projective_refinement = true;
  diag->projective_note = std::to_string(p.matches) + " matches, " +
                          (p.jackknifed ? "keyframe jackknife" : "no jackknife (projective.jackknife off)") +
                          (p.direction_spread ? " and the two directions' difference" : std::string()) + ", " + where;
  refinement->status = Status::kOk;
  refinement->estimate = p.estimate;
  refinement->covariance = p.covariance;
  refinement->projective = true;
  refinement->message = "projective registration of the keyframes' depth: " + diag->projective_note;
  refinement->ms_icp = diag->ms_projective;
  return true;
}

// A camp of the keyframe pairs: the pairs that agree with a hypothesis, pooled again without the
// others, refined again from their own estimate, and judged by the same gates.
struct Camp {
  KeyframeEstimate keyframes;
  Refinement refinement;
  GateVerdict verdict;
  double cloud_overlap = 0.0;  // MergeGates::cloudOverlap() of the verdict's estimate
};

// Refines and judges a camp (camp->keyframes set) that holds at least two pairs. With
// `incumbent_overlap` (the cloudOverlap() of the keyframe estimate the camp would replace, whose
// refinement failed or was not kept; negative when there is none), the clouds must support the
// camp as well: its refinement converged and is kept, or converged and its estimate overlaps the
// clouds more than the incumbent does. @return whether it passes
bool judgeCamp(const MergeGates& gates, const MapRegistration& registration, double incumbent_overlap, Camp* camp) {
  if (camp->keyframes.status != Status::kOk || camp->keyframes.used_pairs < 2) return false;
  camp->refinement = registration.refine(camp->keyframes.estimate, camp->keyframes.matches);
  camp->verdict = gates.judge(camp->keyframes, camp->refinement, registration);
  const Status status = camp->verdict.status;
  if (status != Status::kOk && status != Status::kDegenerate) return false;
  const bool converged = camp->refinement.status == Status::kOk || camp->refinement.status == Status::kDegenerate;
  camp->cloud_overlap = gates.cloudOverlap(camp->verdict.estimate, registration);
  return incumbent_overlap < 0.0 || camp->verdict.refinement_kept ||
         (converged && camp->cloud_overlap > incumbent_overlap);
}

// The keyframe pairs can split into camps that disagree, each with its own relative poses and
// depth matches (on simulated 15 % overlaps without depth images, two of four verified pairs had
// the wrong one of the two essential matrices a mostly planar view allows, 9 and 24 deg off, and
// the medoid of a two-against-two split is either camp). The pooled estimate then lies between
// the camps or in the wrong one. Two independent kinds of evidence can still agree:
// - The refinement on the map clouds converged to one camp, and the gates refused because the
//   clouds fit it better than the keyframe estimate: the camp around the refinement is tried.
// - The gates kept the keyframe estimate (the refinement failed, or converged and was not kept):
//   the camp around the refinement (when it converged) and the camp around each candidate
//   pair's own estimate, when that camp is closed (below), are tried against the keyframe
//   estimate by judgeCamp(), and the best that passes is taken (below). (On a simulated 15 %
//   overlap with 2.5 % drift and no depth images, two right and two wrong pairs pooled 22 deg
//   from the truth, which was reported OK with a 7 deg 1-sigma; the camp of the two right pairs
//   refines from 1.3 deg, overlaps the clouds 16 % against 14 %, and is reported.)
// Nothing is taken from the first refinement but the choice of pairs. @return true when the
// chosen camp replaces kf, refinement and verdict
bool arbitrate(const SimilarityInitializer& initializer, const MergeGates& gates, const MapRegistration& registration,
               KeyframeEstimate* kf, Refinement* refinement, GateVerdict* verdict) {
  int candidates = 0;
  for (const PairEvidence& e : kf->pairs) candidates += e.in_neighbourhood ? 1 : 0;
  if (candidates < 3) return false;
  const bool converged = refinement->status == Status::kOk || refinement->status == Status::kDegenerate;
  const bool merged = verdict->status == Status::kOk || verdict->status == Status::kDegenerate;
  // Refused for another reason (the overlap, or the two estimates excluding each other), or the
  // refinement kept: nothing to arbitrate.
  if (!verdict->clouds_prefer_refinement && !(merged && !verdict->refinement_kept)) return false;
  const auto usedOf = [](const KeyframeEstimate& k) {
    std::vector<bool> used;
    for (const PairEvidence& e : k.pairs) used.push_back(e.used);
    return used;
  };
  // The candidate camps: around the refinement, and around each candidate pair's estimate.
  std::vector<Camp> camps;
  std::vector<int> hypothesis_pair;  // the pair whose estimate each camp was pooled around (-1: refinement)
  if (converged) {
    camps.emplace_back();
    camps.back().keyframes = initializer.poolAround(*kf, refinement->estimate);
    hypothesis_pair.push_back(-1);
  }
  if (!verdict->clouds_prefer_refinement) {
    for (std::size_t i = 0; i < kf->pairs.size(); ++i) {
      if (!kf->pairs[i].in_neighbourhood) continue;
      camps.emplace_back();
      camps.back().keyframes = initializer.poolAround(*kf, kf->pairs[i].estimate);
      hypothesis_pair.push_back(static_cast<int>(i));
    }
  }
  // Around a pair's estimate, a camp is a real split only when it is closed: every pair in it,
  // taken as the hypothesis, gives the same camp. Pairs that drift apart by a continuum (each
  // monocular map's scale drift) give overlapping sets instead, none of them closed (on the real
  // LSD-SLAM bags, six pairs gave four different sets, and refining each would have quadrupled
  // the time of a merge whose every refinement fails to converge).
  const std::vector<bool> incumbent = usedOf(*kf);
  const double incumbent_overlap = merged ? gates.cloudOverlap(verdict->estimate, registration) : -1.0;
  std::vector<std::vector<bool>> judged;
  std::vector<Camp> passed;
  for (std::size_t c = 0; c < camps.size(); ++c) {
    Camp& camp = camps[c];
    if (camp.keyframes.status != Status::kOk) continue;
    const std::vector<bool> used = usedOf(camp.keyframes);
    if (used == incumbent || std::find(judged.begin(), judged.end(), used) != judged.end()) continue;
    bool closed = true;
    for (std::size_t d = 0; d < camps.size() && hypothesis_pair[c] >= 0; ++d) {
      if (hypothesis_pair[d] < 0) continue;
      const bool member = used[static_cast<std::size_t>(hypothesis_pair[d])];
      closed = closed && (!member || (camps[d].keyframes.status == Status::kOk && usedOf(camps[d].keyframes) == used));
    }
    if (!closed) continue;
    judged.push_back(used);
    if (judgeCamp(gates, registration, incumbent_overlap, &camp)) passed.push_back(std::move(camp));
  }
  if (passed.empty()) return false;
  // Several camps can pass (nested ones: the camp around the refinement may hold one more pair
  // than the closed camp inside it): the one whose refinement was kept, then the one that fits
  // the clouds best.
  Camp& camp = *std::max_element(passed.begin(), passed.end(), [](const Camp& a, const Camp& b) {
    return std::make_pair(a.verdict.refinement_kept, a.cloud_overlap) <
           std::make_pair(b.verdict.refinement_kept, b.cloud_overlap);
  });
  const std::string why = verdict->clouds_prefer_refinement ? verdict->message.substr(verdict->message.find(':') + 2)
                         : converged ? "the refinement from the pooled estimate was not kept: " + verdict->message
                                     : "the refinement from the pooled estimate failed: " + refinement->message;
  camp.verdict.message = "the keyframe pairs split and the map clouds side with " +
                         std::to_string(camp.keyframes.used_pairs) + " of them (" + why + "); " + camp.verdict.message;
  // The stages' times stay the first pass's; the camps' are the arbitration's (timed by the caller).
  camp.keyframes.ms = kf->ms;
  camp.refinement.ms_icp = refinement->ms_icp;
  camp.refinement.ms_covariance = refinement->ms_covariance;
  *kf = std::move(camp.keyframes);
  *refinement = std::move(camp.refinement);
  *verdict = std::move(camp.verdict);
  return true;
}

// The message of a successful merge.
std::string mergedMessage(const KeyframeEstimate& kf, const PairEvidence& anchor, const MergeDiagnostics& diag,
                          const GateVerdict& verdict) {
  return "merged 2 maps: " + std::to_string(kf.used_pairs) + " keyframe pair(s) (anchor source " +
         std::to_string(anchor.source_keyframe) + " / target " + std::to_string(anchor.target_keyframe) + ", " +
         std::to_string(anchor.inliers) + " inliers" +
         (diag.earlier_pairs > 0 ? "; no preselected pair verified, " + std::to_string(diag.earlier_pairs) +
                                       " pair(s) that verified in earlier merges added"
                                 : std::string()) +
         "), keyframe scale " + fmt(diag.kalman_scale, 4) + " +- " + fmt(diag.kalman_scale_stddev, 2) + "; " +
         verdict.message +
         (diag.projective_note.empty() ? std::string()
          : diag.projective_refinement ? "; refinement: projective registration of the keyframes' depth (" +
                                             diag.projective_note + ")"
                                       : "; projective refinement " + diag.projective_note);
}

}  // namespace

MergePipeline::MergePipeline(const MergeOptions& options)
    : options_(options), front_end_(options), initializer_(options), gates_(options.merge) {}

MergeResult MergePipeline::merge(const AgentMap& source, const AgentMap& target, const MergeRequest& request,
                                 const std::string& source_key, const std::string& target_key) {
  const auto t_total = Clock::now();
  MergeResult out;
  RegistrationReport& rep = out.report;
  MergeDiagnostics& diag = out.diagnostics;
  auto finish = [&](Status status, const std::string& message) -> MergeResult {
    rep.status = status;
    rep.message = message;
    rep.timings.total = msSince(t_total);
    return out;
  };
  for (const auto& [map, which] : {std::pair<const AgentMap*, const char*>{&source, "source"}, {&target, "target"}}) {
    const std::string problem = checkMap(*map, which);
    if (!problem.empty()) return finish(Status::kInvalidInput, problem);
  }

  // 1. Keyframe front end.
  const FrontEndResult front = front_end_.run(source, target, request, source_key, target_key);
  recordFrontEnd(front, &rep, &diag);
  if (front.status != Status::kOk) return finish(front.status, front.message);
  if (front.verified == 0) {
    std::string message;
    const Status status = noPairVerified(front, &rep, &diag, &message);
    return finish(status, message);
  }

  // 2. Keyframe estimate from every verified pair.
  KeyframeEstimate kf = initializer_.run(source, target, front);
  rep.timings.scale = kf.ms;
  recordKeyframes(kf, &rep, &diag);
  if (kf.status != Status::kOk) return finish(kf.status, kf.message);

  // 3. Refinement on the map clouds.
  MapRegistration registration(options_.registration, options_.merge.refine_scale,
                               options_.merge.reweigh_keyframe_matches);
  const std::string cloud_problem = registration.setClouds(source.cloud, target.cloud);
  rep.timings.filters = registration.filterMs();
  if (!cloud_problem.empty()) return finish(Status::kInvalidInput, cloud_problem);
  recordScaleDetection(registration, options_.registration.scale_detection, &rep);
  double ms_ray_noise = 0.0;
  if (options_.merge.renoise_draws > 0) {
    // The maps' ray noise for the refinement's re-noised registrations (merge.renoise_draws).
    const auto t = Clock::now();
    registration.setRayNoise(measureRayNoise(source, options_.keyframe_depth),
                             measureRayNoise(target, options_.keyframe_depth), options_.merge.renoise_draws);
    ms_ray_noise = msSince(t);
  }
  Refinement refinement;
  if (!options_.merge.projective_refinement || !refineProjectively(source, target, kf, options_, &refinement, &diag)) {
    refinement = registration.refine(kf.estimate, kf.matches);
    refinement.ms_icp += diag.ms_projective;  // a projective stage that ran and was not used (else 0)
  }

  // 4. Gates (and, when the keyframe pairs split, the side the clouds take).
  GateVerdict verdict = gates_.judge(kf, refinement, registration);
  const auto t_arbitration = Clock::now();
  const bool camp_taken = arbitrate(initializer_, gates_, registration, &kf, &refinement, &verdict);
  rep.timings.arbitration = msSince(t_arbitration);
  if (camp_taken) {
    recordKeyframes(kf, &rep, &diag);
    if (diag.projective_refinement) {
      // The camp's refinement is the ICP's (judgeCamp()).
      diag.projective_refinement = false;
      diag.projective_note =
          "set aside (" + diag.projective_note + "): the keyframe pairs split, ICP refinement of a camp";
    }
  }
  recordRefinement(refinement, &rep, &diag);
  rep.timings.covariance += ms_ray_noise;
  recordVerdict(verdict, &rep, &diag);
  const PairEvidence& anchor = kf.pairs[static_cast<std::size_t>(kf.anchor)];
  if (!options_.merge.refine_scale && verdict.refinement_kept) {
    // Scale policy: the refinement kept the keyframe scale, which keeps its uncertainty.
    verdict.covariance(6, 6) = kf.covariance(6, 6);
  }
  diag.covariance = verdict.covariance;
  if (verdict.status != Status::kOk && verdict.status != Status::kDegenerate) {
    return finish(verdict.status, verdict.message);
  }
  rep.transform = verdict.estimate;
  rep.scale_stddev = verdict.estimate.scale() * std::sqrt(std::max(0.0, verdict.covariance(6, 6)));
  const Matrix6d cov = poseCovariance(verdict.covariance);
  Matrix6d info;
  // A DEGENERATE verdict's covariance is not inverted: its unobservable directions would be.
  const bool degenerate = verdict.status == Status::kDegenerate;
  if (degenerate || !poseInformation(cov, &info)) {
    // Unobservable directions: the covariance's own information (degenerateUncertainty()).
    const bool closed_form = verdict.refinement_kept && !refinement.projective;
    const ReportedUncertainty u = degenerateUncertainty(cov, closed_form ? &refinement.closed_form : nullptr);
    rep.covariance = u.covariance;
    rep.information = u.information;
    const std::string closed = closed_form ? refinement.closed_form.message : std::string();
    return finish(Status::kDegenerate, degenerate ? verdict.message
                                                  : "the covariance is not positive definite" +
                                                        (closed.empty() ? std::string() : "; " + closed));
  }
  rep.covariance = cov;
  rep.information = info;
  rep.keyframe_edge = keyframeEdge(source, target, anchor, verdict.estimate, verdict.covariance);
  return finish(Status::kOk, mergedMessage(kf, anchor, diag, verdict));
}

std::optional<MergeEdge> poseGraphEdge(const MergeResult& result) {
  const RegistrationReport& r = result.report;
  if (r.status != Status::kOk || !r.transform || !r.keyframe_edge) return std::nullopt;
  MergeEdge edge;
  edge.target_from_source = *r.transform;
  edge.covariance = result.diagnostics.covariance;
  edge.source_keyframe = r.keyframe_edge->source_keyframe;
  edge.target_keyframe = r.keyframe_edge->target_keyframe;
  return edge;
}

MergeResult mergeMaps(const AgentMap& source, const AgentMap& target, const MergeRequest& request,
                      const MergeOptions& options) {
  MergePipeline pipeline(options);
  return pipeline.merge(source, target, request);
}

}  // namespace pcr_pro
