/**
 * @file truth_comparison.h
 * @brief How far an estimated S_target_source is from a known truth, measured in the convention
 * of the reported covariance, next to the uncertainty the estimate claims (the demo and
 * `pcr_pro_merge --truth`, merge_client's truth_file; docs/FORMATS.md).
 */
#pragma once

#include <optional>
#include <string>

#include "pcr_pro/geometry/sim3.h"
#include "pcr_pro/geometry/types.h"

namespace pcr_pro {

/**
 * The error δ of an estimate, with truth = exp(δ) · estimate (left perturbation in the target
 * frame: the convention of the 6x6 covariance, docs/FORMATS.md), and the reported uncertainty.
 * δ's translation is where the truth puts the target map's origin as the estimate sees it; it is
 * not `t_truth - t_estimate` once the rotation or the scale is off.
 */
struct TruthErrors {
  double rotation_deg = 0.0;   ///< |δ rotation|: angle of R_truth R_estimateᵀ [deg]
  double translation = 0.0;    ///< |δ translation| [target units]
  double scale_percent = 0.0;  ///< 100 (s_estimate / s_truth - 1), signed [%]
  /// √trace of the covariance's rotation block: the root-mean-square rotation error the
  /// estimate claims [deg]; absent without a covariance
  std::optional<double> rotation_sigma_deg;
  /// √trace of its translation block [target units]; absent without a covariance
  std::optional<double> translation_sigma;
  /// 100 · scale_stddev / s_estimate [%]; absent without a scale standard deviation
  std::optional<double> scale_sigma_percent;
  /// δᵀ Σ⁻¹ δ over the 6 pose dimensions [-]: an honest covariance gives 6 on average and less
  /// than 12.6 in 95 % of merges; absent without a covariance or when it is not positive definite
  std::optional<double> pose_chi2;
};

/**
 * @brief Compares an estimate with the truth.
 * @param[in] estimate estimated S_target_source
 * @param[in] truth true S_target_source
 * @param[in] covariance the estimate's 6x6 covariance (x y z rx ry rz) [target units², rad²], if any
 * @param[in] scale_stddev the estimate's scale standard deviation [-], if any
 * @return the errors and the reported uncertainty; every number finite (a non-finite
 *   uncertainty is left out)
 */
TruthErrors compareWithTruth(const Sim3& estimate, const Sim3& truth, const std::optional<Matrix6d>& covariance,
                             const std::optional<double>& scale_stddev);

/**
 * @brief The errors as a YAML block `errors_vs_truth:` (docs/FORMATS.md), to append to a result.
 * @param[in] errors compareWithTruth()'s result
 * @param[in] truth_file the truth file's path, named in a comment
 * @return the block, ending with a newline
 */
std::string truthErrorsYaml(const TruthErrors& errors, const std::string& truth_file);

}  // namespace pcr_pro
