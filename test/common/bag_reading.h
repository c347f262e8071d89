// Reading a bag of agent messages into per-agent stores with the node's own conversions
// (keyframeFromMsg, cloudFromMsg, lsdKeyframeFromMsg, lsdGraphFromMsg), for the ROS tests that
// need no ROS master. Every message must be one of the four kinds and carry its agent's frame.
#pragma once

#include <gtest/gtest.h>
#include <rosbag/bag.h>
#include <rosbag/view.h>

#include <functional>
#include <map>
#include <string>
#include <vector>

#include "pcr_pro/merge/agent_store.h"
#include "pcr_pro/ros/msg_conversion.h"

namespace pcr_pro {
namespace test {

/// The stores of a bag, one per agent (the first topic component), and what was in it.
struct BagContents {
  std::map<std::string, AgentStore> stores;
  std::map<std::string, int> messages;  ///< per topic
  std::vector<ros::Time> times;         ///< of every message, in bag order
};

/// Whether to apply an agent's LSD-SLAM graph message, given how many LSD keyframes and applied
/// graphs of that agent came before it.
using GraphFilter = std::function<bool(int keyframes_before, int graphs_applied_before)>;

/// Reads `file` as the node does; graph messages that `apply_graph` refuses are left out (all are
/// applied without it). Fails the test on an unexpected message, a keyframe of another frame or
/// a graph that updates no pose.
inline BagContents readAgentBag(const std::string& file, const GraphFilter& apply_graph = {}) {
  BagContents out;
  std::map<std::string, int> keyframes, graphs;
  rosbag::Bag bag(file, rosbag::bagmode::Read);
  for (const rosbag::MessageInstance& m : rosbag::View(bag)) {
    const std::string topic = m.getTopic();
    const std::string agent = topic.substr(1, topic.find('/', 1) - 1);
    ++out.messages[topic];
    out.times.push_back(m.getTime());
    auto it = out.stores.emplace(agent, AgentStore(agent + "/map")).first;
    if (const auto kf = m.instantiate<pcr_pro::Keyframe>()) {
      const ros_bridge::DecodedKeyframe d = ros_bridge::keyframeFromMsg(*kf);
      EXPECT_EQ(d.frame_id, agent + "/map");
      it->second.setKeyframe(d.keyframe, d.camera);
    } else if (const auto cloud = m.instantiate<sensor_msgs::PointCloud2>()) {
      it->second.setCloud(ros_bridge::cloudFromMsg(*cloud));
    } else if (const auto lsd = m.instantiate<lsd_slam_viewer::keyframeMsg>()) {
      it->second.setLsdKeyframe(ros_bridge::lsdKeyframeFromMsg(*lsd));
      ++keyframes[agent];
    } else if (const auto graph = m.instantiate<lsd_slam_viewer::keyframeGraphMsg>()) {
      if (apply_graph && !apply_graph(keyframes[agent], graphs[agent])) continue;
      ++graphs[agent];
      EXPECT_GT(it->second.updateLsdPoses(ros_bridge::lsdGraphFromMsg(*graph).poses), 0);
    } else {
      ADD_FAILURE() << "unexpected message on " << topic;
    }
  }
  return out;
}

}  // namespace test
}  // namespace pcr_pro
