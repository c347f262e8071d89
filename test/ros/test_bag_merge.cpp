// The generated demo world's bags (BUILD/sim/demo, written by the build's pcr_pro_simulate --bags:
// the bags demo.launch and the rostests play) decode into mergeable maps: every message is read
// with the rosbag API, converted like the node does (AgentStore per agent, LSD filters, graph
// updates) and merged with the core pipeline; the result must match the world's exact truth
// within its tolerance (test/common/sim_worlds.h). No ROS master.
#include <gtest/gtest.h>
#include <rosbag/bag.h>
#include <rosbag/view.h>

#include <cstdlib>
#include <map>

#include "common/bag_reading.h"
#include "common/sim_worlds.h"
#include "pcr_pro/io/bundle.h"
#include "pcr_pro/merge/merge_pipeline.h"
#include "pcr_pro/merge/agent_store.h"
#include "pcr_pro/ros/msg_conversion.h"

namespace pcr_pro {
namespace ros_bridge {
namespace {

std::string world(const std::string& file) { return test::simPath("demo/" + file); }

std::map<std::string, AgentStore> readBag(const std::string& file, bool apply_graph = true) {
  if (apply_graph) return test::readAgentBag(file).stores;
  return test::readAgentBag(file, [](int, int) { return false; }).stores;
}

// Merges agent_b into agent_a as the node would and measures the result against the truth.
TruthErrors mergeErrors(const std::map<std::string, AgentStore>& stores, MergeResult* result, const std::string& what) {
  *result = mergeMaps(stores.at("agent_b").toAgentMap(LsdFilterOptions()),
                      stores.at("agent_a").toAgentMap(LsdFilterOptions()), MergeRequest(), MergeOptions());
  if (result->report.status != Status::kOk || !result->report.transform) return TruthErrors();
  const TruthErrors e = compareWithTruth(*result->report.transform, loadBundleTruth(world("truth.yaml")).target_source,
                                         result->report.covariance, result->report.scale_stddev);
  const test::PairTolerance t = test::pairTolerance(world("truth.yaml"));
  std::printf("%s: rotation %.3f deg (< %.3f), translation %.4f (< %.4f), scale %.3f %% (< %.3f)\n", what.c_str(),
              e.rotation_deg, t.rotation_deg, e.translation, t.translation, e.scale_percent, t.scale_percent);
  EXPECT_TRUE(test::within(e, t)) << what;
  return e;
}

TEST(GeneratedBags, PcrProFormatMergesToTheTruth) {
  const auto stores = readBag(world("pcr_pro_two_agents.bag"));
  ASSERT_EQ(stores.size(), 2u);
  EXPECT_EQ(stores.at("agent_a").keyframeCount(), loadBundle(world("agent_a")).keyframes.size());
  EXPECT_EQ(stores.at("agent_b").keyframeCount(), loadBundle(world("agent_b")).keyframes.size());
  MergeResult r;
  mergeErrors(stores, &r, "pcr_pro bag");
  ASSERT_EQ(r.report.status, Status::kOk) << r.report.message;
}

TEST(GeneratedBags, LsdSlamFormatMergesToTheTruth) {
  const auto stores = readBag(world("lsd_slam_two_agents.bag"));
  ASSERT_EQ(stores.size(), 2u);
  const AgentMap b = stores.at("agent_b").toAgentMap(LsdFilterOptions());
  EXPECT_EQ(b.keyframes.size(), loadBundle(world("agent_b")).keyframes.size());
  // Every semi-dense pixel travels in the LSD keyframes: far more points than the bundle's cloud
  // (a 10 % share of them, config/simulator.yaml map.cloud_fraction) once the viewer's filters ran.
  EXPECT_GT(b.cloud.cols(), loadBundle(world("agent_b")).cloud.cols());
  std::printf("LSD bag: agent_a %ld points, agent_b %ld points after the viewer filters\n",
              static_cast<long>(stores.at("agent_a").toAgentMap(LsdFilterOptions()).cloud.cols()),
              static_cast<long>(b.cloud.cols()));
  MergeResult r;
  mergeErrors(stores, &r, "LSD bag");
  ASSERT_EQ(r.report.status, Status::kOk) << r.report.message;
}

TEST(GeneratedBags, LsdKeyframesNeedTheGraphPoses) {
  // The keyframe messages carry the tracked poses (with drift); the graph messages, the last one a
  // loop closure, move them to the bundle's map poses.
  const auto with = readBag(world("lsd_slam_two_agents.bag"), true);
  const auto without = readBag(world("lsd_slam_two_agents.bag"), false);
  // float32 camToWorld: 1e-5 of the map's size (~100 float steps)
  for (const std::string agent : {"agent_a", "agent_b"}) {
    const AgentMap bundle = loadBundle(world(agent));
    int moved = 0;
    for (const MapKeyframe& kf : bundle.keyframes) {
      Sim3 graph_pose, tracked_pose;
      ASSERT_TRUE(with.at(agent).keyframePose(kf.id, &graph_pose));
      ASSERT_TRUE(without.at(agent).keyframePose(kf.id, &tracked_pose));
      // LSD-SLAM's depth normalisation scales camToWorld on the right: rotation and position stay.
      const double size = 1.0 + kf.pose.translation().norm();
      EXPECT_LT(rotationDistance(graph_pose.rotation(), kf.pose.rotation()), 1e-5) << agent << " " << kf.id;
      EXPECT_LT((graph_pose.translation() - kf.pose.translation()).norm(), 1e-5 * size) << agent << " " << kf.id;
      moved += (tracked_pose.translation() - kf.pose.translation()).norm() > 100 * 1e-5 * size ||
               rotationDistance(tracked_pose.rotation(), kf.pose.rotation()) > 100 * 1e-5;
    }
    EXPECT_GT(moved, 0) << agent << ": with drift, the graph updates must move keyframes";
  }
}

}  // namespace
}  // namespace ros_bridge
}  // namespace pcr_pro
