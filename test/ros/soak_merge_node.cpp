// Soak test of the merge node (test/ros/soak.test): two agents stream keyframes and map clouds
// (input pcr_pro) or LSD-SLAM keyframes and graphs (input lsd_slam) at several times LSD-SLAM's
// keyframe rate, with a share of invalid messages, while several clients call ~merge over and over,
// concurrently, for a bounded time. Checks: every call is answered with a status it may have, the
// node is alive at the end and still serving, its stores stay within their caps, and its resident
// memory (VmRSS of the node's process, found through the master and the node's XML-RPC getPid) does
// not grow once the caps are reached. Prints (and writes to ~report) the figures.
//
// Private parameters: seconds (60), keyframe_rate (10 Hz per agent), cloud_rate (2 Hz per agent;
// graph messages in lsd_slam mode), callers (3), bad_every (10: every 10th message invalid),
// rss_margin_mb (64), drain_seconds (240: how long outstanding calls may take once the streams
// stop), input (pcr_pro), node (/merge_node), report ("" = none).
#include <diagnostic_msgs/DiagnosticArray.h>
#include <gtest/gtest.h>
#include <ros/network.h>
#include <ros/ros.h>
#include <rosbag/bag.h>
#include <rosbag/view.h>
#include <signal.h>
#include <xmlrpcpp/XmlRpcClient.h>

#include <algorithm>
#include <atomic>
#include <chrono>
#include <cstdio>
#include <cstdlib>
#include <fstream>
#include <map>
#include <mutex>
#include <random>
#include <sstream>
#include <thread>

#include "common/diagnostics_watcher.h"
#include "common/ros_test_main.h"
#include "common/sim_worlds.h"
#include "pcr_pro/MergeMaps.h"
#include "pcr_pro/io/bundle.h"
#include "pcr_pro/ros/msg_conversion.h"

namespace pcr_pro {
namespace ros_bridge {
namespace {

using Response = pcr_pro::MergeMaps::Response;
using Clock = std::chrono::steady_clock;
// A file of the generated demo world (BUILD/sim/demo: agent_a target, agent_b source; exact truth).
std::string world(const std::string& file) { return test::simPath("demo/" + file); }

double secondsSince(Clock::time_point t) { return std::chrono::duration<double>(Clock::now() - t).count(); }

template <typename T>
T param(const std::string& name, T fallback) {
  T v = fallback;
  ros::param::param("~" + name, v, fallback);
  return v;
}

// The pid of a ROS node: master lookupNode, then the node's XML-RPC getPid (what rosnode uses).
int nodePid(const std::string& node) {
  XmlRpc::XmlRpcValue args, result, payload;
  args[0] = ros::this_node::getName();
  args[1] = node;
  if (!ros::master::execute("lookupNode", args, result, payload, true)) return -1;
  std::string host;
  std::uint32_t port = 0;
  if (!ros::network::splitURI(static_cast<std::string>(payload), host, port)) return -1;
  XmlRpc::XmlRpcClient client(host.c_str(), static_cast<int>(port), "/");
  XmlRpc::XmlRpcValue request, response;
  request[0] = ros::this_node::getName();
  if (!client.execute("getPid", request, response) || response.getType() != XmlRpc::XmlRpcValue::TypeArray ||
      response.size() < 3 || static_cast<int>(response[0]) != 1) {
    return -1;
  }
  return static_cast<int>(response[2]);
}

// A "VmRSS:" / "VmHWM:" line of /proc/PID/status [MB]; -1 when the process is gone.
double procStatusMb(int pid, const std::string& key) {
  std::ifstream in("/proc/" + std::to_string(pid) + "/status");
  std::string line;
  while (std::getline(in, line)) {
    if (line.compare(0, key.size(), key) == 0) return std::stod(line.substr(key.size())) / 1024.0;
  }
  return -1.0;
}

// Latest diagnostics values by (task suffix, key).
using Diagnostics = test::DiagnosticsWatcher;

// What one agent streams: good messages cycled with fresh keyframe ids, and invalid ones.
struct AgentStream {
  std::string name;
  std::vector<pcr_pro::Keyframe> keyframes;                 // pcr_pro mode
  std::vector<sensor_msgs::PointCloud2> clouds;             // pcr_pro mode: normal, denser than the cap
  std::vector<lsd_slam_viewer::keyframeMsg> lsd_keyframes;  // lsd_slam mode
  std::vector<Sim3> lsd_poses;
  std::atomic<long> sent_keyframes{0}, sent_clouds{0}, sent_bad{0};
  std::atomic<long> latest_id{-1};
};

Sim3 truth() { return loadBundleTruth(world("truth.yaml")).target_source; }

// The merge tests' tolerance for the world (test/common/sim_worlds.h: twice the spread of its
// keyframe pairs' local truths around the global one, which its drift makes).
const test::PairTolerance& tolerance() {
  static const test::PairTolerance t = test::pairTolerance(world("truth.yaml"));
  return t;
}

// The map cloud three times, jittered by 1 mm: denser than the soak's cap, so the node voxelises it.
Cloud densified(const Cloud& c) {
  Cloud d(3, 3 * c.cols());
  std::mt19937 rng(5);
  std::normal_distribution<double> jitter(0.0, 1e-3);
  for (int k = 0; k < 3; ++k) {
    for (Eigen::Index i = 0; i < c.cols(); ++i) {
      d.col(k * c.cols() + i) = c.col(i) + Eigen::Vector3d(jitter(rng), jitter(rng), jitter(rng));
    }
  }
  return d;
}

void preparePcrPro(AgentStream* a) {
  const AgentMap map = loadBundle(world(a->name));
  for (const MapKeyframe& kf : map.keyframes) {
    a->keyframes.push_back(keyframeToMsg(kf, map.camera, map.frame_id, ros::Time(0), true));
  }
  a->clouds.push_back(cloudToMsg(map.cloud, map.frame_id, ros::Time(0)));
  a->clouds.push_back(cloudToMsg(densified(map.cloud), map.frame_id, ros::Time(0)));
}

// The bag's LSD keyframes, each with the pose of the bag's last graph message (the keyframe
// messages carry LSD-SLAM's pose before its pose-graph optimisation; the graph corrects it), as
// LSD-SLAM re-publishes a keyframe once the graph has moved it.
void prepareLsd(AgentStream* a) {
  rosbag::Bag bag(world("lsd_slam_two_agents.bag"), rosbag::bagmode::Read);
  std::map<long, Sim3> graph_poses;
  for (const rosbag::MessageInstance& m : rosbag::View(bag, rosbag::TopicQuery("/" + a->name + "/lsd_slam/graph"))) {
    for (const auto& [id, pose] : lsdGraphFromMsg(*m.instantiate<lsd_slam_viewer::keyframeGraphMsg>()).poses) {
      graph_poses[id] = pose;
    }
  }
  for (const rosbag::MessageInstance& m :
       rosbag::View(bag, rosbag::TopicQuery("/" + a->name + "/lsd_slam/keyframes"))) {
    lsd_slam_viewer::keyframeMsg kf = *m.instantiate<lsd_slam_viewer::keyframeMsg>();
    const auto it = graph_poses.find(kf.id);
    const Sim3 pose = it != graph_poses.end() ? it->second : sim3FromLsd(kf.camToWorld.data());
    const std::array<float, 7> v = sim3ToLsd(pose);
    std::copy(v.begin(), v.end(), kf.camToWorld.begin());
    a->lsd_keyframes.push_back(kf);
    a->lsd_poses.push_back(pose);
  }
}

// Streams one agent until `stop`: keyframes at keyframe_rate with fresh ids (id + 1000 k), clouds
// (or LSD graphs) at cloud_rate, every bad_every-th message invalid (rotating through classes).
void stream(AgentStream* a, bool lsd, double keyframe_rate, double cloud_rate, int bad_every,
            const std::atomic<bool>& stop) {
  ros::NodeHandle nh;
  ros::Publisher kf_pub, cloud_pub;
  if (lsd) {
    kf_pub = nh.advertise<lsd_slam_viewer::keyframeMsg>(a->name + "/lsd_slam/keyframes", 20);
    cloud_pub = nh.advertise<lsd_slam_viewer::keyframeGraphMsg>(a->name + "/lsd_slam/graph", 20);
  } else {
    kf_pub = nh.advertise<pcr_pro::Keyframe>(a->name + "/keyframes", 20);
    cloud_pub = nh.advertise<sensor_msgs::PointCloud2>(a->name + "/cloud", 20);
  }
  const ros::WallTime wait_end = ros::WallTime::now() + ros::WallDuration(30.0);
  while (!stop && (kf_pub.getNumSubscribers() == 0 || cloud_pub.getNumSubscribers() == 0) &&
         ros::WallTime::now() < wait_end) {
    ros::WallDuration(0.05).sleep();
  }
  const int clouds_every = std::max(1, static_cast<int>(std::lround(keyframe_rate / cloud_rate)));
  ros::WallRate rate(keyframe_rate);
  std::vector<std::pair<long, Sim3>> recent;  // (id, pose) of the last keyframes, for LSD graphs
  long message = 0;
  for (long k = 0; !stop; ++k) {
    const std::size_t n = lsd ? a->lsd_keyframes.size() : a->keyframes.size();
    const std::size_t which = static_cast<std::size_t>(k) % n;
    const bool bad = bad_every > 0 && ++message % bad_every == 0;
    const int bad_class = static_cast<int>((message / std::max(1, bad_every)) % 3);
    const long base_id = lsd ? a->lsd_keyframes[which].id : a->keyframes[which].id;
    const long id = base_id + 1000 * (k / static_cast<long>(n) + 1);
    if (lsd) {
      lsd_slam_viewer::keyframeMsg m = a->lsd_keyframes[which];
      m.id = static_cast<std::int32_t>(id);
      if (bad) {
        if (bad_class == 0) m.pointcloud.resize(m.pointcloud.size() - 12);                    // not w * h * 12
        if (bad_class == 1) std::fill(m.camToWorld.begin(), m.camToWorld.begin() + 4, 0.0f);  // degenerate Sim3
        if (bad_class == 2) m.fx = 0.0f;                                                      // zero intrinsics
      } else {
        recent.emplace_back(id, a->lsd_poses[which]);
        if (recent.size() > 16) recent.erase(recent.begin());
      }
      kf_pub.publish(m);
    } else {
      pcr_pro::Keyframe m = a->keyframes[which];
      m.id = id;
      m.header.stamp = ros::Time::now();
      if (bad) {
        if (bad_class == 0) m.image.encoding = "yuv422";                                     // unsupported encoding
        if (bad_class == 1) m.camera_info.width /= 2;                                        // size vs CameraInfo
        if (bad_class == 2) std::fill(m.camera_info.P.begin(), m.camera_info.P.end(), 0.0);  // zero intrinsics (P, then K)
        if (bad_class == 2) std::fill(m.camera_info.K.begin(), m.camera_info.K.end(), 0.0);
      }
      kf_pub.publish(m);
    }
    (bad ? a->sent_bad : a->sent_keyframes)++;
    if (!bad) a->latest_id = id;
    if (k % clouds_every == 0) {
      const bool bad_cloud = bad_every > 0 && ++message % bad_every == 0;
      if (lsd) {
        LsdGraph g;
        g.poses = recent;
        lsd_slam_viewer::keyframeGraphMsg m = lsdGraphToMsg(g);
        if (bad_cloud) m.numFrames += 1;  // inconsistent count
        cloud_pub.publish(m);
      } else {
        sensor_msgs::PointCloud2 m = a->clouds[static_cast<std::size_t>(k / clouds_every) % a->clouds.size()];
        m.header.stamp = ros::Time::now();
        if (bad_cloud) m.data.resize(m.data.size() - 7);  // data size vs fields
        cloud_pub.publish(m);
      }
      (bad_cloud ? a->sent_bad : a->sent_clouds)++;
    }
    rate.sleep();
  }
}

struct CallStats {
  std::mutex mutex;
  long calls = 0, answered = 0, unexpected = 0, ok_within_tolerance = 0;
  std::map<std::string, long> by_status;
  double max_latency = 0.0, sum_latency = 0.0;
  double worst_rotation_deg = 0.0, worst_scale = 0.0, worst_translation = 0.0;
  std::vector<std::string> problems;
};

// Calls ~merge over and over until `stop`; request kinds rotate: default pair (must be OK), the
// latest keyframe ids (may have been dropped meanwhile, or not overlap), an unknown agent, default again.
void callMerges(int caller, AgentStream* a, AgentStream* b, const std::atomic<bool>& stop, CallStats* stats,
                const std::string& service) {
  const Sim3 expected = truth();
  for (long i = caller; !stop; ++i) {
    pcr_pro::MergeMaps srv;
    const int kind = static_cast<int>(i % 4);
    if (kind == 1) {
      srv.request.use_source_keyframe = srv.request.use_target_keyframe = true;
      srv.request.source_keyframe = b->latest_id;
      srv.request.target_keyframe = a->latest_id;
    }  // otherwise an empty request: the pipeline chooses the pair
    if (kind == 2) srv.request.source_agent = "agent_z";
    const auto t0 = Clock::now();
    const bool answered = ros::service::call(service, srv);
    const double latency = secondsSince(t0);
    std::lock_guard<std::mutex> lock(stats->mutex);
    ++stats->calls;
    if (!answered) {
      stats->problems.push_back("call " + std::to_string(i) + " not answered");
      continue;
    }
    ++stats->answered;
    stats->max_latency = std::max(stats->max_latency, latency);
    stats->sum_latency += latency;
    const auto& r = srv.response;
    ++stats->by_status[r.status_name];
    bool allowed = false;
    if (kind == 2) allowed = r.status == Response::UNKNOWN_AGENT;
    // A given keyframe pair: it may have been dropped meanwhile, or not overlap enough (any stage).
    if (kind == 1) allowed = r.status != Response::UNKNOWN_AGENT && r.status != Response::INVALID_INPUT;
    if (kind == 0 || kind == 3) allowed = r.status == Response::OK;
    if (!allowed) {
      ++stats->unexpected;
      stats->problems.push_back("call kind " + std::to_string(kind) + ": " + r.status_name + ": " + r.message);
    }
    if (r.status == Response::OK) {
      const EdgeData e = edgeFromMsg(r.edge);
      const TruthErrors err = compareWithTruth(e.target_source, expected, std::nullopt, std::nullopt);
      stats->worst_rotation_deg = std::max(stats->worst_rotation_deg, err.rotation_deg);
      stats->worst_scale = std::max(stats->worst_scale, std::abs(err.scale_percent) / 100.0);
      stats->worst_translation = std::max(stats->worst_translation, err.translation);
      // The merge tests' tolerance for the generated world (exact truth; see tolerance()).
      if (test::within(err, tolerance())) ++stats->ok_within_tolerance;
    }
  }
}

TEST(Soak, TwoAgentsStreamWhileMergesAreCalledRepeatedly) {
  ros::NodeHandle nh;
  const double seconds = param("seconds", 60.0);
  const double keyframe_rate = param("keyframe_rate", 10.0);
  const double cloud_rate = param("cloud_rate", 2.0);
  const int callers = param("callers", 3);
  const int bad_every = param("bad_every", 10);
  const double rss_margin_mb = param("rss_margin_mb", 64.0);
  const double drain_seconds = param("drain_seconds", 240.0);
  const std::string input = param<std::string>("input", "pcr_pro");
  const std::string node = param<std::string>("node", "/merge_node");
  const std::string report = param<std::string>("report", "");
  const std::string service = node + "/merge";
  const bool lsd = input == "lsd_slam";

  ASSERT_TRUE(ros::service::waitForService(service, ros::Duration(60.0))) << "no " << service;
  const int pid = nodePid(node);
  ASSERT_GT(pid, 0) << "no pid for " << node;
  Diagnostics diagnostics(nh);

  AgentStream a, b;
  a.name = "agent_a";
  b.name = "agent_b";
  for (AgentStream* s : {&a, &b}) lsd ? prepareLsd(s) : preparePcrPro(s);
  const double rss_idle = procStatusMb(pid, "VmRSS:");

  // RSS sampled every 0.5 s while the soak runs.
  std::vector<std::pair<double, double>> rss;  // (t [s], MB)
  std::mutex rss_mutex;
  std::atomic<bool> stop_sampling{false}, stop{false};
  const auto start = Clock::now();
  std::thread sampler([&] {
    while (!stop_sampling) {
      const double mb = procStatusMb(pid, "VmRSS:");
      {
        std::lock_guard<std::mutex> lock(rss_mutex);
        rss.emplace_back(secondsSince(start), mb);
      }
      std::this_thread::sleep_for(std::chrono::milliseconds(500));
    }
  });
  std::thread stream_a([&] { stream(&a, lsd, keyframe_rate, cloud_rate, bad_every, stop); });
  std::thread stream_b([&] { stream(&b, lsd, keyframe_rate, cloud_rate, bad_every, stop); });
  // The first merge once both agents have sent each of their real keyframes twice (a merge of one
  // keyframe each may rightly find no overlap): from then on every default merge must succeed.
  const auto originals = [lsd](const AgentStream& s) {
    return static_cast<long>(lsd ? s.lsd_keyframes.size() : s.keyframes.size());
  };
  while (secondsSince(start) < 20.0 && (a.sent_keyframes < 2 * originals(a) || b.sent_keyframes < 2 * originals(b))) {
    ros::WallDuration(0.05).sleep();
  }
  ros::WallDuration(0.5).sleep();
  CallStats stats;
  std::vector<std::thread> clients;
  for (int c = 0; c < callers; ++c) {
    clients.emplace_back([&, c] { callMerges(c, &a, &b, stop, &stats, service); });
  }
  while (secondsSince(start) < seconds && procStatusMb(pid, "VmRSS:") > 0.0) ros::WallDuration(0.2).sleep();
  const double streamed_for = secondsSince(start);
  stop = true;
  stream_a.join();
  stream_b.join();
  // Outstanding calls must still be answered: wait for the clients, bounded.
  const auto drain_start = Clock::now();
  std::atomic<int> finished{0};
  for (std::thread& t : clients) {
    std::thread([&finished, t = std::move(t)]() mutable {
      t.join();
      ++finished;
    }).detach();
  }
  while (finished < callers && secondsSince(drain_start) < drain_seconds) ros::WallDuration(0.1).sleep();
  const double drained_in = secondsSince(drain_start);
  const bool drained = finished == callers;
  if (drained) ros::WallDuration(1.5).sleep();  // a last diagnostics update
  stop_sampling = true;
  sampler.join();

  // The node is alive and still serving.
  const bool alive = ::kill(pid, 0) == 0;
  pcr_pro::MergeMaps last;
  last.request.source_agent = "agent_nobody";
  const bool last_answered = drained && ros::service::call(service, last);
  const double rss_end = procStatusMb(pid, "VmRSS:");
  const double rss_peak = procStatusMb(pid, "VmHWM:");

  // RSS once the caps are reached: the largest sample in [25 %, 50 %] of the run against the
  // largest in its last quarter (largest, so that a merge in progress counts in both windows).
  double warm = 0.0, late = 0.0;
  for (const auto& [t, mb] : rss) {
    if (t >= 0.25 * streamed_for && t <= 0.5 * streamed_for) warm = std::max(warm, mb);
    if (t >= 0.75 * streamed_for && t <= streamed_for) late = std::max(late, mb);
  }
  long kf_a = diagnostics.number("agent agent_a", "keyframes"), kf_b = diagnostics.number("agent agent_b", "keyframes");
  std::ostringstream out;
  out << "soak: input " << input << ", " << streamed_for << " s streaming, per agent " << keyframe_rate
      << " keyframes/s and " << cloud_rate << (lsd ? " graphs/s" : " clouds/s") << ", every " << bad_every
      << "th message invalid; " << callers << " concurrent callers\n";
  for (AgentStream* s : {&a, &b}) {
    const std::string task = "agent " + s->name;
    out << "  " << s->name << ": sent " << s->sent_keyframes << " keyframes, " << s->sent_clouds
        << (lsd ? " graphs, " : " clouds, ") << s->sent_bad << " invalid; node: received "
        << diagnostics.value(task, "messages_received") << ", rejected " << diagnostics.value(task, "messages_rejected")
        << ", keyframes kept " << diagnostics.value(task, "keyframes") << ", dropped "
        << diagnostics.value(task, "keyframes_dropped") << ", clouds voxelised "
        << diagnostics.value(task, "clouds_voxelised") << "\n";
  }
  {
    std::lock_guard<std::mutex> lock(stats.mutex);
    out << "  merge calls: " << stats.calls << ", answered " << stats.answered << " (";
    for (const auto& [name, n] : stats.by_status) out << name << " " << n << ", ";
    out << "unexpected " << stats.unexpected << "), latency mean "
        << (stats.answered ? stats.sum_latency / static_cast<double>(stats.answered) : 0.0) << " s, max "
        << stats.max_latency << " s; OK merges within " << tolerance().rotation_deg << " deg / "
        << tolerance().scale_percent << " % / " << tolerance().translation << " of the truth: " << stats.ok_within_tolerance
        << " (worst " << stats.worst_rotation_deg << " deg, " << 100.0 * stats.worst_scale << " %, "
        << stats.worst_translation << "); last calls drained in " << drained_in << " s\n";
  }
  out << "  node RSS [MB]: idle " << rss_idle << ", once capped (max over 25-50 % of the run) " << warm
      << ", last quarter max " << late << ", end " << rss_end << ", peak (VmHWM) " << rss_peak << "; margin "
      << rss_margin_mb << "\n";
  if (!drained) {
    out << "  FAILED: " << callers - finished << " merge call(s) still unanswered " << drain_seconds
        << " s after the streams stopped\n";
  }
  std::printf("%s", out.str().c_str());
  if (!report.empty()) std::ofstream(report) << out.str();
  if (!drained) {
    // The callers' threads still use this frame: leave at once (the missing results fail the test).
    std::fflush(nullptr);
    std::_Exit(1);
  }

  EXPECT_TRUE(alive) << "the node died";
  EXPECT_TRUE(last_answered) << "the node no longer answers";
  EXPECT_EQ(last.response.status, Response::UNKNOWN_AGENT);
  std::lock_guard<std::mutex> lock(stats.mutex);
  EXPECT_GT(stats.calls, callers) << "too few calls to mean anything";
  EXPECT_EQ(stats.answered, stats.calls) << "unanswered calls";
  EXPECT_EQ(stats.unexpected, 0);
  for (std::size_t i = 0; i < std::min<std::size_t>(stats.problems.size(), 10); ++i) ADD_FAILURE() << stats.problems[i];
  EXPECT_GT(stats.by_status["OK"], 0) << "no merge succeeded under load";
  EXPECT_EQ(stats.ok_within_tolerance, stats.by_status["OK"]) << "an OK merge under load is off the truth";
  int max_keyframes = 0;
  ASSERT_TRUE(ros::param::get(node + "/max_keyframes_per_agent", max_keyframes));
  EXPECT_GE(kf_a, 1);
  EXPECT_LE(kf_a, max_keyframes);
  EXPECT_LE(kf_b, max_keyframes);
  EXPECT_GT(diagnostics.number("agent agent_a", "keyframes_dropped"), 0) << "the keyframe cap was never reached";
  for (AgentStream* s : {&a, &b}) {
    const long rejected = diagnostics.number("agent " + s->name, "messages_rejected");
    EXPECT_GT(rejected, 0) << s->name;
    EXPECT_LE(rejected, s->sent_bad.load()) << s->name << ": a valid message was rejected";
  }
  if (!lsd) {
    EXPECT_GT(diagnostics.number("agent agent_a", "clouds_voxelised"), 0) << "the cloud cap was never used";
  }
  EXPECT_GT(warm, 0.0);
  EXPECT_LE(late, warm + rss_margin_mb) << "resident memory grew after the caps were reached";
}

}  // namespace
}  // namespace ros_bridge
}  // namespace pcr_pro

int main(int argc, char** argv) { return pcr_pro::test::runRosTests(argc, argv, "merge_node_soak"); }
