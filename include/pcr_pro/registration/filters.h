/**
 * @file filters.h
 * @brief Point cloud filters and a configurable chain of them (crop, voxel grid, statistical
 * outlier removal, random sampling).
 */
#pragma once

#include <cstdint>
#include <string>
#include <vector>

#include "pcr_pro/geometry/types.h"
#include "pcr_pro/io/param_schema.h"

namespace pcr_pro {

/**
 * @brief PCR-Pro's crop: keep a fraction of the cloud along one axis, e.g. drop the sky side of
 * an outdoor cloud. Points are ranked by their coordinate on the axis.
 */
struct CropOptions {
  int axis = 1;                ///< 0 = x, 1 = y, 2 = z (map frame)
  double keep_fraction = 1.0;  ///< fraction of the points kept, in (0, 1] [-]
  bool keep_lower = true;      ///< keep the points with the lowest coordinates (else the highest)
};

/// Every parameter of CropOptions (filter step `crop`): key, type, default (the member initialiser), range, unit, doc.
template <>
const ParamSchema<CropOptions>& paramSchema<CropOptions>();

/// Voxel grid: one point (the centroid) per occupied voxel. voxelGridFilter() throws InputError
/// for a cloud with non-finite points or a leaf giving more than 2^52 voxels across the cloud.
struct VoxelGridOptions {
  double leaf_size = 0.0;  ///< voxel edge [cloud units]; 0 disables the filter
};

/// Every parameter of VoxelGridOptions (filter step `voxel_grid`): key, type, default (the member initialiser), range, unit, doc.
template <>
const ParamSchema<VoxelGridOptions>& paramSchema<VoxelGridOptions>();

/// Statistical outlier removal: drop points whose mean distance to their k neighbours is large.
struct OutlierRemovalOptions {
  int mean_k = 8;               ///< neighbours per point (>= 1)
  double stddev_multiplier = 2.0;  ///< threshold = mean + multiplier * stddev of the mean distances [-]
};

/// Every parameter of OutlierRemovalOptions (filter step `outlier_removal`): key, type, default (the member initialiser), range, unit, doc.
template <>
const ParamSchema<OutlierRemovalOptions>& paramSchema<OutlierRemovalOptions>();

/// Random sampling: keep each point with a fixed probability (deterministic seed).
struct RandomSamplingOptions {
  double keep_ratio = 1.0;  ///< fraction kept, in (0, 1] [-]
  uint32_t seed = 42;       ///< random seed
};

/// Every parameter of RandomSamplingOptions (filter step `random_sampling`): key, type, default (the member initialiser), range, unit, doc.
template <>
const ParamSchema<RandomSamplingOptions>& paramSchema<RandomSamplingOptions>();

/// Caps the number of points by uniform random subsampling (scale-free, unlike a voxel grid).
struct MaxPointsOptions {
  int max_points = 0;  ///< largest number of points kept; 0 disables the filter
  uint32_t seed = 42;  ///< random seed
};

/// Every parameter of MaxPointsOptions (filter step `max_points`): key, type, default (the member initialiser), range, unit, doc.
template <>
const ParamSchema<MaxPointsOptions>& paramSchema<MaxPointsOptions>();

/// One step of a filter chain.
struct FilterStep {
  enum class Type { kCrop, kVoxelGrid, kOutlierRemoval, kRandomSampling, kMaxPoints };
  Type type = Type::kVoxelGrid;
  CropOptions crop;
  VoxelGridOptions voxel_grid;
  OutlierRemovalOptions outlier_removal;
  RandomSamplingOptions random_sampling;
  MaxPointsOptions max_points;
};

/// A filter chain, applied in order. The default chain is empty (no filtering).
struct FilterChainOptions {
  std::vector<FilterStep> steps;
};

/// @return the name used in configuration files ("crop", "voxel_grid", ...)
const char* filterTypeName(FilterStep::Type type);

/// @throw InputError naming the option when out of range
void validate(const CropOptions& o);
void validate(const VoxelGridOptions& o);
void validate(const OutlierRemovalOptions& o);
void validate(const RandomSamplingOptions& o);
void validate(const MaxPointsOptions& o);
void validate(const FilterChainOptions& o);

Cloud cropFilter(const Cloud& cloud, const CropOptions& options);
Cloud voxelGridFilter(const Cloud& cloud, const VoxelGridOptions& options);
Cloud outlierRemovalFilter(const Cloud& cloud, const OutlierRemovalOptions& options);
Cloud randomSamplingFilter(const Cloud& cloud, const RandomSamplingOptions& options);
Cloud maxPointsFilter(const Cloud& cloud, const MaxPointsOptions& options);

/// The columns maxPointsFilter() keeps of a cloud of `size` points, in increasing order (all of
/// them when the filter is off or the cloud is small enough).
std::vector<Eigen::Index> maxPointsIndices(Eigen::Index size, const MaxPointsOptions& options);

/**
 * @brief Applies every step of the chain in order.
 * @return the filtered cloud (may be empty if the filters removed everything)
 * @throw InputError on invalid options
 */
Cloud applyFilterChain(const Cloud& cloud, const FilterChainOptions& options);

/**
 * @brief Whether the points of a filtered cloud all coincide: on every axis their spread is within
 * the rounding of single-precision coordinates (16 float epsilons of the largest coordinate, since
 * clouds usually come as floats: PCD, ROS messages), so the cloud has no shape to register.
 * @param name the cloud in the message, e.g. "source cloud"
 * @return why the cloud cannot be registered, or "" when its points do not all coincide (or it is empty)
 */
std::string coincidentPoints(const Cloud& cloud, const std::string& name);

}  // namespace pcr_pro
