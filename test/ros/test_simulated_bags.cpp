// The simulator's bags (pcr_pro_simulate --bags, ros_bridge::writeSimulationBags) decode, with the
// node's own conversions (keyframeFromMsg, cloudFromMsg, lsdKeyframeFromMsg, lsdGraphFromMsg,
// AgentStore::toAgentMap), into the maps of the bundles: the pcr_pro bag exactly, the LSD-SLAM bag
// as the same semi-dense points after the LSD viewer's filters, and its graph messages correct the
// drift as the bundle's map poses say. rosbag API, no ROS master.
#include <gtest/gtest.h>
#include <rosbag/bag.h>
#include <rosbag/view.h>
#include <unistd.h>

#include <sys/wait.h>

#include <algorithm>
#include <cstdlib>
#include <filesystem>
#include <fstream>
#include <iterator>
#include <map>
#include <vector>

#include "common/bag_reading.h"
#include "pcr_pro/geometry/kdtree.h"
#include "pcr_pro/merge/agent_store.h"
#include "pcr_pro/ros/msg_conversion.h"
#include "pcr_pro/ros/sim_bags.h"
#include "pcr_pro/sim/simulator.h"

namespace fs = std::filesystem;

namespace pcr_pro {
namespace ros_bridge {
namespace {

using test::BagContents;

// Reads a bag as the node does; skip_final_graph leaves out each agent's last graph message (the
// loop closure): the one after as many graphs as keyframes.
BagContents readBag(const std::string& file, bool skip_final_graph = false) {
  if (!skip_final_graph) return test::readAgentBag(file);
  return test::readAgentBag(file, [](int keyframes, int graphs) { return !(graphs == keyframes && keyframes > 0); });
}

class SimulatedBags : public ::testing::Test {
 protected:
  static void SetUpTestSuite() {
    SimulatorOptions o;
    o.seed = 9;
    o.trajectory.max_keyframes = 3;
    o.drift.scale_drift = 0.04;
    o.drift.bend_deg = 3.0;
    o.drift.loop_closure = 0.6;
    sim_ = new Simulation(simulate(o));
    dir_ = new fs::path(fs::temp_directory_path() / ("pcr_pro_sim_bags_" + std::to_string(::getpid())));
    fs::create_directories(*dir_);
    files_ = new SimBagFiles(writeSimulationBags(dir_->string(), *sim_));
  }
  static void TearDownTestSuite() {
    std::error_code ec;
    fs::remove_all(*dir_, ec);
    delete files_;
    delete dir_;
    delete sim_;
  }
  static Simulation* sim_;
  static fs::path* dir_;
  static SimBagFiles* files_;
};
Simulation* SimulatedBags::sim_ = nullptr;
fs::path* SimulatedBags::dir_ = nullptr;
SimBagFiles* SimulatedBags::files_ = nullptr;

TEST_F(SimulatedBags, TopicsAndTiming) {
  const BagContents ours = readBag(files_->pcr_pro);
  const BagContents lsd = readBag(files_->lsd_slam);
  for (const SimAgent& a : sim_->agents) {
    const int n = static_cast<int>(a.keyframes.size());
    EXPECT_EQ(ours.messages.at("/" + a.name + "/cloud"), 1);
    EXPECT_EQ(ours.messages.at("/" + a.name + "/keyframes"), n);
    EXPECT_EQ(lsd.messages.at("/" + a.name + "/lsd_slam/keyframes"), n);
    EXPECT_EQ(lsd.messages.at("/" + a.name + "/lsd_slam/graph"), n + 1);
  }
  // A fixed time base and one message every 0.1 s in each bag.
  for (const BagContents* b : {&ours, &lsd}) {
    for (std::size_t i = 0; i < b->times.size(); ++i) {
      EXPECT_NEAR((b->times[i] - ros::Time(1600000000, 0)).toSec(), 0.1 * static_cast<double>(i + 1), 1e-6);
    }
  }
}

// Our format carries the bundle's map: the cloud to float32 precision, the poses exactly
// (float64), the depth to the millimetre of its 16UC1 encoding.
TEST_F(SimulatedBags, PcrProBagIsTheBundleMap) {
  const BagContents ours = readBag(files_->pcr_pro);
  for (const SimAgent& a : sim_->agents) {
    const AgentMap m = ours.stores.at(a.name).toAgentMap(LsdFilterOptions());
    ASSERT_EQ(m.cloud.cols(), a.map.cloud.cols());
    EXPECT_LE((m.cloud - a.map.cloud).cwiseAbs().maxCoeff(), a.map.cloud.cwiseAbs().maxCoeff() * std::pow(2.0, -23));
    ASSERT_EQ(m.keyframes.size(), a.map.keyframes.size());
    for (std::size_t k = 0; k < m.keyframes.size(); ++k) {
      EXPECT_EQ(m.keyframes[k].id, a.map.keyframes[k].id);
      EXPECT_LT((m.keyframes[k].pose.matrix() - a.map.keyframes[k].pose.matrix()).cwiseAbs().maxCoeff(), 1e-12);
      EXPECT_EQ(cv::norm(m.keyframes[k].image, a.map.keyframes[k].image, cv::NORM_INF), 0.0);
      cv::Mat diff;
      cv::absdiff(m.keyframes[k].depth, a.map.keyframes[k].depth, diff);
      double worst = 0.0;
      cv::minMaxLoc(diff, nullptr, &worst);
      EXPECT_LE(worst, 0.0005 + 1e-6);  // [m] half a millimetre
    }
  }
}

// The LSD-SLAM bag gives the points the LSD viewer's filters keep of the keyframes in memory
// (extractPoints on toLsdKeyframe, mapped by the final camToWorld): the same number, and every
// decoded point is one of the semi-dense points, mapped by its map pose, that the bundle's cloud
// is a random share of (to float32 precision: camToWorld and inverse depths travel as float32;
// 1e-5 of the cloud's extent is ~100 float steps). So the decoded cloud is the bundle's cloud
// up to the filters and the sampling, with the same noise.
TEST_F(SimulatedBags, LsdBagGivesTheBundleCloud) {
  const BagContents lsd = readBag(files_->lsd_slam);
  for (const SimAgent& a : sim_->agents) {
    const AgentMap m = lsd.stores.at(a.name).toAgentMap(LsdFilterOptions());
    ASSERT_EQ(m.keyframes.size(), a.keyframes.size());
    Eigen::Index expected = 0;
    std::vector<Eigen::Vector3d> all;
    for (std::size_t k = 0; k < a.keyframes.size(); ++k) {
      const SimKeyframe& kf = a.keyframes[k];
      expected += extractPoints(toLsdKeyframe(kf, a.map.camera, static_cast<double>(k)), LsdFilterOptions()).camera_points.cols();
      for (Eigen::Index i = 0; i < kf.semi_dense.points.cols(); ++i) {
        all.push_back(kf.map_pose.apply(Eigen::Vector3d(kf.semi_dense.points.col(i))));
      }
    }
    EXPECT_EQ(m.cloud.cols(), expected);
    Cloud all_cloud(3, static_cast<Eigen::Index>(all.size()));
    for (std::size_t i = 0; i < all.size(); ++i) all_cloud.col(static_cast<Eigen::Index>(i)) = all[i];
    const double extent = (all_cloud.rowwise().maxCoeff() - all_cloud.rowwise().minCoeff()).norm();
    const double eps2 = std::pow(1e-5 * extent, 2);
    const KdTree all_tree(all_cloud);
    Eigen::Index decoded_off = 0;
    for (Eigen::Index i = 0; i < m.cloud.cols(); ++i) {
      double d2 = 0.0;
      all_tree.nearest(m.cloud.col(i), &d2);
      decoded_off += d2 > eps2;
    }
    EXPECT_EQ(decoded_off, 0) << a.name << ": decoded LSD points that are no semi-dense point";
    const KdTree decoded(m.cloud);
    Eigen::Index bundle_in = 0;
    for (Eigen::Index i = 0; i < a.map.cloud.cols(); ++i) {
      double d2 = 0.0;
      decoded.nearest(a.map.cloud.col(i), &d2);
      bundle_in += d2 <= eps2;
    }
    std::printf("%s: %ld decoded LSD points of %zu semi-dense points; %.1f %% of the %ld bundle points are among them\n",
                a.name.c_str(), static_cast<long>(m.cloud.cols()), all.size(),
                100.0 * static_cast<double>(bundle_in) / static_cast<double>(a.map.cloud.cols()),
                static_cast<long>(a.map.cloud.cols()));
    EXPECT_GT(bundle_in, 0);
  }
}

// Keyframe messages carry the tracked (drifting) poses; the last graph message moves them to the
// bundle's map poses (loop_closure 0.6 of the way to the drift-free ones).
TEST_F(SimulatedBags, GraphUpdatesCorrectTheDrift) {
  const BagContents before = readBag(files_->lsd_slam, true);
  const BagContents after = readBag(files_->lsd_slam, false);
  const double float_tolerance = 1e-5;
  int moved = 0;
  for (const SimAgent& a : sim_->agents) {
    for (const SimKeyframe& kf : a.keyframes) {
      Sim3 b, c;
      ASSERT_TRUE(before.stores.at(a.name).keyframePose(kf.id, &b));
      ASSERT_TRUE(after.stores.at(a.name).keyframePose(kf.id, &c));
      const Sim3 unnormalise(1.0 / kf.lsd_scale, Eigen::Matrix3d::Identity(), Eigen::Vector3d::Zero());
      const Sim3 tracked = b * unnormalise, map = c * unnormalise;
      const double size = 1.0 + kf.map_pose.translation().norm();
      EXPECT_LT((tracked.matrix() - kf.tracked_pose.matrix()).cwiseAbs().maxCoeff(), float_tolerance * size);
      EXPECT_LT((map.matrix() - kf.map_pose.matrix()).cwiseAbs().maxCoeff(), float_tolerance * size);
      moved += (kf.tracked_pose.matrix() - kf.map_pose.matrix()).cwiseAbs().maxCoeff() > 100 * float_tolerance * size;
    }
  }
  EXPECT_GT(moved, 0) << "with drift, the loop closure must move keyframes";
}

// The tool: exit 2 with one line naming the option on bad input, 0 and the files otherwise.
struct ToolRun {
  int status = -1;
  std::string err;
};

ToolRun runTool(const std::string& args) {
  const fs::path err = fs::temp_directory_path() / ("pcr_pro_sim_tool_err_" + std::to_string(::getpid()));
  const int raw = std::system((std::string(PCR_PRO_SIMULATE_BIN) + " " + args + " > /dev/null 2> " + err.string()).c_str());
  ToolRun r;
  r.status = WIFEXITED(raw) ? WEXITSTATUS(raw) : -1;
  std::ifstream in(err);
  r.err.assign(std::istreambuf_iterator<char>(in), {});
  fs::remove(err);
  return r;
}

TEST(SimulateTool, BadInputIsOneLineAndExitTwo) {
  const fs::path out = fs::temp_directory_path() / ("pcr_pro_sim_tool_" + std::to_string(::getpid()));
  const std::vector<std::pair<std::string, std::string>> cases{
      {"", "--output"},
      {"--output " + out.string() + " --overlap 2", "--overlap 2: layout.overlap"},
      {"--output " + out.string() + " --overlap x", "--overlap"},
      {"--output " + out.string() + " --agents 0", "--agents"},
      {"--output " + out.string() + " --bend-deg 90", "drift.bend_deg"},
      {"--output " + out.string() + " --seed -4", "--seed"},
      {"--output " + out.string() + " --config /nonexistent/sim.yaml", "/nonexistent/sim.yaml"},
      {"--output " + out.string() + " --frobnicate", "--frobnicate"},
  };
  for (const auto& [args, named] : cases) {
    const ToolRun r = runTool(args);
    EXPECT_EQ(r.status, 2) << args;
    EXPECT_NE(r.err.find(named), std::string::npos) << args << " -> " << r.err;
    EXPECT_EQ(std::count(r.err.begin(), r.err.end(), '\n'), 1) << args << " -> " << r.err;
  }
  EXPECT_FALSE(fs::exists(out));
  EXPECT_EQ(runTool("--help").status, 0);
}

TEST(SimulateTool, WritesBundlesTruthAndBags) {
  const fs::path out = fs::temp_directory_path() / ("pcr_pro_sim_tool_ok_" + std::to_string(::getpid()));
  const fs::path config = fs::temp_directory_path() / ("pcr_pro_sim_tool_" + std::to_string(::getpid()) + ".yaml");
  std::ofstream(config) << "trajectory: {max_keyframes: 2}\n";
  const ToolRun r = runTool("--config " + config.string() + " --output " + out.string() + " --seed 3 --bags --quiet");
  ASSERT_EQ(r.status, 0) << r.err;
  for (const char* f : {"agent_a/bundle.yaml", "agent_b/map.pcd", "truth.yaml", "truth_agent_b_agent_a.yaml",
                        "simulation.yaml", "summary.yaml", "pcr_pro_two_agents.bag", "lsd_slam_two_agents.bag"}) {
    EXPECT_TRUE(fs::exists(out / f)) << f;
  }
  EXPECT_EQ(loadSimulatorConfig((out / "simulation.yaml").string()).seed, 3u);
  fs::remove_all(out);
  fs::remove(config);
}

}  // namespace
}  // namespace ros_bridge
}  // namespace pcr_pro
