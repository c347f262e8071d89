#include "pcr_pro/merge/merge_pipeline.h"

#include <algorithm>
#include <chrono>
#include <cmath>
#include <sstream>
#include <vector>

#include "pcr_pro/registration/cloud_registration.h"
#include "pcr_pro/registration/filters.h"
#include "pcr_pro/geometry/kdtree.h"

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

// A keyframe and its SIFT features.
struct KeyframeEntry {
  const MapKeyframe* keyframe = nullptr;
  KeyframeFeatures features;
};

// Keyframes of a map to consider: the requested one, or all of them.
std::vector<KeyframeEntry> selectKeyframes(const AgentMap& map, const std::optional<long>& id, const char* which,
                                           std::string* error) {
  std::vector<KeyframeEntry> out;
  for (const MapKeyframe& kf : map.keyframes) {
    if (!id || kf.id == *id) out.push_back(KeyframeEntry{&kf, {}});
  }
  if (out.empty()) {
    *error = id ? std::string(which) + " keyframe " + std::to_string(*id) + " is not in the " + which + " map"
                : std::string(which) + " map has no keyframes";
  }
  return out;
}

std::string checkMap(const AgentMap& map, const char* which) {
  if (!map.camera.valid()) return std::string(which) + " map: invalid camera intrinsics or image size";
  if (map.cloud.cols() == 0) return std::string(which) + " map: empty cloud";
  for (const MapKeyframe& kf : map.keyframes) {
    if (kf.image.empty() || kf.image.type() != CV_8UC1) {
      return std::string(which) + " keyframe " + std::to_string(kf.id) + ": image missing or not 8-bit grey";
    }
    if (kf.image.cols != map.camera.width || kf.image.rows != map.camera.height) {
      return std::string(which) + " keyframe " + std::to_string(kf.id) + ": image size differs from the camera's";
    }
    if (!(kf.pose.scale() > 0.0) || !kf.pose.matrix().allFinite()) {
      return std::string(which) + " keyframe " + std::to_string(kf.id) + ": invalid pose";
    }
  }
  return "";
}

// Median distance of target points to their nearest other target point (a sample of them).
double medianSpacing(const KdTree& tree) {
  const Cloud& pts = tree.points();
  const Eigen::Index n = pts.cols();
  const Eigen::Index step = std::max<Eigen::Index>(1, n / 2000);
  std::vector<double> d;
  std::vector<Eigen::Index> idx;
  std::vector<double> d2;
  for (Eigen::Index i = 0; i < n; i += step) {
    tree.knn(pts.col(i), 2, &idx, &d2);
    if (d2.size() == 2) d.push_back(std::sqrt(d2[1]));
  }
  if (d.empty()) return 0.0;
  std::nth_element(d.begin(), d.begin() + static_cast<std::ptrdiff_t>(d.size() / 2), d.end());
  return d[d.size() / 2];
}

// Source points sampled by the overlap gate: the fraction is then known to about ±0.7 %.
constexpr Eigen::Index kOverlapSamples = 5000;

// Fraction of (a sample of) the moved source points within `radius` of a target point.
double overlapFraction(const Cloud& moved_source, const KdTree& target_tree, double radius) {
  const Eigen::Index n = moved_source.cols();
  if (n == 0) return 0.0;
  const Eigen::Index step = std::max<Eigen::Index>(1, n / kOverlapSamples);
  Eigen::Index inside = 0, total = 0;
  const double r2 = radius * radius;
  for (Eigen::Index i = 0; i < n; i += step, ++total) {
    double d2 = 0.0;
    if (target_tree.nearest(moved_source.col(i), &d2) >= 0 && d2 <= r2) ++inside;
  }
  return static_cast<double>(inside) / static_cast<double>(total);
}

}  // namespace

RelativePoseResult keyframePairPose(const FeatureMatches& matches, const PinholeCamera& target_camera,
                                    const PinholeCamera& source_camera, const RelativePoseOptions& options) {
  std::vector<Eigen::Vector3d> bt, bs;
  bt.reserve(matches.pixels_a.size());
  bs.reserve(matches.pixels_a.size());
  for (std::size_t k = 0; k < matches.pixels_a.size(); ++k) {
    bt.push_back(target_camera.bearing(matches.pixels_a[k].x(), matches.pixels_a[k].y()));
    bs.push_back(source_camera.bearing(matches.pixels_b[k].x(), matches.pixels_b[k].y()));
  }
  const double focal = 0.5 * (source_camera.focal() + target_camera.focal());
  return estimateRelativePose(bt, bs, focal, options);
}

KeyframeGuess keyframeGuess(const AgentMap& source, const MapKeyframe& source_keyframe, const AgentMap& target,
                            const MapKeyframe& target_keyframe, const FeatureMatches& matches,
                            const RelativePoseResult& pose, const MergeOptions& options) {
  KeyframeGuess g;
  const KeyframeDepth depth_s(source_keyframe, source.camera, source.cloud, options.keyframe_depth);
  const KeyframeDepth depth_t(target_keyframe, target.camera, target.cloud, options.keyframe_depth);
  std::vector<Eigen::Vector3d> ps, pt;
  for (int k : pose.inliers) {
    Eigen::Vector3d a, b;
    const auto ku = static_cast<std::size_t>(k);
    if (depth_t.pointAt(matches.pixels_a[ku].x(), matches.pixels_a[ku].y(), &a) &&
        depth_s.pointAt(matches.pixels_b[ku].x(), matches.pixels_b[ku].y(), &b)) {
      pt.push_back(a);
      ps.push_back(b);
    }
  }
  g.depth_matches = static_cast<int>(ps.size());
  g.scale = estimateScale(ps, pt, pose.rotation, pose.translation_direction, options.scale_estimation);
  if (g.scale.status != Status::kOk) return g;
  // Target camera -> target map, keyframe similarity, source map -> source camera. Camera
  // points are in map units (P = pose scale * p_cam).
  const Sim3 keyframe_sim(g.scale.scale, pose.rotation, g.scale.lambda * pose.translation_direction);
  const Sim3 cam_t(1.0, target_keyframe.pose.rotation(), target_keyframe.pose.translation());
  const Sim3 cam_s(1.0, source_keyframe.pose.rotation(), source_keyframe.pose.translation());
  g.initial = cam_t * keyframe_sim * cam_s.inverse();
  return g;
}

MergeResult mergeMaps(const AgentMap& source, const AgentMap& target, const MergeRequest& request,
                      const MergeOptions& options) {
  validate(options);
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
  std::string error;
  std::vector<KeyframeEntry> src_kfs = selectKeyframes(source, request.source_keyframe, "source", &error);
  if (src_kfs.empty()) return finish(Status::kInvalidInput, error);
  std::vector<KeyframeEntry> tgt_kfs = selectKeyframes(target, request.target_keyframe, "target", &error);
  if (tgt_kfs.empty()) return finish(Status::kInvalidInput, error);

  // --- features: SIFT once per keyframe, then FLANN matching per candidate pair
  auto t = Clock::now();
  std::vector<KeyframeEntry*> all;
  for (auto& e : src_kfs) all.push_back(&e);
  for (auto& e : tgt_kfs) all.push_back(&e);
#pragma omp parallel for schedule(dynamic)
  for (std::size_t i = 0; i < all.size(); ++i) {
    all[i]->features = extractFeatures(all[i]->keyframe->image, options.matching);
  }
  struct Candidate {
    const KeyframeEntry* source = nullptr;
    const KeyframeEntry* target = nullptr;
    FeatureMatches matches;  // a = target, b = source
    RelativePoseResult pose;
  };
  // Pairs to match in full: all of them, or the max_candidate_pairs with the most votes.
  std::vector<std::pair<std::size_t, std::size_t>> pairs;
  for (std::size_t i = 0; i < src_kfs.size(); ++i) {
    for (std::size_t j = 0; j < tgt_kfs.size(); ++j) pairs.emplace_back(i, j);
  }
  diag.keyframe_pairs = static_cast<int>(pairs.size());
  const auto max_pairs = static_cast<std::size_t>(options.merge.max_candidate_pairs);
  if (max_pairs > 0 && pairs.size() > max_pairs) {
    std::vector<const KeyframeFeatures*> sf, tf;
    for (const auto& e : src_kfs) sf.push_back(&e.features);
    for (const auto& e : tgt_kfs) tf.push_back(&e.features);
    const std::vector<std::vector<int>> votes = keyframePairVotes(sf, tf, options.matching);
    std::stable_sort(pairs.begin(), pairs.end(), [&](const auto& a, const auto& b) {
      return votes[a.first][a.second] > votes[b.first][b.second];
    });
    pairs.resize(max_pairs);
  }
  // Sequential: FLANN's randomised trees draw from std::rand().
  std::vector<Candidate> candidates(pairs.size());
  for (std::size_t k = 0; k < pairs.size(); ++k) {
    Candidate& c = candidates[k];
    c.source = &src_kfs[pairs[k].first];
    c.target = &tgt_kfs[pairs[k].second];
    c.matches = matchFeatures(c.target->features, c.source->features, options.matching);
  }
  rep.timings.features = msSince(t);
  diag.candidate_pairs = static_cast<int>(candidates.size());

  // --- relative pose per pair with enough matches; keep the most verified inliers
  t = Clock::now();
  Candidate* best = nullptr;
  Candidate* most_matches = nullptr;
  for (Candidate& c : candidates) {
    if (!most_matches || c.matches.size() > most_matches->matches.size()) most_matches = &c;
    if (static_cast<int>(c.matches.size()) < options.matching.min_matches) {
      c.pose.status = Status::kNotEnoughMatches;
      c.pose.message = std::to_string(c.matches.size()) + " feature matches < matching.min_matches " +
                       std::to_string(options.matching.min_matches);
      continue;
    }
    c.pose = keyframePairPose(c.matches, target.camera, source.camera, options.relative_pose);
    if (c.pose.status == Status::kOk && (!best || c.pose.inlier_count > best->pose.inlier_count)) best = &c;
  }
  rep.timings.relative_pose = msSince(t);
  if (!best) {
    const Candidate& c = *most_matches;
    Status status = c.pose.status == Status::kOk ? Status::kRelativePoseFailed : c.pose.status;
    if (status == Status::kDegenerate) status = Status::kRelativePoseFailed;
    rep.source_keyframe = c.source->keyframe->id;
    rep.target_keyframe = c.target->keyframe->id;
    diag.feature_matches = static_cast<int>(c.matches.size());
    return finish(status, "no keyframe pair verified (" + std::to_string(candidates.size()) +
                              " tried); best pair source " + std::to_string(c.source->keyframe->id) + " / target " +
                              std::to_string(c.target->keyframe->id) + ": " + c.pose.message);
  }
  const MapKeyframe& kf_s = *best->source->keyframe;
  const MapKeyframe& kf_t = *best->target->keyframe;
  rep.source_keyframe = kf_s.id;
  rep.target_keyframe = kf_t.id;
  diag.feature_matches = static_cast<int>(best->matches.size());
  diag.relative_pose_inliers = best->pose.inlier_count;

  // --- keyframe depth, the Kalman-filter scale and the initial map-to-map similarity
  t = Clock::now();
  const KeyframeGuess guess = keyframeGuess(source, kf_s, target, kf_t, best->matches, best->pose, options);
  const ScaleEstimate& scale = guess.scale;
  rep.timings.scale = msSince(t);
  diag.depth_matches = guess.depth_matches;
  diag.kalman_scale = scale.scale;
  diag.kalman_scale_stddev = scale.scale_stddev;
  diag.kalman_inliers = scale.inliers;
  if (scale.status != Status::kOk) {
    return finish(scale.status, "scale from " + std::to_string(guess.depth_matches) +
                                    " inlier matches with depth on both sides (" +
                                    std::to_string(best->pose.inlier_count) + " inliers): " + scale.message);
  }
  diag.initial = guess.initial;

  // --- scale detection, filters, ICP with scale refinement, covariance
  // The filters run once here: registration and the overlap gate share the filtered clouds.
  RegistrationOptions reg_options = options.registration;
  reg_options.icp.estimate_scale = options.merge.refine_scale;
  reg_options.filters.steps.clear();
  const StageTimings front = rep.timings;
  const std::optional<long> sk = rep.source_keyframe, tk = rep.target_keyframe;
  t = Clock::now();
  const Cloud source_filtered = applyFilterChain(source.cloud, options.registration.filters);
  const Cloud target_filtered = applyFilterChain(target.cloud, options.registration.filters);
  const double filter_ms = msSince(t);
  if (source_filtered.cols() == 0 || target_filtered.cols() == 0) {
    return finish(Status::kInvalidInput, std::string("the filters removed every point of the ") +
                                             (source_filtered.cols() == 0 ? "source" : "target") + " map cloud");
  }
  t = Clock::now();
  const KdTree target_tree(target_filtered);  // shared by the ICP and the overlap gate
  const double tree_ms = msSince(t);
  rep = registerClouds(source_filtered, target_filtered, diag.initial, reg_options, &target_tree);
  rep.timings.filters = filter_ms;
  rep.timings.icp += tree_ms;
  rep.source_keyframe = sk;
  rep.target_keyframe = tk;
  rep.timings.features = front.features;
  rep.timings.relative_pose = front.relative_pose;
  rep.timings.scale += front.scale;
  if (!options.merge.refine_scale) rep.scale_stddev = scale.scale_stddev;
  if (rep.status != Status::kOk && rep.status != Status::kDegenerate) return finish(rep.status, rep.message);

  // --- quality gates against false merges
  const Sim3& final_sim = *rep.transform;
  const double correction = rotationDistance(final_sim.rotation(), diag.initial.rotation()) * 180.0 / M_PI;
  if (correction > options.merge.max_icp_rotation_correction_deg) {
    return finish(Status::kIcpNotConverged, "refused: ICP rotated the keyframe-based guess by " + fmt(correction) +
                                                " deg > merge.max_icp_rotation_correction_deg " +
                                                fmt(options.merge.max_icp_rotation_correction_deg));
  }
  const double disagreement = std::abs(final_sim.scale() / scale.scale - 1.0);
  if (disagreement > options.merge.max_scale_disagreement) {
    return finish(Status::kScaleFailed, "refused: ICP scale " + fmt(final_sim.scale(), 4) + " disagrees with the Kalman scale " +
                                            fmt(scale.scale, 4) + " by " + fmt(100 * disagreement) + " %");
  }
  const double radius = options.merge.overlap_distance_factor * medianSpacing(target_tree);
  diag.overlap = overlapFraction(final_sim.apply(source_filtered), target_tree, radius);
  if (diag.overlap < options.merge.min_overlap) {
    return finish(Status::kIcpNotConverged, "refused: only " + fmt(100 * diag.overlap) +
                                                " % of the source map overlaps the target after alignment (< " +
                                                fmt(100 * options.merge.min_overlap) + " %)");
  }
  if (rep.status == Status::kDegenerate) return finish(rep.status, rep.message);
  return finish(Status::kOk, "merged 2 maps: keyframes source " + std::to_string(kf_s.id) + " / target " +
                                 std::to_string(kf_t.id) + ", " + std::to_string(best->pose.inlier_count) +
                                 " inliers, Kalman scale " + fmt(scale.scale, 4) + " +- " +
                                 fmt(scale.scale_stddev, 2) + ", overlap " + fmt(100 * diag.overlap) + " %");
}

}  // namespace pcr_pro
