/**
 * @file scale_estimation.h
 * @brief Scale by Kalman filter (PCR-Pro §Scale by Kalman filter): fuses matched 3D points of
 * two keyframes into the scale between two maps and the length of the keyframe baseline.
 *
 * Model: every match gives P_s (source keyframe camera, source-map units) and P_t (target
 * keyframe camera, target-map units) with
 *
 *   P_t = s * R * P_s + lambda * t_hat + noise,
 *
 * where R and the unit direction t_hat come from the relative-pose stage, s is the scale
 * between the maps [target units per source unit] and lambda the baseline length [target units].
 * The state x = (s, lambda) is estimated by a linear Kalman filter: measurement z = P_t,
 * H = [R * P_s, t_hat] (3x2).
 */
#pragma once

#include <Eigen/Core>
#include <string>
#include <vector>

#include "pcr_pro/geometry/types.h"
#include "pcr_pro/io/param_schema.h"

namespace pcr_pro {

/// Options of the scale estimation stage.
struct ScaleEstimationOptions {
  /// Standard deviation of a point's depth noise along its viewing ray, as a fraction of the
  /// point's distance from the camera [-], > 0. For depth looked up in the map cloud projected
  /// into a keyframe it is the least: the merge takes the cloud's measured noise when larger
  /// (KeyframeDepth::projectedRelativeNoise()).
  double relative_depth_noise = 0.02;
  /// Standard deviation of a point's noise across its viewing ray, as a fraction of its distance
  /// [-], > 0 (pixel error / focal length: 1 px at f = 500 px is 0.002).
  double relative_lateral_noise = 0.002;
  /// Innovation gate: a match whose Mahalanobis distance² exceeds this is rejected as an outlier
  /// [-], > 0 (chi-square with 3 DoF: 7.81 = 95 %, 11.34 = 99 %, 16.27 = 99.9 %).
  double gating_chi2 = 11.34;
  /// Fewer accepted matches than this fails the estimate (and fewer input matches than this
  /// gives kNotEnoughMatches) [matches], >= 2.
  int min_inliers = 8;
  /// Fewer accepted matches than this fraction of the usable matches fails the estimate, in
  /// [0, 1] [-] (0 = no check). Guards against a filter that latched onto a few chance matches.
  double min_inlier_ratio = 0.2;
  /// The estimate fails when scale_stddev / scale exceeds this [-], > 0.
  double max_relative_stddev = 0.1;
  /// Number of filter passes over all matches, >= 1. Each pass restarts from the previous
  /// pass's estimate with a re-broadened prior and reconsiders every match.
  int passes = 2;
  /// Prior standard deviation at the start of every pass, relative to the starting estimate
  /// [-], > 0: sigma_s = prior_relative_stddev * s0 and sigma_lambda = prior_relative_stddev *
  /// max(|lambda0|, median |P_t|). Large = the data dominate the result.
  double prior_relative_stddev = 1.0;
};

/// Every parameter of ScaleEstimationOptions (YAML block `scale_estimation`): key, type, default (the member initialiser), range, unit, doc.
template <>
const ParamSchema<ScaleEstimationOptions>& paramSchema<ScaleEstimationOptions>();

/// @throw InputError naming the option (e.g. "scale_estimation.passes must be >= 1")
void validate(const ScaleEstimationOptions& options);

/// Outcome of the scale estimation. The numbers are meaningful only when status is kOk; on a
/// failure they hold whatever the filter reached (or zeros) and message says why.
struct ScaleEstimate {
  Status status = Status::kScaleFailed;
  std::string message;
  double scale = 0.0;          ///< s [target units per source unit]
  double scale_stddev = 0.0;   ///< standard deviation of s [target units per source unit]
  double lambda = 0.0;         ///< baseline length along t_hat [target units]
  double lambda_stddev = 0.0;  ///< standard deviation of lambda [target units]
  /// Covariance of (s, lambda) [(target/source units)², target²/source units, target units²].
  Eigen::Matrix2d covariance = Eigen::Matrix2d::Zero();
  int inliers = 0;  ///< matches accepted by the gate in the last pass
  int used = 0;     ///< usable matches (finite, non-zero points) fed to the filter
  /// Per input match: true when accepted in the last pass (false for unusable matches).
  std::vector<bool> inlier_mask;
};

/**
 * @brief Estimates the scale s and the baseline length lambda from matched 3D points.
 *
 * Noise model (per match): cov(P) = |P|² (σ_d² b bᵀ + σ_l² (I − b bᵀ)) for both points, b the
 * unit viewing ray, σ_d = relative_depth_noise, σ_l = relative_lateral_noise, unless the caller
 * gives the points' own covariances; the measurement noise is cov(P_t) + s² R cov(P_s) Rᵀ with s
 * the current estimate.
 * Initialisation: s0 = median of the positive per-match least-squares scales, lambda0 = median
 * of t_hatᵀ (P_t − s0 R P_s). Each pass orders the matches by their Mahalanobis residual at the
 * pass's starting estimate (most consistent first), then runs sequential Kalman updates from a
 * broad prior, rejecting a match when its innovation's χ² exceeds gating_chi2. At the end of a
 * pass, one Newton step adds the score term of the noise's dependence on s (s rᵀN⁻¹ C N⁻¹ r,
 * C = R cov(P_s) Rᵀ), which removes the errors-in-variables bias of s towards zero.
 *
 * @param[in] points_source P_s per match, source keyframe camera frame [source units]
 * @param[in] points_target P_t per match, target keyframe camera frame [target units]
 * @param[in] R rotation from the source to the target keyframe camera
 * @param[in] t_hat unit direction of the translation from the relative-pose stage
 * @param[in] options filter options
 * @param[in] covariances_source optional per-match cov(P_s) [source units²], e.g. from LSD-SLAM's
 * inverse-depth variance (KeyframeDepth::sampleAt()); null = the noise model above for every
 * match. An entry that is not finite and positive definite (e.g. zero: unknown) falls back to
 * the noise model for that point.
 * @param[in] covariances_target optional per-match cov(P_t) [target units²], as covariances_source
 * @return the estimate; status kNotEnoughMatches when fewer than min_inliers matches are given
 * or usable, kScaleFailed when the filter accepts fewer than min_inliers matches or less than
 * min_inlier_ratio of the usable ones, the scale is not finite and > 0, or its relative standard
 * deviation exceeds max_relative_stddev. Non-finite or zero points are skipped, never an error.
 * @throw InputError when the vectors (and given covariance vectors) differ in size, R is not a finite rotation (RᵀR = I within
 * 1e-6, det > 0), t_hat is not a finite unit vector (|t_hat| = 1 within 1e-6), or the options
 * are invalid
 */
ScaleEstimate estimateScale(const std::vector<Eigen::Vector3d>& points_source,
                            const std::vector<Eigen::Vector3d>& points_target, const Eigen::Matrix3d& R,
                            const Eigen::Vector3d& t_hat, const ScaleEstimationOptions& options,
                            const std::vector<Eigen::Matrix3d>* covariances_source = nullptr,
                            const std::vector<Eigen::Matrix3d>* covariances_target = nullptr);

}  // namespace pcr_pro
