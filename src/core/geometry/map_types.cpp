#include "pcr_pro/geometry/map_types.h"

#include <algorithm>
#include <cmath>

namespace pcr_pro {

bool PinholeCamera::valid() const {
  return std::isfinite(fx) && std::isfinite(fy) && std::isfinite(cx) && std::isfinite(cy) && fx > 0.0 && fy > 0.0 &&
         width > 0 && height > 0;
}

Eigen::Vector3d PinholeCamera::bearing(double u, double v) const {
  return Eigen::Vector3d((u - cx) / fx, (v - cy) / fy, 1.0).normalized();
}

bool PinholeCamera::project(const Eigen::Vector3d& p, double* u, double* v) const {
  if (!(p.z() > 0.0)) return false;
  *u = fx * p.x() / p.z() + cx;
  *v = fy * p.y() / p.z() + cy;
  return true;
}

std::map<long, long> keyframeRanks(const AgentMap& map) {
  std::vector<long> ids;
  ids.reserve(map.keyframes.size());
  for (const MapKeyframe& kf : map.keyframes) ids.push_back(kf.id);
  std::sort(ids.begin(), ids.end());
  std::map<long, long> rank;
  for (std::size_t i = 0; i < ids.size(); ++i) {
    if (i == 0 || ids[i] != ids[i - 1]) rank.emplace(ids[i], static_cast<long>(i));  // the first of equal ids
  }
  return rank;
}

}  // namespace pcr_pro
