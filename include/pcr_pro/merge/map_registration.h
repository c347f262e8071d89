/**
 * @file map_registration.h
 * @brief The merge's refinement: the map clouds filtered once and the target indexed once; an
 * overlap-aware similarity ICP (reciprocal matching, adaptive distance gate, Cauchy kernel) that
 * carries the keyframe matches along as anchors; the overlap of the aligned maps; and a
 * covariance that covers, besides the residual noise, how the estimate moves between spatial
 * blocks of the overlap (map distortion, scale drift, partial-overlap bias).
 */
#pragma once

#include <memory>
#include <string>
#include <vector>

#include "pcr_pro/geometry/kdtree.h"
#include "pcr_pro/geometry/similarity_fit.h"
#include "pcr_pro/merge/ray_noise.h"
#include "pcr_pro/registration/config.h"
#include "pcr_pro/registration/covariance.h"
#include "pcr_pro/registration/icp.h"

namespace pcr_pro {

/// A ball in the target map's frame where the overlap is measured (MapRegistration::overlap()).
struct OverlapRegion {
  Eigen::Vector3d centre = Eigen::Vector3d::Zero();  ///< [target units]
  double radius = 0.0;                               ///< [target units]; 0 = the whole maps
};

/**
 * @brief Where the maps overlap: the ball around the keyframe matches' target points that holds
 * them all (the surfaces the used keyframe pairs see in common). Each monocular map's scale
 * drifts, so two maps align only where they overlap; over the whole maps the overlap fraction
 * would measure the drift elsewhere (on lsd_slam_7scenes 20-22 % of the whole maps against
 * 36-42 % in this ball).
 * @param[in] matches keyframe matches (target points in the target frame)
 * @return the ball [target units]; radius 0 (the whole maps) with fewer than 3 matches
 */
OverlapRegion overlapRegion(const std::vector<PointMatch3>& matches);

/// Outcome of MapRegistration::refine().
struct Refinement {
  Status status = Status::kIcpNotConverged;  ///< kOk, kDegenerate or kIcpNotConverged
  std::string message;
  Sim3 estimate;                           ///< S_target_source
  Matrix7d covariance = Matrix7d::Zero();  ///< similarity_fit.h convention (log scale as 7th)
  IcpResult icp;
  CovarianceResult closed_form;  ///< Censi / calibrated, on the ICP correspondences
  int blocks = 0;                ///< spatial blocks of the block spread
  /// How much the spread between blocks enlarged the closed-form covariance (1 = not at all) [-].
  double block_spread_factor = 1.0;
  /// The anchors' information was multiplied by this in the step that gave the estimate
  /// (1 = the ICP's own estimate) [-]: MapRegistration::refine().
  double anchor_weight = 1.0;
  /// The ICP registered the target onto the source and the result was inverted (the source map
  /// is clearly the noisier one: IcpOptions::register_noisier_as_target). estimate, covariance, closed_form
  /// (covariance, information, noise_stddev) and icp (transform, fitness_rmse) are then in the
  /// requested direction; icp.matches stays in the direction the ICP ran.
  bool reversed = false;
  /// How much noisier the source's surfaces are than the target's, in the target's units at the
  /// initial estimate: the ratio of their thickness (surfaceThickness2(), square-rooted) [-]; 1
  /// when not measured (IcpOptions::register_noisier_as_target off).
  double noise_ratio = 1.0;
  /// estimate and covariance are the projective registration's of the keyframes' depth
  /// (merge.projective_refinement), not the ICP's; the gates then do not combine it with the
  /// keyframe estimate (MergeGates::judge())
  bool projective = false;
  /// Re-noised registrations whose spread is in covariance (MapRegistration::setRayNoise();
  /// 0 = none: not asked for, or fewer than two gave an estimate).
  int renoise_draws = 0;
  /// That spread, as added to covariance (similarity_fit.h convention; zero when renoise_draws is 0).
  Matrix7d renoise_spread = Matrix7d::Zero();
  double ms_icp = 0.0, ms_covariance = 0.0;
};

/**
 * @brief Stage 3 of the merge (see the file comment). Built once per pair of clouds; refine()
 * and overlap() may then be called as often as needed.
 */
class MapRegistration {
 public:
  /**
   * @param[in] options the geometric stages (filters, icp, covariance)
   * @param[in] estimate_scale the scale policy: refine the scale too, or keep the initial one
   * @param[in] reweigh_anchors when the ICP's block spread says the clouds' own covariance is
   *   f > 1 times too small, weigh the anchors f times up (refine();
   *   MergeGateOptions::reweigh_keyframe_matches)
   * The clearly noisier map is registered onto the other when options.icp's
   * register_noisier_as_target is on (refine()).
   * @throw InputError on invalid options
   */
  MapRegistration(const RegistrationOptions& options, bool estimate_scale, bool reweigh_anchors);
  ~MapRegistration();

  /**
   * @brief Filters both clouds (once) and indexes the target.
   * @return an empty string, or why the clouds cannot be registered (a filter left one empty)
   * @throw InputError on an empty input cloud
   */
  std::string setClouds(const Cloud& source, const Cloud& target);

  /**
   * @brief Refines S_target_source from `initial` with the ICP and the anchors. With
   * reweigh_anchors (constructor), when the ICP's block_spread_factor f exceeds 1, one
   * Gauss-Newton step at the ICP's final correspondences with the anchors' information times f
   * moves the estimate (anchor_weight = f), and the covariance is computed there. With
   * covariance.jackknife_blocks > 0 the covariance then covers the spread of the refinement
   * re-run without each spatial block (jackknife.h; that many more ICP runs).
   * With icp.sampling.register_noisier_as_target (options) and a source at least twice as noisy
   * (noiseRatio() squared >= 2), all of this runs from the target onto the source and the result is inverted
   * (Refinement::reversed).
   * @param[in] initial starting estimate (the keyframe estimate)
   * @param[in] anchors 3D-3D keyframe matches (group = keyframe pair); may be empty
   */
  Refinement refine(const Sim3& initial, const std::vector<PointMatch3>& anchors) const;

  /**
   * @brief The re-noising policy (merge.renoise_draws): refine() then registers the clouds again
   * `draws` times from its estimate, each time with both clouds re-noised along their maps'
   * rays (renoiseAlongRays(); the same anchors), and adds the spread of those estimates around
   * its own to the covariance (Refinement::renoise_spread). The closed form and the block spread
   * hold the normals and correspondences fixed; a registration of re-noised clouds re-fits them,
   * which is where most of the ICP's error on noisy semi-dense maps comes from (docs/DESIGN.md).
   * The spread is block-diagonal at the anchors' centroid (at the aligned source cloud's without
   * anchors), each 3x3 block (translation, rotation) isotropic with its trace: a few draws fix a
   * size, not directions. Nothing is added when a model is not valid() or fewer than two draws
   * give an estimate (the message says so).
   * @param[in] source, target the two maps' models (measureRayNoise())
   * @param[in] draws re-noised registrations, >= 0; 0 = off
   * @throw InputError when draws < 0
   */
  void setRayNoise(const RayNoise& source, const RayNoise& target, int draws);

  /// How much noisier the source's surfaces are than the target's at the scale of `target_source`
  /// (Refinement::noise_ratio); 1 when either thickness is unknown.
  double noiseRatio(const Sim3& target_source) const;

  /**
   * @brief Overlap of the aligned maps: the larger of the fraction of (a sample of) the source
   * points that have a target point within `factor` spacings and the same fraction of the target
   * points towards the source; the spacing is the larger of the two clouds' median spacings.
   * Only the points that the alignment puts inside `region` count (default: all).
   */
  double overlap(const Sim3& target_source, double factor, const OverlapRegion& region = OverlapRegion()) const;

  const Cloud& source() const { return source_; }
  const Cloud& target() const { return target_; }
  const KdTree& targetTree() const { return *target_tree_; }
  double filterMs() const { return filter_ms_; }

 private:
  // The ICP options with the scale policy.
  IcpOptions icpOptions() const;
  // refine() in one direction: `source` onto `target` (indexed by target_tree).
  Refinement refineDirected(const Cloud& source, const Cloud& target, const KdTree& target_tree, const Sim3& initial,
                            const std::vector<PointMatch3>& anchors, const RayNoise& source_noise,
                            const RayNoise& target_noise) const;
  // The re-noised registrations' spread into `refinement` (setRayNoise()), in the direction the
  // ICP ran (source onto target).
  void addRenoisedSpread(const Cloud& source, const Cloud& target, const std::vector<PointMatch3>& anchors,
                         const RayNoise& source_noise, const RayNoise& target_noise, Refinement* refinement) const;
  // refineDirected() before the jackknife.
  Refinement refineOnce(const Cloud& source, const KdTree& target_tree, const Sim3& initial,
                        const std::vector<PointMatch3>& anchors) const;
  // The refinement's covariance (closed form with the anchors, covered by the block spread),
  // status and message at refinement->estimate from its ICP correspondences. @return the block
  // spread's information of the clouds and the anchors (similarity_fit.h convention; zero when
  // the status is not kOk or the spread could not be formed)
  Matrix7d finish(const std::vector<PointMatch3>& anchors, Refinement* refinement) const;
  // The estimate moved by one Gauss-Newton step with the anchors' information times `weight`
  // on top of `information` (finish()'s, which holds them once; see refine()); `estimate`
  // itself when that system is singular.
  Sim3 reweighedStep(const Sim3& estimate, const Matrix7d& information, const std::vector<PointMatch3>& anchors,
                     double weight) const;
  RegistrationOptions options_;
  bool estimate_scale_;
  bool reweigh_anchors_;
  Cloud source_, target_;
  double source_thickness2_ = 0.0, target_thickness2_ = 0.0;  // surfaceThickness2() [own units²]
  std::unique_ptr<KdTree> target_tree_, source_tree_;
  double target_spacing_ = 0.0, source_spacing_ = 0.0;
  double filter_ms_ = 0.0;
  RayNoise source_noise_, target_noise_;
  int renoise_draws_ = 0;
};

}  // namespace pcr_pro
