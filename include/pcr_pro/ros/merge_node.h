/**
 * @file merge_node.h
 * @brief The merge node (and nodelet): subscriptions per agent, the `~merge` service, the
 * published fused / aligned clouds, the latched edge, tf and diagnostics. The pipeline runs in a
 * worker thread on a copy of the agents' data, so data callbacks keep running during a merge.
 */
#pragma once

#include <diagnostic_updater/diagnostic_updater.h>
#include <geometry_msgs/PoseWithCovarianceStamped.h>
#include <lsd_slam_viewer/keyframeGraphMsg.h>
#include <lsd_slam_viewer/keyframeMsg.h>
#include <pcr_pro/Keyframe.h>
#include <pcr_pro/MergeMaps.h>
#include <ros/callback_queue.h>
#include <ros/ros.h>
#include <sensor_msgs/PointCloud2.h>
#include <tf2_ros/static_transform_broadcaster.h>

#include <condition_variable>
#include <deque>
#include <future>
#include <map>
#include <memory>
#include <mutex>
#include <string>
#include <thread>
#include <vector>

#include "pcr_pro/merge/agent_store.h"
#include "pcr_pro/ros/node_options.h"

namespace pcr_pro {
namespace ros_bridge {

class MergeNode {
 public:
  /**
   * @param[in] nh node handle whose namespace holds the agents' topics (X/keyframes, ...)
   * @param[in] pnh private node handle (~merge, ~fused_cloud, ~aligned_cloud, ~edge)
   * @param[in] options validated options (see loadNodeOptions())
   */
  MergeNode(const ros::NodeHandle& nh, const ros::NodeHandle& pnh, NodeOptions options);
  ~MergeNode();
  MergeNode(const MergeNode&) = delete;
  MergeNode& operator=(const MergeNode&) = delete;

 private:
  // One warning per (agent, topic, kind) and period; the others are counted and reported with the next.
  struct Throttle {
    ros::WallTime last;
    std::size_t suppressed = 0;
  };
  struct Agent {
    AgentOptions options;
    std::mutex mutex;  // guards everything below
    AgentStore store;
    std::size_t received = 0, rejected = 0, graph_updates = 0;
    std::size_t keyframes_dropped = 0, clouds_voxelised = 0, points_dropped_nonfinite = 0;
    std::string last_rejection;
    std::map<std::string, Throttle> throttles;
    std::vector<ros::Subscriber> subscribers;
  };
  struct MergeState {
    bool attempted = false;
    std::string status = "none", message = "no merge yet";
    int merges_ok = 0, merges_failed = 0;
  };

  void onKeyframe(Agent* agent, const pcr_pro::Keyframe::ConstPtr& msg);
  void onCloud(Agent* agent, const sensor_msgs::PointCloud2::ConstPtr& msg);
  void onLsdKeyframe(Agent* agent, const lsd_slam_viewer::keyframeMsg::ConstPtr& msg);
  void onLsdGraph(Agent* agent, const lsd_slam_viewer::keyframeGraphMsg::ConstPtr& msg);
  void reject(Agent* agent, const std::string& topic, const std::string& what);
  /// ROS_WARN of "<topic>: <what>" at most once per kWarnPeriod per (agent, key); call with agent->mutex held.
  void warnThrottled(Agent* agent, const std::string& key, const std::string& text);
  void noteDropped(Agent* agent, const std::string& topic, long added, const std::vector<long>& dropped);
  void noteCloudCap(Agent* agent, const std::string& what, const CloudCap& cap);

  bool onMergeService(pcr_pro::MergeMaps::Request& request, pcr_pro::MergeMaps::Response& response);
  pcr_pro::MergeMaps::Response merge(const pcr_pro::MergeMaps::Request& request);
  void workerLoop();

  void agentDiagnostics(Agent* agent, diagnostic_updater::DiagnosticStatusWrapper& status);
  void mergeDiagnostics(diagnostic_updater::DiagnosticStatusWrapper& status);

  ros::NodeHandle nh_, pnh_;
  const NodeOptions options_;
  std::vector<std::unique_ptr<Agent>> agents_;

  ros::Publisher fused_pub_, aligned_pub_, edge_pub_, edge_pose_pub_;
  tf2_ros::StaticTransformBroadcaster static_tf_;
  diagnostic_updater::Updater diagnostics_;
  ros::Timer diagnostics_timer_;

  std::mutex merge_state_mutex_;
  MergeState merge_state_;

  // The service has its own callback queue and thread: a merge never blocks data callbacks.
  ros::CallbackQueue service_queue_;
  ros::ServiceServer merge_service_;
  std::unique_ptr<ros::AsyncSpinner> service_spinner_;

  // Worker thread running the pipeline.
  std::mutex jobs_mutex_;
  std::condition_variable jobs_cv_;
  std::deque<std::packaged_task<pcr_pro::MergeMaps::Response()>> jobs_;
  bool stop_ = false;
  std::thread worker_;
};

}  // namespace ros_bridge
}  // namespace pcr_pro
