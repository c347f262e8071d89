/**
 * @file parameter_tables.h
 * @brief The README's parameter tables, printed from the stages' schemas (param_schema.h), and
 * the check that the README holds them as printed.
 *
 * A generated section of a Markdown text stands between the lines `<!-- params:NAME -->` and
 * `<!-- /params:NAME -->`; `pcr_pro_params --update README.md` rewrites every such section.
 */
#pragma once

#include <string>
#include <utility>
#include <vector>

namespace pcr_pro {

/**
 * @brief The tables of the configuration files, one section per file.
 * @return (name, Markdown) pairs: "icp_yaml" (scale_detection, filters, icp, covariance) and
 * "merge_yaml" (matching, relative_pose, keyframe_depth, scale_estimation, merge, limits)
 */
std::vector<std::pair<std::string, std::string>> configParameterTables();

/**
 * @brief Replaces the text of every generated section of a Markdown text.
 * @param[in] text the Markdown text (e.g. the README)
 * @param[in] sections (name, Markdown) pairs; a section of the text without a pair is left as it is
 * @return the text with each named section's body replaced
 * @throw InputError when a section's start has no matching end
 */
std::string withParameterTables(const std::string& text,
                                const std::vector<std::pair<std::string, std::string>>& sections);

}  // namespace pcr_pro
