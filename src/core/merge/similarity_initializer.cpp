#include "pcr_pro/merge/similarity_initializer.h"

#include <Eigen/Cholesky>

#include <Eigen/Eigenvalues>

#include <algorithm>
#include <chrono>
#include <cstdio>
#include <cstdlib>
#include <limits>
#include <cmath>
#include <map>
#include <memory>
#include <sstream>

#include "pcr_pro/frontend/keyframe_depth.h"
#include "pcr_pro/frontend/relative_pose_covariance.h"

namespace pcr_pro {
namespace {

using Clock = std::chrono::steady_clock;

std::string fmt(double v, int precision = 3) {
  std::ostringstream os;
  os.precision(precision);
  os << v;
  return os.str();
}

// Covariance of a keyframe point from the depth noise model of the scale stage: relative noise
// σ_d along the viewing ray and σ_l across it, both times the point's distance.
Eigen::Matrix3d pointCovariance(const Eigen::Vector3d& p, const ScaleEstimationOptions& o) {
  const double d2 = p.squaredNorm();
  const Eigen::Vector3d b = p / std::sqrt(d2);
  const Eigen::Matrix3d along = b * b.transpose();
  return d2 * (o.relative_depth_noise * o.relative_depth_noise * along +
               o.relative_lateral_noise * o.relative_lateral_noise * (Eigen::Matrix3d::Identity() - along));
}

// Rigid part of a keyframe pose: keyframe points are already in map units (KeyframeDepth::pointAt).
Sim3 rigidPart(const Sim3& pose) { return Sim3(1.0, pose.rotation(), pose.translation()); }

class DepthLookup {
 public:
  DepthLookup(const KeyframeDepthOptions& options) : options_(options) {}
  const KeyframeDepth& of(const MapKeyframe& keyframe, const AgentMap& map) {
    auto it = depths_.find(&keyframe);
    if (it == depths_.end()) {
      it = depths_.emplace(&keyframe, std::make_unique<KeyframeDepth>(keyframe, map.camera, map.cloud, options_)).first;
    }
    return *it->second;
  }

 private:
  KeyframeDepthOptions options_;
  std::map<const MapKeyframe*, std::unique_ptr<KeyframeDepth>> depths_;
};

// The pair's Kalman scale, own estimate and map-frame matches.
PairEvidence pairEvidence(const CandidatePair& c, int group, const AgentMap& source, const AgentMap& target,
                          DepthLookup* depths, const MergeOptions& o) {
  PairEvidence e;
  e.source_keyframe = c.source->id;
  e.target_keyframe = c.target->id;
  e.feature_matches = static_cast<int>(c.matches.size());
  e.inliers = c.pose.inlier_count;
  const KeyframeDepth& dt = depths->of(*c.target, target);
  const KeyframeDepth& ds = depths->of(*c.source, source);
  std::vector<Eigen::Vector3d> ps, pt;
  for (int k : c.pose.inliers) {
    const auto ku = static_cast<std::size_t>(k);
    Eigen::Vector3d a, b;
    if (dt.pointAt(c.matches.pixels_a[ku].x(), c.matches.pixels_a[ku].y(), &a) &&
        ds.pointAt(c.matches.pixels_b[ku].x(), c.matches.pixels_b[ku].y(), &b)) {
      pt.push_back(a);
      ps.push_back(b);
    }
  }
  e.depth_matches = static_cast<int>(ps.size());
  e.scale = estimateScale(ps, pt, c.pose.rotation, c.pose.translation_direction, o.scale_estimation);
  if (e.scale.status != Status::kOk) {
    e.note = "scale from " + std::to_string(e.depth_matches) + " matches with depth on both sides: " + e.scale.message;
    return e;
  }
  const Sim3 cam_t = rigidPart(c.target->pose), cam_s = rigidPart(c.source->pose);
  const Sim3 keyframe_sim(e.scale.scale, c.pose.rotation, e.scale.lambda * c.pose.translation_direction);
  e.estimate = cam_t * keyframe_sim * cam_s.inverse();
  const double s = e.estimate.scale();
  const Eigen::Matrix3d& r = e.estimate.rotation();
  for (std::size_t k = 0; k < ps.size(); ++k) {
    if (!e.scale.inlier_mask[k]) continue;
    PointMatch3 m;
    m.source = cam_s.apply(ps[k]);
    m.target = cam_t.apply(pt[k]);
    const Eigen::Matrix3d cs = cam_s.rotation() * pointCovariance(ps[k], o.scale_estimation) * cam_s.rotation().transpose();
    const Eigen::Matrix3d ct = cam_t.rotation() * pointCovariance(pt[k], o.scale_estimation) * cam_t.rotation().transpose();
    m.covariance = ct + s * s * r * cs * r.transpose();
    m.group = group;
    e.matches.push_back(m);
  }
  // The relative pose's rotation in the maps' frames, with its covariance from the inliers'
  // epipolar residuals (rotated from the target camera's axes into the target map's).
  std::vector<Eigen::Vector3d> bt, bs;
  for (std::size_t k = 0; k < c.matches.size(); ++k) {
    bt.push_back(target.camera.bearing(c.matches.pixels_a[k].x(), c.matches.pixels_a[k].y()));
    bs.push_back(source.camera.bearing(c.matches.pixels_b[k].x(), c.matches.pixels_b[k].y()));
  }
  const double focal = 0.5 * (source.camera.focal() + target.camera.focal());
  // Floor: half the RANSAC pixel error, the noise the inlier gate was drawn for.
  const Eigen::Matrix3d rot_cov =
      relativeRotationCovariance(bt, bs, c.pose, focal, 0.5 * o.relative_pose.pixel_error);
  e.rotation.rotation = cam_t.rotation() * c.pose.rotation * cam_s.rotation().transpose();
  e.rotation.covariance = cam_t.rotation() * rot_cov * cam_t.rotation().transpose();
  e.rotation.group = group;
  SimilarityFitOptions fo;
  fo.estimate_scale = true;
  const SimilarityFit fit = fitSimilarity(e.matches, {e.rotation}, e.estimate, fo);
  if (!fit.ok) {
    e.note = "its " + std::to_string(e.matches.size()) + " matches do not determine a similarity";
    return e;
  }
  e.estimate = fit.estimate;
  e.covariance = fit.covariance;
  e.has_estimate = true;
  return e;
}

using Vector7d = Eigen::Matrix<double, 7, 1>;

// Projection of a symmetric matrix onto the positive semi-definite cone.
Matrix7d psdPart(const Matrix7d& m) {
  const Eigen::SelfAdjointEigenSolver<Matrix7d> eig(0.5 * (m + m.transpose()));
  const Vector7d ev = eig.eigenvalues().cwiseMax(0.0);
  return eig.eigenvectors() * ev.asDiagonal() * eig.eigenvectors().transpose();
}

// Random-effects pooling of per-pair estimates (tangent vectors v about a common reference, with
// their own covariances s): v_p = θ + b_p + e_p, e_p ~ N(0, S_p) the pair's noise, b_p ~ N(0, T)
// what makes pairs disagree beyond their noise (keyframe pose errors, map distortion, scale
// drift). T by the method of moments (DerSimonian-Laird, multivariate), θ by weights
// (S_p + T)⁻¹. With one pair T is unknown and zero.
struct Pooled {
  Vector7d theta = Vector7d::Zero();
  Matrix7d covariance = Matrix7d::Zero();
  Matrix7d between = Matrix7d::Zero();  // T
  bool ok = false;
};

Pooled randomEffects(const std::vector<Vector7d>& v, const std::vector<Matrix7d>& s, const std::vector<int>& use) {
  Pooled out;
  if (use.empty()) return out;
  const auto k = static_cast<double>(use.size());
  Matrix7d mean_within = Matrix7d::Zero();
  for (int i : use) mean_within += s[static_cast<std::size_t>(i)] / k;
  for (int iter = 0; iter < 50; ++iter) {
    Matrix7d wsum = Matrix7d::Zero();
    Vector7d wv = Vector7d::Zero();
    for (int i : use) {
      const auto iu = static_cast<std::size_t>(i);
      const Eigen::LDLT<Matrix7d> ldlt(s[iu] + out.between);
      if (ldlt.info() != Eigen::Success) return out;
      const Matrix7d w = ldlt.solve(Matrix7d::Identity());
      wsum += w;
      wv += w * v[iu];
    }
    const Eigen::LDLT<Matrix7d> total(wsum);
    if (total.info() != Eigen::Success) return out;
    out.covariance = total.solve(Matrix7d::Identity());
    out.theta = out.covariance * wv;
    if (use.size() < 2) break;
    Matrix7d spread = Matrix7d::Zero();
    for (int i : use) {
      const Vector7d r = v[static_cast<std::size_t>(i)] - out.theta;
      spread += r * r.transpose() / (k - 1.0);
    }
    const Matrix7d next = psdPart(spread - mean_within);
    const bool settled = (next - out.between).norm() <= 1e-10 * (1e-300 + next.norm());
    out.between = next;
    if (settled) break;
  }
  out.covariance = 0.5 * (out.covariance + out.covariance.transpose()).eval();
  out.ok = out.covariance.allFinite() && out.theta.allFinite();
  return out;
}

// Squared Mahalanobis distance of a vector with a covariance.
double mahalanobis2(const Vector7d& d, const Matrix7d& c) {
  const Eigen::LDLT<Matrix7d> ldlt(c);
  if (ldlt.info() != Eigen::Success) return std::numeric_limits<double>::infinity();
  return d.dot(ldlt.solve(d));
}

}  // namespace

SimilarityInitializer::SimilarityInitializer(const MergeOptions& options) : options_(options) { validate(options_); }

KeyframeEstimate SimilarityInitializer::run(const AgentMap& source, const AgentMap& target,
                                            const FrontEndResult& front) const {
  const auto t0 = Clock::now();
  KeyframeEstimate out;
  DepthLookup depths(options_.keyframe_depth);
  for (int i = 0; i < front.verified; ++i) {
    out.pairs.push_back(pairEvidence(front.pairs[static_cast<std::size_t>(i)], i, source, target, &depths, options_));
    out.pairs.back().used = out.pairs.back().has_estimate;
  }
  auto finish = [&](Status status, const std::string& message) {
    out.status = status;
    out.message = message;
    out.ms = std::chrono::duration<double, std::milli>(Clock::now() - t0).count();
    return out;
  };
  for (const PairEvidence& e : out.pairs) out.used_pairs += e.used ? 1 : 0;
  if (out.used_pairs == 0) {
    if (out.pairs.empty()) return finish(Status::kRelativePoseFailed, "no keyframe pair verified");
    const PairEvidence& best = out.pairs.front();
    const Status status = best.scale.status == Status::kOk ? Status::kScaleFailed : best.scale.status;
    return finish(status, "no verified keyframe pair gave a scale (" + std::to_string(out.pairs.size()) +
                              " tried); best pair source " + std::to_string(best.source_keyframe) + " / target " +
                              std::to_string(best.target_keyframe) + ", " + std::to_string(best.inliers) +
                              " inliers: " + best.note);
  }
  // Pool the pairs' own estimates (random effects), then drop the pair that disagrees most with
  // the others beyond both their noise and the between-pair spread measured without it
  // (leave-one-out, so that a gross outlier does not hide in a spread it inflates itself).
  int reference = -1;
  for (std::size_t i = 0; i < out.pairs.size(); ++i) {
    if (out.pairs[i].used && (reference < 0 || out.pairs[i].matches.size() >
                                                    out.pairs[static_cast<std::size_t>(reference)].matches.size())) {
      reference = static_cast<int>(i);
    }
  }
  const Sim3 ref = out.pairs[static_cast<std::size_t>(reference)].estimate;
  // Pool in a well-conditioned parametrisation: translation about the centroid of the matched
  // target points, rotation and log scale times their RMS radius (all in target units), so that
  // a far-away frame origin does not couple rotation and translation.
  Eigen::Vector3d centroid = Eigen::Vector3d::Zero();
  int count = 0;
  for (const PairEvidence& e : out.pairs) {
    for (const PointMatch3& m : e.matches) {
      centroid += m.target;
      ++count;
    }
  }
  centroid /= std::max(1, count);
  double radius2 = 0.0;
  for (const PairEvidence& e : out.pairs) {
    for (const PointMatch3& m : e.matches) radius2 += (m.target - centroid).squaredNorm();
  }
  const double radius = std::max(std::sqrt(radius2 / std::max(1, count)), 1e-9);
  Matrix7d to_delta = Matrix7d::Identity();  // δ = to_delta · u
  to_delta.block<3, 3>(0, 3) = skew(centroid);
  to_delta.block<3, 1>(0, 6) = -centroid;
  for (int k = 3; k < 7; ++k) to_delta.col(k) /= radius;
  const Matrix7d to_u = to_delta.inverse();
  std::vector<Vector7d> v(out.pairs.size(), Vector7d::Zero());
  std::vector<Matrix7d> cov(out.pairs.size(), Matrix7d::Identity());
  for (std::size_t i = 0; i < out.pairs.size(); ++i) {
    if (!out.pairs[i].has_estimate) continue;
    v[i] = to_u * similarityDifference(out.pairs[i].estimate, ref);
    cov[i] = to_u * out.pairs[i].covariance * to_u.transpose();
  }
  // Which pairs agree. Distances between pair estimates are measured in the pooling's units
  // (target units: translation at the matches' centroid, rotation and log scale times their
  // radius), not in Mahalanobis terms: a wrong relative pose often comes with a wide covariance,
  // which would make it statistically close to everything. The medoid pair (smallest median
  // distance to the others) is the consensus; a pair is dropped when it lies more than four
  // times the lower quartile of the pairs' distances from the medoid (map distortion makes good
  // pairs disagree a little; a wrong relative pose lands degrees away, and the lower quartile
  // keeps a minority of wrong pairs from setting the scale they are judged by) and when, in
  // addition, the disagreement is beyond both pairs' noise (merge.pair_consistency_chi2).
  std::vector<int> with_estimate;
  for (std::size_t i = 0; i < out.pairs.size(); ++i) {
    if (out.pairs[i].used) with_estimate.push_back(static_cast<int>(i));
  }
  const std::size_t k_pairs = with_estimate.size();
  std::vector<std::vector<double>> dist(k_pairs, std::vector<double>(k_pairs, 0.0));
  for (std::size_t a = 0; a < k_pairs; ++a) {
    for (std::size_t b = a + 1; b < k_pairs; ++b) {
      dist[a][b] = dist[b][a] = (v[static_cast<std::size_t>(with_estimate[a])] -
                                 v[static_cast<std::size_t>(with_estimate[b])]).norm();
    }
  }
  std::size_t medoid = 0;
  double medoid_score = std::numeric_limits<double>::infinity();
  for (std::size_t a = 0; a < k_pairs; ++a) {
    std::vector<double> others;
    for (std::size_t b = 0; b < k_pairs; ++b) {
      if (b != a) others.push_back(dist[a][b]);
    }
    std::sort(others.begin(), others.end());
    // Ties (e.g. two pairs) go to the pair with more inliers, first in the front end's order.
    const double score = others.empty() ? 0.0 : others[others.size() / 2];
    if (score < medoid_score) {
      medoid_score = score;
      medoid = a;
    }
  }
  std::vector<double> to_medoid;
  for (std::size_t b = 0; b < k_pairs; ++b) {
    if (b != medoid) to_medoid.push_back(dist[b][medoid]);
  }
  std::sort(to_medoid.begin(), to_medoid.end());
  // With two pairs there is no majority: only a disagreement beyond both pairs' noise and four
  // times... nothing to compare with; the pair with fewer inliers then goes when they disagree
  // beyond their noise by more than a hundredfold (a gross error).
  const double distance_gate = to_medoid.size() >= 2 ? 4.0 * to_medoid[(to_medoid.size() - 1) / 4] : 0.0;
  const double chi2_gate = k_pairs >= 3 ? options_.merge.pair_consistency_chi2 : 100.0 * options_.merge.pair_consistency_chi2;
  const auto im = static_cast<std::size_t>(with_estimate[medoid]);
  std::vector<int> use;
  for (std::size_t b = 0; b < k_pairs; ++b) {
    const auto ib = static_cast<std::size_t>(with_estimate[b]);
    PairEvidence& e = out.pairs[ib];
    e.consistency_chi2 = b == medoid ? 0.0 : mahalanobis2(v[ib] - v[im], cov[ib] + cov[im]);
    if (b == medoid || dist[b][medoid] <= distance_gate || e.consistency_chi2 <= chi2_gate) {
      use.push_back(with_estimate[b]);
      continue;
    }
    e.used = false;
    e.note = "dropped: disagrees with the consensus pair source " + std::to_string(out.pairs[im].source_keyframe) +
             " / target " + std::to_string(out.pairs[im].target_keyframe) + " (by " + fmt(dist[b][medoid]) +
             " target units at the matches, > 4x the closer pairs' " + fmt(distance_gate / 4.0) +
             "; squared Mahalanobis distance " + fmt(e.consistency_chi2) + ")";
    --out.used_pairs;
    ++out.dropped_pairs;
  }
  Pooled pooled = randomEffects(v, cov, use);
  if (!pooled.ok) return finish(Status::kScaleFailed, "the keyframe pairs' estimates do not pool");
  pooled.theta = to_delta * pooled.theta;
  pooled.covariance = to_delta * pooled.covariance * to_delta.transpose();
  pooled.between = to_delta * pooled.between * to_delta.transpose();
  // The keyframe estimate: one robust fit over the consensus pairs' matches and relative-pose
  // rotations, so that each pair weighs by its evidence (a pair with many matches and a short
  // baseline outweighs a wide, sparse one, whose errors its own covariance understates), from
  // the random-effects centre. Its covariance covers both the fit's (noise, scaled by the
  // residuals, and the spread between pairs with three or more) and the random-effects one.
  SimilarityFit fit;
  {
    std::vector<PointMatch3> all;
    std::vector<RotationMeasurement> rotations;
    for (const PairEvidence& e : out.pairs) {
      if (!e.used) continue;
      all.insert(all.end(), e.matches.begin(), e.matches.end());
      rotations.push_back(e.rotation);
    }
    fit = fitSimilarity(all, rotations, applyDelta(pooled.theta, ref));
    if (!fit.ok) return finish(Status::kScaleFailed, "the keyframe pairs' matches do not determine a similarity");
    out.matches = std::move(all);
  }
  const Sim3 pooled_estimate = fit.estimate;
  const Matrix7d pooled_covariance = coveringCovariance(fit.covariance, pooled.covariance) + pooled.between;
  // Keep only the pooled inlier matches for the refinement.
  std::vector<PointMatch3> inliers;
  std::vector<int> per_pair(out.pairs.size(), 0);
  for (std::size_t k = 0; k < out.matches.size(); ++k) {
    if (!fit.inliers[k]) continue;
    inliers.push_back(out.matches[k]);
    ++per_pair[static_cast<std::size_t>(out.matches[k].group)];
  }
  out.matches = std::move(inliers);
  for (std::size_t i = 0; i < out.pairs.size(); ++i) {
    PairEvidence& e = out.pairs[i];
    if (!e.used) continue;
    e.note = "used: " + std::to_string(per_pair[i]) + " of its " + std::to_string(e.matches.size()) +
             " matches are pooled inliers";
    if (out.anchor < 0 || per_pair[i] > per_pair[static_cast<std::size_t>(out.anchor)]) out.anchor = static_cast<int>(i);
  }
  out.fit = fit;
  out.estimate = pooled_estimate;
  out.covariance = pooled_covariance;
  out.between = pooled.between;
  return finish(Status::kOk, std::to_string(out.used_pairs) + " keyframe pair(s) pooled, " +
                                 std::to_string(out.matches.size()) + " matches");
}

}  // namespace pcr_pro
