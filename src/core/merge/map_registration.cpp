#include "pcr_pro/merge/map_registration.h"

#include <Eigen/Cholesky>

#include <algorithm>
#include <chrono>
#include <cmath>
#include <cstdint>
#include <limits>
#include <map>
#include <numeric>
#include <sstream>

#include "pcr_pro/geometry/normals.h"
#include "pcr_pro/registration/filters.h"
#include "pcr_pro/registration/jackknife.h"

namespace pcr_pro {
namespace {

using Clock = std::chrono::steady_clock;
using Vector7d = Eigen::Matrix<double, 7, 1>;

double msSince(Clock::time_point start) {
  return std::chrono::duration<double, std::milli>(Clock::now() - start).count();
}

// Points sampled by the overlap measure: the fraction is then known to about ±0.7 %.
constexpr Eigen::Index kOverlapSamples = 5000;
// Information (pseudo-inverse on the active block) of a covariance.
Matrix7d informationOf(const Matrix7d& cov, int d) {
  Matrix7d out = Matrix7d::Zero();
  const Eigen::MatrixXd block = cov.topLeftCorner(d, d);
  const Eigen::LDLT<Eigen::MatrixXd> ldlt(block);
  if (ldlt.info() != Eigen::Success) return out;
  out.topLeftCorner(d, d) = ldlt.solve(Eigen::MatrixXd::Identity(d, d));
  return out;
}

// Fraction of (a sample of) `points` mapped by `map` that have a neighbour in `tree` within
// `radius`, among the points that `map` puts inside `region` (all of them when its radius is 0).
double coveredFraction(const Cloud& points, const Sim3& map, const KdTree& tree, double radius,
                       const OverlapRegion& region) {
  const Eigen::Index n = points.cols();
  if (n == 0 || tree.size() == 0) return 0.0;
  std::vector<Eigen::Vector3d> mapped;
  const double region2 = region.radius * region.radius;
  for (Eigen::Index i = 0; i < n; ++i) {
    const Eigen::Vector3d y = map.apply(Eigen::Vector3d(points.col(i)));
    if (region.radius == 0.0 || (y - region.centre).squaredNorm() <= region2) mapped.push_back(y);
  }
  if (mapped.empty()) return 0.0;
  const std::size_t step = std::max<std::size_t>(1, mapped.size() / kOverlapSamples);
  std::size_t inside = 0, total = 0;
  const double r2 = radius * radius;
  for (std::size_t i = 0; i < mapped.size(); i += step, ++total) {
    double d2 = 0.0;
    if (tree.nearest(mapped[i], &d2) >= 0 && d2 <= r2) ++inside;
  }
  return static_cast<double>(inside) / static_cast<double>(total);
}

// The anchors as matches of the inverse similarity (target map onto source map): the two points
// exchanged, and the residual covariance (target units, at `at`) moved into source units:
// r' = S^-1(target) - source = -R^T r / s.
std::vector<PointMatch3> reversedAnchors(const std::vector<PointMatch3>& anchors, const Sim3& at) {
  std::vector<PointMatch3> out = anchors;
  const Eigen::Matrix3d r = at.rotation();
  const double s2 = at.scale() * at.scale();
  for (PointMatch3& m : out) {
    std::swap(m.source, m.target);
    m.covariance = r.transpose() * m.covariance * r / s2;
  }
  return out;
}

// A refinement of S_source_target turned into one of S_target_source (Refinement::reversed).
void invertRefinement(Refinement* r) {
  const Sim3 forward = r->estimate.inverse();
  // Left perturbations: the covariance of S^-1 is Ad(S^-1) C Ad(S^-1)^T (similarity_fit.h).
  const Matrix7d ad = similarityAdjoint(forward);
  r->estimate = forward;
  r->covariance = ad * r->covariance * ad.transpose();
  r->covariance = 0.5 * (r->covariance + r->covariance.transpose()).eval();
  r->icp.transform = r->icp.transform.inverse();
  // Lengths in the ICP's target units (the source map's) into the target map's.
  r->icp.fitness_rmse *= forward.scale();
  invertCovarianceResult(forward, &r->closed_form);
  r->reversed = true;
}

}  // namespace

OverlapRegion overlapRegion(const std::vector<PointMatch3>& matches) {
  OverlapRegion region;
  if (matches.size() < 3) return region;
  for (const PointMatch3& m : matches) region.centre += m.target;
  region.centre /= static_cast<double>(matches.size());
  for (const PointMatch3& m : matches) region.radius = std::max(region.radius, (m.target - region.centre).norm());
  return region;
}

MapRegistration::MapRegistration(const RegistrationOptions& options, bool estimate_scale, bool reweigh_anchors)
    : options_(options), estimate_scale_(estimate_scale), reweigh_anchors_(reweigh_anchors) {
  validate(options_);
}

MapRegistration::~MapRegistration() = default;

std::string MapRegistration::setClouds(const Cloud& source, const Cloud& target) {
  if (source.cols() == 0) throw InputError("source cloud is empty");
  if (target.cols() == 0) throw InputError("target cloud is empty");
  const auto t = Clock::now();
  source_ = applyFilterChain(source, options_.filters);
  target_ = applyFilterChain(target, options_.filters);
  filter_ms_ = msSince(t);
  if (source_.cols() == 0 || target_.cols() == 0) {
    return std::string("the filters removed every point of the ") + (source_.cols() == 0 ? "source" : "target") +
           " map cloud";
  }
  std::string shapeless = coincidentPoints(source_, "source map cloud");
  if (shapeless.empty()) shapeless = coincidentPoints(target_, "target map cloud");
  if (!shapeless.empty()) return shapeless;
  target_tree_ = std::make_unique<KdTree>(target_);
  source_tree_ = std::make_unique<KdTree>(source_);
  target_spacing_ = medianSpacing(*target_tree_);
  source_spacing_ = medianSpacing(*source_tree_);
  if (options_.icp.register_noisier_as_target) {
    const int k = options_.icp.normal_neighbors;
    target_thickness2_ = surfaceThickness2(*target_tree_, k, kThicknessSamples);
    source_thickness2_ = surfaceThickness2(*source_tree_, k, kThicknessSamples);
  }
  return "";
}

double MapRegistration::overlap(const Sim3& s, double factor, const OverlapRegion& region) const {
  if (!target_tree_) return 0.0;
  const double radius = factor * std::max(target_spacing_, source_spacing_ * s.scale());
  const double source_part = coveredFraction(source_, s, *target_tree_, radius, region);
  // Target points towards the source: in source units the radius and the region shrink by the
  // scale.
  OverlapRegion in_source;
  in_source.centre = s.inverse().apply(region.centre);
  in_source.radius = region.radius / s.scale();
  const double target_part = coveredFraction(target_, s.inverse(), *source_tree_, radius / s.scale(), in_source);
  return std::max(source_part, target_part);
}

double MapRegistration::noiseRatio(const Sim3& target_source) const {
  return pcr_pro::noiseRatio(target_source.scale(), source_thickness2_, target_thickness2_);
}

Refinement MapRegistration::refine(const Sim3& initial, const std::vector<PointMatch3>& anchors) const {
  if (!target_tree_) throw InputError("MapRegistration::refine: setClouds() first");
  const double ratio = noiseRatio(initial);
  if (!options_.icp.register_noisier_as_target || !clearlyNoisier(ratio)) {
    Refinement out = refineDirected(source_, target_, *target_tree_, initial, anchors, source_noise_, target_noise_);
    out.noise_ratio = ratio;
    return out;
  }
  Refinement out = refineDirected(target_, source_, *source_tree_, initial.inverse(), reversedAnchors(anchors, initial),
                                  target_noise_, source_noise_);
  invertRefinement(&out);
  out.noise_ratio = ratio;
  std::ostringstream msg;
  msg.precision(3);
  msg << "registered the target onto the source (the source's surfaces are " << ratio
      << " times as thick): " << out.message;
  out.message = msg.str();
  return out;
}

void MapRegistration::setRayNoise(const RayNoise& source, const RayNoise& target, int draws) {
  if (draws < 0) throw InputError("MapRegistration::setRayNoise: draws must be >= 0, got " + std::to_string(draws));
  source_noise_ = source;
  target_noise_ = target;
  renoise_draws_ = draws;
}

Refinement MapRegistration::refineDirected(const Cloud& source, const Cloud& target, const KdTree& target_tree,
                                           const Sim3& initial, const std::vector<PointMatch3>& anchors,
                                           const RayNoise& source_noise, const RayNoise& target_noise) const {
  Refinement out = refineOnce(source, target_tree, initial, anchors);
  if (out.status != Status::kOk) return out;
  const int blocks = options_.covariance.jackknife_blocks;
  if (blocks > 0) {
    const auto t = Clock::now();
    const JackknifeSpread spread =
        jackknifeCovariance(source, target, out.estimate, icpOptions(), blocks, anchors.empty() ? nullptr : &anchors);
    if (spread.ok) out.covariance = coveringCovariance(out.covariance, spread.covariance);
    out.message += "; " + spread.message;
    out.ms_covariance += msSince(t);
  }
  if (renoise_draws_ > 0) addRenoisedSpread(source, target, anchors, source_noise, target_noise, &out);
  return out;
}

void MapRegistration::addRenoisedSpread(const Cloud& source, const Cloud& target,
                                        const std::vector<PointMatch3>& anchors, const RayNoise& source_noise,
                                        const RayNoise& target_noise, Refinement* refinement) const {
  Refinement& out = *refinement;
  if (!source_noise.valid() || !target_noise.valid()) {
    out.message += std::string("; no re-noised registrations: the ") + (source_noise.valid() ? "target" : "source") +
                   " map's ray noise was not measured (no keyframe's projection of its cloud holds enough pixel pairs)";
    return;
  }
  const auto t = Clock::now();
  const IcpOptions icp = icpOptions();
  // The draws are independent and seeded by their index (a merge repeated gives the same
  // covariance, however the draws are spread over threads): one per core.
  const int draws = renoise_draws_;
  std::vector<Vector7d> all(static_cast<std::size_t>(draws));
  std::vector<char> has(static_cast<std::size_t>(draws), 0);
#pragma omp parallel for schedule(dynamic)
  for (int k = 0; k < draws; ++k) {
    const auto draw = static_cast<std::uint64_t>(k);
    const Cloud s = renoiseAlongRays(source, source_noise, 2 * draw + 1);
    const KdTree tree(renoiseAlongRays(target, target_noise, 2 * draw + 2));
    const IcpResult r = alignIcp(s, tree, out.estimate, icp, anchors.empty() ? nullptr : &anchors);
    const Vector7d d = similarityDifference(r.transform, out.estimate);
    const auto i = static_cast<std::size_t>(k);
    all[i] = d;
    has[i] = (r.status == Status::kOk || r.correspondences >= icp.min_correspondences) && d.allFinite() ? 1 : 0;
  }
  std::vector<Vector7d> deltas;
  for (std::size_t i = 0; i < all.size(); ++i) {
    if (has[i]) deltas.push_back(all[i]);
  }
  out.ms_covariance += msSince(t);
  std::ostringstream msg;
  msg.precision(3);
  if (deltas.size() < 2) {
    msg << "; re-noised registrations: " << deltas.size() << " of " << renoise_draws_
        << " gave an estimate, fewer than 2: no spread added";
    out.message += msg.str();
    return;
  }
  // Their mean square around the estimate (each draw is a fresh error of the same kind), at the
  // anchors' centroid (where the edge is measured) or the aligned source's.
  Matrix7d m = Matrix7d::Zero();
  for (const Vector7d& d : deltas) m += d * d.transpose() / static_cast<double>(deltas.size());
  Eigen::Vector3d centre = Eigen::Vector3d::Zero();
  if (!anchors.empty()) {
    for (const PointMatch3& a : anchors) centre += a.target / static_cast<double>(anchors.size());
  } else {
    centre = out.estimate.apply(source).rowwise().mean();
  }
  Matrix7d spread = isotropicBlocksAt(m, centre);
  if (!estimate_scale_) {
    spread.row(6).setZero();
    spread.col(6).setZero();
  }
  if (!spread.allFinite()) {
    out.message += "; re-noised registrations: the spread is not finite, not added";
    return;
  }
  out.covariance += spread;
  out.renoise_spread = spread;
  out.renoise_draws = static_cast<int>(deltas.size());
  msg << "; spread of " << out.renoise_draws << " re-noised registrations added (rotation "
      << std::sqrt(std::max(0.0, spread.block<3, 3>(3, 3).trace() / 3.0)) * 180.0 / M_PI << " deg per axis)";
  out.message += msg.str();
}

IcpOptions MapRegistration::icpOptions() const {
  IcpOptions icp_options = options_.icp;
  icp_options.estimate_scale = estimate_scale_;
  return icp_options;
}

Refinement MapRegistration::refineOnce(const Cloud& source, const KdTree& target_tree, const Sim3& initial,
                                       const std::vector<PointMatch3>& anchors) const {
  Refinement out;
  const auto t = Clock::now();
  out.icp = alignIcp(source, target_tree, initial, icpOptions(), &anchors);
  out.ms_icp = msSince(t);
  out.estimate = out.icp.transform;
  out.status = out.icp.status;
  out.message = out.icp.message;
  if (out.icp.status != Status::kOk) return out;
  const Matrix7d information = finish(anchors, &out);
  if (!reweigh_anchors_ || anchors.empty() || out.status != Status::kOk || !(out.block_spread_factor > 1.0)) return out;
  // The clouds' information is block_spread_factor times too large in the direction they
  // misjudge most (the maps do not fit one similarity), and the ICP's optimum then follows the
  // surfaces' distortion, where the keyframe matches, with their full 3D residuals, measure the
  // similarity of the overlap itself. Weighing the matches up by that factor (the clouds down)
  // gives the two kinds of evidence the weights they really carry.
  const double weight = out.block_spread_factor;
  const Sim3 moved = reweighedStep(out.estimate, information, anchors, weight);
  if (moved.matrix() == out.estimate.matrix()) return out;
  Refinement again = out;
  again.estimate = moved;
  finish(anchors, &again);
  again.ms_covariance += out.ms_covariance;
  if (again.status != Status::kOk) {
    out.message += "; the step with the keyframe matches weighed up failed, not taken: " + again.message;
    return out;
  }
  again.anchor_weight = weight;
  std::ostringstream msg;
  msg.precision(3);
  msg << again.message << "; keyframe matches weighed x" << weight
      << " against the clouds (the ICP's block spread), which moved the estimate "
      << rotationDistance(moved.rotation(), out.estimate.rotation()) * 180.0 / M_PI << " deg";
  again.message = msg.str();
  return again;
}

Sim3 MapRegistration::reweighedStep(const Sim3& estimate, const Matrix7d& information,
                                    const std::vector<PointMatch3>& anchors, double weight) const {
  Matrix7d h_anchors = Matrix7d::Zero();
  Eigen::Matrix<double, 7, 1> g_anchors = Eigen::Matrix<double, 7, 1>::Zero();
  addAnchorNormalEquations(anchors, estimate, Eigen::Vector3d::Zero(), &h_anchors, &g_anchors);
  // `information` holds the clouds and the anchors once; the anchors get weight - 1 more. At the
  // converged estimate the clouds' gradient cancelled the anchors', so the reweighed gradient is
  // (weight - 1) times theirs.
  const int d = estimate_scale_ ? 7 : 6;
  const Eigen::MatrixXd h = (information + (weight - 1.0) * h_anchors).topLeftCorner(d, d);
  const Eigen::VectorXd g = (weight - 1.0) * g_anchors.head(d);
  const Eigen::LDLT<Eigen::MatrixXd> ldlt(h);
  // Numerically singular (a direction neither the clouds nor the anchors hold): no step.
  if (ldlt.info() != Eigen::Success || ldlt.rcond() < 1e-14) return estimate;
  Eigen::Matrix<double, 7, 1> delta = Eigen::Matrix<double, 7, 1>::Zero();
  delta.head(d) = ldlt.solve(-g);
  if (!delta.allFinite()) return estimate;
  return Sim3(std::exp(delta(6)), expSO3(delta.segment<3>(3)), delta.head<3>()) * estimate;
}

Matrix7d MapRegistration::finish(const std::vector<PointMatch3>& anchors, Refinement* refinement) const {
  Refinement& out = *refinement;
  const auto t = Clock::now();
  const ErrorMetric metric = options_.icp.error_metric;
  out.closed_form = computeIcpCovariance(out.icp.matches, out.estimate, metric, estimate_scale_, options_.covariance);
  if (out.closed_form.status != Status::kOk) {
    out.status = out.closed_form.status;
    out.message = out.closed_form.message;
    out.covariance = logScaleCovariance(out.closed_form, out.estimate.scale());
    out.ms_covariance = msSince(t);
    return Matrix7d::Zero();
  }
  const int d = estimate_scale_ ? 7 : 6;
  const Correspondences& m = out.icp.matches;
  // The model covariance: the (calibrated) closed form of the ICP joined with the anchors'
  // information; then covering the spread between spatial blocks and anchor groups.
  const BlockSpread spread = blockSpreadCovariance(m, out.estimate, metric, estimate_scale_, &anchors);
  Matrix7d h_anchor = Matrix7d::Zero();
  addAnchorNormalEquations(anchors, out.estimate, Eigen::Vector3d::Zero(), &h_anchor, nullptr);
  const Matrix7d closed = logScaleCovariance(out.closed_form, out.estimate.scale());
  const Matrix7d model = informationOf(informationOf(closed, d) + h_anchor, d);
  out.covariance = model;
  out.blocks = spread.clusters;
  out.block_spread_factor = 1.0;
  if (spread.ok) out.covariance = coveringCovariance(model, spread.sandwich, &out.block_spread_factor);
  out.ms_covariance = msSince(t);
  if (!out.covariance.allFinite()) {
    out.status = Status::kDegenerate;
    out.message = "refinement: the covariance is not finite";
    return Matrix7d::Zero();
  }
  std::ostringstream msg;
  msg.precision(3);
  msg << out.icp.message << "; covariance from " << m.source.cols() << " correspondences and " << anchors.size()
      << " anchors in " << out.blocks << " block(s) and anchor group(s), block spread x" << out.block_spread_factor
      << ", calibration x" << out.closed_form.inflation;
  out.message = msg.str();
  return spread.ok ? spread.information : Matrix7d::Zero();
}

}  // namespace pcr_pro
