/**
 * @file sim3.h
 * @brief Similarity transform S = (s, R, t) mapping p' = s * R * p + t.
 */
#pragma once

#include <Eigen/Core>
#include <Eigen/Geometry>

#include "pcr_pro/geometry/types.h"

namespace pcr_pro {

/**
 * @brief A 3D similarity transform: p' = s * R * p + t.
 *
 * Composition follows the usual convention: (a * b).apply(p) == a.apply(b.apply(p)).
 */
class Sim3 {
 public:
  /// Identity.
  Sim3();
  /**
   * @param[in] scale s > 0 [-]
   * @param[in] rotation R, orthonormal with det +1
   * @param[in] translation t [target units]
   */
  Sim3(double scale, const Eigen::Matrix3d& rotation, const Eigen::Vector3d& translation);
  /// @param[in] q rotation as a quaternion (normalised here).
  Sim3(double scale, const Eigen::Quaterniond& q, const Eigen::Vector3d& translation);

  static Sim3 identity() { return Sim3(); }

  /**
   * @brief Builds a Sim3 from a 4x4 matrix [sR t; 0 1].
   * The scale is the cube root of det(sR); the rotation is the nearest rotation (SVD).
   * @throw InputError when the upper-left block is singular or a reflection, or the last row
   * is not (0 0 0 1).
   */
  static Sim3 fromMatrix(const Eigen::Matrix4d& m);

  /// @return the 4x4 matrix [sR t; 0 1].
  Eigen::Matrix4d matrix() const;

  double scale() const { return scale_; }
  const Eigen::Matrix3d& rotation() const { return rotation_; }
  const Eigen::Vector3d& translation() const { return translation_; }
  Eigen::Quaterniond quaternion() const { return Eigen::Quaterniond(rotation_); }

  /// @return s * R * p + t
  Eigen::Vector3d apply(const Eigen::Vector3d& p) const { return scale_ * (rotation_ * p) + translation_; }
  /// Applies the transform to every column of a cloud.
  Cloud apply(const Cloud& cloud) const;

  /// @return the inverse similarity: (1/s, Rᵀ, -Rᵀ t / s)
  Sim3 inverse() const;
  /// @return this ∘ other
  Sim3 operator*(const Sim3& other) const;

  /// @return rotation angle of R [rad]
  double rotationAngle() const;

 private:
  double scale_;
  Eigen::Matrix3d rotation_;
  Eigen::Vector3d translation_;
};

/// @return the angle of Ra * Rbᵀ [rad]
double rotationDistance(const Eigen::Matrix3d& ra, const Eigen::Matrix3d& rb);

/// @return skew-symmetric matrix [v]x such that [v]x w = v x w
Eigen::Matrix3d skew(const Eigen::Vector3d& v);

/// @return the rotation exp([w]x) (Rodrigues)
Eigen::Matrix3d expSO3(const Eigen::Vector3d& w);

/// @return the nearest rotation to a 3x3 matrix (SVD projection, det +1)
Eigen::Matrix3d projectToRotation(const Eigen::Matrix3d& m);

}  // namespace pcr_pro
