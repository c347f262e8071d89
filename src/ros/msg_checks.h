// Checks shared by the message conversions (msg_image.cpp, msg_cloud.cpp, msg_pose.cpp,
// msg_lsd.cpp): private to the ROS layer, not installed.
#pragma once

#include <cmath>
#include <cstdint>
#include <sstream>
#include <string>

#include "pcr_pro/geometry/types.h"

namespace pcr_pro {
namespace ros_bridge {
namespace detail {

/// @throw InputError "<field>: <what>"
[[noreturn]] inline void fail(const std::string& field, const std::string& what) {
  throw InputError(field + ": " + what);
}

template <typename T>
std::string str(const T& v) {
  std::ostringstream s;
  s << v;
  return s.str();
}

// Largest image side accepted [px] (also for CameraInfo and LSD keyframes): keeps every size
// product in range of int and of 64-bit arithmetic.
constexpr std::uint32_t kMaxImageSide = 100000;
// Similarity poses: scale in [1/kMaxScale, kMaxScale], |translation| components <= kMaxTranslation;
// beyond that a pose is degenerate (it would put map points at infinity or on one point).
constexpr double kMaxScale = 1e9;
constexpr double kMaxTranslation = 1e9;

inline bool finite(double v) { return std::isfinite(v); }

// A translation within the pose bounds. @throw InputError naming `field`
inline void checkTranslation(double x, double y, double z, const std::string& field) {
  if (!finite(x) || !finite(y) || !finite(z)) fail(field, "must be finite");
  if (std::abs(x) > kMaxTranslation || std::abs(y) > kMaxTranslation || std::abs(z) > kMaxTranslation) {
    fail(field, "degenerate: a component beyond " + str(kMaxTranslation) + " map units");
  }
}

// A similarity scale within the pose bounds. @throw InputError naming `field`
inline void checkScale(double s, const std::string& field) {
  if (!finite(s) || !(s >= 1.0 / kMaxScale) || s > kMaxScale) {
    fail(field, "degenerate similarity: scale must be finite and in [1e-9, 1e9], got " + str(s));
  }
}

}  // namespace detail
}  // namespace ros_bridge
}  // namespace pcr_pro
