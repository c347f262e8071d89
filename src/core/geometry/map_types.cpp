#include "pcr_pro/geometry/map_types.h"

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

}  // namespace pcr_pro
