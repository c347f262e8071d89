/**
 * @file scale_detection.h
 * @brief Scale detection (PCR-Pro §Scale Detection): compares robust 3D extents of two clouds.
 */
#pragma once

#include <Eigen/Core>

#include "pcr_pro/geometry/types.h"
#include "pcr_pro/io/param_schema.h"

namespace pcr_pro {

/// Options of the scale detection stage.
struct ScaleDetectionOptions {
  /// Fraction of the points trimmed at each end of every principal axis before measuring the
  /// extent, in [0, 0.45] [-]. Makes the extent robust to outliers.
  double trim_fraction = 0.05;
  /// A target/source size ratio above this (or below its inverse) flags a scale difference [-], > 1.
  double ratio_threshold = 1.2;
};

/// Every parameter of ScaleDetectionOptions (YAML block `scale_detection`): key, type, default (the member initialiser), range, unit, doc.
template <>
const ParamSchema<ScaleDetectionOptions>& paramSchema<ScaleDetectionOptions>();

/// @throw InputError naming the first option out of range
void validate(const ScaleDetectionOptions& options);

/// Robust extent of one cloud along its principal axes.
struct CloudExtent {
  Eigen::Vector3d centroid = Eigen::Vector3d::Zero();  ///< mean point [cloud units]
  Eigen::Matrix3d axes = Eigen::Matrix3d::Identity();  ///< principal axes as columns, largest first
  Eigen::Vector3d extents = Eigen::Vector3d::Zero();   ///< trimmed range along each axis [cloud units]
  double size = 0.0;                                   ///< norm of extents (trimmed diagonal) [cloud units]
};

/// Outcome of comparing two clouds.
struct ScaleDetectionResult {
  CloudExtent source;
  CloudExtent target;
  /// target size / source size: approximately the scale that maps source units to target units [-]
  double ratio = 1.0;
  /// true when ratio is outside [1/threshold, threshold]
  bool scale_difference_detected = false;
};

/**
 * @brief Robust extent of a cloud: PCA axes, then the trimmed range along each axis.
 * @param[in] cloud at least one point
 * @param[in] trim_fraction fraction trimmed at each end, in [0, 0.45]
 */
CloudExtent robustExtent(const Cloud& cloud, double trim_fraction);

/**
 * @brief Compares the extents of two clouds.
 * @throw InputError on empty clouds or invalid options
 */
ScaleDetectionResult detectScale(const Cloud& source, const Cloud& target, const ScaleDetectionOptions& options);

}  // namespace pcr_pro
