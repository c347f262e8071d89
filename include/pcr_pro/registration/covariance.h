/**
 * @file covariance.h
 * @brief Closed-form ICP covariance (Censi 2007; Prakhya et al. 2015 for 3D point-to-point,
 * and the point-to-plane analogue) and the information matrix for a pose-graph edge.
 *
 * cov(x) ≈ H⁻¹ (∂²J/∂z∂x) cov(z) (∂²J/∂z∂x)ᵀ H⁻¹, evaluated at the converged pose on the final
 * correspondences and accumulated per correspondence in O(n). The pose perturbation is a left
 * perturbation in the target frame, δ = (x, y, z, rot_x, rot_y, rot_z[, log scale]):
 * S = exp(δ) · Ŝ.
 *
 * Three models (CovarianceOptions::model):
 * - closed_form: Censi's formula with independent isotropic point noise. With nearest-neighbour
 *   correspondences re-made on sparse, independently sampled clouds it is over-confident: the
 *   error then also comes from how each cloud samples the surface (edges, curvature, non-planar
 *   clutter, shared target points), which the residuals at the converged pose do not show.
 * - calibrated: the closed form inflated by a factor measured on the data itself by
 *   split-sample re-registration. The matched points are split at random into two disjoint
 *   halves (source and target each), each half pair is re-registered by the same ICP from the
 *   converged pose (correspondences re-made), and the disagreement of the two half estimates is
 *   compared with what the closed form predicts for it: κ = (δ_A − δ_B)ᵀ (P_A + P_B)⁻¹ (δ_A − δ_B) / 6,
 *   averaged over several random splits. Independent halves make δ_A − δ_B carry every error
 *   source of a re-matched registration, sampling included; the closed-form covariance is then
 *   multiplied by max(1, κ̄).
 *   The halves are drawn from a random sample of at most calibration_max_points matches, not
 *   from all of them. κ̄ depends on that sample size: large halves of a dense cloud under-predict
 *   the full registration's error (ANEES 1.43 at 10k points with 4000), small ones over-predict
 *   (0.8 at 600). The default 800 was chosen with the Monte-Carlo of docs/BENCHMARKS.md run
 *   over three seeds and 80 trials each (ANEES 0.88–1.13 for 2k–10k points at 1 cm noise). Limitation: a bias that both
 *   halves share (noise close to the point spacing, with trimming and noisy normals) is not seen
 *   by a split; at 3 cm noise on 10k points in a 4 m room the calibrated ANEES is about 5.
 *   Since the ICP's planes pass through their neighbours' centroids the same Monte-Carlo gives
 *   0.54 / 0.62 / 0.71 at 2k / 5k / 10k points (too wide; 0.80 / 1.10 / 1.25 before), its mean
 *   factor 1.6-1.7: the full registration's error fell more than the halves' disagreement
 *   (probably because a half's sparser neighbourhoods gain less from the centroids; not measured).
 * - blocks (default): the closed form, enlarged to cover the spread of the estimate between
 *   spatial blocks of the correspondences (and the anchor groups), see blockSpreadCovariance();
 *   on independent noise it equals the closed form (Monte-Carlo 0.83 / 0.97 / 1.12).
 */
#pragma once

#include <optional>
#include <string>

#include "pcr_pro/registration/icp.h"
#include "pcr_pro/geometry/sim3.h"
#include "pcr_pro/geometry/types.h"
#include "pcr_pro/io/param_schema.h"

namespace pcr_pro {

/// How the covariance is computed (see the file comment).
enum class CovarianceModel {
  kClosedForm,  ///< Censi's closed form, independent isotropic noise
  kCalibrated,  ///< closed form inflated by the split-sample re-registration factor
  kBlocks,      ///< closed form, covering the spread between spatial blocks (blockSpreadCovariance())
};

/// @return "closed_form", "calibrated" or "blocks"
const char* covarianceModelName(CovarianceModel model);
/// @return false when the name is unknown
bool parseCovarianceModel(const std::string& name, CovarianceModel* model);

/// Options of the covariance stage.
struct CovarianceOptions {
  CovarianceModel model = CovarianceModel::kBlocks;
  /// Random splits into two halves averaged for the calibration factor (calibrated model) (>= 1).
  int calibration_splits = 8;
  /// The calibration re-registers at most this many correspondences (a random subset, split in
  /// two halves) [points]; 0 = all (calibrated model). Sets both its cost and κ̄ (see above).
  int calibration_max_points = 800;
  /// Isotropic noise of each point coordinate, in both clouds [target units]; 0 = estimate it
  /// from the residuals of the final correspondences.
  double sensor_noise_stddev = 0.0;
  /// A direction is unobservable (status DEGENERATE) when the condition number of the
  /// geometric information (normals, rotation in units of the cloud radius) exceeds this [-].
  double degeneracy_condition_threshold = kDefaultDegeneracyCondition;
  /// Neighbours used to estimate normals of the matched target points when the
  /// correspondences carry none (point-to-point ICP) (>= 3).
  int normal_neighbors = 10;
  /// Spatial jackknife (registration/jackknife.h): the registration is re-run this many times,
  /// each time without one spatial block of the overlap, and the covariance is raised until it
  /// covers the spread of those estimates [-]; 0 = off, else >= 3. It measures what the closed
  /// form and the linearised block spread miss on noisy semi-dense maps (normals fitted to the
  /// noise, the weak directions of a low overlap): on the bench's 24 simulated worlds (15-60 %
  /// overlap, 0-5 % drift, inverse-depth noise 0.01-0.03), the refinement alone started at the
  /// truth had a 6-DoF ANEES of 49 with the blocks model and 1.75 with 8 jackknife blocks (46 and
  /// 1.66 on 44 held-out worlds). Off by default: it costs that many more ICP runs (docs/DESIGN.md, What
  /// the covariance covers).
  int jackknife_blocks = 0;
};

/// Every parameter of CovarianceOptions (YAML block `covariance`): key, type, default (the member initialiser), range, unit, doc.
template <>
const ParamSchema<CovarianceOptions>& paramSchema<CovarianceOptions>();

/// @throw InputError naming the option when out of range
void validate(const CovarianceOptions& options);

/// Covariance and information of an ICP result.
struct CovarianceResult {
  Status status = Status::kOk;  ///< kOk, kDegenerate, or kIcpNotConverged (too few correspondences)
  std::string message;
  Matrix6d covariance = Matrix6d::Zero();   ///< (x, y, z, rot_x, rot_y, rot_z) [target units², rad²]
  Matrix6d information = Matrix6d::Zero();  ///< inverse of covariance; zero along unobservable directions
  bool with_scale = false;                  ///< covariance7 is valid
  Matrix7d covariance7 = Matrix7d::Zero();  ///< as covariance, plus the scale s as 7th variable [-]
  double scale_stddev = 0.0;                ///< sqrt of covariance7(6, 6) [-]
  double noise_stddev = 0.0;                ///< the noise σ used [target units]
  /// Factor applied to the closed-form covariance (1 for closed_form; max(1, κ̄) for calibrated) [-]
  double inflation = 1.0;
  int calibration_splits_used = 0;          ///< splits whose two halves both re-registered
  double condition_number = 0.0;            ///< of the normalised geometric information [-]
  int correspondences = 0;
};

/// The spread of an estimate between spatial blocks of its correspondences (and anchor groups).
struct BlockSpread {
  bool ok = false;
  int clusters = 0;  ///< spatial blocks plus anchor groups
  /// Cluster-robust (sandwich) covariance H⁻¹ (K/(K-1) Σ g_k g_kᵀ) H⁻¹ of δ = (x y z rx ry rz log s),
  /// a left perturbation about the target frame's origin (similarity_fit.h convention).
  Matrix7d sandwich = Matrix7d::Zero();
  Matrix7d information = Matrix7d::Zero();  ///< H, the model's information of δ
};

/**
 * @brief How much the estimate moves between parts of the data: the correspondences are split
 * into up to 16 spatial blocks (median splits of the matched points along their widest axis,
 * at least 50 correspondences each); each block's gradient of the weighted least-squares cost at
 * the solution, and each anchor group's, enter a cluster-robust sandwich. Errors that are not
 * independent per point (map distortion, scale drift, partial-overlap bias, a block sampled
 * unevenly) make blocks disagree, and the sandwich grows with them; on independent noise it
 * equals the closed form.
 * @param[in] matches final correspondences (with weights, residual_scale and spacing from alignIcp())
 * @param[in] transform the solution S_target_source
 * @param[in] metric the ICP's error metric
 * @param[in] with_scale the scale was estimated
 * @param[in] anchors anchor matches of the solution (may be null)
 */
BlockSpread blockSpreadCovariance(const Correspondences& matches, const Sim3& transform, ErrorMetric metric,
                                  bool with_scale, const std::vector<PointMatch3>* anchors = nullptr);

/**
 * @brief Recursive median splits of the points along their widest axis into at most `blocks`
 * blocks of at least 50 points each (fewer blocks when the points are too few).
 * @return the indices of each block's points
 */
std::vector<std::vector<Eigen::Index>> spatialBlocks(const Cloud& points, int blocks);

/**
 * @brief The covariance without its cross terms between the translation at `centre`, the
 * rotation and the log scale (similarity_fit.h convention in and out). A spread measured from a
 * few estimates resolves those correlations poorly; a translation at the data's centre leaves
 * out the rotation's lever arm, which one at a far origin carries.
 */
Matrix7d blockDiagonalAt(const Matrix7d& covariance, const Eigen::Vector3d& centre);

/**
 * @brief As blockDiagonalAt(), with each 3x3 block (the translation at `centre`, the rotation)
 * replaced by its trace spread evenly over its three axes. Two or three estimates fix the size
 * of a spread, not its directions: their sample covariance has rank 1 or 2, and taken as it is
 * it would claim no spread at all across them.
 */
Matrix7d isotropicBlocksAt(const Matrix7d& covariance, const Eigen::Vector3d& centre);

/**
 * @brief Raises a covariance result until it covers `spread` (7x7 of δ with the log scale as
 * 7th variable, coveringCovariance()): its 6x6 covariance, information and 7x7 are updated.
 * @return the largest enlargement along any direction [-], 1 when spread is inside already
 */
double coverCovarianceResult(const Matrix7d& spread, const Sim3& transform, bool with_scale, CovarianceResult* result);

/**
 * @brief A covariance result of a registration run the other way round, of S = forward⁻¹
 * (the target registered onto the source), turned into one of `forward` = S_target_source:
 * covariance, covariance7 and scale_stddev moved by the similarity adjoint (left perturbations,
 * similarity_fit.h; the scale's uncertainty enters the translation's), information with them,
 * noise_stddev into the target's units.
 */
void invertCovarianceResult(const Sim3& forward, CovarianceResult* result);

/// @return the 7x7 covariance of δ with the log scale as 7th variable, from a CovarianceResult
Matrix7d logScaleCovariance(const CovarianceResult& result, double scale);

/**
 * @brief The information of a pose covariance that need not be positive definite: its inverse
 * along the eigen-directions where it is positive (an eigenvalue above 1e-14 of the largest, the
 * pose-graph export's test), zero along the rest. No information is then claimed where the
 * covariance gives none (a zero or negative variance is not a measurement of certainty).
 * @return the symmetric information; zero when the covariance is not finite
 */
Matrix6d positivePartInformation(const Matrix6d& covariance);

/// The pose covariance and information a result reports (either may be absent or zero).
struct ReportedUncertainty {
  std::optional<Matrix6d> covariance;        ///< absent when there is no finite one to report
  Matrix6d information = Matrix6d::Zero();
};

/**
 * @brief What a merge reports when its pose covariance is not positive definite (DEGENERATE): the
 * covariance itself when finite, with positivePartInformation() of it, so that the two hold
 * together. That holds when the estimate kept is the ICP's too: its closed form's information is
 * the ICP's alone, before the merge widened the covariance, and would claim more than the
 * covariance reported beside it. Only a covariance that is not finite falls back on the closed
 * form's covariance and information, when the ICP's estimate is kept; otherwise nothing is claimed.
 * @param[in] covariance the merge's 6x6 pose covariance, finite or not
 * @param[in] icp_closed_form the kept ICP refinement's closed form; nullptr when the estimate kept
 *   is not the ICP's (the keyframe estimate, a projective refinement)
 */
ReportedUncertainty degenerateUncertainty(const Matrix6d& covariance, const CovarianceResult* icp_closed_form);

/**
 * @brief Closed-form covariance of an ICP result.
 * @param[in] matches final correspondences (source points in the source frame)
 * @param[in] transform converged S_target_source
 * @param[in] metric error metric the ICP minimised (point-to-plane needs target normals)
 * @param[in] with_scale the scale was estimated too (adds the 7th variable)
 * @param[in] options noise, degeneracy and model settings
 * @return the covariance; the calibrated model re-registers halves of the correspondences with
 *         alignIcp() (default options, the given metric and scale setting) from `transform`
 */
CovarianceResult computeIcpCovariance(const Correspondences& matches, const Sim3& transform, ErrorMetric metric,
                                      bool with_scale, const CovarianceOptions& options);

}  // namespace pcr_pro
