#include "pcr_pro/frontend/scale_estimation.h"

#include <Eigen/Cholesky>
#include <Eigen/LU>
#include <algorithm>
#include <cmath>
#include <limits>
#include <numeric>
#include <sstream>

#include "pcr_pro/geometry/median.h"

namespace pcr_pro {

namespace {

// Tolerance on |t_hat| - 1 and on RᵀR - I.
constexpr double kUnitTolerance = 1e-6;

using Matrix32d = Eigen::Matrix<double, 3, 2>;
using Matrix23d = Eigen::Matrix<double, 2, 3>;

// One usable match, with what the filter needs precomputed.
struct Match {
  size_t index = 0;                                 // position in the input vectors
  Eigen::Vector3d a = Eigen::Vector3d::Zero();      // R * P_s [source units, target axes]
  Eigen::Vector3d z = Eigen::Vector3d::Zero();      // P_t [target units]
  Eigen::Matrix3d cov_t = Eigen::Matrix3d::Zero();  // cov(P_t) [target units²]
  Eigen::Matrix3d cov_s = Eigen::Matrix3d::Zero();  // R cov(P_s) Rᵀ [source units²]
};

// Depth noise model of a camera-frame point: σ_d along the ray, σ_l across it, both relative to
// the point's distance.
Eigen::Matrix3d pointCovariance(const Eigen::Vector3d& p, double sigma_d, double sigma_l) {
  const double d2 = p.squaredNorm();
  const Eigen::Vector3d b = p / std::sqrt(d2);
  const Eigen::Matrix3d along = b * b.transpose();
  return d2 * (sigma_d * sigma_d * along + sigma_l * sigma_l * (Eigen::Matrix3d::Identity() - along));
}

// The caller's covariance of point i when it is usable (finite, positive definite), else the
// noise model's.
Eigen::Matrix3d givenOr(const std::vector<Eigen::Matrix3d>* given, size_t i, const Eigen::Vector3d& p, double sigma_d,
                        double sigma_l) {
  if (given != nullptr) {
    const Eigen::Matrix3d& c = (*given)[i];
    if (c.allFinite() && c.isApprox(c.transpose()) && Eigen::LLT<Eigen::Matrix3d>(c).info() == Eigen::Success) return c;
  }
  return pointCovariance(p, sigma_d, sigma_l);
}

Matrix32d measurementMatrix(const Match& m, const Eigen::Vector3d& t_hat) {
  Matrix32d h;
  h.col(0) = m.a;
  h.col(1) = t_hat;
  return h;
}

// Measurement noise of a match at scale s: cov(P_t) + s² R cov(P_s) Rᵀ.
Eigen::Matrix3d measurementNoise(const Match& m, double s) { return m.cov_t + (s * s) * m.cov_s; }

// Mahalanobis distance² of a residual under a covariance; +inf when not computable.
double mahalanobis2(const Eigen::Vector3d& r, const Eigen::Matrix3d& cov) {
  if (!r.allFinite() || !cov.allFinite()) return std::numeric_limits<double>::infinity();
  const Eigen::LLT<Eigen::Matrix3d> llt(cov);
  if (llt.info() != Eigen::Success) return std::numeric_limits<double>::infinity();
  const double d2 = r.dot(llt.solve(r));
  return std::isfinite(d2) && d2 >= 0.0 ? d2 : std::numeric_limits<double>::infinity();
}

std::string formatDouble(double v) {
  std::ostringstream os;
  os.precision(4);
  os << v;
  return os.str();
}

}  // namespace

template <>
const ParamSchema<ScaleEstimationOptions>& paramSchema<ScaleEstimationOptions>() {
  using O = ScaleEstimationOptions;
  using R = ParamRange;
  static const ParamSchema<O> schema{"scale_estimation", {
      {"relative_depth_noise", &O::relative_depth_noise, R::above(0), "-",
       "depth noise as a fraction of the distance; with depth from the projected map cloud, the least (the cloud's "
       "measured noise when larger)"},
      {"relative_lateral_noise", &O::relative_lateral_noise, R::above(0), "-",
       "noise across the ray as a fraction of the distance"},
      {"gating_chi2", &O::gating_chi2, R::above(0), "-", "innovation gate, chi-square with 3 DoF (11.34 = 99 %)"},
      {"min_inliers", &O::min_inliers, R::atLeast(2), "", "fewer accepted matches: SCALE_FAILED"},
      {"min_inlier_ratio", &O::min_inlier_ratio, R::closed(0, 1), "-", "smaller accepted fraction: SCALE_FAILED"},
      {"max_relative_stddev", &O::max_relative_stddev, R::above(0), "-", "larger stddev/scale: SCALE_FAILED"},
      {"passes", &O::passes, R::atLeast(1), "", "Kalman filter passes over the matches"},
      {"prior_relative_stddev", &O::prior_relative_stddev, R::above(0), "-",
       "prior stddev of each pass, relative to the estimate"},
  }};
  return schema;
}

void validate(const ScaleEstimationOptions& o) {
  checkRanges(paramSchema<ScaleEstimationOptions>(), o);
}

namespace {

// Throws InputError on mismatched sizes, a non-rotation R or a non-unit t_hat.
void checkScaleInputs(const std::vector<Eigen::Vector3d>& points_source,
                      const std::vector<Eigen::Vector3d>& points_target, const Eigen::Matrix3d& R,
                      const Eigen::Vector3d& t_hat, const std::vector<Eigen::Matrix3d>* covariances_source,
                      const std::vector<Eigen::Matrix3d>* covariances_target) {
  if (points_source.size() != points_target.size()) {
    throw InputError("scale estimation: " + std::to_string(points_source.size()) + " source points but " +
                     std::to_string(points_target.size()) + " target points");
  }
  for (const auto* c : {covariances_source, covariances_target}) {
    if (c != nullptr && c->size() != points_source.size()) {
      throw InputError("scale estimation: " + std::to_string(c->size()) + " point covariances for " +
                       std::to_string(points_source.size()) + " matches");
    }
  }
  if (!R.allFinite() || !((R.transpose() * R - Eigen::Matrix3d::Identity()).cwiseAbs().maxCoeff() <= kUnitTolerance) ||
      !(R.determinant() > 0.0)) {
    throw InputError("scale estimation: R must be a finite rotation matrix");
  }
  if (!t_hat.allFinite() || !(std::abs(t_hat.norm() - 1.0) <= kUnitTolerance)) {
    throw InputError("scale estimation: t_hat must be a finite unit vector");
  }
}

// Usable matches (finite, non-zero points) and their noise.
std::vector<Match> usableMatches(const std::vector<Eigen::Vector3d>& points_source,
                                 const std::vector<Eigen::Vector3d>& points_target, const Eigen::Matrix3d& R,
                                 const ScaleEstimationOptions& options,
                                 const std::vector<Eigen::Matrix3d>* covariances_source,
                                 const std::vector<Eigen::Matrix3d>* covariances_target) {
  const size_t n = points_source.size();
  const double sigma_d = options.relative_depth_noise;
  const double sigma_l = options.relative_lateral_noise;
  std::vector<Match> matches;
  matches.reserve(n);
  for (size_t i = 0; i < n; ++i) {
    const Eigen::Vector3d& ps = points_source[i];
    const Eigen::Vector3d& pt = points_target[i];
    if (!ps.allFinite() || !pt.allFinite()) continue;
    const double ns = ps.squaredNorm();
    const double nt = pt.squaredNorm();
    if (!(ns > 0.0 && std::isfinite(ns) && nt > 0.0 && std::isfinite(nt))) continue;
    Match m;
    m.index = i;
    m.a = R * ps;
    m.z = pt;
    m.cov_t = givenOr(covariances_target, i, pt, sigma_d, sigma_l);
    m.cov_s = R * givenOr(covariances_source, i, ps, sigma_d, sigma_l) * R.transpose();
    if (!m.a.allFinite() || !m.cov_t.allFinite() || !m.cov_s.allFinite()) continue;
    matches.push_back(m);
  }
  return matches;
}

// Robust initialisation: median of the per-match least-squares scales, then the median
// baseline length at that scale; *distance_scale is the median target distance. False when no
// match gives a positive scale.
bool robustStart(const std::vector<Match>& matches, const Eigen::Vector3d& t_hat, Eigen::Vector2d* start,
                 double* distance_scale) {
  std::vector<double> scales;
  std::vector<double> distances;
  for (const Match& m : matches) {
    distances.push_back(m.z.norm());
    const double aa = m.a.squaredNorm();
    const double at = m.a.dot(t_hat);
    const double det = aa - at * at;    // |a|² sin²(angle between a and t_hat)
    if (!(det > 1e-12 * aa)) continue;  // point on the baseline: scale not observable
    const double s = (m.a.dot(m.z) - at * t_hat.dot(m.z)) / det;
    if (s > 0.0 && std::isfinite(s)) scales.push_back(s);
  }
  if (scales.empty()) return false;
  *distance_scale = median(distances);
  Eigen::Vector2d& x_start = *start;
  x_start(0) = median(scales);
  {
    std::vector<double> lambdas;
    lambdas.reserve(matches.size());
    for (const Match& m : matches) lambdas.push_back(t_hat.dot(m.z - x_start(0) * m.a));
    x_start(1) = median(lambdas);
  }
  return true;
}

// Most consistent matches first (by Mahalanobis distance at x_start), so that the state is
// tight before outliers come.
void consistencyOrder(const std::vector<Match>& matches, const Eigen::Vector3d& t_hat, const Eigen::Vector2d& x_start,
                      std::vector<size_t>* order, std::vector<double>* start_d2) {
  for (size_t k = 0; k < matches.size(); ++k) {
    const Match& m = matches[k];
    (*start_d2)[k] = mahalanobis2(m.z - measurementMatrix(m, t_hat) * x_start, measurementNoise(m, x_start(0)));
  }
  std::iota(order->begin(), order->end(), size_t{0});
  std::stable_sort(order->begin(), order->end(), [&](size_t i, size_t j) { return (*start_d2)[i] < (*start_d2)[j]; });
}

// One Kalman sweep over the matches in `order`, gating each innovation; accepted[k] marks the
// matches used.
void kalmanSweep(const std::vector<Match>& matches, const std::vector<size_t>& order, const Eigen::Vector3d& t_hat,
                 const ScaleEstimationOptions& options, Eigen::Vector2d* x_io, Eigen::Matrix2d* P_io,
                 std::vector<bool>* accepted) {
  Eigen::Vector2d& x = *x_io;
  Eigen::Matrix2d& P = *P_io;
  for (size_t k : order) {
    const Match& m = matches[k];
    const Matrix32d H = measurementMatrix(m, t_hat);
    const Eigen::Matrix3d N = measurementNoise(m, x(0));
    const Eigen::Vector3d innovation = m.z - H * x;
    const Eigen::Matrix3d S = H * P * H.transpose() + N;
    if (!S.allFinite() || !innovation.allFinite()) continue;
    const Eigen::LLT<Eigen::Matrix3d> llt(S);
    if (llt.info() != Eigen::Success) continue;
    const double d2 = innovation.dot(llt.solve(innovation));
    if (!(d2 <= options.gating_chi2)) continue;  // outlier (or NaN)
    // K = P Hᵀ S⁻¹, Joseph-form covariance update.
    const Matrix23d K = llt.solve(H * P).transpose();
    const Eigen::Vector2d x_new = x + K * innovation;
    const Eigen::Matrix2d I_KH = Eigen::Matrix2d::Identity() - K * H;
    Eigen::Matrix2d P_new = I_KH * P * I_KH.transpose() + K * N * K.transpose();
    P_new = 0.5 * (P_new + P_new.transpose()).eval();
    if (!x_new.allFinite() || !P_new.allFinite()) continue;
    x = x_new;
    P = P_new;
    (*accepted)[k] = true;
  }
}

// Errors-in-variables correction. The filter solves sum Hᵀ N⁻¹ r = 0 with N evaluated at
// the running scale, but H holds the noisy R * P_s, which biases s towards zero by about
// s * tr(N⁻¹ C) per match (C = R cov(P_s) Rᵀ, "regression dilution"). The maximum-likelihood
// score, with N = N(s) differentiated too, has the extra term s * rᵀ N⁻¹ C N⁻¹ r whose
// expectation cancels that bias; one Newton step with the posterior covariance P as inverse
// Hessian adds it. It is a second-order effect (about 0.1 % of s for 2 % depth noise), but it
// grows relative to the standard deviation as matches accumulate. Returns that score.
double dilutionScore(const std::vector<Match>& matches, const std::vector<bool>& accepted,
                     const Eigen::Vector3d& t_hat, const Eigen::Vector2d& x) {
  double score = 0.0;
  for (size_t k = 0; k < matches.size(); ++k) {
    if (!accepted[k]) continue;
    const Match& m = matches[k];
    const Eigen::Vector3d r = m.z - measurementMatrix(m, t_hat) * x;
    const Eigen::LLT<Eigen::Matrix3d> llt(measurementNoise(m, x(0)));
    if (llt.info() != Eigen::Success) continue;
    const Eigen::Vector3d w = llt.solve(r);
    score += x(0) * w.dot(m.cov_s * w);
  }
  return score;
}

// The status and message of a finished estimate against the options' acceptance limits.
void judgeScale(const ScaleEstimationOptions& options, ScaleEstimate* result_out) {
  ScaleEstimate& result = *result_out;
  const std::string summary = "scale " + formatDouble(result.scale) + " +- " + formatDouble(result.scale_stddev) +
                              " from " + std::to_string(result.inliers) + " of " + std::to_string(result.used) +
                              " matches";
  result.status = Status::kScaleFailed;
  if (!(result.scale > 0.0 && std::isfinite(result.scale) && std::isfinite(result.lambda))) {
    result.message = "scale estimation: non-positive or non-finite " + summary;
  } else if (result.inliers < options.min_inliers) {
    result.message = "scale estimation: too few inliers, " + summary + " (at least " +
                     std::to_string(options.min_inliers) + " needed)";
  } else if (result.inliers < options.min_inlier_ratio * result.used) {
    result.message = "scale estimation: inlier ratio too low, " + summary;
  } else if (!(result.scale_stddev <= options.max_relative_stddev * result.scale)) {
    result.message = "scale estimation: too uncertain, " + summary + " (relative stddev above " +
                     formatDouble(options.max_relative_stddev) + ")";
  } else {
    result.status = Status::kOk;
    result.message = "scale estimation: " + summary;
  }
}

}  // namespace

ScaleEstimate estimateScale(const std::vector<Eigen::Vector3d>& points_source,
                            const std::vector<Eigen::Vector3d>& points_target, const Eigen::Matrix3d& R,
                            const Eigen::Vector3d& t_hat, const ScaleEstimationOptions& options,
                            const std::vector<Eigen::Matrix3d>* covariances_source,
                            const std::vector<Eigen::Matrix3d>* covariances_target) {
  validate(options);
  checkScaleInputs(points_source, points_target, R, t_hat, covariances_source, covariances_target);

  ScaleEstimate result;
  const size_t n = points_source.size();
  result.inlier_mask.assign(n, false);
  if (n < static_cast<size_t>(options.min_inliers)) {
    result.status = Status::kNotEnoughMatches;
    result.message = "scale estimation: " + std::to_string(n) + " matches, at least " +
                     std::to_string(options.min_inliers) + " needed";
    return result;
  }

  const std::vector<Match> matches =
      usableMatches(points_source, points_target, R, options, covariances_source, covariances_target);
  result.used = static_cast<int>(matches.size());
  if (result.used < options.min_inliers) {
    result.status = Status::kNotEnoughMatches;
    result.message = "scale estimation: " + std::to_string(result.used) + " usable matches (finite, non-zero " +
                     "points) of " + std::to_string(n) + ", at least " + std::to_string(options.min_inliers) +
                     " needed";
    return result;
  }

  double distance_scale = 0.0;
  Eigen::Vector2d x_start;
  if (!robustStart(matches, t_hat, &x_start, &distance_scale)) {
    result.status = Status::kScaleFailed;
    result.message = "scale estimation: no match gives a positive scale";
    return result;
  }

  Eigen::Vector2d x = x_start;
  Eigen::Matrix2d P = Eigen::Matrix2d::Zero();
  std::vector<bool> accepted(matches.size(), false);
  std::vector<size_t> order(matches.size());
  std::vector<double> start_d2(matches.size());
  for (int pass = 0; pass < options.passes; ++pass) {
    if (!(x_start(0) > 0.0 && std::isfinite(x_start(0)) && std::isfinite(x_start(1)))) break;
    consistencyOrder(matches, t_hat, x_start, &order, &start_d2);

    // Broad prior around the starting estimate.
    const double sigma_s = options.prior_relative_stddev * x_start(0);
    const double sigma_lambda = options.prior_relative_stddev * std::max(std::abs(x_start(1)), distance_scale);
    x = x_start;
    P = Eigen::Vector2d(sigma_s * sigma_s, sigma_lambda * sigma_lambda).asDiagonal();
    std::fill(accepted.begin(), accepted.end(), false);

    kalmanSweep(matches, order, t_hat, options, &x, &P, &accepted);
    const double score = dilutionScore(matches, accepted, t_hat, x);
    const Eigen::Vector2d x_corrected = x + P.col(0) * score;
    if (x_corrected.allFinite()) x = x_corrected;
    x_start = x;
  }

  result.scale = x(0);
  result.lambda = x(1);
  result.covariance = P;
  result.scale_stddev = std::sqrt(std::max(0.0, P(0, 0)));
  result.lambda_stddev = std::sqrt(std::max(0.0, P(1, 1)));
  result.inliers = 0;
  for (size_t k = 0; k < matches.size(); ++k) {
    if (accepted[k]) {
      result.inlier_mask[matches[k].index] = true;
      ++result.inliers;
    }
  }
  judgeScale(options, &result);
  return result;
}

}  // namespace pcr_pro
