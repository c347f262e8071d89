/**
 * @file config.h
 * @brief Registration configuration: one options struct per stage, loaded from YAML
 * (config/icp.yaml), bound through each stage's parameter schema (io/param_schema.h). Missing
 * keys keep the struct default; unknown keys, keys given twice and out-of-range values are errors
 * that name the file, the key and its line.
 */
#pragma once

#include <string>

#include "pcr_pro/registration/covariance.h"
#include "pcr_pro/registration/filters.h"
#include "pcr_pro/registration/icp.h"
#include "pcr_pro/registration/scale_detection.h"

namespace pcr_pro {

/// Configuration of the geometric registration stages.
struct RegistrationOptions {
  ScaleDetectionOptions scale_detection;
  FilterChainOptions filters;
  IcpOptions icp;
  CovarianceOptions covariance;
};

/// @throw InputError naming the first invalid option
void validate(const RegistrationOptions& options);

/**
 * @brief Loads a registration configuration file.
 * @param[in] path YAML file with optional blocks scale_detection, filters, icp, covariance
 * @return the options, defaults for absent keys, validated
 * @throw InputError "<path>: <key>: <what is wrong> (line N)" for unreadable files, bad YAML,
 * unknown or duplicate keys, wrong types or out-of-range values
 */
RegistrationOptions loadRegistrationConfig(const std::string& path);

/**
 * @brief Same as loadRegistrationConfig() from YAML text (for tests and for ROS parameters).
 * @param[in] text YAML text
 * @param[in] origin name used in error messages (e.g. the file name)
 */
RegistrationOptions parseRegistrationConfig(const std::string& text, const std::string& origin);

}  // namespace pcr_pro
