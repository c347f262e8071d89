// The shipped bags decode into mergeable maps: every message of test/data/bags is read with the
// rosbag API, converted like the node does (AgentStore per agent, LSD filters, graph updates)
// and merged with the core pipeline; the result must match the known truth. No ROS master.
#include <gtest/gtest.h>
#include <rosbag/bag.h>
#include <rosbag/view.h>

#include <cstdlib>
#include <map>

#include "pcr_pro/io/bundle.h"
#include "pcr_pro/merge/merge_pipeline.h"
#include "pcr_pro/merge/agent_store.h"
#include "pcr_pro/ros/msg_conversion.h"

namespace pcr_pro {
namespace ros_bridge {
namespace {

const std::string kDataDir = PCR_PRO_TEST_DATA_DIR;
// Tolerances of test/unit/test_merge.cpp (the data's poses are good to about 1 deg / a few cm).
constexpr double kRotationTolDeg = 1.0, kScaleTol = 0.015, kTranslationTol = 0.12;

std::map<std::string, AgentStore> readBag(const std::string& file, bool apply_graph = true) {
  std::map<std::string, AgentStore> stores;
  rosbag::Bag bag(file, rosbag::bagmode::Read);
  for (const rosbag::MessageInstance& m : rosbag::View(bag)) {
    const std::string topic = m.getTopic();
    const std::string agent = topic.substr(1, topic.find('/', 1) - 1);
    auto it = stores.emplace(agent, AgentStore(agent + "/map")).first;
    if (const auto kf = m.instantiate<pcr_pro::Keyframe>()) {
      const DecodedKeyframe d = keyframeFromMsg(*kf);
      EXPECT_EQ(d.frame_id, agent + "/map");
      it->second.setKeyframe(d.keyframe, d.camera);
    } else if (const auto cloud = m.instantiate<sensor_msgs::PointCloud2>()) {
      it->second.setCloud(cloudFromMsg(*cloud));
    } else if (const auto lsd = m.instantiate<lsd_slam_viewer::keyframeMsg>()) {
      it->second.setLsdKeyframe(lsdKeyframeFromMsg(*lsd));
    } else if (const auto graph = m.instantiate<lsd_slam_viewer::keyframeGraphMsg>()) {
      if (apply_graph) {
        EXPECT_GT(it->second.updateLsdPoses(lsdGraphFromMsg(*graph).poses), 0);
      }
    } else {
      ADD_FAILURE() << "unexpected message on " << topic;
    }
  }
  return stores;
}

struct Errors {
  double rotation_deg, scale_rel, translation;
};

Errors mergeErrors(const std::map<std::string, AgentStore>& stores, MergeResult* result) {
  const BundleTruth truth = loadBundleTruth(kDataDir + "/bundles/depth/truth.yaml");
  *result = mergeMaps(stores.at("agent_b").toAgentMap(LsdFilterOptions()), stores.at("agent_a").toAgentMap(LsdFilterOptions()),
                      MergeRequest(), MergeOptions());
  if (result->report.status != Status::kOk) return {1e9, 1e9, 1e9};
  const Sim3& s = *result->report.transform;
  const Sim3& t = truth.target_source;
  return {rotationDistance(s.rotation(), t.rotation()) * 180.0 / M_PI, std::abs(s.scale() / t.scale() - 1.0),
          (s.translation() - t.translation()).norm()};
}

TEST(ShippedBags, PcrProFormatMergesToTheTruth) {
  const auto stores = readBag(kDataDir + "/bags/pcr_pro_two_agents.bag");
  ASSERT_EQ(stores.size(), 2u);
  EXPECT_EQ(stores.at("agent_a").keyframeCount(), 3u);
  EXPECT_EQ(stores.at("agent_b").keyframeCount(), 2u);
  MergeResult r;
  const Errors e = mergeErrors(stores, &r);
  ASSERT_EQ(r.report.status, Status::kOk) << r.report.message;
  RecordProperty("rotation_error_deg", std::to_string(e.rotation_deg));
  std::printf("pcr_pro bag: rotation %.3f deg, scale %.4f %%, translation %.4f\n", e.rotation_deg, 100 * e.scale_rel,
              e.translation);
  EXPECT_LT(e.rotation_deg, kRotationTolDeg);
  EXPECT_LT(e.scale_rel, kScaleTol);
  EXPECT_LT(e.translation, kTranslationTol);
}

TEST(ShippedBags, LsdSlamFormatMergesToTheTruth) {
  const auto stores = readBag(kDataDir + "/bags/lsd_slam_two_agents.bag");
  ASSERT_EQ(stores.size(), 2u);
  const AgentMap b = stores.at("agent_b").toAgentMap(LsdFilterOptions());
  EXPECT_EQ(b.keyframes.size(), 2u);
  EXPECT_GT(b.cloud.cols(), 5000);
  std::printf("LSD bag: agent_a %ld points, agent_b %ld points after the viewer filters\n",
              static_cast<long>(stores.at("agent_a").toAgentMap(LsdFilterOptions()).cloud.cols()),
              static_cast<long>(b.cloud.cols()));
  MergeResult r;
  const Errors e = mergeErrors(stores, &r);
  ASSERT_EQ(r.report.status, Status::kOk) << r.report.message;
  std::printf("LSD bag: rotation %.3f deg, scale %.4f %%, translation %.4f\n", e.rotation_deg, 100 * e.scale_rel,
              e.translation);
  EXPECT_LT(e.rotation_deg, kRotationTolDeg);
  EXPECT_LT(e.scale_rel, kScaleTol);
  EXPECT_LT(e.translation, kTranslationTol);
}

TEST(ShippedBags, LsdKeyframesNeedTheGraphPoses) {
  // The bag's keyframe messages carry pre-optimisation poses; the graph message corrects them.
  const auto with = readBag(kDataDir + "/bags/lsd_slam_two_agents.bag", true);
  const auto without = readBag(kDataDir + "/bags/lsd_slam_two_agents.bag", false);
  Sim3 a, b;
  ASSERT_TRUE(with.at("agent_a").keyframePose(2, &a));
  ASSERT_TRUE(without.at("agent_a").keyframePose(2, &b));
  EXPECT_GT(rotationDistance(a.rotation(), b.rotation()) * 180.0 / M_PI, 1.0);
  // With the graph poses, the keyframes are those of the bundle (up to LSD's depth normalisation).
  const AgentMap bundle = loadBundle(kDataDir + "/bundles/depth/agent_a");
  for (const MapKeyframe& kf : bundle.keyframes) {
    Sim3 pose;
    ASSERT_TRUE(with.at("agent_a").keyframePose(kf.id, &pose));
    EXPECT_LT(rotationDistance(pose.rotation(), kf.pose.rotation()), 1e-6);
    EXPECT_LT((pose.translation() - kf.pose.translation()).norm(), 1e-5);
  }
}

}  // namespace
}  // namespace ros_bridge
}  // namespace pcr_pro
