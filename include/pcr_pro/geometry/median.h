/**
 * @file median.h
 * @brief The medians the pipeline's robust scales are built on (one definition for every stage).
 */
#pragma once

#include <algorithm>
#include <cstddef>
#include <vector>

namespace pcr_pro {

/**
 * @brief The element of rank n / 2 of `values` (for an even count the larger of the two middle
 * ones), found by partial sorting: O(n), the values reordered. The robust spreads (1.4826 x the
 * median absolute deviation) of the ICP, the normals and the depth noise use it; the half-step
 * bias of an even count is below their own precision.
 * @return 0 when values is empty
 */
inline double upperMedian(std::vector<double>* values) {
  if (values->empty()) return 0.0;
  const auto mid = values->begin() + static_cast<std::ptrdiff_t>(values->size() / 2);
  std::nth_element(values->begin(), mid, values->end());
  return *mid;
}

/// upperMedian() of a copy.
inline double upperMedian(std::vector<double> values) { return upperMedian(&values); }

/**
 * @brief The median of `values`: the middle element, or the mean of the two middle ones for an
 * even count (for small samples, e.g. a few keyframe pairs' scales, where the two differ).
 * @return 0 when values is empty
 */
inline double median(std::vector<double> values) {
  if (values.empty()) return 0.0;
  const std::size_t mid = values.size() / 2;
  const double upper = upperMedian(&values);
  if (values.size() % 2 != 0) return upper;
  return 0.5 * (upper + *std::max_element(values.begin(), values.begin() + static_cast<std::ptrdiff_t>(mid)));
}

}  // namespace pcr_pro
