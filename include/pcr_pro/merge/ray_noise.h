/**
 * @file ray_noise.h
 * @brief A map cloud's depth noise as the map itself shows it, for re-noising the cloud
 * (merge.renoise_draws; MapRegistration::setRayNoise()). A monocular SLAM map's points err along
 * the rays of the keyframes that measured them, Gaussian in inverse depth (LSD-SLAM's model).
 * Each point's ray is taken from its nearest keyframe centre; the noise's size is the map's own
 * measure of its depth noise, KeyframeDepth::projectedRelativeNoise(), read where the cloud is
 * dense enough for a lookup, so no setting carries a noise level.
 */
#pragma once

#include <cstdint>
#include <vector>

#include "pcr_pro/frontend/keyframe_depth.h"
#include "pcr_pro/geometry/map_types.h"
#include "pcr_pro/geometry/types.h"

namespace pcr_pro {

/// One map's ray noise model (measureRayNoise()).
struct RayNoise {
  Cloud centres;  ///< keyframe centres [map units] (3 x keyframes)
  /// Per keyframe: the inverse-depth standard deviation of the points nearest its centre,
  /// relative_noise / their mean distance from it [1 / map units].
  std::vector<double> inverse_depth_stddev;
  /// ρ: the median over the measured keyframes of KeyframeDepth::projectedRelativeNoise() (the
  /// keyframe's depth image set aside) [-]; 0 = not measured.
  double relative_noise = 0.0;
  int measured_keyframes = 0;  ///< keyframes whose projected cloud measured its noise
  /// @return true when the model can re-noise a cloud
  bool valid() const { return relative_noise > 0.0 && centres.cols() > 0; }
};

/**
 * @brief Measures a map's ray noise: ρ on at most `max_keyframes` keyframes spread evenly along
 * the map's keyframe list (each one's projection of the map cloud: KeyframeDepth with the depth
 * image set aside), and every keyframe's mean distance to the cloud points nearest its centre.
 * At the mean distance the relative depth noise is then ρ, and it grows with the distance as an
 * inverse-depth noise does. The result is not valid() when the map has no keyframes or no
 * keyframe's projection holds enough pixel pairs (KeyframeDepth::kMinNoisePairs).
 * @param[in] map the map (its cloud and keyframes, in map units)
 * @param[in] options the keyframe depth lookup's options (its neighbourhood is ρ's scale)
 * @param[in] max_keyframes keyframes measured, >= 1 (each costs one projection of the cloud)
 * @throw InputError when max_keyframes < 1, or as KeyframeDepth's constructor
 */
RayNoise measureRayNoise(const AgentMap& map, const KeyframeDepthOptions& options, int max_keyframes = 8);

/**
 * @brief The cloud with every point moved along the ray from its nearest centre of `noise`: its
 * inverse distance 1 / d plus σ n, σ that keyframe's inverse_depth_stddev and n a standard
 * normal draw (a draw that would put the point behind the centre leaves it where it is).
 * Deterministic for a given seed.
 * @param[in] cloud points [map units]
 * @param[in] noise a valid() model of the same map
 * @param[in] seed the random draw's seed
 * @throw InputError when the model is not valid()
 */
Cloud renoiseAlongRays(const Cloud& cloud, const RayNoise& noise, std::uint64_t seed);

}  // namespace pcr_pro
