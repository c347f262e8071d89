/**
 * @file quaternion_check.h
 * @brief The warning for an orientation quaternion read far from unit norm.
 */
#pragma once

#include <string>

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

}  // namespace pcr_pro
