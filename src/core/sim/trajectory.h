// Internal to the simulator: camera paths and map drift (see simulator.h for the model).
#pragma once

#include <cstdint>
#include <vector>

#include "pcr_pro/geometry/sim3.h"
#include "pcr_pro/sim/simulator.h"
#include "pcr_pro/sim/world.h"

namespace pcr_pro {
namespace sim_detail {

/// Where an agent goes: its azimuth range and view angle (resolved from the options).
struct AgentPath {
  double azimuth_start_deg = 0.0;
  double azimuth_span_deg = 0.0;
  double view_angle_deg = 0.0;
  std::uint64_t seed = 0;  ///< of the wobble phases
};

/// The keyframe poses of a path.
struct PathKeyframes {
  std::vector<Sim3> poses;     ///< camera -> world, rigid [m]
  std::vector<double> motion;  ///< motion from the first keyframe [m] (translation + 0.5 m/rad * rotation)
};

/**
 * @brief The keyframes along an agent's path (a new one every keyframe_distance or
 * keyframe_angle_deg, at most max_keyframes).
 * @param[in] agent_field e.g. "per_agent[1]" for error messages
 * @throw InputError when a camera cannot be kept free (TrajectoryOptions::clearance)
 */
PathKeyframes keyframePath(const World& world, const TrajectoryOptions& options, const AgentPath& path,
                           const std::string& agent_field);

/// Estimated poses of one agent: drift built up along the path, per-keyframe noise, loop closure.
struct DriftedPoses {
  std::vector<Sim3> tracked;  ///< camera -> map as tracked
  std::vector<Sim3> map;      ///< camera -> map after the loop closure
};

/**
 * @brief Applies the drift model to the true poses.
 * @param[in] world_to_map the drift-free map frame
 * @param[in] scale_drift, bend_deg this agent's drift
 * @param[in] seed of the pose noise
 */
DriftedPoses driftPoses(const PathKeyframes& path, const Sim3& world_to_map, double scale_drift, double bend_deg,
                        const DriftOptions& options, std::uint64_t seed);

/// @return a pose component-wise between a (fraction 0) and b (fraction 1): geometric scale,
/// slerped rotation, linear translation
Sim3 interpolate(const Sim3& a, const Sim3& b, double fraction);

}  // namespace sim_detail
}  // namespace pcr_pro
