/**
 * @file relative_pose.h
 * @brief Relative pose between two keyframe cameras (PCR-Pro §Relative Pose): OpenGV central
 * relative-pose RANSAC on bearing vectors, then optional non-linear refinement on the inliers.
 *
 * CONVENTION. The result maps SOURCE camera coordinates into the TARGET camera:
 *
 *     P_target = R * P_source + lambda * t_hat,   |t_hat| = 1, lambda > 0 unknown
 *
 * so R = R_target_source and t_hat is the direction of the source camera centre seen from the
 * target camera, in target camera coordinates (monocular: the length lambda is not observable).
 * Internally the target bearings are OpenGV's viewpoint 1 and the source bearings viewpoint 2;
 * OpenGV returns [R12 | t12] with P_1 = R12 * P_2 + t12. The unit test
 * test_relative_pose.cpp checks this numerically against synthetic ground truth.
 *
 * RANSAC THRESHOLD. OpenGV's CentralRelativePoseSacProblem scores a correspondence by
 * triangulating it and adding the two reprojection errors (1 - cos(angle)) measured in
 * viewpoint 1 and in viewpoint 2. A pixel error psi at focal length f is the angle
 * atan(psi / f), so the threshold used for the sum of the two terms is
 *
 *     threshold = 2 * (1 - cos(atan(psi / f)))
 *
 * (ransacThreshold()), i.e. a correspondence is an inlier when the RMS of its two angular
 * errors is below the angle of psi pixels.
 */
#pragma once

#include <Eigen/Core>
#include <cstdint>
#include <string>
#include <vector>

#include "pcr_pro/geometry/types.h"
#include "pcr_pro/io/param_schema.h"

namespace pcr_pro {

/// Minimal solver used inside RANSAC (OpenGV CentralRelativePoseSacProblem algorithms).
enum class RelativePoseAlgorithm {
  kNister,     ///< "NISTER": Nistér's five-point solver
  kStewenius,  ///< "STEWENIUS": Stewénius' five-point solver (Gröbner basis)
  kSevenPt,    ///< "SEVENPT": seven-point solver
  kEightPt,    ///< "EIGHTPT": linear eight-point solver
};

/// @return the configuration name of an algorithm: "NISTER", "STEWENIUS", "SEVENPT" or "EIGHTPT".
const char* relativePoseAlgorithmName(RelativePoseAlgorithm algorithm);

/**
 * @brief Parses an algorithm name (case-insensitive).
 * @param[in] name "NISTER", "STEWENIUS", "SEVENPT" or "EIGHTPT"
 * @param[out] algorithm the parsed algorithm, untouched when the name is unknown
 * @return false when the name is unknown
 */
bool parseRelativePoseAlgorithm(const std::string& name, RelativePoseAlgorithm* algorithm);

/**
 * @brief Number of correspondences OpenGV draws per RANSAC sample: the minimal solver plus
 * the extra points it uses to pick the right decomposition of the essential matrix.
 * @param[in] algorithm minimal solver
 * @return 8 (NISTER, STEWENIUS) or 9 (SEVENPT, EIGHTPT) [correspondences]
 */
int relativePoseSampleSize(RelativePoseAlgorithm algorithm);

/// Options of the relative pose stage (YAML block `relative_pose`).
struct RelativePoseOptions {
  /// Minimal solver inside RANSAC.
  RelativePoseAlgorithm algorithm = RelativePoseAlgorithm::kStewenius;
  /// Inlier pixel error psi: RMS of the two reprojection errors of an inlier [px], > 0.
  double pixel_error = 1.0;
  /// Upper bound on the number of RANSAC iterations [-], >= 1.
  int max_iterations = 1000;
  /// RANSAC stops once it has drawn an outlier-free sample with this probability [-], in (0, 1).
  double probability = 0.999;
  /// Refine the RANSAC model by non-linear optimisation on its inliers, then recompute the
  /// inliers with the refined model; then take it to the optimum of the inliers' Sampson errors
  /// (refineOnSampsonError()), where its rotation covariance is computed.
  bool nonlinear_refinement = true;
  /// Fewest inliers for the relative pose to be accepted [correspondences], >= 5.
  int min_inliers = 15;
  /// Smallest fraction of the given correspondences that must be inliers [-], in [0, 1].
  double min_inlier_ratio = 0.3;
  /// Degeneracy guard: the bearings of each camera must stand out of their best-fitting plane
  /// through the optical centre (a line in the image; also catches all-identical points) by at
  /// least this RMS distance, expressed in pixels at focal length f [px], >= 0.
  double min_spread_px = 5.0;
  /// Seed of RANSAC's random generator (which correspondences each iteration draws): equal
  /// bearings, options and seed give equal results, bit for bit [-].
  std::uint64_t seed = kDefaultSeed;
};

/// Every parameter of RelativePoseOptions (YAML block `relative_pose`): key, type, default (the member initialiser), range, unit, doc.
template <>
const ParamSchema<RelativePoseOptions>& paramSchema<RelativePoseOptions>();

/**
 * @brief Checks every field of the options.
 * @param[in] options options to check
 * @throw InputError naming the first invalid key, e.g. "relative_pose.pixel_error must be > 0"
 */
void validate(const RelativePoseOptions& options);

/**
 * @brief RANSAC threshold on OpenGV's score for a pixel error (see the file comment).
 * @param[in] pixel_error psi [px], > 0
 * @param[in] focal_px f [px], > 0
 * @return 2 * (1 - cos(atan(psi / f))) [-]
 */
double ransacThreshold(double pixel_error, double focal_px);

/// Outcome of estimateRelativePose().
struct RelativePoseResult {
  /// kOk; kNotEnoughMatches (too few valid correspondences, inliers or inlier ratio);
  /// kRelativePoseFailed (RANSAC found no model, or the model is not finite);
  /// kDegenerate (the correspondences or the inliers lie on one image line / one point).
  Status status = Status::kRelativePoseFailed;
  /// Why, in one line, for the user.
  std::string message;
  /// R = R_target_source: P_target = R * P_source + lambda * t_hat. Identity when no model.
  Eigen::Matrix3d rotation = Eigen::Matrix3d::Identity();
  /// t_hat, unit direction of the source camera centre in target camera coordinates [-].
  /// Zero when no model.
  Eigen::Vector3d translation_direction = Eigen::Vector3d::Zero();
  /// Indices (into the input vectors, increasing) of the inlier correspondences.
  std::vector<int> inliers;
  /// inliers.size() [correspondences]
  int inlier_count = 0;
  /// inlier_count / number of given correspondences [-]
  double inlier_ratio = 0.0;
};

/**
 * @brief Relative pose of two calibrated cameras from bearing-vector correspondences.
 *
 * Bearings are normalize(K⁻¹ [u v 1]ᵀ) (PinholeCamera::bearing()); they are normalised again
 * here. Correspondences with a non-finite or zero bearing on either side take no part and are
 * never inliers. RANSAC draws its samples from a generator seeded with options.seed (OpenGV's own
 * would be seeded with 12345 or the clock): the result is reproducible. The rotation,
 * translation direction and inliers are filled in whenever a model was found, also when the
 * status is kNotEnoughMatches or kDegenerate because of the inliers.
 * @param[in] bearings_target bearing i in the target camera [unit vector]
 * @param[in] bearings_source bearing i in the source camera, same point as bearings_target[i]
 * @param[in] focal_px focal length used to turn options.pixel_error into an angle [px], > 0
 * @param[in] options RANSAC and refinement options (validated here)
 * @return the relative pose, P_target = R * P_source + lambda * t_hat, with a status
 * @throw InputError when the two vectors differ in length, focal_px is not finite and > 0, or
 * the options are invalid
 */
RelativePoseResult estimateRelativePose(const std::vector<Eigen::Vector3d>& bearings_target,
                                        const std::vector<Eigen::Vector3d>& bearings_source, double focal_px,
                                        const RelativePoseOptions& options);

}  // namespace pcr_pro
