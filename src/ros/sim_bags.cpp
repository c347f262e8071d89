#include "pcr_pro/ros/sim_bags.h"

#include <rosbag/bag.h>

#include <algorithm>

#include "pcr_pro/ros/msg_conversion.h"

namespace pcr_pro {
namespace ros_bridge {
namespace {

const ros::Time kStart(1600000000, 0);  // fixed time base: the bags are reproducible
// Seconds between messages of one bag: a played bag lasts (messages x kStep); at 0.1 s the demo
// world's bags (agent_a and agent_b) play in 1.7 s and 3.2 s.
const double kStep = 0.1;

LsdGraph graphMessage(const std::vector<std::pair<long, Sim3>>& poses, bool loop_closure) {
  LsdGraph g;
  g.poses = poses;
  for (std::size_t k = 1; k < poses.size(); ++k) {
    g.constraints.push_back({static_cast<int>(poses[k - 1].first), static_cast<int>(poses[k].first), 0.01f});
  }
  if (loop_closure && poses.size() > 2) {
    g.constraints.push_back({static_cast<int>(poses.back().first), static_cast<int>(poses.front().first), 0.01f});
  }
  return g;
}

}  // namespace

SimBagFiles writeSimulationBags(const std::string& dir, const Simulation& sim) {
  SimBagFiles files{dir + "/pcr_pro_two_agents.bag", dir + "/lsd_slam_two_agents.bag"};
  rosbag::Bag ours, lsd;
  try {
    ours.open(files.pcr_pro, rosbag::bagmode::Write);
  } catch (const rosbag::BagException& e) {
    throw InputError(files.pcr_pro + ": cannot write bag (" + e.what() + ")");
  }
  try {
    lsd.open(files.lsd_slam, rosbag::bagmode::Write);
  } catch (const rosbag::BagException& e) {
    throw InputError(files.lsd_slam + ": cannot write bag (" + e.what() + ")");
  }
  ours.setCompression(rosbag::compression::LZ4);
  lsd.setCompression(rosbag::compression::LZ4);
  ros::Time t_ours = kStart, t_lsd = kStart;  // each bag its own time line
  const auto next = [](ros::Time& t) { return t = t + ros::Duration(kStep); };
  // The pair of truth.yaml only: a node with the default agents subscribes to every topic of the
  // bags, so that `rosbag play --wait-for-subscribers` starts.
  const std::size_t agents = std::min<std::size_t>(2, sim.agents.size());
  for (std::size_t i = 0; i < agents; ++i) {
    const SimAgent& agent = sim.agents[i];
    const std::string ns = "/" + agent.name;
    const AgentMap& map = agent.map;
    ours.write(ns + "/cloud", next(t_ours), cloudToMsg(map.cloud, map.frame_id, t_ours));
    for (const MapKeyframe& kf : map.keyframes) {
      ours.write(ns + "/keyframes", next(t_ours), keyframeToMsg(kf, map.camera, map.frame_id, t_ours, true));
    }
    for (std::size_t k = 0; k < agent.keyframes.size(); ++k) {
      const LsdKeyframe kf = toLsdKeyframe(agent.keyframes[k], map.camera, static_cast<double>(k));
      lsd.write(ns + "/lsd_slam/keyframes", next(t_lsd), lsdKeyframeToMsg(kf));
      lsd.write(ns + "/lsd_slam/graph", next(t_lsd), lsdGraphToMsg(graphMessage(agent.graph_snapshots[k], false)));
    }
    lsd.write(ns + "/lsd_slam/graph", next(t_lsd), lsdGraphToMsg(graphMessage(agent.graph_snapshots.back(), true)));
  }
  ours.close();
  lsd.close();
  return files;
}

}  // namespace ros_bridge
}  // namespace pcr_pro
