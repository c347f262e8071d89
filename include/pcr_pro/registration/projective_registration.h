/**
 * @file projective_registration.h
 * @brief Similarity between two monocular maps from their keyframes' semi-dense depth with its
 * per-pixel uncertainty (LSD-SLAM keyframes), by projective association instead of nearest
 * neighbours in 3D.
 *
 * Each usable pixel of one map's keyframes (its depth and standard deviation known, the relative
 * standard deviation at most max_relative_stddev) becomes a 3D point with its error along its own
 * view ray. Moved by the current similarity and projected into each keyframe of the other map, it
 * is matched with one pixel with depth within search_radius_px. Each candidate pixel gives two
 * residuals: the point's depth against that pixel's depth, and its offset across the image edge
 * there (along the grey image's gradient). Both are weighed by the two maps' noise: the pixel's
 * depth standard deviation, edge_stddev_px across the edge, and the moving point's error along its
 * own ray as seen from the other keyframe, and the depth also by the two maps' relative depth
 * disagreement beyond that noise (scale drift, distortion), measured from the depth residuals every
 * iteration (depth_disagreement). The candidate whose residual pair is the shortest in that
 * metric (the likeliest to be the same point) is the match. Every projection inside a keyframe of
 * the other map also compares the point's grey level with that image's (photometric), as LSD-SLAM's
 * own keyframe-to-keyframe tracking does. Gauss-Newton on the 7 DoF with a Cauchy
 * kernel (width in robust spreads of the whitened residuals), matches re-made every iteration,
 * until the steps are negligible (the ICP's differential check) or max_iterations
 * (ICP_NOT_CONVERGED).
 *
 * Why the likeliest pixel and not the nearest: semi-dense depth lies on image edges, which are
 * often depth edges, so the nearest pixel with depth is often on the other surface. Matched that
 * way, the estimate ran away on real LSD-SLAM keyframes: every step lowered the cost of its own
 * matches and the next matching raised it more (docs/DESIGN.md).
 *
 * Why: a semi-dense point's depth error runs along its view ray, often farther than the point
 * spacing, so nearest neighbours in 3D are not correspondences and planes fitted to them lie in
 * the noise (docs/DESIGN.md). A pixel's position across an image edge is precise; its
 * depth is not, and is weighed as such.
 *
 * The two directions (the source's points into the target's keyframes, and the target's into the
 * source's, inverted) are not equally good: the moving points' own ray noise biases the estimate,
 * by how much depends on the geometry of the two maps' views (docs/DESIGN.md). Both are run; the one whose
 * whitened residuals fit their noise model better (the smaller median squared Mahalanobis length)
 * is returned.
 *
 * Its covariance (ProjectiveResult::covariance) is the Gauss-Newton one plus two spreads that
 * per-pixel noise does not make: the estimate's spread when each keyframe with matches is left
 * out in turn (a delete-one-keyframe jackknife per map, ProjectiveOptions::jackknife), and the two
 * directions' difference (direction_spread), which holds the moving points' shared noise bias.
 * Under the Gauss-Newton covariance alone the bench's worlds gave an ANEES of 150-1,300; with both
 * spreads, 0.7-1.5 in rotation and 6 DoF and 0.42 in scale (docs/DESIGN.md).
 */
#pragma once

#include <string>

#include "pcr_pro/frontend/keyframe_depth.h"
#include "pcr_pro/geometry/map_types.h"
#include "pcr_pro/geometry/sim3.h"
#include "pcr_pro/geometry/similarity_fit.h"
#include "pcr_pro/geometry/types.h"
#include "pcr_pro/io/param_schema.h"

namespace pcr_pro {

/// Options of the projective registration (YAML block `projective` of the merge configuration;
/// the merge uses this stage with MergeGateOptions::projective_refinement).
struct ProjectiveOptions {
  /// Standard deviation of an image edge's position across the edge [px], > 0: pixel
  /// quantisation (1/sqrt(12) = 0.29 px) plus the edge detector's own jitter.
  double edge_stddev_px = 0.5;
  /// A projected point is matched with the likeliest pixel with depth (file comment) within this
  /// radius [px], >= 0. Semi-dense depth lies on edges one or two pixels wide.
  int search_radius_px = 1;
  /// Pixels whose depth claims a larger relative standard deviation are not used [-], in (0, 1).
  /// By default the keyframe depth lookup's limit (KeyframeDepthOptions::max_relative_stddev),
  /// measured on real LSD-SLAM keyframes: pixels that claim more are often far wrong.
  double max_relative_stddev = KeyframeDepthOptions().max_relative_stddev;
  /// Every n-th usable pixel of the moving map's keyframes becomes a point [-], >= 1.
  int pixel_step = 6;
  /// Gauss-Newton iterations at most [-], >= 1; a direction still moving then is not converged
  /// (ICP_NOT_CONVERGED). The matches are re-made every iteration, and the estimate creeps to its
  /// fixed point with slowly shrinking steps in one direction: from the truth, 18 of the bench's
  /// worlds needed 5-42 iterations without extrapolation and 5-43 with it (docs/DESIGN.md).
  int max_iterations = 60;
  /// Cauchy kernel width in robust spreads of the whitened residuals [-], > 0.
  double kernel_width = 2.385;
  /// When the last two steps point the same way (cosine in the information's metric above
  /// kExtrapolationMinCosine) and shrink, take the rest of their geometric series at once (at most
  /// kExtrapolationMaxFactor times the step), as the ICP does (IcpOptions::extrapolation).
  bool extrapolation = true;
  /// Estimate the two maps' relative depth disagreement beyond their per-pixel noise (scale drift,
  /// distortion) from the depth residuals every iteration, and weigh the depth by it: each pixel's
  /// depth variance gains (rho z)^2, rho the smallest value for which the median squared whitened
  /// depth residual is a chi-square's with 1 DoF (0.455). rho is 0 where the depth residuals fit
  /// their per-pixel variance. Off: the per-pixel variance alone, under which two real LSD-SLAM maps
  /// slid 21-165 deg away (docs/DESIGN.md).
  bool depth_disagreement = true;
  /// Also compare each moving point's grey level with each fixed keyframe's image where it projects
  /// (bilinear, the image's gradient as Jacobian), with a brightness offset per keyframe pair and
  /// the noise measured from the differences every iteration. It needs no pixel with depth near the
  /// projection: on the real LSD-SLAM maps the depth and edge residuals alone let the estimate slide
  /// on, and with this it converges (docs/DESIGN.md).
  bool photometric = true;
  /// The images are smoothed by a Gaussian of this standard deviation before their grey levels and
  /// gradients are compared [px], >= 0: the gradient then reaches about that far beyond an edge. 1 px
  /// keeps the edges' own width (semi-dense depth lies on edges 1-2 px wide). Probes with 2 px: on
  /// the real maps 1.25 deg from the overlap truth instead of 1.33, on the bench's simulated worlds a
  /// median rotation error from the truth of 0.36 deg instead of 0.30 (docs/DESIGN.md).
  double photometric_blur_px = 1.0;
  /// The covariance adds the estimate's spread between re-runs that each leave out one keyframe (a
  /// delete-one-keyframe jackknife in the kept direction, one for each map's keyframes, summed): what
  /// a monocular map gets wrong keyframe by keyframe (its depth's scale, its pose's drift) is not
  /// per-pixel noise, and under the Gauss-Newton covariance alone the bench's worlds gave an ANEES
  /// of 150-1,300 (docs/DESIGN.md). Each map needs two keyframes with matches or more;
  /// otherwise the covariance holds no keyframe's error and ProjectiveResult::jackknifed is false.
  /// Costs one registration of one direction per keyframe with matches.
  bool jackknife = true;
  /// The jackknife's leave-outs use every n-th of the moving points [-], >= 1 (1: all of them): a
  /// trade of the covariance's fidelity for time. The leave-outs then start from the subsample's own
  /// estimate with every keyframe (one more registration), the same subsample in each, so the shift
  /// it makes is common to all and the spread, taken about the leave-outs' mean, does not hold it.
  /// What the subsample adds is its own noise in each leave-out, which on the whole widens the
  /// spread. Measured (make bench sections, docs/DESIGN.md): 2 kept the covariance's
  /// calibration and 4 made it too wide on the simulated worlds; on the real LSD-SLAM bags the merge with
  /// merge.projective_refinement took 9.6 s with 2 and 6.6-8.6 s with 4, against 11.5-12.7 s with 1
  /// (before the leave-outs ran side by side, which brought 1 to 10.0-10.1 s). The subsample leaves
  /// the estimate as it is.
  int jackknife_point_step = 1;
  /// The covariance also adds the difference δ between the two directions' estimates as a spread
  /// δδᵀ (without its cross terms, as the jackknife's). The moving points' own depth noise biases
  /// each direction differently (file comment), and that bias is shared by every keyframe, so the
  /// jackknife cannot see it; which direction is nearer the truth is not known, so the kept one may
  /// be off by as much as their difference. Applied when the other direction gave an estimate.
  bool direction_spread = true;
};

/// Every parameter of ProjectiveOptions: key, type, default (the member initialiser), range, unit, doc.
template <>
const ParamSchema<ProjectiveOptions>& paramSchema<ProjectiveOptions>();

/// @throw InputError naming the option when out of range
void validate(const ProjectiveOptions& options);

/// Outcome of registerProjective().
struct ProjectiveResult {
  /// kOk; kInvalidInput (no usable depth); kNotEnoughMatches; kIcpNotConverged (the kept direction
  /// still moved after max_iterations: estimate and covariance are filled, but not final)
  Status status = Status::kInvalidInput;
  std::string message;
  Sim3 estimate;                           ///< S_target_source
  /// Of δ about the estimate (similarity_fit.h): the Gauss-Newton covariance plus, when jackknifed,
  /// the keyframe jackknife's spread, plus the two directions' difference as a spread
  /// (direction_spread), each without its cross terms between the translation at the overlap's
  /// centre, the rotation and the log scale (blockDiagonalAt(), as the ICP's jackknife).
  Matrix7d covariance = Matrix7d::Zero();
  /// The Gauss-Newton normal matrix's inverse alone (per-residual noise only), for comparison.
  Matrix7d gauss_newton_covariance = Matrix7d::Zero();
  /// The covariance holds the keyframe jackknife (ProjectiveOptions::jackknife; false when a map has
  /// fewer than two keyframes with matches).
  bool jackknifed = false;
  /// Keyframes of the moving and of the fixed map left out whose registration gave an estimate, and
  /// of those, the ones still moving at max_iterations (kept, as the ICP's jackknife does).
  int jackknife_moving_keyframes = 0, jackknife_fixed_keyframes = 0, jackknife_not_converged = 0;
  /// The covariance holds the two directions' difference (ProjectiveOptions::direction_spread), whose
  /// rotation [deg] and log scale [-] are these.
  bool direction_spread = false;
  double direction_difference_deg = 0.0, direction_difference_scale = 0.0;
  /// Median squared Mahalanobis length of the whitened residual pairs at the estimate, under the
  /// two maps' per-pixel noise alone (without depth_disagreement) [-] (1.39 for a single residual
  /// pair that follows its noise model exactly; less, since each match is the likeliest of several
  /// pixels: 0.3-0.4 on the bench's worlds at the truth). The direction whose value is smaller is
  /// the one kept.
  double median_chi2 = 0.0;
  /// The two maps' relative depth disagreement rho at the estimate [-] (0 with the option off, or
  /// where the depth residuals fit their per-pixel noise; ProjectiveOptions::depth_disagreement).
  double depth_disagreement = 0.0;
  /// Grey-level comparisons at the estimate and their robust noise [grey levels] (0 without
  /// ProjectiveOptions::photometric).
  int photometric_rows = 0;
  double photometric_stddev = 0.0;
  int matches = 0;         ///< point-keyframe matches at the estimate
  bool reversed = false;   ///< the target's points moved into the source's keyframes, inverted
  int iterations = 0;
  int extrapolations = 0;  ///< iterations that took the rest of a creeping series at once
  /// The other direction's estimate and median chi-square, for the report [-].
  Sim3 other_estimate;
  double other_median_chi2 = 0.0;
};

/// @return true when every keyframe of the map has depth with a per-pixel standard deviation
bool hasDepthUncertainty(const AgentMap& map);

/**
 * @brief Registers the source map onto the target map by projective association of their
 * keyframes' semi-dense depth (file comment), both directions, from `initial`.
 * @param[in] source, target maps whose keyframes carry depth and depth_stddev (hasDepthUncertainty())
 * @param[in] initial S_target_source to start from
 * @return kInvalidInput when a map's keyframes have no depth with uncertainty; kNotEnoughMatches
 *   when neither direction finds 7 matches or more; kIcpNotConverged when the better direction
 *   still moved after max_iterations; else kOk with the better direction
 * @throw InputError on invalid options
 */
ProjectiveResult registerProjective(const AgentMap& source, const AgentMap& target, const Sim3& initial,
                                    const ProjectiveOptions& options = ProjectiveOptions());

}  // namespace pcr_pro
