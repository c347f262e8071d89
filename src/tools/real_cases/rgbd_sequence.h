// Real RGB-D frames with camera -> world poses, read from the real-data directory (never copied
// into the project): the 7-Scenes "redkitchen" frames and the slambook2 ch5 frames. See each data
// set's SOURCE.txt for where the data comes from and what its poses are worth.
#pragma once

#include <functional>
#include <map>
#include <opencv2/core.hpp>
#include <string>
#include <vector>

#include "pcr_pro/geometry/map_types.h"
#include "pcr_pro/geometry/sim3.h"

namespace pcr_pro {
namespace real_cases {

/// One RGB-D frame.
struct RgbdFrame {
  long id = 0;
  cv::Mat grey;   ///< CV_8UC1, the colour image converted to grey
  cv::Mat depth;  ///< CV_32FC1 depth along the optical axis [m], 0 = none
};

/// What a data set's own documentation says about its accuracy (its SOURCE.txt), used to state
/// the accuracy of the truth written with every case.
struct SequenceFacts {
  std::string data_set;                ///< folder name in the data directory
  double pose_rotation_deg = 0.0;      ///< stated accuracy of the camera -> world rotations [deg]
  double pose_translation_m = 0.0;     ///< stated accuracy of the camera -> world positions [m]
  double depth_colour_offset_m = 0.0;  ///< distance between the depth and colour cameras when the depth
                                       ///< is not registered to colour, else 0 [m]
  std::string note;                    ///< one line for the truth files
};

/// A sequence of RGB-D frames with poses; images are read when first asked for.
class RgbdSequence {
 public:
  using Loader = std::function<RgbdFrame(long id)>;

  RgbdSequence(PinholeCamera camera, std::map<long, Sim3> poses, SequenceFacts facts, Loader loader);

  const PinholeCamera& camera() const { return camera_; }
  const SequenceFacts& facts() const { return facts_; }
  /// @return the ids of every frame, in order
  std::vector<long> ids() const;
  /// @return camera -> world of frame id [m]; @throw InputError for an unknown id
  const Sim3& pose(long id) const;
  /// @return frame id, read on first use; @throw InputError for an unknown id or an unreadable file
  const RgbdFrame& frame(long id);

 private:
  PinholeCamera camera_;
  std::map<long, Sim3> poses_;
  SequenceFacts facts_;
  Loader loader_;
  std::map<long, RgbdFrame> cache_;
};

/**
 * @brief Opens DIR = <data>/7scenes_redkitchen: camera-intrinsics.txt and
 * frames/frame-NNNNNN.{color.jpg,depth.png,pose.txt} (ids = NNNNNN).
 * @throw InputError naming the file when the intrinsics or a pose cannot be read
 */
RgbdSequence openSevenScenes(const std::string& dir);

/**
 * @brief Opens DIR = <data>/slambook2_ch5_rgbd: color/i.png, depth/i.pgm and pose.txt
 * (tx ty tz qx qy qz qw per line, frame i = line i, from 1).
 * @throw InputError naming the file when pose.txt cannot be read
 */
RgbdSequence openSlambook2(const std::string& dir);

}  // namespace real_cases
}  // namespace pcr_pro
