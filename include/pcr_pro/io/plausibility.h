/**
 * @file plausibility.h
 * @brief Values read from files and messages that are well formed but no real sensor gives: an
 * orientation quaternion far from unit norm (a warning), implausible camera intrinsics (an error).
 */
#pragma once

#include <optional>
#include <string>
#include <utility>

#include "pcr_pro/geometry/map_types.h"

namespace pcr_pro {

/// Largest | ‖q‖ - 1 | of an orientation quaternion read from a file or a message that passes
/// without a warning: 1e-3 is far above float rounding (1e-7) and the 6 to 9 digits that files and
/// messages carry, so a larger deviation means the writer did not normalise (e.g. a scale folded in).
constexpr double kQuaternionNormTolerance = 1e-3;

/**
 * @brief The warning to give for an orientation quaternion far from unit norm (it is normalised
 * and used all the same).
 * @param[in] norm ‖q‖ of the quaternion as read
 * @param[in] field where it was read, e.g. "keyframes[2].pose.orientation"
 * @return "<field>: quaternion norm <norm> is not 1 (|norm - 1| > 0.001); normalised", or empty
 *   when |norm - 1| <= kQuaternionNormTolerance
 */
std::string quaternionNormWarning(double norm, const std::string& field);

/**
 * @brief Intrinsics no calibration gives: a focal length below one pixel, or a principal point
 * more than one image size outside the image (a unit or field mix-up: metres, normalised
 * coordinates, cx and width swapped). The image size must be set (> 0).
 * @param[in] camera fx, fy, cx, cy [px], width, height [px]
 * @return the first offending key ("fx", "fy", "cx" or "cy") and what is wrong with it, e.g.
 *   {"cy", "principal point far outside the image (2530.5 px): must be in [-height, 2 height] =
 *   [-480, 960] px"}; empty when the intrinsics are plausible
 */
std::optional<std::pair<std::string, std::string>> implausibleIntrinsics(const PinholeCamera& camera);

}  // namespace pcr_pro
