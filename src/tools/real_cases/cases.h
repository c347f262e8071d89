// The real two-agent cases: which frames each agent gets, its frame, scale and drift, and
// writing each case (both agents' bundles, with and without depth images, and the truth).
#pragma once

#include <string>
#include <vector>

#include "real_cases/case_truth.h"
#include "real_cases/rgbd_sequence.h"

namespace pcr_pro {
namespace real_cases {

/// One written case, for the index and the summary.
struct CaseSummary {
  std::string path;  ///< relative to the output directory, e.g. "7scenes/overlap_460_900/depth"
  std::string data_set;
  bool overlap = false;
  bool depth_images = false;
  long reference_target = 0, reference_source = 0;  ///< the keyframe pair the case is built around
  double angle_deg = 0.0, distance_m = 0.0;         ///< of that pair
  double target_scale = 0.0, source_scale = 0.0;    ///< map units per metre at the first frame
  double target_drift = 0.0, source_drift = 0.0;    ///< relative scale change along the window
  long target_points = 0, source_points = 0;
  double target_seen_by_source = 0.0, source_seen_by_target = 0.0;
  TruthAccuracy accuracy;
};

/**
 * @brief Builds the 7-Scenes cases into OUTPUT/7scenes/<case>/{depth,nodepth}.
 * @param[in,out] sequence the 7scenes_redkitchen frames
 * @param[in] output output directory
 * @return one summary per written case directory
 * @throw InputError when a frame cannot be read, a case turns out ill-chosen, or writing fails
 */
std::vector<CaseSummary> buildSevenScenesCases(RgbdSequence& sequence, const std::string& output);

/**
 * @brief Builds the slambook2 cases into OUTPUT/slambook2/{depth,nodepth,nooverlap,sharedworld}.
 * @throw InputError as buildSevenScenesCases()
 */
std::vector<CaseSummary> buildSlambook2Cases(RgbdSequence& sequence, const std::string& output);

/// @return the YAML index of the cases (OUTPUT/index.yaml), documented in docs/FORMATS.md
std::string indexYaml(const std::vector<CaseSummary>& cases, const std::string& data_dir);

}  // namespace real_cases
}  // namespace pcr_pro
