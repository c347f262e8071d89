/**
 * @file report.h
 * @brief The registration result as reported by the offline tools (result YAML contract).
 */
#pragma once

#include <optional>
#include <string>

#include "pcr_pro/geometry/sim3.h"
#include "pcr_pro/geometry/types.h"

namespace pcr_pro {

/// Wall time of each stage [ms].
struct StageTimings {
  double features = 0.0;
  double relative_pose = 0.0;
  double scale = 0.0;  ///< scale detection (+ scale estimation in the merge pipeline)
  double filters = 0.0;
  double icp = 0.0;
  double covariance = 0.0;
  double total = 0.0;
};

/// Everything a registration reports. Optional parts are absent when the run stopped early.
struct RegistrationReport {
  Status status = Status::kInvalidInput;
  std::string message;
  std::optional<long> source_keyframe;
  std::optional<long> target_keyframe;
  std::optional<Sim3> transform;  ///< S_target_source
  std::optional<Matrix6d> covariance;
  std::optional<Matrix6d> information;
  std::optional<double> scale_stddev;
  std::optional<double> condition_number;
  std::optional<double> noise_stddev;
  std::optional<double> fitness_rmse;
  std::optional<int> correspondences;
  std::optional<bool> scale_difference_detected;
  std::optional<double> detected_scale_ratio;
  int icp_iterations = 0;
  StageTimings timings;
};

/// @return the report as the contract's result YAML (one document, keys in contract order)
std::string toYaml(const RegistrationReport& report);

}  // namespace pcr_pro
