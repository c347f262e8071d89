/**
 * @file bundle_writer.h
 * @brief Writing one agent's map as a map bundle (the format loadBundle() reads, see
 * docs/FORMATS.md) and the ground truth of a two-agent case (the format loadBundleTruth() reads).
 * Used by the simulator and by the builder of the real-data cases.
 */
#pragma once

#include <string>

#include "pcr_pro/geometry/map_types.h"
#include "pcr_pro/io/bundle.h"

namespace pcr_pro {

/// How writeBundle() stores an agent's map.
struct BundleWriteOptions {
  /// Write the keyframes' depth images (16-bit PNG) when they have one.
  bool write_depth = true;
  /// 16-bit depth value = round(depth [camera units] * depth_scale); 0 = chosen per keyframe so
  /// that its largest depth maps to about 60000 (the full 16-bit range, whatever the units) [1 / camera units], >= 0.
  double depth_scale = 0.0;
  /// A comment line at the top of bundle.yaml (without '#'); empty = none.
  std::string comment;
};

/**
 * @brief Writes DIR/bundle.yaml, DIR/map.pcd and DIR/keyframes/<id>.png (and <id>_depth.png),
 * creating DIR. Keyframe images are written as they are (8-bit grey); depths of 0, non-finite or
 * beyond the 16-bit range are written as 0 (unknown).
 * @param[in] dir bundle directory (created when missing)
 * @param[in] map the agent's map; keyframe ids must be unique
 * @param[in] options what to write
 * @throw InputError naming the file when it cannot be written, or the field of `map` at fault
 *   (invalid camera, empty or non-grey image, image size other than the camera's, duplicate id,
 *   invalid pose)
 */
void writeBundle(const std::string& dir, const AgentMap& map, const BundleWriteOptions& options = BundleWriteOptions());

/**
 * @brief Writes a truth.yaml that loadBundleTruth() reads back: target/source agent names,
 * overlap, S_target_source, world_to_target, world_to_source and world_poses.
 * @param[in] path file to write
 * @param[in] truth the truth
 * @param[in] comment text written as '#' comment lines at the top (may hold several lines)
 * @param[in] extra_yaml further top-level YAML written verbatim after the known keys (keys
 *   loadBundleTruth() ignores), e.g. per-keyframe truth; empty = none
 * @throw InputError naming the file when it cannot be written
 */
void writeBundleTruth(const std::string& path, const BundleTruth& truth, const std::string& comment = "",
                      const std::string& extra_yaml = "");

/// @return "{scale: s, rotation: [qx, qy, qz, qw], translation: [x, y, z]}" with 12 significant digits
std::string sim3FlowYaml(const Sim3& s);

/// @return a number as the bundle and truth writers write it: 12 significant digits
std::string yamlNumber(double v);

}  // namespace pcr_pro
