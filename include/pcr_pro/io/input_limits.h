/**
 * @file input_limits.h
 * @brief Resource bounds on what one agent's input may bring into memory (YAML block `limits`
 * of config/merge.yaml). The readers refuse input beyond a bound with an InputError that names
 * the file, the field and the limit, before they allocate for it.
 *
 * Worst-case memory of one loaded agent, from these bounds: about
 * 48 B x max_cloud_points (reading + the cloud) plus 5 B x max_image_pixels per keyframe (grey
 * 8-bit + depth float) x max_keyframes, plus the size of the cloud file while it is parsed.
 */
#pragma once

#include <cstdint>
#include "pcr_pro/io/param_schema.h"

namespace pcr_pro {

/// Hard ceiling of InputLimits::max_cloud_points [points].
constexpr std::int64_t kMaxCloudPointsCeiling = 200'000'000;

/// Resource bounds on the input of the merge and of the offline tools.
struct InputLimits {
  /// Most points in one input cloud (a bundle's map cloud, a pcr_pro_icp cloud) [points], in
  /// [1, kMaxCloudPointsCeiling]. A PCD whose header declares more, or a CSV with more rows, is
  /// refused (not subsampled: the filters chain's max_points / voxel_grid steps subsample).
  std::int64_t max_cloud_points = 10'000'000;
  /// Most keyframes in one bundle [-], >= 1.
  std::int64_t max_keyframes = 1000;
  /// Most pixels of the camera (width x height), hence of each keyframe and depth image [px], >= 1.
  std::int64_t max_image_pixels = 4096LL * 4096LL;
};

/// Every parameter of InputLimits (YAML block `limits`): key, type, default (the member initialiser), range, unit, doc.
template <>
const ParamSchema<InputLimits>& paramSchema<InputLimits>();

/// @throw InputError naming the first out-of-range bound ("limits.<key> must be ...")
void validate(const InputLimits& limits);

}  // namespace pcr_pro
