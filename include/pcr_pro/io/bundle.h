/**
 * @file bundle.h
 * @brief Reading one agent's map bundle (the offline input of the merge, see docs/FORMATS.md
 * "Map bundle") and the ground truth of two-agent test cases (docs/FORMATS.md "Truth of a
 * two-agent case").
 */
#pragma once

#include <functional>
#include <map>
#include <string>
#include <vector>

#include "pcr_pro/io/input_limits.h"
#include "pcr_pro/io/param_schema.h"
#include "pcr_pro/geometry/map_types.h"
#include "pcr_pro/geometry/sim3.h"

namespace pcr_pro {

/**
 * @brief Reads one image file of a bundle as it is stored (8- or 16-bit, any channel count).
 * @param[in] path an existing regular file
 * @param[in] expected_size the camera's image size [px]; a reader that can tell the size from
 *   the file's header may refuse another size before it decodes (bounded memory)
 * @return the decoded image, never empty
 * @throw InputError "<path>: <what is wrong>" (loadBundle() appends the bundle field)
 */
using ImageFileReader = std::function<cv::Mat(const std::string& path, const cv::Size& expected_size)>;

/**
 * @brief The core's ImageFileReader: OpenCV's decoder (cv::imdecode, unchanged), with no
 * process-wide state (it neither captures nor redirects stderr, so it is safe in any thread). A
 * JPEG cut short (no end-of-image marker after its last scan), which libjpeg would decode with a
 * warning only, is refused. Decoders may still print their own warnings on stderr; the offline
 * tools pass a stricter reader of their own that captures them and walks PNG chunks.
 * @throw InputError "<path>: cannot read image[: reason]"
 */
cv::Mat decodeImageFile(const std::string& path, const cv::Size& expected_size);

/// The schema of a bundle's `camera` block (also the simulator configuration's): fx, fy, width,
/// height > 0 [px], cx, cy finite [px], every key required in a bundle.
template <>
const ParamSchema<PinholeCamera>& paramSchema<PinholeCamera>();

/**
 * @brief Reads a map bundle: DIR/bundle.yaml and the files it names (paths relative to DIR).
 *
 * Every field is validated: required keys present, unknown or duplicate keys rejected (catches
 * typos), types and list lengths, finite numbers, fx, fy, width, height > 0, non-zero
 * quaternions (normalised here), pose scale > 0, at least one keyframe, unique keyframe ids,
 * depth_scale > 0 and present whenever depth is, readable image and depth files of the camera's
 * size, depth a 16-bit single-channel image.
 *
 * Keyframe images become 8-bit grey (colour is converted). Depth images become CV_32FC1 holding
 * value / depth_scale [camera units]; 0 stays 0 (unknown). A keyframe without depth gets an empty
 * depth matrix. frame_id defaults to "map" and pose.scale to 1.
 *
 * Resource bounds (limits): more than limits.max_keyframes keyframes, a camera of more than
 * limits.max_image_pixels pixels or a cloud of more than limits.max_cloud_points points is refused
 * with an InputError naming the field and the limit; an image of another size than the camera's
 * is refused (before it is decoded when read_image can tell the size from the file's header).
 *
 * @param[in] dir bundle directory
 * @param[in] limits resource bounds
 * @param[in] read_image reads each keyframe and depth image file; empty: decodeImageFile()
 * @return the agent's map: frame id, map cloud [map units], camera, keyframes in file order
 * @throw InputError with a one-line message naming the file and the field at fault, e.g.
 *   "bundles/a/bundle.yaml: keyframes[2].pose.scale: must be > 0, got 0 (line 23)" or
 *   "bundles/a/keyframes/3.png: cannot read image (keyframes[0].image)". Errors of the map cloud
 *   are those of readCloud() followed by " (cloud)".
 * @param[out] warnings when given, one line per oddity that does not stop the reading, e.g.
 *   "bundles/a/bundle.yaml: keyframes[2].pose.orientation: quaternion norm 1.5 is not 1
 *   (|norm - 1| > 0.001); normalised (line 23)" (plausibility.h)
 */
AgentMap loadBundle(const std::string& dir, const InputLimits& limits = InputLimits(),
                    std::vector<std::string>* warnings = nullptr, const ImageFileReader& read_image = {});

/**
 * @brief Ground truth of a two-agent case (CASE/truth.yaml, written by writeBundleTruth(); see
 * docs/FORMATS.md for its keys and for how S_target_source is defined when the maps drift).
 */
struct BundleTruth {
  std::string target_agent = "agent_a";  ///< bundle directory name of the target agent
  std::string source_agent = "agent_b";  ///< bundle directory name of the source agent
  bool overlap = true;                   ///< false when no correct pipeline can merge the pair
  Sim3 target_source;                    ///< S_target_source: source map -> target map [target units]
  Sim3 world_to_target;                  ///< world (metres) -> target map
  Sim3 world_to_source;                  ///< world (metres) -> source map
  /// camera -> world pose of every frame used by the case, by keyframe id [m]
  std::map<long, Sim3> world_poses;
};

/**
 * @brief Reads a truth.yaml file.
 * @param[in] path file path
 * @return the parsed truth; keys it does not use (case, keyframes, note) are ignored
 * @throw InputError naming the file and field when the file is missing, malformed, or a
 *   transform is missing or invalid (non-finite, scale <= 0, zero quaternion)
 */
BundleTruth loadBundleTruth(const std::string& path);

}  // namespace pcr_pro
