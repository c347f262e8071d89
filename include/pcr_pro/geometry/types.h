/**
 * @file types.h
 * @brief Basic types shared by every stage of the pcr_pro core: clouds, status codes, errors.
 */
#pragma once

#include <Eigen/Core>

#include <cstdint>
#include <stdexcept>
#include <string>

namespace pcr_pro {

/// Default seed of the core's random generators (the `seed` field of an options struct, the
/// node's `~seed`, the tools' `--seed`): every stage owns its generator, seeded from its options,
/// so equal inputs and seeds give bit-for-bit equal results.
inline constexpr std::uint64_t kDefaultSeed = 1;

/// A point cloud: one 3D point per column [map units].
using Cloud = Eigen::Matrix3Xd;
/// 6x6 pose covariance / information in the order (x, y, z, rot_x, rot_y, rot_z).
using Matrix6d = Eigen::Matrix<double, 6, 6>;
using Vector6d = Eigen::Matrix<double, 6, 1>;
using Matrix7d = Eigen::Matrix<double, 7, 7>;

/**
 * @brief Outcome of a registration stage or of the whole pipeline.
 * The names (see statusName()) are part of the result YAML contract.
 */
enum class Status {
  kOk,
  kNotEnoughMatches,
  kRelativePoseFailed,
  kScaleFailed,
  kIcpNotConverged,
  kDegenerate,
  kInvalidInput,
  kNoOverlap,  ///< the aligned maps share too little of their clouds: refused, not merged
  /// the keyframe evidence and the clouds contradict each other (merge_gates.h): refused, not merged
  kInconsistent,
};

/// @return the contract name of a status, e.g. "NOT_ENOUGH_MATCHES".
const char* statusName(Status status);

/**
 * @brief Parses a contract status name.
 * @param[in] name e.g. "OK"
 * @param[out] status the parsed status
 * @return false when the name is unknown
 */
bool parseStatus(const std::string& name, Status* status);

/**
 * @brief Bad input (file, field or value). what() is a one-line message that names the file
 * and/or field at fault, ready for the user.
 */
class InputError : public std::runtime_error {
 public:
  explicit InputError(const std::string& message) : std::runtime_error(message) {}
};

}  // namespace pcr_pro
