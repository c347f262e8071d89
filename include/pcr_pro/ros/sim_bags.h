/**
 * @file sim_bags.h
 * @brief The two ROS bags of a simulated world (pcr_pro_simulate --bags) with the topics a merge
 * node subscribes to, for agent_a and agent_b (the pair of truth.yaml): a fixed time base
 * (1600000000 s), the agents one after the other, one message every 0.1 s in each bag, so that
 * the demo world's bags play in a few seconds (demo.launch, the rostests).
 */
#pragma once

#include <string>

#include "pcr_pro/sim/simulator.h"

namespace pcr_pro {
namespace ros_bridge {

/// Names of the written bags.
struct SimBagFiles {
  std::string pcr_pro;   ///< DIR/pcr_pro_two_agents.bag
  std::string lsd_slam;  ///< DIR/lsd_slam_two_agents.bag
};

/**
 * @brief Writes, for each of the first two agents X (agent_a and agent_b; further agents are left
 * out, so that a node with the default agents subscribes to every topic of the bags):
 * - DIR/pcr_pro_two_agents.bag: `X/cloud` (sensor_msgs/PointCloud2, the map cloud, frame
 *   X/map), then `X/keyframes` (pcr_pro/Keyframe: grey image, CameraInfo, map pose and scale,
 *   the depth image of the bundle as 16UC1 in millimetres (REP 118; camera units are
 *   metres) when there is one);
 * - DIR/lsd_slam_two_agents.bag: per keyframe `X/lsd_slam/keyframes`
 *   (lsd_slam_viewer/keyframeMsg: every semi-dense pixel's normalised inverse depth and
 *   variance, the tracked camToWorld), each followed by `X/lsd_slam/graph`
 *   (lsd_slam_viewer/keyframeGraphMsg: the snapshot of every keyframe so far, constraints between
 *   consecutive keyframes), then the last graph (the loop closure: the map poses, and a
 *   constraint from the last keyframe to the first).
 * Both LZ4-compressed; deterministic.
 * @param[in] dir output directory (must exist)
 * @param[in] simulation simulate()'s result
 * @return the two file names
 * @throw InputError naming the bag that cannot be written
 */
SimBagFiles writeSimulationBags(const std::string& dir, const Simulation& simulation);

}  // namespace ros_bridge
}  // namespace pcr_pro
