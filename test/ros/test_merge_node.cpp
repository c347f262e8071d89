// rostest integration tests of the merge node: bags played into the running node, messages
// published live, the ~merge service, the published edge / clouds / tf / diagnostics, and a
// refused start on a bad configuration. Which suite runs is chosen by the .test file
// (--gtest_filter).
#include <diagnostic_msgs/DiagnosticArray.h>
#include <gtest/gtest.h>
#include <ros/ros.h>
#include <rosbag/bag.h>
#include <rosbag/view.h>
#include <tf2_ros/buffer.h>
#include <tf2_ros/transform_listener.h>

#include <cstdio>
#include <map>
#include <mutex>
#include <sys/wait.h>

#include "pcr_pro/MergeMaps.h"
#include "pcr_pro/core/bundle.h"
#include "pcr_pro/ros/agent_store.h"
#include "pcr_pro/ros/msg_conversion.h"

namespace pcr_pro {
namespace ros_bridge {
namespace {

using Response = pcr_pro::MergeMaps::Response;
const std::string kDataDir = PCR_PRO_TEST_DATA_DIR;
const std::string kService = "merge_node/merge";
// Tolerances of test/unit/test_merge.cpp (the data's poses are good to about 1 deg / a few cm).
constexpr double kRotationTolDeg = 1.0, kScaleTol = 0.015, kTranslationTol = 0.12;

Sim3 truth() { return loadBundleTruth(kDataDir + "/bundles/depth/truth.yaml").target_source; }

void expectNear(const Sim3& est, const Sim3& expected, const std::string& what) {
  const double rot = rotationDistance(est.rotation(), expected.rotation()) * 180.0 / M_PI;
  const double scale = std::abs(est.scale() / expected.scale() - 1.0);
  const double trans = (est.translation() - expected.translation()).norm();
  std::printf("%s: rotation error %.3f deg, scale error %.3f %%, translation error %.4f\n", what.c_str(), rot,
              100.0 * scale, trans);
  EXPECT_LT(rot, kRotationTolDeg) << what;
  EXPECT_LT(scale, kScaleTol) << what;
  EXPECT_LT(trans, kTranslationTol) << what;
}

// Latest status of every diagnostics task, by name.
class DiagnosticsWatcher {
 public:
  explicit DiagnosticsWatcher(ros::NodeHandle& nh)
      : sub_(nh.subscribe("/diagnostics", 50, &DiagnosticsWatcher::onDiagnostics, this)) {}
  std::string value(const std::string& task, const std::string& key) {
    std::lock_guard<std::mutex> lock(mutex_);
    for (const auto& [name, status] : latest_) {
      if (name.size() < task.size() || name.compare(name.size() - task.size(), task.size(), task) != 0) continue;
      for (const auto& kv : status.values) {
        if (kv.key == key) return kv.value;
      }
    }
    return "";
  }
  /// Waits until value(task, key) == expected.
  bool waitFor(const std::string& task, const std::string& key, const std::string& expected, double seconds = 20.0) {
    const ros::WallTime end = ros::WallTime::now() + ros::WallDuration(seconds);
    while (ros::ok() && ros::WallTime::now() < end) {
      if (value(task, key) == expected) return true;
      ros::WallDuration(0.1).sleep();
    }
    return false;
  }

 private:
  void onDiagnostics(const diagnostic_msgs::DiagnosticArray::ConstPtr& msg) {
    std::lock_guard<std::mutex> lock(mutex_);
    for (const auto& s : msg->status) latest_[s.name] = s;
  }
  std::mutex mutex_;
  std::map<std::string, diagnostic_msgs::DiagnosticStatus> latest_;
  ros::Subscriber sub_;
};

// Keeps the latest message of a (latched) topic.
template <typename M>
class Latest {
 public:
  Latest(ros::NodeHandle& nh, const std::string& topic)
      : sub_(nh.subscribe<M>(topic, 2, [this](const typename M::ConstPtr& m) {
          std::lock_guard<std::mutex> lock(mutex_);
          msg_ = m;
        })) {}
  typename M::ConstPtr get() {
    std::lock_guard<std::mutex> lock(mutex_);
    return msg_;
  }
  typename M::ConstPtr waitNewerThan(const ros::Time& stamp, double seconds = 10.0) {
    const ros::WallTime end = ros::WallTime::now() + ros::WallDuration(seconds);
    while (ros::ok() && ros::WallTime::now() < end) {
      const auto m = get();
      if (m && m->header.stamp >= stamp) return m;
      ros::WallDuration(0.05).sleep();
    }
    return nullptr;
  }

 private:
  std::mutex mutex_;
  typename M::ConstPtr msg_;
  ros::Subscriber sub_;
};

// Waits until the node has taken every message of the bag (the player runs beside the test).
void waitForBag(const std::string& file, DiagnosticsWatcher& diagnostics) {
  std::map<std::string, int> counts;
  rosbag::Bag bag(file, rosbag::bagmode::Read);
  for (const rosbag::MessageInstance& m : rosbag::View(bag)) {
    ++counts[m.getTopic().substr(1, m.getTopic().find('/', 1) - 1)];
  }
  for (const auto& [agent, n] : counts) {
    ASSERT_TRUE(diagnostics.waitFor("agent " + agent, "messages_received", std::to_string(n), 90.0))
        << agent << ": the node did not receive the bag's " << n << " messages (has "
        << diagnostics.value("agent " + agent, "messages_received") << ")";
  }
}

Response callMerge(const std::string& source = "", const std::string& target = "", long source_kf = -1,
                   long target_kf = -1) {
  pcr_pro::MergeMaps srv;
  srv.request.source_agent = source;
  srv.request.target_agent = target;
  srv.request.source_keyframe = source_kf;
  srv.request.target_keyframe = target_kf;
  EXPECT_TRUE(ros::service::waitForService(kService, ros::Duration(30.0)));
  EXPECT_TRUE(ros::service::call(kService, srv));
  return srv.response;
}

// Reads a bag into agent stores, as the node does (for the expected cloud sizes).
std::map<std::string, AgentStore> readBag(const std::string& file) {
  std::map<std::string, AgentStore> stores;
  rosbag::Bag bag(file, rosbag::bagmode::Read);
  for (const rosbag::MessageInstance& m : rosbag::View(bag)) {
    const std::string agent = m.getTopic().substr(1, m.getTopic().find('/', 1) - 1);
    auto it = stores.emplace(agent, AgentStore(agent + "/map")).first;
    if (const auto kf = m.instantiate<pcr_pro::Keyframe>()) {
      const DecodedKeyframe d = keyframeFromMsg(*kf);
      it->second.setKeyframe(d.keyframe, d.camera);
    } else if (const auto cloud = m.instantiate<sensor_msgs::PointCloud2>()) {
      it->second.setCloud(cloudFromMsg(*cloud));
    } else if (const auto lsd = m.instantiate<lsd_slam_viewer::keyframeMsg>()) {
      it->second.setLsdKeyframe(lsdKeyframeFromMsg(*lsd));
    } else if (const auto graph = m.instantiate<lsd_slam_viewer::keyframeGraphMsg>()) {
      it->second.updateLsdPoses(lsdGraphFromMsg(*graph).poses);
    }
  }
  return stores;
}

// Checks a successful merge: edge vs truth, latched edge, fused / aligned clouds, tf.
void checkMergeOutputs(const Response& r, const Sim3& expected, std::size_t target_points, std::size_t source_points,
                       const std::string& what) {
  ros::NodeHandle nh;
  ASSERT_EQ(r.status, Response::OK) << r.status_name << ": " << r.message;
  EXPECT_EQ(r.status_name, "OK");
  const EdgeData edge = edgeFromMsg(r.edge);
  expectNear(edge.target_source, expected, what);
  EXPECT_EQ(r.edge.header.frame_id, "agent_a/map");
  EXPECT_EQ(r.edge.source_agent, "agent_b");
  EXPECT_EQ(r.edge.target_frame, "agent_a/map");
  EXPECT_EQ(r.edge.source_frame, "agent_b/map");
  EXPECT_GT(r.edge.scale_stddev, 0.0);
  EXPECT_GT(r.edge.correspondences, 100);
  EXPECT_GT(edge.covariance.diagonal().minCoeff(), 0.0);
  EXPECT_LT((edge.covariance * edge.information - Matrix6d::Identity()).norm(), 1e-3);

  Latest<pcr_pro::MapEdge> latched_edge(nh, "merge_node/edge");
  Latest<sensor_msgs::PointCloud2> fused(nh, "merge_node/fused_cloud");
  Latest<sensor_msgs::PointCloud2> aligned(nh, "merge_node/aligned_cloud");
  const auto e = latched_edge.waitNewerThan(r.edge.header.stamp);
  ASSERT_TRUE(e) << "no latched edge";
  EXPECT_EQ(e->scale, r.edge.scale);
  const auto f = fused.waitNewerThan(r.edge.header.stamp);
  ASSERT_TRUE(f) << "no fused cloud";
  EXPECT_EQ(f->header.frame_id, "agent_a/map");
  EXPECT_EQ(static_cast<std::size_t>(f->width) * f->height, target_points + source_points);
  const auto a = aligned.waitNewerThan(r.edge.header.stamp);
  ASSERT_TRUE(a) << "no aligned cloud";
  EXPECT_EQ(a->header.frame_id, "agent_b/map");
  EXPECT_EQ(static_cast<std::size_t>(a->width) * a->height, source_points);

  tf2_ros::Buffer buffer;
  tf2_ros::TransformListener listener(buffer);
  geometry_msgs::TransformStamped t;
  ASSERT_NO_THROW(t = buffer.lookupTransform("agent_a/map", "agent_b/map", ros::Time(0), ros::Duration(10.0)));
  const auto& tr = t.transform.translation;
  EXPECT_NEAR(tr.x, r.edge.pose.pose.position.x, 1e-9);
  EXPECT_NEAR(tr.y, r.edge.pose.pose.position.y, 1e-9);
  EXPECT_NEAR(tr.z, r.edge.pose.pose.position.z, 1e-9);
  const Eigen::Quaterniond q(t.transform.rotation.w, t.transform.rotation.x, t.transform.rotation.y,
                             t.transform.rotation.z);
  EXPECT_LT(rotationDistance(q.toRotationMatrix(), edge.target_source.rotation()), 1e-9);
  // aligned cloud + rigid tf overlays the fused cloud's source part: S(p) = R (s p) + t
  const Cloud aligned_points = cloudFromMsg(*a), fused_points = cloudFromMsg(*f);
  const Eigen::Vector3d via_tf = q * aligned_points.col(0) + Eigen::Vector3d(tr.x, tr.y, tr.z);
  EXPECT_LT((via_tf - fused_points.col(static_cast<Eigen::Index>(target_points))).norm(), 1e-3);
}

// --- merge_from_bag.test ------------------------------------------------------------------------

TEST(FromBag, MergesToTheTruthAndPublishesEdgeCloudsAndTf) {
  ros::NodeHandle nh;
  DiagnosticsWatcher diagnostics(nh);
  const std::string bag = kDataDir + "/bags/pcr_pro_two_agents.bag";
  const auto stores = readBag(bag);
  waitForBag(bag, diagnostics);
  const Response r = callMerge();
  checkMergeOutputs(r, truth(), stores.at("agent_a").cloudPoints(), stores.at("agent_b").cloudPoints(),
                    "pcr_pro bag through the node");
}

// --- merge_from_lsd_bag.test --------------------------------------------------------------------

TEST(FromLsdBag, MergesToTheTruthAndGraphUpdatesMoveKeyframes) {
  ros::NodeHandle nh;
  const std::string bag = kDataDir + "/bags/lsd_slam_two_agents.bag";
  const auto stores = readBag(bag);
  const LsdFilterOptions filters;
  const std::size_t a_points = static_cast<std::size_t>(stores.at("agent_a").toAgentMap(filters).cloud.cols());
  const std::size_t b_points = static_cast<std::size_t>(stores.at("agent_b").toAgentMap(filters).cloud.cols());
  DiagnosticsWatcher diagnostics(nh);
  waitForBag(bag, diagnostics);
  const Response r = callMerge();
  checkMergeOutputs(r, truth(), a_points, b_points, "LSD-SLAM bag through the node");
  ASSERT_EQ(r.status, Response::OK);

  // A pose-graph update that moves all of agent_b's keyframes by G: the merge must follow,
  // S_target_source' = S * G^-1.
  LsdGraph graph;
  {
    rosbag::Bag b(bag, rosbag::bagmode::Read);
    for (const rosbag::MessageInstance& m : rosbag::View(b, rosbag::TopicQuery("/agent_b/lsd_slam/graph"))) {
      graph = lsdGraphFromMsg(*m.instantiate<lsd_slam_viewer::keyframeGraphMsg>());
    }
  }
  ASSERT_EQ(graph.poses.size(), 2u);
  const Sim3 g(1.3, Eigen::Quaterniond(Eigen::AngleAxisd(0.5, Eigen::Vector3d(0.2, 1.0, -0.3).normalized())),
               Eigen::Vector3d(0.5, -0.2, 0.4));
  for (auto& [id, pose] : graph.poses) pose = g * pose;
  ros::Publisher pub = nh.advertise<lsd_slam_viewer::keyframeGraphMsg>("agent_b/lsd_slam/graph", 1, true);
  ASSERT_TRUE(diagnostics.waitFor("agent agent_b", "graph_updates", "1"));
  pub.publish(lsdGraphToMsg(graph));
  ASSERT_TRUE(diagnostics.waitFor("agent agent_b", "graph_updates", "2")) << "the graph update never arrived";
  EXPECT_EQ(diagnostics.value("agent agent_b", "keyframes"), "2");
  const Response moved = callMerge();
  ASSERT_EQ(moved.status, Response::OK) << moved.message;
  expectNear(edgeFromMsg(moved.edge).target_source, truth() * g.inverse(), "after the graph update");
}

// --- merge_node_live.test -----------------------------------------------------------------------

class Live : public ::testing::Test {
 protected:
  void SetUp() override {
    for (const std::string agent : {"agent_a", "agent_b"}) {
      keyframes_[agent] = nh_.advertise<pcr_pro::Keyframe>(agent + "/keyframes", 10);
      clouds_[agent] = nh_.advertise<sensor_msgs::PointCloud2>(agent + "/cloud", 10);
    }
    const ros::WallTime end = ros::WallTime::now() + ros::WallDuration(20.0);
    while (ros::WallTime::now() < end) {
      bool all = true;
      for (auto& [agent, pub] : keyframes_) all = all && pub.getNumSubscribers() > 0 && clouds_[agent].getNumSubscribers() > 0;
      if (all) break;
      ros::WallDuration(0.1).sleep();
    }
  }
  void publishAgent(const std::string& agent, const Sim3& moved = Sim3()) {
    AgentMap map = loadBundle(kDataDir + "/bundles/depth/" + agent);
    clouds_[agent].publish(cloudToMsg(moved.apply(map.cloud), map.frame_id, ros::Time::now()));
    for (MapKeyframe& kf : map.keyframes) {
      kf.pose = moved * kf.pose;
      keyframes_[agent].publish(keyframeToMsg(kf, map.camera, map.frame_id, ros::Time::now()));
    }
  }
  ros::NodeHandle nh_;
  std::map<std::string, ros::Publisher> keyframes_, clouds_;
};

TEST_F(Live, ServiceBeforeDataAnswersNoDataAndTheNodeStaysUp) {
  const Response r = callMerge();
  EXPECT_EQ(r.status, Response::NO_DATA);
  EXPECT_EQ(r.status_name, "NO_DATA");
  EXPECT_NE(r.message.find("agent_a"), std::string::npos) << r.message;
  const Response unknown = callMerge("agent_x");
  EXPECT_EQ(unknown.status, Response::UNKNOWN_AGENT);
  EXPECT_NE(unknown.message.find("agent_x"), std::string::npos) << unknown.message;
  EXPECT_EQ(callMerge("agent_a", "agent_a").status, Response::UNKNOWN_AGENT);
  EXPECT_TRUE(ros::service::exists(kService, false));
  EXPECT_EQ(callMerge().status, Response::NO_DATA);
}

TEST_F(Live, InvalidMessagesAreRejectedAndTheNodeKeepsServing) {
  DiagnosticsWatcher diagnostics(nh_);
  ASSERT_TRUE(diagnostics.waitFor("agent agent_a", "messages_rejected", "0"));
  const AgentMap map = loadBundle(kDataDir + "/bundles/depth/agent_a");
  sensor_msgs::PointCloud2 cloud = cloudToMsg(map.cloud, "agent_a/map", ros::Time::now());
  cloud.data.resize(cloud.data.size() - 5);  // width * height * point_step != data.size()
  clouds_["agent_a"].publish(cloud);
  pcr_pro::Keyframe kf = keyframeToMsg(map.keyframes[0], map.camera, "agent_a/map", ros::Time::now());
  kf.camera_info.K[0] = 0.0;  // zero intrinsics
  keyframes_["agent_a"].publish(kf);
  kf = keyframeToMsg(map.keyframes[0], map.camera, "agent_b/map", ros::Time::now());  // wrong frame
  keyframes_["agent_a"].publish(kf);
  EXPECT_TRUE(diagnostics.waitFor("agent agent_a", "messages_rejected", "3"));
  EXPECT_EQ(diagnostics.value("agent agent_a", "keyframes"), "0");
  EXPECT_EQ(callMerge().status, Response::NO_DATA);
}

TEST_F(Live, MergesAndAResentKeyframeIdReplacesTheOldOne) {
  DiagnosticsWatcher diagnostics(nh_);
  publishAgent("agent_a");
  publishAgent("agent_b");
  ASSERT_TRUE(diagnostics.waitFor("agent agent_a", "keyframe_ids", "1, 2, 4"));
  ASSERT_TRUE(diagnostics.waitFor("agent agent_b", "keyframe_ids", "3, 5"));
  ASSERT_TRUE(diagnostics.waitFor("agent agent_b", "messages_received", "3"));
  const Response first = callMerge();
  ASSERT_EQ(first.status, Response::OK) << first.message;
  expectNear(edgeFromMsg(first.edge).target_source, truth(), "live messages");

  // Re-send agent_b's keyframes (same ids) and cloud moved by G: they replace the old ones.
  const Sim3 g(0.5, Eigen::Quaterniond(Eigen::AngleAxisd(-0.7, Eigen::Vector3d(1.0, 0.1, 0.4).normalized())),
               Eigen::Vector3d(-1.0, 0.3, 0.8));
  publishAgent("agent_b", g);
  ASSERT_TRUE(diagnostics.waitFor("agent agent_b", "messages_received", "6"));
  EXPECT_EQ(diagnostics.value("agent agent_b", "keyframes"), "2");
  EXPECT_EQ(diagnostics.value("agent agent_b", "keyframe_ids"), "3, 5");
  const Response second = callMerge();
  ASSERT_EQ(second.status, Response::OK) << second.message;
  expectNear(edgeFromMsg(second.edge).target_source, truth() * g.inverse(), "re-sent keyframes");

  const Response given = callMerge("agent_b", "agent_a", 3, 2);
  ASSERT_EQ(given.status, Response::OK) << given.message;
  EXPECT_EQ(given.edge.source_keyframe, 3);
  EXPECT_EQ(given.edge.target_keyframe, 2);
  const Response unknown = callMerge("agent_b", "agent_a", 42, -1);
  EXPECT_EQ(unknown.status, Response::UNKNOWN_KEYFRAME);
  EXPECT_NE(unknown.message.find("42"), std::string::npos);
}

TEST(BadConfig, TheNodeRefusesToStartAndNamesTheKey) {
  const auto run = [](const std::string& name, const std::string& key_in_message) {
    std::string out;
    const std::string cmd = std::string(PCR_PRO_MERGE_NODE_BIN) + " __name:=" + name + " 2>&1";
    FILE* pipe = popen(cmd.c_str(), "r");
    ASSERT_NE(pipe, nullptr);
    char buffer[512];
    while (std::fgets(buffer, sizeof(buffer), pipe)) out += buffer;
    const int status = pclose(pipe);
    EXPECT_TRUE(WIFEXITED(status));
    EXPECT_EQ(WEXITSTATUS(status), 1) << out;
    EXPECT_NE(out.find(key_in_message), std::string::npos) << out;
  };
  ros::param::set("/bad_queue/queue_size", 0);
  run("bad_queue", "~queue_size");
  ros::param::set("/bad_frame/agent_b/frame_id", "/agent_b/map");
  run("bad_frame", "~agent_b/frame_id");
  ros::param::set("/bad_typo/publish_tff", true);
  run("bad_typo", "~publish_tff");
  ros::param::set("/bad_type/input", 3);
  run("bad_type", "~input");
  ros::param::set("/bad_file/merge_config", "/nonexistent/merge.yaml");
  run("bad_file", "~merge_config");
}

}  // namespace
}  // namespace ros_bridge
}  // namespace pcr_pro

int main(int argc, char** argv) {
  ::testing::InitGoogleTest(&argc, argv);
  ros::init(argc, argv, "merge_node_test");
  ros::AsyncSpinner spinner(2);
  spinner.start();
  const int result = RUN_ALL_TESTS();
  spinner.stop();
  ros::shutdown();
  return result;
}
