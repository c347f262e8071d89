#include "pcr_pro/io/plausibility.h"

#include <cmath>
#include <sstream>
#include <tuple>

namespace pcr_pro {

std::string quaternionNormWarning(double norm, const std::string& field) {
  if (std::abs(norm - 1.0) <= kQuaternionNormTolerance) return "";
  std::ostringstream out;
  out.precision(9);
  out << field << ": quaternion norm " << norm << " is not 1 (|norm - 1| > " << kQuaternionNormTolerance
      << "); normalised";
  return out.str();
}

std::optional<std::pair<std::string, std::string>> implausibleIntrinsics(const PinholeCamera& camera) {
  auto text = [](double v) {
    std::ostringstream out;
    out.precision(9);
    out << v;
    return out.str();
  };
  for (const auto& [key, f] : {std::pair{"fx", camera.fx}, std::pair{"fy", camera.fy}}) {
    if (!(f >= 1.0)) return std::pair{std::string(key), "a focal length below one pixel (" + text(f) + " px): must be >= 1 px"};
  }
  for (const auto& [key, c, size, name] : {std::tuple{"cx", camera.cx, camera.width, "width"},
                                           std::tuple{"cy", camera.cy, camera.height, "height"}}) {
    if (!(c >= -size && c <= 2.0 * size)) {
      return std::pair{std::string(key), "principal point far outside the image (" + text(c) + " px): must be in [-" +
                                             std::string(name) + ", 2 " + name + "] = [" + std::to_string(-size) +
                                             ", " + std::to_string(2 * size) + "] px"};
    }
  }
  return std::nullopt;
}

}  // namespace pcr_pro
