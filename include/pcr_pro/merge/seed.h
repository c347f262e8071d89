/**
 * @file seed.h
 * @brief One seed for every random stage of a merge configuration (the node's `~seed`, the tools'
 * `--seed`). Each stage owns its generator and takes its seed from its options; this sets them all.
 */
#pragma once

#include <cstdint>

#include "pcr_pro/merge/merge_pipeline.h"

namespace pcr_pro {

/// @brief Seeds the random steps of a filter chain (random_sampling, max_points) with the low 32 bits of `seed`.
inline void setSeed(FilterChainOptions* filters, std::uint64_t seed) {
  for (FilterStep& step : filters->steps) {
    step.random_sampling.seed = static_cast<std::uint32_t>(seed);
    step.max_points.seed = static_cast<std::uint32_t>(seed);
  }
}

/**
 * @brief Sets the seed of every randomised stage of a configuration: the descriptor index of the
 * keyframe matching, the relative pose RANSAC and the configured random filter steps
 * (random_sampling, max_points). The ICP's source sampling, the covariance calibration and the
 * keyframe stage's joint estimate (when it has more than 30 matches) draw from fixed seeds of
 * their own. Equal inputs, options and seed give bit-for-bit equal merges.
 * @param[in,out] options configuration to seed
 * @param[in] seed the seed [-]; the filter steps take its low 32 bits
 */
inline void setSeed(MergeOptions* options, std::uint64_t seed) {
  options->matching.seed = seed;
  options->relative_pose.seed = seed;
  setSeed(&options->registration.filters, seed);
}

}  // namespace pcr_pro
