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

/// One RGB-D frame, in the colour camera (RgbdSequence::camera()).
struct RgbdFrame {
  long id = 0;
  cv::Mat grey;  ///< CV_8UC1, the colour image converted to grey
  /// CV_32FC1 depth along the colour camera's optical axis [m], registered to grey: pixel (r, c)
  /// holds the depth of what grey shows at (r, c). 0 = none.
  cv::Mat depth;
};

/// What a data set's own documentation says about its accuracy (its SOURCE.txt), used to state
/// the accuracy of the truth written with every case.
struct SequenceFacts {
  std::string data_set;                ///< folder name in the data directory
  double pose_rotation_deg = 0.0;      ///< stated accuracy of the camera -> world rotations [deg]
  double pose_translation_m = 0.0;     ///< stated accuracy of the camera -> world positions [m]
  /// Distance between the depth and colour cameras that the registration of the depth to the
  /// colour image ignores (registerDepth() takes them as one centre), else 0 [m].
  double depth_colour_offset_m = 0.0;
  std::string note;                    ///< one line for the truth files
};

/**
 * @brief Registers a depth image to a colour image: every depth pixel is back-projected with the
 * depth camera's intrinsics and projected into the colour camera; where several land on one
 * colour pixel the nearest depth wins (z-buffer). The two cameras are taken to share their
 * centre and orientation (their extrinsic is not known for the data sets used here; see
 * SequenceFacts::depth_colour_offset_m). Colour pixels that no depth pixel lands on stay 0.
 * @param[in] depth CV_32FC1 depth [m] of depth_camera's size, 0 / non-finite = none
 * @param[in] depth_camera intrinsics the depth was measured with
 * @param[in] colour_camera intrinsics of the colour image
 * @return CV_32FC1 depth along the colour camera's axis [m] of colour_camera's size, 0 = none
 * @throw InputError when depth is not CV_32FC1 of depth_camera's size or a camera is invalid
 */
cv::Mat registerDepth(const cv::Mat& depth, const PinholeCamera& depth_camera, const PinholeCamera& colour_camera);

/// A sequence of RGB-D frames with poses; images are read when first asked for.
class RgbdSequence {
 public:
  using Loader = std::function<RgbdFrame(long id)>;

  /// @param[in] camera the colour camera (of the frames' grey images and registered depth)
  /// @param[in] depth_camera the camera the depth was measured with (== camera when the data's
  ///   depth is registered to colour)
  RgbdSequence(PinholeCamera camera, PinholeCamera depth_camera, std::map<long, Sim3> poses, SequenceFacts facts,
               Loader loader);

  /// @return the colour camera: intrinsics of every frame's grey image and registered depth
  const PinholeCamera& camera() const { return camera_; }
  /// @return the camera the depth images were measured with, before registerDepth()
  const PinholeCamera& depthCamera() const { return depth_camera_; }
  const SequenceFacts& facts() const { return facts_; }
  /// @return the ids of every frame, in order
  std::vector<long> ids() const;
  /// @return camera -> world of frame id [m]; @throw InputError for an unknown id
  const Sim3& pose(long id) const;
  /// @return frame id, read on first use; @throw InputError for an unknown id or an unreadable file
  const RgbdFrame& frame(long id);

 private:
  PinholeCamera camera_, depth_camera_;
  std::map<long, Sim3> poses_;
  SequenceFacts facts_;
  Loader loader_;
  std::map<long, RgbdFrame> cache_;
};

/**
 * @brief Opens DIR = <data>/7scenes_redkitchen: camera-intrinsics.txt (the depth camera's) and
 * frames/frame-NNNNNN.{color.jpg,depth.png,pose.txt} (ids = NNNNNN). The colour camera is the
 * one measured on these frames (see kSevenScenesColourFocal in the source); each frame's depth
 * is registered to its colour image with registerDepth().
 * @throw InputError naming the file when the intrinsics or a pose cannot be read
 */
RgbdSequence openSevenScenes(const std::string& dir);

/**
 * @brief Opens DIR = <data>/slambook2_ch5_rgbd: color/i.png, depth/i.pgm and pose.txt
 * (tx ty tz qx qy qz qw per line, frame i = line i, from 1). Its depth is registered to colour
 * already: one camera for both.
 * @throw InputError naming the file when pose.txt cannot be read
 */
RgbdSequence openSlambook2(const std::string& dir);

}  // namespace real_cases
}  // namespace pcr_pro
