// Streaming a bag of LSD-SLAM messages into a running merge node (input lsd_slam), as the rostests
// and the node benchmark (bench/bench_node.cpp) do: every message on its agent's topic in the
// bag's order, each once the node has taken the one before (its diagnostics' messages_received),
// so that none is lost or overtaken on the way. `rosbag play` into a loaded machine once lost a
// 3.7 MB keyframe and once delivered a graph before the keyframe it moves (two topics are two
// connections). Needs a ROS master and a spinner; no gtest, so that a benchmark can use it.
#pragma once

#include <lsd_slam_viewer/keyframeGraphMsg.h>
#include <lsd_slam_viewer/keyframeMsg.h>
#include <rosbag/bag.h>
#include <rosbag/view.h>
#include <ros/ros.h>

#include <algorithm>
#include <map>
#include <string>
#include <vector>

#include "common/diagnostics_watcher.h"

namespace pcr_pro {
namespace test {

/// Waits until `pub` has a subscriber (the node), so that nothing published is lost.
/// @return false after `seconds` [s] without one
inline bool waitForSubscriber(const ros::Publisher& pub, double seconds = 20.0) {
  const ros::WallTime end = ros::WallTime::now() + ros::WallDuration(seconds);
  while (ros::ok() && ros::WallTime::now() < end) {
    if (pub.getNumSubscribers() > 0) return true;
    ros::WallDuration(0.05).sleep();
  }
  return false;
}

/// What streamLsdBag() did.
struct LsdBagStream {
  std::map<std::string, int> messages;  ///< messages the node took, per agent
  std::string error;                    ///< why the stream stopped; empty when every message was taken
};

/**
 * @brief Publishes every LSD-SLAM keyframe and graph message of a bag, each once the node took the
 * one before; other topics (liveframes, poses) are skipped.
 * @param[in] file the bag
 * @param[in] diagnostics the node's diagnostics (its "agent X" tasks' messages_received)
 * @param[in] root_agent for a bag recorded in the root namespace as LSD-SLAM publishes
 *   (/lsd_slam/...), the agent whose namespace its messages go to; empty: the bag's topics are
 *   already /X/lsd_slam/...
 * @param[in] agents the node's agents (topics X/lsd_slam/keyframes and X/lsd_slam/graph)
 * @param[in] seconds_per_message how long the node may take to count a message [s]
 * @return the messages per agent, and the error that stopped the stream
 */
inline LsdBagStream streamLsdBag(const std::string& file, DiagnosticsWatcher& diagnostics,
                                 const std::string& root_agent = "",
                                 const std::vector<std::string>& agents = {"agent_a", "agent_b"},
                                 double seconds_per_message = 30.0) {
  ros::NodeHandle nh;
  std::map<std::string, ros::Publisher> publishers;
  std::map<std::string, long> received;
  for (const std::string& agent : agents) {
    publishers[agent + "/lsd_slam/keyframes"] =
        nh.advertise<lsd_slam_viewer::keyframeMsg>(agent + "/lsd_slam/keyframes", 5);
    publishers[agent + "/lsd_slam/graph"] = nh.advertise<lsd_slam_viewer::keyframeGraphMsg>(agent + "/lsd_slam/graph", 5);
    received[agent] = std::max(0L, diagnostics.number("agent " + agent, "messages_received"));
  }
  LsdBagStream out;
  for (const auto& [topic, pub] : publishers) {
    if (!waitForSubscriber(pub)) {
      out.error = topic + ": the node did not subscribe";
      return out;
    }
  }
  ros::WallDuration(0.5).sleep();  // the node's side of the connections
  rosbag::Bag bag(file, rosbag::bagmode::Read);
  for (const rosbag::MessageInstance& m : rosbag::View(bag)) {
    const std::string topic = root_agent.empty() ? m.getTopic().substr(1) : root_agent + m.getTopic();
    const std::string agent = topic.substr(0, topic.find('/'));
    if (publishers.count(topic) == 0) continue;  // e.g. liveframes or poses
    if (const auto kf = m.instantiate<lsd_slam_viewer::keyframeMsg>()) publishers.at(topic).publish(*kf);
    if (const auto graph = m.instantiate<lsd_slam_viewer::keyframeGraphMsg>()) publishers.at(topic).publish(*graph);
    const std::string expected = std::to_string(++received[agent]);
    if (!diagnostics.waitFor("agent " + agent, "messages_received", expected, seconds_per_message)) {
      out.error = file + ": " + topic + ": message " + std::to_string(out.messages[agent] + 1) +
                  " not received within " + std::to_string(seconds_per_message) + " s (the node has " +
                  diagnostics.value("agent " + agent, "messages_received") + ", rejected " +
                  diagnostics.value("agent " + agent, "messages_rejected") + ")";
      return out;
    }
    ++out.messages[agent];
  }
  return out;
}

}  // namespace test
}  // namespace pcr_pro
