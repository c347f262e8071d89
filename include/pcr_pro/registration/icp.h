/**
 * @file icp.h
 * @brief ICP refinement chain in the spirit of libpointmatcher: k-d tree matching, maximum
 * distance and trimmed outlier rejection, point-to-point / point-to-plane minimisation with an
 * optional bounded scale update, counter and differential stop checks.
 */
#pragma once

#include <string>

#include "pcr_pro/geometry/sim3.h"
#include "pcr_pro/geometry/types.h"

namespace pcr_pro {

class KdTree;

/// Error minimised by the ICP step.
enum class ErrorMetric { kPointToPoint, kPointToPlane };

/// @return "point_to_point" or "point_to_plane"
const char* errorMetricName(ErrorMetric metric);
/// @return false when the name is unknown
bool parseErrorMetric(const std::string& name, ErrorMetric* metric);

/// The coarse level's differential check is this many times looser than the final one [-].
constexpr double kCoarseToleranceFactor = 10.0;

/// Options of the ICP chain; each block mirrors one stage of config/icp.yaml.
struct IcpOptions {
  // --- sampling
  /// The source is randomly subsampled (deterministic seed) to at most this many points before
  /// the iterations [points]; 0 = all. The target is always used whole.
  int max_source_points = 10000;
  /// Coarse-to-fine: the iterations first run on random subsets of the (sampled) source of
  /// this many points, then four times as many, ... (each level used while the sample has more
  /// than twice its size), each until the differential check passes at kCoarseToleranceFactor
  /// times the thresholds below; then on the whole sample. The counter check applies to each
  /// level [points]; 0 = one level.
  int coarse_source_points = 2000;
  // --- matcher
  int normal_neighbors = 10;  ///< neighbours used to estimate target normals (>= 3)
  // --- outlier rejection
  /// Correspondences farther apart than this are rejected [target units]; 0 = no limit.
  double max_correspondence_distance = 0.0;
  /// Fraction of the closest correspondences kept after the distance check, in (0, 1] [-].
  double trim_ratio = 0.8;
  // --- error minimisation
  ErrorMetric error_metric = ErrorMetric::kPointToPlane;
  /// Estimate a similarity (scale) instead of a rigid transform.
  bool estimate_scale = false;
  /// Largest relative scale change in one iteration, in (0, 1) [-].
  double max_scale_step = 0.1;
  /// Extrapolation: when successive steps point the same way and shrink, take the rest of
  /// their geometric series at once (Besl & McKay's acceleration), which saves most of the
  /// slow creeping iterations near convergence.
  bool extrapolation = true;
  /// The scale is kept inside [min_scale_ratio, max_scale_ratio] times the initial scale [-].
  double min_scale_ratio = 0.5;
  double max_scale_ratio = 2.0;
  // --- stop checks
  int max_iterations = 60;  ///< counter check
  /// Differential check: stop when the last step moved less than this fraction of the target
  /// cloud's RMS radius [-] ...
  double min_relative_translation_change = 1e-4;
  /// ... and rotated less than this [rad] ...
  double min_rotation_change = 1e-4;
  /// ... and changed the scale by less than this fraction [-].
  double min_scale_change = 1e-4;
  /// Fewer correspondences than this after rejection fails the registration.
  int min_correspondences = 10;
};

/// @throw InputError naming the option when out of range
void validate(const IcpOptions& options);

/// Correspondences at the final pose, as used for the fitness and the covariance.
struct Correspondences {
  Cloud source;          ///< matched source points, in the source frame [source units]
  Cloud target;          ///< matched target points, in the target frame [target units]
  /// Unit normals at the target points (from the target's k nearest neighbours); may be empty
  /// when built by hand, then the covariance estimates them on the matched targets.
  Cloud target_normals;
};

/// Outcome of an ICP run.
struct IcpResult {
  Status status = Status::kIcpNotConverged;
  std::string message;
  Sim3 transform;              ///< S_target_source
  double fitness_rmse = 0.0;   ///< RMS distance of the kept correspondences at the final pose [target units]
  int correspondences = 0;     ///< kept correspondences at the final pose
  bool converged = false;      ///< the differential check stopped the iterations
  int iterations = 0;
  Correspondences matches;     ///< final correspondences
};

/**
 * @brief Registers source onto target.
 * @param[in] source cloud in the source frame
 * @param[in] target cloud in the target frame
 * @param[in] initial initial guess of S_target_source
 * @param[in] options chain configuration
 * @return the result; status kOk when converged, kIcpNotConverged otherwise (too few
 *         correspondences, iteration limit, numerical failure) with a message
 * @throw InputError on invalid options or empty clouds
 */
IcpResult alignIcp(const Cloud& source, const Cloud& target, const Sim3& initial, const IcpOptions& options);

/// As above, on a k-d tree of the target built by the caller (tree.points() is the target),
/// for callers that query the target again afterwards.
IcpResult alignIcp(const Cloud& source, const KdTree& target_tree, const Sim3& initial, const IcpOptions& options);

/**
 * @brief Closed-form similarity (Umeyama) between paired points: dst ≈ s R src + t.
 * @param[in] with_scale estimate s; otherwise s = 1
 * @return the best transform in the least-squares sense
 */
Sim3 umeyama(const Cloud& src, const Cloud& dst, bool with_scale);

}  // namespace pcr_pro
