/**
 * @file similarity_fit.h
 * @brief Robust similarity between two maps from 3D-3D point matches with per-match
 * covariances and optional rotation measurements, grouped by where they come from (a keyframe
 * pair, a spatial block), with a covariance that also holds the disagreement between groups.
 *
 * Perturbation convention (as the rest of pcr_pro): a 7-vector δ = (δx δy δz, δrx δry δrz, δσ)
 * acts on the left, S = exp(δ) · Ŝ: the point y = Ŝ(x) moves to e^δσ R(δr) y + δt, about the
 * target frame's origin; δσ = δs / s is the relative scale change.
 */
#pragma once

#include <Eigen/Core>
#include <vector>

#include "pcr_pro/geometry/sim3.h"
#include "pcr_pro/geometry/types.h"

namespace pcr_pro {

/// One 3D-3D match: target ≈ S(source).
struct PointMatch3 {
  Eigen::Vector3d source;  ///< point in the source frame [source units]
  Eigen::Vector3d target;  ///< point in the target frame [target units]
  /// Covariance of the residual S(source) - target, in the target frame [target units²]
  /// (cov(target) + s² R cov(source) Rᵀ at the expected S). Must be symmetric positive definite.
  Eigen::Matrix3d covariance = Eigen::Matrix3d::Identity();
  int group = 0;  ///< where the match comes from (keyframe pair, block), >= 0
};

/// A measurement of the rotation alone: R ≈ rotation (left perturbation, target frame).
struct RotationMeasurement {
  Eigen::Matrix3d rotation = Eigen::Matrix3d::Identity();
  Eigen::Matrix3d covariance = Eigen::Matrix3d::Identity();  ///< of the rotation vector [rad²]
  int group = 0;
};

/// Options of fitSimilarity().
struct SimilarityFitOptions {
  bool estimate_scale = true;  ///< 7 DoF; otherwise the scale stays at the initial one
  /// Cauchy kernel width on the Mahalanobis distance of a match [-], > 0 (2.4 keeps 95 % efficiency
  /// for 3-DoF Gaussian residuals while outliers lose their pull).
  double kernel_width = 2.4;
  /// A match whose squared Mahalanobis distance at the solution exceeds this is an outlier [-]
  /// (χ² with 3 DoF: 16.27 = 99.9 %).
  double outlier_chi2 = 16.27;
  int max_iterations = 30;  ///< Gauss-Newton iterations, >= 1
};

/// Outcome of fitSimilarity().
struct SimilarityFit {
  bool ok = false;      ///< enough inliers and a finite, positive-definite solution
  Sim3 estimate;        ///< S_target_source
  /// Covariance of δ (see the file comment) [target units², rad², -]: the noise model scaled by the
  /// residuals' own level when that is larger (max(1, χ²/dof)), and, with three groups or more,
  /// covering the cluster-robust (sandwich) spread between groups too.
  Matrix7d covariance = Matrix7d::Zero();
  Matrix7d information = Matrix7d::Zero();  ///< H = Σ Jᵀ W J of the noise model (unscaled)
  std::vector<bool> inliers;                ///< per point match
  int inlier_count = 0;
  double chi2 = 0.0;             ///< Σ Mahalanobis² of the inliers (and rotation terms)
  int dof = 0;                   ///< 3 inliers + 3 rotation terms - parameters
  double variance_factor = 1.0;  ///< max(1, χ²/dof) [-]
  int groups = 0;                ///< groups with at least one inlier
  /// How much the between-group spread enlarged the covariance (largest generalised eigenvalue of
  /// the cluster-robust covariance against the scaled model covariance; 1 = not at all) [-].
  double group_spread_factor = 1.0;
};

/**
 * @brief Iteratively reweighted Gauss-Newton (Cauchy kernel) from `initial`.
 * @param[in] matches point matches
 * @param[in] rotations rotation measurements (may be empty)
 * @param[in] initial starting S_target_source
 * @param[in] options kernel, gate, iterations
 * @return the fit; ok = false when fewer than 3 inliers remain or the system is singular
 */
SimilarityFit fitSimilarity(const std::vector<PointMatch3>& matches, const std::vector<RotationMeasurement>& rotations,
                            const Sim3& initial, const SimilarityFitOptions& options = SimilarityFitOptions());

/**
 * @brief The Jacobian of S(x) w.r.t. δ at y = Ŝ(x): [I, -[y]x, y] (3 x 7).
 * @param[in] y the transformed point [target units]
 */
Eigen::Matrix<double, 3, 7> similarityJacobian(const Eigen::Vector3d& y);

/**
 * @brief δ with a = exp(δ) · b, to first order in the rotation: (a.t - (sa/sb) Ra Rbᵀ b.t, log(Ra Rbᵀ), log(sa / sb)).
 */
Eigen::Matrix<double, 7, 1> similarityDifference(const Sim3& a, const Sim3& b);

/**
 * @brief The pose part of similarityDifference(): the left-perturbation error δ = (δt, δω) with
 * a = exp(δ) · b to first order, in the order of the 6x6 covariances (x y z rot_x rot_y rot_z);
 * e.g. an estimate's error against its truth, a = estimate, b = truth.
 */
Vector6d poseDifference(const Sim3& a, const Sim3& b);

/**
 * @brief The adjoint of a similarity G in this convention: G · exp(δ) · G⁻¹ = exp(Ad_G δ), so a
 * covariance C of δ about Ŝ becomes Ad_G C Ad_Gᵀ about G Ŝ G⁻¹ (e.g. moved from the target map's
 * frame into a keyframe's, about P⁻¹ Ŝ with G = P⁻¹). With G = (s, R, t):
 * Ad_G = [[sR, [t]x R, -t], [0, R, 0], [0, 0, 1]]. The covariance of s⁻¹ (left perturbation) is
 * Ad(s⁻¹) Σ Ad(s⁻¹)ᵀ when Σ is that of s.
 */
Matrix7d similarityAdjoint(const Sim3& g);

/// @return RMS distance [target units] between where a and b put the matches' source points (0 without matches)
double rmsMoveOfMatches(const std::vector<PointMatch3>& matches, const Sim3& a, const Sim3& b);

/// @return exp(δ) · s (the update of the file comment's convention)
Sim3 applyDelta(const Eigen::Matrix<double, 7, 1>& delta, const Sim3& s);

/**
 * @brief The smallest covariance (in the generalised-eigenvalue sense) that covers both a and b:
 * a^½ V max(Λ, 1) Vᵀ a^½ with V Λ Vᵀ the eigen-decomposition of a^-½ b a^-½. Directions where a is
 * zero take b's variance.
 * @param[out] factor largest eigenvalue of a^-½ b a^-½ (1 when b is inside a); may be null
 */
Matrix7d coveringCovariance(const Matrix7d& a, const Matrix7d& b, double* factor = nullptr);

}  // namespace pcr_pro
