#include "pcr_pro/io/quaternion_check.h"

#include <cmath>
#include <sstream>

namespace pcr_pro {

std::string quaternionNormWarning(double norm, const std::string& field) {
  if (std::abs(norm - 1.0) <= kQuaternionNormTolerance) return "";
  std::ostringstream out;
  out.precision(9);
  out << field << ": quaternion norm " << norm << " is not 1 (|norm - 1| > " << kQuaternionNormTolerance
      << "); normalised";
  return out.str();
}

}  // namespace pcr_pro
