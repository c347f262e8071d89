#include "pcr_pro/merge/similarity_initializer.h"

#include <Eigen/Cholesky>

#include <Eigen/Eigenvalues>

#include <algorithm>
#include <array>
#include <chrono>
#include <cstdio>
#include <cstdlib>
#include <limits>
#include <cmath>
#include <map>
#include <memory>
#include <random>
#include <sstream>

#include "pcr_pro/frontend/keyframe_depth.h"
#include "pcr_pro/frontend/relative_pose_covariance.h"
#include "pcr_pro/geometry/median.h"
#include "pcr_pro/registration/icp.h"

namespace pcr_pro {
namespace {

using Clock = std::chrono::steady_clock;

// Two independent measurements of one rotation disagree when their squared Mahalanobis distance
// exceeds the chi-square 99.9 % quantile with 3 DoF: one false alarm in a thousand pairs whose
// two covariances are right.
constexpr double kRotationAgreementChi2 = 16.27;
// The median of the chi-square distribution with 3 DoF.
constexpr double kChi2MedianThreeDof = 2.366;

std::string fmt(double v, int precision = 3) {
  std::ostringstream os;
  os.precision(precision);
  os << v;
  return os.str();
}

// Covariance of a keyframe point P = z·(x, y, 1) (camera frame, map units). Without a per-pixel
// depth uncertainty (depth_stddev 0), the depth noise model of the scale stage: relative noise
// σ_d along the viewing ray and σ_l across it, both times the point's distance. With one, the
// depth's own standard deviation σ_z moves the point along the ray (dP/dz = P / z), and σ_l
// (the feature's pixel error) across it.
//
// Depth looked up in the map cloud projected into the keyframe has no per-pixel uncertainty,
// but the cloud's noise is measured where it is dense (KeyframeDepth::projectedRelativeNoise()):
// σ_d is then the larger of that and scale_estimation.relative_depth_noise, the configured noise
// being the least a depth is trusted with. Without it, the depth matches of a map noisier than
// the configured 2 % were given too small a variance: the simulated semi-dense maps at
// inverse-depth noise 0.03 measure 4.6-5.0 % (their lookups' true errors 5.4-6.1 %), a variance
// 5-6 times the configured one.
Eigen::Matrix3d pointCovariance(const Eigen::Vector3d& p, double depth_stddev, const KeyframeDepth& depth,
                                const ScaleEstimationOptions& o) {
  const double sigma_d = std::max(o.relative_depth_noise, depth.projectedRelativeNoise());
  const double d2 = p.squaredNorm();
  const Eigen::Vector3d b = p / std::sqrt(d2);
  const Eigen::Matrix3d along = b * b.transpose();
  const Eigen::Matrix3d across = d2 * o.relative_lateral_noise * o.relative_lateral_noise *
                                 (Eigen::Matrix3d::Identity() - along);
  if (depth_stddev > 0.0) {
    const Eigen::Vector3d dp_dz = p / p.z();
    return depth_stddev * depth_stddev * dp_dz * dp_dz.transpose() + across;
  }
  return d2 * sigma_d * sigma_d * along + across;
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

// The relative pose's rotation in the maps' frames, with its covariance from the inliers'
// epipolar residuals (rotated from the target camera's axes into the target map's).
RotationMeasurement rotationMeasurement(const CandidatePair& c, const AgentMap& source, const AgentMap& target,
                                        const Sim3& cam_s, const Sim3& cam_t, const MergeOptions& o) {
  std::vector<Eigen::Vector3d> bt, bs;
  for (std::size_t k = 0; k < c.matches.size(); ++k) {
    bt.push_back(target.camera.bearing(c.matches.pixels_a[k].x(), c.matches.pixels_a[k].y()));
    bs.push_back(source.camera.bearing(c.matches.pixels_b[k].x(), c.matches.pixels_b[k].y()));
  }
  const double focal = 0.5 * (source.camera.focal() + target.camera.focal());
  // Floor: half the RANSAC pixel error, the noise the inlier gate was drawn for.
  const Eigen::Matrix3d rot_cov =
      relativeRotationCovariance(bt, bs, c.pose, focal, 0.5 * o.relative_pose.pixel_error);
  RotationMeasurement m;
  m.rotation = cam_t.rotation() * c.pose.rotation * cam_s.rotation().transpose();
  m.covariance = cam_t.rotation() * rot_cov * cam_t.rotation().transpose();
  return m;
}

// The part of a pair's relative-pose rotation error that the epipolar residuals cannot see, as a
// covariance added to the rotation measurement (map frame, left perturbation, rad²): errors
// common to all of one image's keypoints, which do not average down with the number of matches.
// A principal point off by δ pixels (or a detector's sub-pixel convention, or lens distortion
// left over where the matches lie) turns the image's bearings by about δ / f about the two axes
// across its optical axis; the relative pose absorbs that turn whole, so its residuals do not
// grow. Its 1-sigma is taken as relative_pose.pixel_error (ψ, the keypoint accuracy the inlier
// gate is drawn for), independently in each image; ψ / f is 0.11 deg on slambook2 and 0.22 deg on
// the bench's 320x240 worlds.
// - In the pair check (rotationDisagreement(); stop 61): before it, the check was a knife edge on
//   real RGB-D pairs: on slambook2's sharedworld the best pair (150 inliers, 83 depth matches)
//   passed while OpenCV SIFT's quarter-pixel keypoint shift was left in and failed once it was
//   taken off (0.26 deg, squared distance 22.1 > 16.3), and no shift swept from -0.5 to +0.25 px
//   kept it but the old one. The pairs the check refuses on simulated worlds are 3-24 deg off.
//   (A depth image shifted 1-2 px against its keyframe image, simulated, moved the check's
//   squared distances by under 1 %.)
// - In the measurement itself, wherever it is used (the pair's own similarity, the leave-one-out
//   check, the pooled fit; 2026-12-07): with the term in the check alone, a single pair on the
//   real slambook2 maps without depth images claimed a rotation 1-sigma of 0.02-0.04 deg and lay
//   0.07-0.14 deg per axis from the truth (robustness sweep, full density and 30 %, roll 0 and 90 deg).
//   The bench's effect is in docs/DESIGN.md ("One keyframe pair's relative-pose rotation claims
//   too much").
Eigen::Matrix3d keypointOffsetCovariance(const RotationMeasurement& m, const Sim3& cam_s, const Sim3& cam_t,
                                         const AgentMap& source, const AgentMap& target, const MergeOptions& o) {
  const double psi = o.relative_pose.pixel_error;
  const Eigen::Vector3d across(1.0, 1.0, 0.0);
  // Target image: R' = exp(Rt ε) R. Source image: R' = exp(-(R Rs) ε) R.
  const Eigen::Matrix3d rt = cam_t.rotation();
  const Eigen::Matrix3d rs = m.rotation * cam_s.rotation();
  const double at = psi / target.camera.focal(), as = psi / source.camera.focal();
  return at * at * rt * across.asDiagonal() * rt.transpose() + as * as * rs * across.asDiagonal() * rs.transpose();
}

// The relative pose's rotation and the pair's own depth matches measure the same rotation
// independently. When they disagree beyond both their noise, the relative pose is the wrong one
// of a twin (a mostly planar view gives two essential matrices that fit the same inliers) or a
// wrong match set, and its rotation, far more confident than the matches, would carry the
// pooled estimate with it: the pair is not used. (On a simulated room with 15 % overlap, a pair
// seen 64 deg apart had 83 inliers and a relative rotation 23.6 deg wrong with a 1-sigma of
// 0.07 deg, while its 48 depth matches alone fit within 1.1 deg of the truth: squared
// Mahalanobis distance 173; the pooled estimate went 22 deg wrong and the merge was refused.)
// The matches are the Kalman inliers: fitting every depth match instead flagged more of the
// real LSD-SLAM pairs, whose semi-dense depths are noisier than their variance says, and left
// 2 of 34 pairs to merge lsd_slam_7scenes b->a, 7.6 % from the truth with a 2.1 % stddev.
// Their difference's covariance holds both measurements' noise, the rotation's with the
// keypoints' common offset (keypointOffsetCovariance()).
// Returns why the pair is not used, or "" when the two agree (or the matches alone do not
// determine a similarity, and so cannot contradict the relative pose).
std::string rotationDisagreement(const std::vector<PointMatch3>& matches, const RotationMeasurement& rotation,
                                 const Sim3& start, const SimilarityFitOptions& fo) {
  const SimilarityFit alone = fitSimilarity(matches, {}, start, fo);
  if (!alone.ok) return "";
  const Eigen::Vector3d dr = similarityDifference(Sim3(1.0, rotation.rotation, Eigen::Vector3d::Zero()),
                                                  Sim3(1.0, alone.estimate.rotation(), Eigen::Vector3d::Zero()))
                                 .segment<3>(3);
  const Eigen::LDLT<Eigen::Matrix3d> ldlt(rotation.covariance + alone.covariance.block<3, 3>(3, 3));
  const double chi2 = ldlt.info() == Eigen::Success ? dr.dot(ldlt.solve(dr)) : 0.0;
  if (chi2 <= kRotationAgreementChi2) return "";
  return "its relative pose's rotation disagrees with its own " + std::to_string(matches.size()) +
         " depth matches by " + fmt(dr.norm() * 180.0 / M_PI) + " deg (squared Mahalanobis distance " + fmt(chi2) +
         " > " + fmt(kRotationAgreementChi2) + "): a planar twin or a wrong match set";
}

// A pair's relative-pose inliers with depth on both sides, as map points with each side's
// covariance in its map's frame (map units): what the joint estimate (jointEstimate()) pools
// when no pair has enough of them for a scale of its own.
struct DepthMatches {
  std::vector<Eigen::Vector3d> source, target;
  std::vector<Eigen::Matrix3d> cov_source, cov_target;
};

// The residual covariance of depth match k of `m` under a similarity of scale s and rotation r.
Eigen::Matrix3d matchCovariance(const DepthMatches& m, std::size_t k, double s, const Eigen::Matrix3d& r) {
  return m.cov_target[k] + s * s * r * m.cov_source[k] * r.transpose();
}

// Depth match k of `m` as a point match of group `group`, its covariance at the similarity `at`.
PointMatch3 pointMatch(const DepthMatches& m, std::size_t k, const Sim3& at, int group) {
  PointMatch3 p;
  p.source = m.source[k];
  p.target = m.target[k];
  p.covariance = matchCovariance(m, k, at.scale(), at.rotation());
  p.group = group;
  return p;
}

// The pair's Kalman scale, own estimate and map-frame matches; *raw gets every depth match.
PairEvidence pairEvidence(const CandidatePair& c, int group, const AgentMap& source, const AgentMap& target,
                          DepthLookup* depths, const MergeOptions& o, DepthMatches* raw) {
  PairEvidence e;
  e.source_keyframe = c.source->id;
  e.target_keyframe = c.target->id;
  e.feature_matches = static_cast<int>(c.matches.size());
  e.inliers = c.pose.inlier_count;
  const KeyframeDepth& dt = depths->of(*c.target, target);
  const KeyframeDepth& ds = depths->of(*c.source, source);
  std::vector<Eigen::Vector3d> ps, pt;
  std::vector<Eigen::Matrix3d> cov_s, cov_t;  // camera frames, map units
  for (int k : c.pose.inliers) {
    const auto ku = static_cast<std::size_t>(k);
    Eigen::Vector3d a, b;
    double sa = 0.0, sb = 0.0;
    if (dt.pointAt(c.matches.pixels_a[ku].x(), c.matches.pixels_a[ku].y(), &a, &sa) &&
        ds.pointAt(c.matches.pixels_b[ku].x(), c.matches.pixels_b[ku].y(), &b, &sb)) {
      pt.push_back(a);
      ps.push_back(b);
      cov_t.push_back(pointCovariance(a, sa, dt, o.scale_estimation));
      cov_s.push_back(pointCovariance(b, sb, ds, o.scale_estimation));
    }
  }
  e.depth_matches = static_cast<int>(ps.size());
  const Sim3 cam_t = rigidPart(c.target->pose), cam_s = rigidPart(c.source->pose);
  for (std::size_t k = 0; k < ps.size(); ++k) {
    raw->source.push_back(cam_s.apply(ps[k]));
    raw->target.push_back(cam_t.apply(pt[k]));
    raw->cov_source.push_back(cam_s.rotation() * cov_s[k] * cam_s.rotation().transpose());
    raw->cov_target.push_back(cam_t.rotation() * cov_t[k] * cam_t.rotation().transpose());
  }
  e.scale = estimateScale(ps, pt, c.pose.rotation, c.pose.translation_direction, o.scale_estimation, &cov_s, &cov_t);
  if (e.scale.status != Status::kOk) {
    e.note = "scale from " + std::to_string(e.depth_matches) + " matches with depth on both sides: " + e.scale.message;
    return e;
  }
  {
    std::vector<double> distances;
    for (std::size_t k = 0; k < pt.size(); ++k) {
      if (e.scale.inlier_mask[k]) distances.push_back(pt[k].norm());
    }
    e.baseline_ratio = std::abs(e.scale.lambda) / upperMedian(&distances);
  }
  const Sim3 keyframe_sim(e.scale.scale, c.pose.rotation, e.scale.lambda * c.pose.translation_direction);
  e.estimate = cam_t * keyframe_sim * cam_s.inverse();
  for (std::size_t k = 0; k < ps.size(); ++k) {
    if (e.scale.inlier_mask[k]) e.matches.push_back(pointMatch(*raw, k, e.estimate, group));
  }
  e.rotation = rotationMeasurement(c, source, target, cam_s, cam_t, o);
  e.rotation.covariance += keypointOffsetCovariance(e.rotation, cam_s, cam_t, source, target, o);
  e.rotation.group = group;
  SimilarityFitOptions fo;
  fo.estimate_scale = true;
  const SimilarityFit fit = fitSimilarity(e.matches, {e.rotation}, e.estimate, fo);
  if (!fit.ok) {
    e.note = "its " + std::to_string(e.matches.size()) + " matches do not determine a similarity";
    return e;
  }
  const std::string disagreement = rotationDisagreement(e.matches, e.rotation, fit.estimate, fo);
  if (!disagreement.empty()) {
    e.note = disagreement;
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

// The block diagonal (translation at the matches' centroid | rotation | scale) of a covariance in
// the pooling frame. The pairs' estimates are few and far from independent (pairs share
// keyframes, and a keyframe's depth and pose errors reach every pair it is in), so their spread
// resolves the correlations between these blocks poorly: on the simulator's drift worlds the
// full matrices claim a combined rotation-translation direction to 0.2 mm and 0.01 deg where the
// local truth lies 11 of those standard deviations away (6-DoF NEES within the chi-square 95 %
// bound in 4 of 12 worlds); without the cross terms 12 of 12, and the scale 12 of 12.
// The between-pair spread from K pairs is a sample covariance of rank at most K - 1: with two
// pairs it sees the spread only along the one direction in which they differ, and claims none
// across it, where the local similarity varies as well (each map's drift bends it in every
// direction). Then each 3x3 block (translation, rotation) gets at least a third of its trace in
// every direction: the unbiased estimate of an isotropic spread from the pairs' difference, while
// the direction they do differ in keeps what it shows. On 14 drifting simulated LSD worlds the
// two-pair merges had 6-DoF NEES up to 27 (a spread of 0.016 deg about one axis beside 0.36 deg
// about another); with this, at most 7.1. Applied to three pairs as well it made the 48 simulated
// bench worlds' 6-DoF ANEES 0.63 (too wide); two pairs only: 0.69, and 94 % of their rotation
// NEES under the chi-square 95 % bound (88 % before).
Matrix7d fullRankBlocks(const Matrix7d& m, std::size_t pairs) {
  if (pairs > 2) return m;
  Matrix7d out = m;
  for (int b = 0; b < 6; b += 3) {
    const Eigen::SelfAdjointEigenSolver<Eigen::Matrix3d> eig(m.block<3, 3>(b, b));
    const double floor = std::max(0.0, eig.eigenvalues().sum()) / 3.0;
    const Eigen::Vector3d values = eig.eigenvalues().cwiseMax(floor);
    out.block<3, 3>(b, b) = eig.eigenvectors() * values.asDiagonal() * eig.eigenvectors().transpose();
  }
  return out;
}

Matrix7d blockDiagonal(const Matrix7d& m) {
  Matrix7d out = Matrix7d::Zero();
  out.block<3, 3>(0, 0) = m.block<3, 3>(0, 0);
  out.block<3, 3>(3, 3) = m.block<3, 3>(3, 3);
  out(6, 6) = m(6, 6);
  return out;
}

// Squared Mahalanobis distance of a vector with a covariance.
double mahalanobis2(const Vector7d& d, const Matrix7d& c) {
  const Eigen::LDLT<Matrix7d> ldlt(c);
  if (ldlt.info() != Eigen::Success) return std::numeric_limits<double>::infinity();
  return d.dot(ldlt.solve(d));
}


// Each map's scale and orientation drift along its path: keyframe pairs far apart along the
// paths see different local similarities (on lsd_slam_7scenes the start of one map overlaps the
// middle of the other too, 20-26 deg and 25-40 % away from the similarity where the paths
// overlap). The edge belongs to one place: the pairs used are those whose keyframes lie within
// `k` keyframes (in id order, which is the order along the path for LSD-SLAM and the simulator)
// of the best pair's (the first pair with an estimate: most relative-pose inliers). Returns how
// many pairs were set aside.
int keepNeighbourhood(const AgentMap& source, const AgentMap& target, int k, std::vector<PairEvidence>* pairs) {
  if (k <= 0) return 0;
  const std::map<long, long> rs = keyframeRanks(source), rt = keyframeRanks(target);
  const PairEvidence* best = nullptr;
  for (const PairEvidence& e : *pairs) {
    if (e.used) {
      best = &e;
      break;
    }
  }
  if (best == nullptr) return 0;
  const long bs = rs.at(best->source_keyframe), bt = rt.at(best->target_keyframe);
  const std::string centre = "source " + std::to_string(best->source_keyframe) + " / target " +
                             std::to_string(best->target_keyframe);
  int distant = 0;
  for (PairEvidence& e : *pairs) {
    if (!e.used || (std::abs(rs.at(e.source_keyframe) - bs) <= k && std::abs(rt.at(e.target_keyframe) - bt) <= k)) {
      continue;
    }
    e.used = false;
    e.note = "not used: more than merge.local_keyframes " + std::to_string(k) +
             " keyframes along a path from the best pair " + centre;
    ++distant;
  }
  return distant;
}

// The pooling's well-conditioned parametrisation: translation about the centroid of the matched
// target points, rotation and log scale times their RMS radius (all in target units), so that a
// far-away frame origin does not couple rotation and translation.
struct PoolingFrame {
  Matrix7d to_delta = Matrix7d::Identity();  // δ = to_delta · u
  Matrix7d to_u = Matrix7d::Identity();
};

PoolingFrame poolingFrame(const std::vector<PairEvidence>& pairs) {
  Eigen::Vector3d centroid = Eigen::Vector3d::Zero();
  int count = 0;
  for (const PairEvidence& e : pairs) {
    for (const PointMatch3& m : e.matches) {
      centroid += m.target;
      ++count;
    }
  }
  centroid /= std::max(1, count);
  double radius2 = 0.0;
  for (const PairEvidence& e : pairs) {
    for (const PointMatch3& m : e.matches) radius2 += (m.target - centroid).squaredNorm();
  }
  const double radius = std::max(std::sqrt(radius2 / std::max(1, count)), 1e-9);
  PoolingFrame f;
  f.to_delta.block<3, 3>(0, 3) = skew(centroid);
  f.to_delta.block<3, 1>(0, 6) = -centroid;
  for (int k = 3; k < 7; ++k) f.to_delta.col(k) /= radius;
  f.to_u = f.to_delta.inverse();
  return f;
}

// Which pairs agree. Distances between pair estimates are measured in the pooling's units
// (target units: translation at the matches' centroid, rotation and log scale times their
// radius), not in Mahalanobis terms: a wrong relative pose often comes with a wide covariance,
// which would make it statistically close to everything. The medoid pair (smallest median
// distance to the others) is the consensus. A pair is dropped when it lies more than four times
// the median of the pairs' distances from the medoid and when, in addition, the disagreement is
// beyond both pairs' noise (chi2_gate). The median, not a lower quantile: each monocular map's
// scale drifts, so pairs from different parts of the overlap disagree by a continuum (on the real
// LSD-SLAM maps of lsd_slam_7scenes by 10-25 % in scale between neighbouring pairs), while a wrong
// relative pose or a depth propagated at a wrong scale lands far outside it (a factor 2.5-3 in
// scale there); the median keeps a minority of such pairs from setting the yardstick. With two
// pairs there is no majority: the one with fewer inliers goes only when they disagree beyond
// their noise by more than a hundredfold (a gross error). Returns the kept pairs' indices and
// marks the dropped ones.
std::vector<int> consensus(const std::vector<Vector7d>& v, const std::vector<Matrix7d>& cov, double chi2_option,
                           std::vector<PairEvidence>* pairs) {
  std::vector<int> with_estimate;
  for (std::size_t i = 0; i < pairs->size(); ++i) {
    if ((*pairs)[i].used) with_estimate.push_back(static_cast<int>(i));
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
  const double distance_gate = to_medoid.size() >= 2 ? 4.0 * to_medoid[(to_medoid.size() - 1) / 2] : 0.0;
  const double chi2_gate = k_pairs >= 3 ? chi2_option : 100.0 * chi2_option;
  const auto im = static_cast<std::size_t>(with_estimate[medoid]);
  std::vector<int> use;
  for (std::size_t b = 0; b < k_pairs; ++b) {
    const auto ib = static_cast<std::size_t>(with_estimate[b]);
    PairEvidence& e = (*pairs)[ib];
    e.consistency_chi2 = b == medoid ? 0.0 : mahalanobis2(v[ib] - v[im], cov[ib] + cov[im]);
    if (b == medoid || dist[b][medoid] <= distance_gate || e.consistency_chi2 <= chi2_gate) {
      use.push_back(with_estimate[b]);
      continue;
    }
    e.used = false;
    e.note = "dropped: disagrees with the consensus pair source " + std::to_string((*pairs)[im].source_keyframe) +
             " / target " + std::to_string((*pairs)[im].target_keyframe) + " (by " + fmt(dist[b][medoid]) +
             " target units at the matches, > 4x the pairs' median " + fmt(distance_gate / 4.0) +
             "; squared Mahalanobis distance " + fmt(e.consistency_chi2) + ")";
  }
  return use;
}

// The pooled estimate's matches (for the refinement's anchors): every used pair's matches that
// fit it within the pair's noise and the between-pair spread; and the anchor pair, the used pair
// with the most of them.
void selectPooledMatches(KeyframeEstimate* out) {
  std::vector<PointMatch3> all;
  for (const PairEvidence& e : out->pairs) {
    if (e.used) all.insert(all.end(), e.matches.begin(), e.matches.end());
  }
  SimilarityFit& fit = out->fit;
  fit.estimate = out->estimate;
  fit.inliers.assign(all.size(), false);
  fit.inlier_count = 0;
  const SimilarityFitOptions fo;
  std::vector<int> per_pair(out->pairs.size(), 0);
  out->matches.clear();
  for (std::size_t k = 0; k < all.size(); ++k) {
    const Eigen::Vector3d r = out->estimate.apply(all[k].source) - all[k].target;
    const Eigen::Matrix<double, 3, 7> j = similarityJacobian(out->estimate.apply(all[k].source));
    PointMatch3 m = all[k];
    m.covariance = all[k].covariance + j * out->between * j.transpose();
    fit.inliers[k] = r.dot(m.covariance.ldlt().solve(r)) <= fo.outlier_chi2;
    if (!fit.inliers[k]) continue;
    ++fit.inlier_count;
    ++per_pair[static_cast<std::size_t>(m.group)];
    out->matches.push_back(m);
  }
  // The anchor: of the used pairs with at least half the most pooled inliers, the one whose own
  // similarity lies closest to the pooled estimate (RMS over the pooled matches, target units).
  // Each map's scale and orientation drift along its path, so every pair has its own local
  // similarity; the pooled estimate is near their average, and the edge is honest about the
  // place it is attached to when that place is the one whose similarity the average is. Taking
  // the pair with the most inliers instead put the anchor anywhere along the overlap: on 13
  // drifting simulated LSD worlds (2-5 % scale drift) the keyframe estimate lay 0.1-1.2 % in scale
  // from that pair's local truth and the edge's scale NEES averaged 3.3; with this anchor 0.01-0.4 %
  // and 0.67.
  const int most = per_pair.empty() ? 0 : *std::max_element(per_pair.begin(), per_pair.end());
  double best = std::numeric_limits<double>::infinity();
  for (std::size_t i = 0; i < out->pairs.size(); ++i) {
    PairEvidence& e = out->pairs[i];
    if (!e.used) continue;
    e.note = "used: " + std::to_string(per_pair[i]) + " of its " + std::to_string(e.matches.size()) +
             " matches are pooled inliers";
    if (2 * per_pair[i] < most) continue;
    const double move = rmsMoveOfMatches(out->matches, e.estimate, out->estimate);
    if (move < best) {
      best = move;
      out->anchor = static_cast<int>(i);
    }
  }
}

// Each used pair's relative-pose rotation against the depth matches of the other used pairs
// pooled (leave one out). A pair's own matches cannot always expose a wrong relative pose
// (rotationDisagreement()): with few of them and semi-dense depth, whose noise lies mostly along
// the viewing rays, they fit the wrong one of a planar view's two essential matrices nearly as
// well as the right one. The other pairs' matches are independent of it, and a wrong rotation's
// covariance, far smaller than any match fit's, would carry the pooled estimate with it.
// - Yardstick: the squared Mahalanobis distance under both covariances, against
//   kRotationAgreementChi2 scaled by the pairs' own median distance over the chi-square median
//   (when above 1). Each map's drift and distortion make every pair's local rotation differ from
//   the others' by a continuum that no covariance holds (on 7-Scenes by 2-50 deg); the median
//   pair measures that continuum, so only a pair far outside it goes, as in consensus().
// - The worst pair goes, and the check is repeated, while three pairs or more remain: with two
//   there is no majority.
// (On a simulated 15 % overlap with 2.5 % drift and LSD-SLAM's keyframe depth, pairs 23 and 9 deg
// wrong with 1-sigmas of 0.08 and 0.5 deg passed the consensus, whose median distance they set,
// and pooled the keyframe estimate 22 deg from the truth, reported OK; their own 14 matches each
// disagreed with them by only 4 and 7 deg. Against the others' matches: squared distances 2009
// and 359, gates 52 and 56; the right pairs' at most 8.1.)
void dropRotationOutliers(std::vector<PairEvidence>* pairs) {
  for (;;) {
    std::vector<std::size_t> used;
    for (std::size_t i = 0; i < pairs->size(); ++i) {
      if ((*pairs)[i].used) used.push_back(i);
    }
    if (used.size() < 3) return;
    // Each pair's leave-one-out fit is independent of the others' (one robust fit over the other
    // pairs' matches, about 1.3 ms for 900 matches): they run in parallel, and are gathered in
    // the pairs' order so the result does not depend on the threads. On the bench's 50 x 50
    // keyframe merge (35 pairs, two rounds) this loop was the keyframe stage's largest part.
    const auto n_used = static_cast<std::ptrdiff_t>(used.size());
    std::vector<double> chi2_of(used.size(), -1.0), deg_of(used.size(), 0.0);  // < 0: not tested
#pragma omp parallel for schedule(dynamic)
    for (std::ptrdiff_t i = 0; i < n_used; ++i) {
      const std::size_t p = used[static_cast<std::size_t>(i)];
      std::vector<PointMatch3> others;
      for (const std::size_t q : used) {
        if (q != p) others.insert(others.end(), (*pairs)[q].matches.begin(), (*pairs)[q].matches.end());
      }
      if (others.size() < 3) continue;
      Cloud src(3, static_cast<Eigen::Index>(others.size())), dst(3, static_cast<Eigen::Index>(others.size()));
      for (std::size_t k = 0; k < others.size(); ++k) {
        src.col(static_cast<Eigen::Index>(k)) = others[k].source;
        dst.col(static_cast<Eigen::Index>(k)) = others[k].target;
      }
      const Sim3 start = umeyama(src, dst, true);
      if (!(start.scale() > 0.0) || !start.matrix().allFinite()) continue;
      const SimilarityFit fit = fitSimilarity(others, {}, start);
      if (!fit.ok) continue;
      const RotationMeasurement& r = (*pairs)[p].rotation;
      const Eigen::Vector3d dr = similarityDifference(Sim3(1.0, r.rotation, Eigen::Vector3d::Zero()),
                                                      Sim3(1.0, fit.estimate.rotation(), Eigen::Vector3d::Zero()))
                                     .segment<3>(3);
      const Eigen::LDLT<Eigen::Matrix3d> ldlt(r.covariance + fit.covariance.block<3, 3>(3, 3));
      const double chi2 = ldlt.info() == Eigen::Success ? dr.dot(ldlt.solve(dr)) : 0.0;
      if (!std::isfinite(chi2)) continue;
      chi2_of[static_cast<std::size_t>(i)] = chi2;
      deg_of[static_cast<std::size_t>(i)] = dr.norm() * 180.0 / M_PI;
    }
    std::vector<double> chi2s, degs;
    std::vector<std::size_t> tested;
    for (std::size_t i = 0; i < used.size(); ++i) {
      if (chi2_of[i] < 0.0) continue;
      chi2s.push_back(chi2_of[i]);
      degs.push_back(deg_of[i]);
      tested.push_back(used[i]);
    }
    if (tested.size() < 3) return;
    std::vector<double> sorted = chi2s;
    std::sort(sorted.begin(), sorted.end());
    const double median = sorted[(sorted.size() - 1) / 2];
    const double gate = kRotationAgreementChi2 * std::max(1.0, median / kChi2MedianThreeDof);
    const auto worst = static_cast<std::size_t>(std::max_element(chi2s.begin(), chi2s.end()) - chi2s.begin());
    if (chi2s[worst] <= gate) return;
    PairEvidence& e = (*pairs)[tested[worst]];
    e.used = false;
    e.note = "dropped: its relative pose's rotation disagrees with the other pairs' depth matches by " +
             fmt(degs[worst]) + " deg (squared Mahalanobis distance " + fmt(chi2s[worst]) + " > " + fmt(gate) + ")";
  }
}

// Which pairs agree with a hypothesis of S_target_source that the map clouds support (the
// refinement), when the pairs split into camps that the medoid cannot tell apart (two against
// two). The same yardstick as consensus(), with the hypothesis as the centre: a pair is kept when
// it lies within four times the distance of the second-closest pair (two pairs at least, as a
// pooled estimate needs) or agrees with the hypothesis within its own noise. Marks the others.
std::vector<int> agreeWith(const std::vector<Vector7d>& v, const std::vector<Matrix7d>& cov, const Vector7d& centre,
                           double chi2_gate, std::vector<PairEvidence>* pairs) {
  std::vector<int> candidates;
  std::vector<double> dist;
  for (std::size_t i = 0; i < pairs->size(); ++i) {
    if (!(*pairs)[i].used) continue;
    candidates.push_back(static_cast<int>(i));
    dist.push_back((v[i] - centre).norm());
  }
  std::vector<double> sorted = dist;
  std::sort(sorted.begin(), sorted.end());
  const double distance_gate = sorted.size() >= 2 ? 4.0 * sorted[1] : 0.0;
  std::vector<int> use;
  for (std::size_t k = 0; k < candidates.size(); ++k) {
    PairEvidence& e = (*pairs)[static_cast<std::size_t>(candidates[k])];
    e.consistency_chi2 = mahalanobis2(v[static_cast<std::size_t>(candidates[k])] - centre,
                                      cov[static_cast<std::size_t>(candidates[k])]);
    if (dist[k] <= distance_gate || e.consistency_chi2 <= chi2_gate) {
      use.push_back(candidates[k]);
      continue;
    }
    e.used = false;
    e.note = "dropped: disagrees with the estimate the map clouds support (by " + fmt(dist[k]) +
             " target units at the matches, > 4x the second-closest pair's " + fmt(distance_gate / 4.0) +
             "; squared Mahalanobis distance " + fmt(e.consistency_chi2) + ")";
  }
  return use;
}

// Hypotheses the joint estimate tries at most (every three of its matches up to 30 matches), and
// the fixed seed of its draws beyond that.
constexpr std::size_t kJointHypotheses = 4060;
constexpr std::uint32_t kJointSeed = 20261130u;

// The joint estimate, for when no verified pair has enough depth matches (relative-pose inliers
// with depth on both sides) for its own Kalman scale. In the maps' frames every pair's depth
// matches obey the same similarity (up to each map's drift), so a few from each of several pairs
// determine it together. Keyframe depth taken from a semi-dense map cloud covers few of SIFT's
// keypoints: on 7-Scenes without depth images, 4 of 12 overlapping pairs of maps had 0-6 such
// matches in each of their 4-15 verified keyframe pairs, and were refused (NOT_ENOUGH_MATCHES).
// - Pairs: those with depth matches within merge.local_keyframes of the first of them (the most
//   relative-pose inliers), as for the pooled estimate.
// - Hypotheses: the similarity through three of their matches (every three up to 30 matches,
//   kJointHypotheses drawn beyond) whose triangle is wider than their noise; the one that the
//   most matches fit within their noise (χ² 3 DoF, SimilarityFitOptions::outlier_chi2) wins,
//   then one robust fit over those matches.
// - The relative poses' rotations are not used: on those 7-Scenes maps the rotations of pairs
//   of one merge disagreed by 2-50 deg, far beyond their own 0.2-4 deg, which would make the
//   estimate as over-confident. With the rotations that agree with the best hypothesis in the
//   fit, none of the 3 cases that pooled merged; without them one does (overlap_450_860, whose
//   refinement had disagreed with the keyframe matches at χ² 120), and the other two are
//   refused as before.
// It needs scale_estimation.min_inliers matches in the fit from two pairs at least (no single
// pair could give a scale alone), and the scale's relative standard deviation within
// scale_estimation.max_relative_stddev: the limits a pair's own scale has. Its covariance is the
// fit's (which covers the spread between pairs with three or more). The pairs have no estimates
// of their own, so there is no between-pair spread to add and nothing to arbitrate between.
// @return whether *out now holds the estimate (status kOk); *out is unchanged otherwise
bool jointEstimate(const AgentMap& source, const AgentMap& target, const std::vector<DepthMatches>& raw,
                   const MergeOptions& o, KeyframeEstimate* out) {
  std::vector<PairEvidence> pairs = out->pairs;
  for (std::size_t b = 0; b < pairs.size(); ++b) pairs[b].used = !raw[b].source.empty();
  const int distant = keepNeighbourhood(source, target, o.merge.local_keyframes, &pairs);
  std::vector<std::pair<std::size_t, std::size_t>> all;  // (pair, match)
  for (std::size_t b = 0; b < pairs.size(); ++b) {
    if (!pairs[b].used) continue;
    for (std::size_t k = 0; k < raw[b].source.size(); ++k) all.emplace_back(b, k);
  }
  const auto min_inliers = static_cast<std::size_t>(o.scale_estimation.min_inliers);
  const std::size_t n = all.size();
  if (n < std::max<std::size_t>(3, min_inliers)) return false;
  const SimilarityFitOptions fo;
  // How many matches a similarity fits within their noise, and (to break ties) how closely.
  const auto score = [&](const Sim3& h, std::vector<bool>* inlier) {
    double cost = 0.0;
    int count = 0;
    for (std::size_t i = 0; i < n; ++i) {
      const DepthMatches& m = raw[all[i].first];
      const std::size_t k = all[i].second;
      const Eigen::Vector3d r = h.apply(m.source[k]) - m.target[k];
      double chi2 = r.dot(matchCovariance(m, k, h.scale(), h.rotation()).ldlt().solve(r));
      if (!std::isfinite(chi2)) chi2 = fo.outlier_chi2 + 1.0;
      const bool in = chi2 <= fo.outlier_chi2;
      if (inlier) (*inlier)[i] = in;
      count += in ? 1 : 0;
      cost += std::min(chi2, fo.outlier_chi2);
    }
    return std::make_pair(count, -cost);
  };
  // Every three matches while they are few; beyond, kJointHypotheses threes drawn from a fixed
  // seed (equal inputs give equal results).
  std::vector<std::array<std::size_t, 3>> threes;
  if (n * (n - 1) * (n - 2) / 6 <= kJointHypotheses) {
    for (std::size_t i = 0; i < n; ++i) {
      for (std::size_t j = i + 1; j < n; ++j) {
        for (std::size_t l = j + 1; l < n; ++l) threes.push_back({i, j, l});
      }
    }
  } else {
    std::mt19937 rng(kJointSeed);
    std::uniform_int_distribution<std::size_t> pick(0, n - 1);
    while (threes.size() < kJointHypotheses) {
      const std::size_t i = pick(rng), j = pick(rng), l = pick(rng);
      if (i != j && j != l && i != l) threes.push_back({i, j, l});
    }
  }
  std::pair<int, double> best{0, 0.0};
  Sim3 start;
  Cloud src(3, 3), dst(3, 3);
  for (const std::array<std::size_t, 3>& three : threes) {
    double noise2 = 0.0;
    for (int c = 0; c < 3; ++c) {
      const DepthMatches& m = raw[all[three[c]].first];
      src.col(c) = m.source[all[three[c]].second];
      dst.col(c) = m.target[all[three[c]].second];
      noise2 += m.cov_target[all[three[c]].second].trace();
    }
    // Three matches whose triangle is no wider than their noise fix no rotation: twice its area
    // must exceed nine times their summed target variance (sides beyond about three sigma).
    const Eigen::Vector3d e1 = dst.col(1) - dst.col(0), e2 = dst.col(2) - dst.col(0);
    if (e1.cross(e2).norm() <= 9.0 * noise2) continue;
    const Sim3 h = umeyama(src, dst, true);
    if (!(h.scale() > 0.0) || !h.matrix().allFinite()) continue;
    const auto s = score(h, nullptr);
    if (s > best) {
      best = s;
      start = h;
    }
  }
  if (static_cast<std::size_t>(best.first) < min_inliers) return false;
  std::vector<bool> inlier(n, false);
  score(start, &inlier);
  std::vector<PointMatch3> matches;
  for (std::size_t i = 0; i < n; ++i) {
    if (!inlier[i]) continue;
    matches.push_back(pointMatch(raw[all[i].first], all[i].second, start, static_cast<int>(all[i].first)));
  }
  const SimilarityFit fit = fitSimilarity(matches, {}, start, fo);
  if (!fit.ok || !fit.covariance.allFinite() || !fit.estimate.matrix().allFinite()) return false;
  std::vector<int> per_pair(pairs.size(), 0);
  std::vector<PointMatch3> kept;
  for (std::size_t k = 0; k < matches.size(); ++k) {
    if (!fit.inliers[k]) continue;
    ++per_pair[static_cast<std::size_t>(matches[k].group)];
    kept.push_back(matches[k]);
  }
  const auto holding = static_cast<int>(std::count_if(per_pair.begin(), per_pair.end(), [](int c) { return c > 0; }));
  const double relative_stddev = std::sqrt(std::max(0.0, fit.covariance(6, 6)));
  if (kept.size() < min_inliers || holding < 2 || relative_stddev > o.scale_estimation.max_relative_stddev) {
    return false;
  }
  out->pairs = std::move(pairs);
  out->matches = std::move(kept);
  out->fit = fit;
  out->estimate = fit.estimate;
  out->mean_covariance = 0.5 * (fit.covariance + fit.covariance.transpose());
  out->between = Matrix7d::Zero();
  out->covariance = out->mean_covariance;
  out->used_pairs = holding;
  out->distant_pairs = distant;
  out->dropped_pairs = 0;
  int most = 0;
  for (std::size_t b = 0; b < out->pairs.size(); ++b) {
    PairEvidence& e = out->pairs[b];
    e.in_neighbourhood = false;  // no estimate of its own to pool around
    if (!e.used) continue;
    if (per_pair[b] == 0) {
      e.used = false;
      e.note += "; not used jointly: none of its depth matches fits the joint similarity";
      continue;
    }
    e.estimate = fit.estimate;
    e.covariance = out->covariance;
    e.matches.clear();
    for (const PointMatch3& m : out->matches) {
      if (m.group == static_cast<int>(b)) e.matches.push_back(m);
    }
    e.note = "used jointly: " + std::to_string(per_pair[b]) + " of its " + std::to_string(e.depth_matches) +
             " depth matches fit the similarity of " + std::to_string(holding) + " pairs' matches pooled (alone, " +
             e.note + ")";
    if (per_pair[b] > most) {
      most = per_pair[b];
      out->anchor = static_cast<int>(b);
    }
  }
  out->status = Status::kOk;
  out->message = std::to_string(holding) + " keyframe pair(s) pooled jointly (none had the depth matches for a "
                 "scale of its own), " + std::to_string(out->matches.size()) + " matches";
  return true;
}

// The edge's predictive covariance: the pooled estimate's own plus the between-pair spread.
void setPredictiveCovariance(KeyframeEstimate* out) {
  out->covariance = out->mean_covariance + out->between;
  out->covariance = 0.5 * (out->covariance + out->covariance.transpose()).eval();
}

}  // namespace

// Each map's scale drifts, so the pairs' local scales spread about the pooled one by what the
// between-pair covariance T measures: for a pair taken at random. The anchor is not: it is the
// pair whose own estimate lies closest to the pooled one (selectPooledMatches()), and its local
// scale is correspondingly closer. Given its own scale's deviation r from the keyframe estimate,
// with variance S, the anchor's local deviation b has the random-effects posterior
// N(g r, g S), g = T / (T + S), whatever the selection on r, so the edge's scale variance from
// the spread is E[b^2 | r] = g^2 r^2 + g S instead of T: T's scale row and column are rescaled to
// it. On the bench's 36 drifting simulated merges (seeds 0-1, depth images and LSD keyframe
// depth) the used pairs' local scales lay 0.60 % RMS from the reported estimate and T gave
// 0.59 %, but the anchor's lay 0.36 %, and the reported scale ANEES against the anchor's local
// truth was 0.58 (72 merges) and 0.74 (144 held-out); with the posterior 0.76 and 0.92.
// The scale alone: the same posterior for the whole of T made the rotation over-confident
// (ANEES 1.51, 81 % under the chi-square 95 % bound on the 72), because a pair's relative-pose
// rotation covariance claims too much (README, known limitations), which g then believes.
void conditionScaleOnAnchor(KeyframeEstimate* out) {
  if (out->anchor < 0) return;
  const PairEvidence& a = out->pairs[static_cast<std::size_t>(out->anchor)];
  const double t = out->between(6, 6), s = a.covariance(6, 6);
  if (!a.has_estimate || !(t > 0.0) || !(s > 0.0) || !std::isfinite(t + s)) return;
  const double r = similarityDifference(a.estimate, out->estimate)(6);
  const double g = t / (t + s);
  const double posterior = g * g * r * r + g * s;
  if (!std::isfinite(posterior) || !(posterior > 0.0)) return;
  const double f = std::sqrt(posterior / t);
  out->between.row(6) *= f;
  out->between.col(6) *= f;
  setPredictiveCovariance(out);
}

SimilarityInitializer::SimilarityInitializer(const MergeOptions& options) : options_(options) { validate(options_); }

KeyframeEstimate SimilarityInitializer::run(const AgentMap& source, const AgentMap& target,
                                            const FrontEndResult& front) const {
  const auto t0 = Clock::now();
  KeyframeEstimate out;
  DepthLookup depths(options_.keyframe_depth);
  std::vector<DepthMatches> raw(static_cast<std::size_t>(std::max(0, front.verified)));
  for (int i = 0; i < front.verified; ++i) {
    out.pairs.push_back(pairEvidence(front.pairs[static_cast<std::size_t>(i)], i, source, target, &depths, options_,
                                     &raw[static_cast<std::size_t>(i)]));
    out.pairs.back().used = out.pairs.back().has_estimate;
  }
  for (const PairEvidence& e : out.pairs) out.used_pairs += e.used ? 1 : 0;
  if (out.used_pairs > 0) {
    out.distant_pairs = keepNeighbourhood(source, target, options_.merge.local_keyframes, &out.pairs);
    out.used_pairs -= out.distant_pairs;
    for (PairEvidence& e : out.pairs) e.in_neighbourhood = e.used;
    pool(nullptr, &out);
  } else if (out.pairs.empty()) {
    out.status = Status::kRelativePoseFailed;
    out.message = "no keyframe pair verified";
  } else if (!jointEstimate(source, target, raw, options_, &out)) {
    const PairEvidence& best = out.pairs.front();
    out.status = best.scale.status == Status::kOk ? Status::kScaleFailed : best.scale.status;
    out.message = "no verified keyframe pair gave a scale (" + std::to_string(out.pairs.size()) +
                  " tried); best pair source " + std::to_string(best.source_keyframe) + " / target " +
                  std::to_string(best.target_keyframe) + ", " + std::to_string(best.inliers) + " inliers: " + best.note +
                  "; nor did the pairs' depth matches pooled";
  }
  out.ms = std::chrono::duration<double, std::milli>(Clock::now() - t0).count();
  return out;
}

KeyframeEstimate SimilarityInitializer::poolAround(const KeyframeEstimate& keyframes, const Sim3& hypothesis) const {
  const auto t0 = Clock::now();
  KeyframeEstimate out;
  out.pairs = keyframes.pairs;
  out.distant_pairs = keyframes.distant_pairs;
  for (PairEvidence& e : out.pairs) {
    e.used = e.in_neighbourhood;
    out.used_pairs += e.used ? 1 : 0;
  }
  if (out.used_pairs == 0) {
    out.status = Status::kScaleFailed;
    out.message = "no keyframe pair to pool";
    return out;
  }
  pool(&hypothesis, &out);
  out.ms = std::chrono::duration<double, std::milli>(Clock::now() - t0).count();
  return out;
}

void SimilarityInitializer::pool(const Sim3* hypothesis, KeyframeEstimate* out_ptr) const {
  KeyframeEstimate& out = *out_ptr;
  auto finish = [&](Status status, const std::string& message) {
    out.status = status;
    out.message = message;
  };
  // The pairs' own estimates about a common reference, in a well-conditioned frame.
  int reference = -1;
  for (std::size_t i = 0; i < out.pairs.size(); ++i) {
    if (out.pairs[i].used && (reference < 0 || out.pairs[i].matches.size() >
                                                    out.pairs[static_cast<std::size_t>(reference)].matches.size())) {
      reference = static_cast<int>(i);
    }
  }
  const Sim3 ref = out.pairs[static_cast<std::size_t>(reference)].estimate;
  const PoolingFrame frame = poolingFrame(out.pairs);
  std::vector<Vector7d> v(out.pairs.size(), Vector7d::Zero());
  std::vector<Matrix7d> cov(out.pairs.size(), Matrix7d::Identity());
  for (std::size_t i = 0; i < out.pairs.size(); ++i) {
    if (!out.pairs[i].has_estimate) continue;
    v[i] = frame.to_u * similarityDifference(out.pairs[i].estimate, ref);
    cov[i] = frame.to_u * out.pairs[i].covariance * frame.to_u.transpose();
  }
  dropRotationOutliers(&out.pairs);
  const std::vector<int> use =
      hypothesis ? agreeWith(v, cov, frame.to_u * similarityDifference(*hypothesis, ref),
                             options_.merge.pair_consistency_chi2, &out.pairs)
                 : consensus(v, cov, options_.merge.pair_consistency_chi2, &out.pairs);
  out.dropped_pairs = out.used_pairs - static_cast<int>(use.size());
  out.used_pairs = static_cast<int>(use.size());
  Pooled pooled = randomEffects(v, cov, use);
  if (!pooled.ok) return finish(Status::kScaleFailed, "the keyframe pairs' estimates do not pool");
  pooled.between = fullRankBlocks(blockDiagonal(pooled.between), use.size());
  pooled.covariance = blockDiagonal(pooled.covariance);
  const Sim3 pooled_mean = applyDelta(frame.to_delta * pooled.theta, ref);
  out.between = frame.to_delta * pooled.between * frame.to_delta.transpose();
  // The keyframe estimate: one robust fit over the consensus pairs' matches and relative-pose
  // rotations, so that each pair weighs by its evidence (a pair with many matches and a short
  // baseline outweighs a wide, sparse one, whose errors its own covariance understates), from
  // the random-effects centre. Its covariance covers both the fit's (noise, scaled by the
  // residuals, and the spread between pairs with three or more) and the random-effects mean's.
  std::vector<PointMatch3> all;
  std::vector<RotationMeasurement> rotations;
  for (const PairEvidence& e : out.pairs) {
    if (!e.used) continue;
    all.insert(all.end(), e.matches.begin(), e.matches.end());
    rotations.push_back(e.rotation);
  }
  const SimilarityFit fit = fitSimilarity(all, rotations, pooled_mean);
  if (!fit.ok) return finish(Status::kScaleFailed, "the keyframe pairs' matches do not determine a similarity");
  out.fit = fit;
  out.estimate = fit.estimate;
  out.mean_covariance =
      coveringCovariance(fit.covariance, frame.to_delta * pooled.covariance * frame.to_delta.transpose());
  // The edge is attached to one keyframe pair; what it claims is the similarity where that pair
  // is. Against that local truth the pooled estimate errs by its own error and by how much the
  // local similarity differs from the pooled one, which the between-pair spread measures (map
  // distortion, each map's scale drift): the predictive covariance.
  selectPooledMatches(&out);
  conditionScaleOnAnchor(&out);
  setPredictiveCovariance(&out);
  return finish(Status::kOk, std::to_string(out.used_pairs) + " keyframe pair(s) pooled, " +
                                 std::to_string(out.matches.size()) + " matches");
}

}  // namespace pcr_pro
