#include "pcr_pro/merge/ray_noise.h"

#include <algorithm>
#include <cmath>
#include <random>
#include <string>

#include "pcr_pro/geometry/kdtree.h"

namespace pcr_pro {

RayNoise measureRayNoise(const AgentMap& map, const KeyframeDepthOptions& options, int max_keyframes) {
  if (max_keyframes < 1)
    throw InputError("measureRayNoise: max_keyframes must be >= 1, got " + std::to_string(max_keyframes));
  RayNoise out;
  const std::size_t n = map.keyframes.size();
  if (n == 0 || map.cloud.cols() == 0) return out;
  out.centres.resize(3, static_cast<Eigen::Index>(n));
  for (std::size_t k = 0; k < n; ++k)
    out.centres.col(static_cast<Eigen::Index>(k)) = map.keyframes[k].pose.translation();

  // ρ from the cloud as each keyframe sees it projected: the depth image (when there is one) is
  // another sensor's noise, not the cloud's.
  std::vector<double> rhos;
  const std::size_t measured = std::min(n, static_cast<std::size_t>(max_keyframes));
  for (std::size_t i = 0; i < measured; ++i) {
    MapKeyframe keyframe = map.keyframes[i * n / measured];
    keyframe.depth = cv::Mat();
    keyframe.depth_stddev = cv::Mat();
    const double rho = KeyframeDepth(keyframe, map.camera, map.cloud, options).projectedRelativeNoise();
    if (rho > 0.0) rhos.push_back(rho);
  }
  out.measured_keyframes = static_cast<int>(rhos.size());
  if (rhos.empty()) return out;
  std::nth_element(rhos.begin(), rhos.begin() + static_cast<std::ptrdiff_t>(rhos.size() / 2), rhos.end());
  out.relative_noise = rhos[rhos.size() / 2];

  // Each keyframe's mean distance to the points nearest its centre: where ρ holds.
  const KdTree centres(out.centres);
  std::vector<double> sum(n, 0.0), count(n, 0.0);
  for (Eigen::Index i = 0; i < map.cloud.cols(); ++i) {
    double d2 = 0.0;
    const Eigen::Index k = centres.nearest(Eigen::Vector3d(map.cloud.col(i)), &d2);
    if (k < 0) continue;
    sum[static_cast<std::size_t>(k)] += std::sqrt(d2);
    count[static_cast<std::size_t>(k)] += 1.0;
  }
  // A keyframe nearest to no point (or only to points at its centre) takes the map's mean.
  double all_sum = 0.0, all_count = 0.0;
  for (std::size_t k = 0; k < n; ++k) all_sum += sum[k], all_count += count[k];
  const double map_mean = all_count > 0.0 ? all_sum / all_count : 0.0;
  out.inverse_depth_stddev.resize(n, 0.0);
  for (std::size_t k = 0; k < n; ++k) {
    const double mean = count[k] > 0.0 && sum[k] > 0.0 ? sum[k] / count[k] : map_mean;
    out.inverse_depth_stddev[k] = mean > 0.0 ? out.relative_noise / mean : 0.0;
  }
  if (!(map_mean > 0.0)) out.relative_noise = 0.0;  // every point at a keyframe centre: no rays
  return out;
}

Cloud renoiseAlongRays(const Cloud& cloud, const RayNoise& noise, std::uint64_t seed) {
  if (!noise.valid()) throw InputError("renoiseAlongRays: the ray noise model is not valid");
  const KdTree centres(noise.centres);
  std::mt19937_64 rng(seed);
  std::normal_distribution<double> normal(0.0, 1.0);
  Cloud out = cloud;
  for (Eigen::Index i = 0; i < cloud.cols(); ++i) {
    const Eigen::Vector3d p = cloud.col(i);
    double d2 = 0.0;
    const Eigen::Index k = centres.nearest(p, &d2);
    const double draw = normal(rng);  // drawn for every point, so that the draws do not shift
    if (k < 0 || !(d2 > 0.0)) continue;
    const double d = std::sqrt(d2);
    const double inverse = 1.0 / d + noise.inverse_depth_stddev[static_cast<std::size_t>(k)] * draw;
    if (!(inverse > 0.0)) continue;
    const Eigen::Vector3d c = noise.centres.col(k);
    out.col(i) = c + (p - c) * (1.0 / (inverse * d));
  }
  return out;
}

}  // namespace pcr_pro
