// One simulated monocular-SLAM agent made from a window of real RGB-D frames: its keyframes, its
// LSD-like semi-dense map cloud fused from every frame of the window, its own map frame and scale,
// and a scale drift integrated along its path, with the exact local truth of every frame.
#pragma once

#include <cstdint>
#include <map>
#include <opencv2/core.hpp>
#include <string>
#include <vector>

#include "pcr_pro/geometry/map_types.h"
#include "pcr_pro/sim/semi_dense.h"
#include "real_cases/rgbd_sequence.h"

namespace pcr_pro {
namespace real_cases {

/// How to build one agent.
struct AgentSpec {
  std::string name;             ///< bundle directory name, e.g. "agent_a"
  std::vector<long> frames;     ///< the frames of the agent's window, in path order (>= 1)
  std::vector<long> keyframes;  ///< the frames that become keyframes, a subset of frames (>= 1)
  Sim3 world_to_map;            ///< world [m] -> map similarity at the first frame (the map's origin and scale)
  /// Relative change of the map scale from the first to the last frame, e.g. 0.02: the scale
  /// grows by 2 % along the path (integrated over the path length) [-], > -1.
  double scale_drift = 0.0;
  cv::Rect crop;                ///< the part of the images the agent sees; empty = the whole image
  SemiDenseOptions semi_dense;  ///< how each frame's semi-dense depth is sampled
  std::uint64_t seed = 0;       ///< seed of the semi-dense sampling (per frame: mixed with the frame id)
};

/// @throw InputError naming the field (agent name included) when the spec is invalid
void validate(const AgentSpec& spec);

/// A built agent and its truth.
struct BuiltAgent {
  /// The bundle content: camera = the colour camera; keyframe depth = the frame's measured depth
  /// registered to its colour image [m] (camera units).
  AgentMap map;
  /// G_k: world [m] -> map near frame k. With scale drift every frame has its own: neighbouring
  /// frames agree, far ones do not. camera -> map of frame k = G_k * camera_to_world[k].
  std::map<long, Sim3> world_to_map;
  std::map<long, Sim3> camera_to_world;  ///< true pose of every frame of the window [m]
  std::map<long, cv::Mat> depth;         ///< registered depth of every frame, cropped [m], 0 = none
  Cloud world_points;                    ///< the map cloud's points in the world frame [m]
  std::vector<long> point_frames;        ///< the frame each cloud point was sampled in
  double path_length_m = 0.0;            ///< length of the camera path over the window [m]
};

/**
 * @brief Semi-dense points of one frame, as LSD-SLAM would keep them: sampleSemiDense() on the
 * frame's depth with the pixels near a depth discontinuity removed first. Near such an edge a
 * colour pixel can see the other side of the edge than its depth pixel: within one pixel when the
 * registration knows the cameras' extrinsic, within f * offset / z pixels when it takes them as
 * one centre while the depth camera sits `offset` beside the colour camera (the parallax of that
 * baseline at depth z).
 * @param[in] grey CV_8UC1 image of the camera's size
 * @param[in] depth CV_32FC1 depth [m] registered to grey, of the camera's size, 0 = none
 * @param[in] camera intrinsics of grey and depth
 * @param[in] depth_colour_offset_m baseline between the depth and colour cameras that the
 *   registration ignored [m], >= 0
 * @param[in] options sampling options
 * @param[in] seed random seed
 * @return the sampled depth and points in the camera frame [m]
 */
SemiDenseKeyframe sampleFrame(const cv::Mat& grey, const cv::Mat& depth, const PinholeCamera& camera,
                              double depth_colour_offset_m, const SemiDenseOptions& options, std::uint64_t seed);

/**
 * @brief Builds an agent from a window of frames.
 * @param[in,out] sequence the frames (read on first use)
 * @param[in] spec the agent
 * @return the agent's map and its truth
 * @throw InputError on an invalid spec or unreadable frames
 */
BuiltAgent buildAgent(RgbdSequence& sequence, const AgentSpec& spec);

/// @return a 64-bit mix of a seed and a value (splitmix64 finaliser), for per-frame seeds
std::uint64_t mixSeed(std::uint64_t seed, std::uint64_t value);

}  // namespace real_cases
}  // namespace pcr_pro
