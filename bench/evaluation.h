// How the benchmark judges one merge against a truth (issue 12, item 7): errors in the issue's
// terms, the floors, and the NEES of an estimate under its covariance plus the truth's own
// uncertainty; pooled over many cases into ANEES and the fraction under the chi-square bounds.
// Shared by the real-case and simulated sections.
#pragma once

#include <string>
#include <vector>

#include "pcr_pro/geometry/sim3.h"
#include "pcr_pro/geometry/types.h"

namespace pcr_pro {
namespace bench {

/// The floors of issue 12: rotation [deg], translation [% of the map extent], |scale error| [%].
struct Floors {
  double rotation_deg = 1.0;
  double translation_pct = 2.0;
  double scale_pct = 1.5;
};

/// chi-square 95 % quantiles for 1, 3, 6 and 7 degrees of freedom.
constexpr double kChi2_95_1 = 3.841;
constexpr double kChi2_95_3 = 7.815;
constexpr double kChi2_95_6 = 12.592;
constexpr double kChi2_95_7 = 14.067;

/// How far a case's truth may itself be from the real answer, each taken as a 1-sigma per axis
/// about `centre` (where the maps overlap): rotation [rad], translation [target units], relative
/// scale [-]. Zero for an exact truth.
struct TruthAccuracy {
  double rotation = 0.0;
  double translation = 0.0;
  double scale_rel = 0.0;
  Eigen::Vector3d centre = Eigen::Vector3d::Zero();  ///< [target units]
};

/**
 * The truth's own uncertainty as a 7x7 covariance in the merge's convention (left perturbation
 * about the target origin, similarity_fit.h): isotropic about `centre`, moved to the origin by the
 * Jacobian of t0 = tc + [c]x dr - c ds, so that a rotation of the truth about the overlap does not
 * show up as a translation error.
 */
Matrix7d truthCovariance(const TruthAccuracy& accuracy);

/// One estimate of S_target_source judged against the truth.
struct Score {
  bool has = false;          ///< an estimate existed
  double rotation_deg = 0.0;
  double translation_pct = 0.0;  ///< where the estimate and the truth put the source centroid, % of the extent
  double scale_pct = 0.0;        ///< signed: estimate / truth - 1 [%]
  bool within_floors = false;
  bool has_covariance = false;   ///< a positive-definite covariance came with it
  /// NEES with the truth's uncertainty added to the covariance: rotation (3), 6-DoF (x y z rx ry rz), scale (1).
  double nees_rot = 0.0, nees6 = 0.0, nees_scale = 0.0;
  /// The same without the truth's uncertainty (the estimate's covariance alone).
  double raw_rot = 0.0, raw6 = 0.0, raw_scale = 0.0;
};

/**
 * @brief Scores `estimate` (with `covariance`, 7x7, or zero when it has none).
 * @param[in] source_centroid centroid of the source map cloud [source units]
 * @param[in] extent diagonal of the target cloud's 5-95 % box [target units]
 */
Score score(const Sim3& estimate, const Matrix7d& covariance, const Sim3& truth, const Matrix7d& truth_covariance,
            const Eigen::Vector3d& source_centroid, double extent, const Floors& floors = Floors());

/// Diagonal of the axis-aligned box between the 5 % and 95 % quantiles of each coordinate.
double boxDiagonal(const Cloud& cloud);

/// Pooled consistency of many scores (those with a covariance).
struct NeesPool {
  int n = 0;
  double anees_rot = 0.0, anees6 = 0.0, anees_scale = 0.0;        ///< mean NEES / dof
  double under_rot = 0.0, under6 = 0.0, under_scale = 0.0;        ///< fraction under the 95 % bound
  double raw_anees_rot = 0.0, raw_anees6 = 0.0, raw_anees_scale = 0.0;  ///< without the truth's uncertainty
  double raw_under6 = 0.0, raw_under_scale = 0.0;
};
NeesPool pool(const std::vector<Score>& scores);

/// The covariance floors: ANEES in [0.7, 1.5] and >= 90 % under the 95 % bound, for 6-DoF and scale.
bool neesFloorsMet(const NeesPool& p);

/// "1.02 (93 %)"-style cell: ANEES and fraction under the bound.
std::string neesCell(double anees, double under);

}  // namespace bench
}  // namespace pcr_pro
