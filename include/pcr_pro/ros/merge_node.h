/**
 * @file merge_node.h
 * @brief The merge node (and nodelet): subscriptions per agent, the `~merge` and `~edges`
 * services, automatic merging as the maps grow, the published fused / aligned clouds, the latched
 * edge and merge history, tf and diagnostics. Every merge runs on one worker thread, on a copy of
 * the agents' data, one at a time: data callbacks keep running during a merge.
 */
#pragma once

#include <diagnostic_updater/diagnostic_updater.h>
#include <geometry_msgs/PoseWithCovarianceStamped.h>
#include <lsd_slam_viewer/keyframeGraphMsg.h>
#include <lsd_slam_viewer/keyframeMsg.h>
#include <pcr_pro/EdgeHistory.h>
#include <pcr_pro/GetEdges.h>
#include <pcr_pro/Keyframe.h>
#include <pcr_pro/MergeMaps.h>
#include <ros/callback_queue.h>
#include <ros/ros.h>
#include <sensor_msgs/PointCloud2.h>
#include <tf2_ros/static_transform_broadcaster.h>

#include <condition_variable>
#include <deque>
#include <functional>
#include <map>
#include <memory>
#include <mutex>
#include <optional>
#include <string>
#include <thread>
#include <vector>

#include "pcr_pro/merge/agent_store.h"
#include "pcr_pro/merge/merge_pipeline.h"
#include "pcr_pro/ros/auto_merge.h"
#include "pcr_pro/ros/node_options.h"

namespace pcr_pro {
namespace ros_bridge {

class MergeNode {
 public:
  /**
   * @param[in] nh node handle whose namespace holds the agents' topics (X/keyframes, ...)
   * @param[in] pnh private node handle (~merge, ~edges, ~fused_cloud, ~aligned_cloud, ~edge, ...)
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
    std::uint64_t keyframes_added = 0, keyframe_moves = 0;  // for automatic merging (MapProgress)
    std::string last_rejection;
    std::map<std::string, Throttle> throttles;
    std::vector<ros::Subscriber> subscribers;
  };
  /// Where a merge's wall time on the worker went [ms], for the diagnostics (benchmarks read it).
  struct MergeTiming {
    double total_ms = 0.0;    // snapshot to published outputs
    double maps_ms = 0.0;     // the agents' snapshots turned into maps (LSD keyframes -> cloud)
    double publish_ms = 0.0;  // edge, fused / aligned clouds, tf, history
    StageTimings stages;      // the pipeline's own (stages.total: the whole pipeline)
    int features_computed = 0, features_cached = 0;  // keyframes whose SIFT was computed / came from the cache
    int pairs_computed = 0, pairs_cached = 0;  // candidate pairs matched and posed / taken from the pair cache
    int vote_rows_computed = 0;  // source keyframes whose votes of the pair preselection were computed
    int earlier_pairs = 0;  // pairs that verified in earlier merges, added as no preselected pair verified
    // "icp", or "projective" (merge.projective_refinement), with MergeDiagnostics::projective_note
    std::string refinement = "icp";
    double projective_ms = 0.0;  // the projective registration's part of stages.icp
  };
  struct MergeState {
    bool attempted = false;
    std::string status = "none", message = "no merge yet", pair, trigger;
    int merges_ok = 0, merges_failed = 0, merges_auto = 0;
    std::optional<MergeTiming> timing;  // of the last merge that ran the pipeline
  };
  /// One merge to run: the agents (resolved names) and optionally the keyframes.
  struct MergeJob {
    std::string source, target;
    MergeRequest keyframes;
    std::string trigger;  // "service" or "auto"
  };
  /// What a merge works on: copies of both stores, taken under their locks.
  struct Snapshot {
    Agent* agent = nullptr;
    AgentStore store;
    std::string rejections;  // "; N message(s) rejected, the last: ..." or empty
    MapProgress progress;
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
  /// Counts a keyframe in the agent's progress: a new id, or a re-sent one (its pose may have moved).
  static void noteKeyframe(Agent* agent, bool replaced);
  /// @return the agent's progress; call with agent->mutex held
  MapProgress progress(const Agent& agent) const;

  bool onMergeService(pcr_pro::MergeMaps::Request& request, pcr_pro::MergeMaps::Response& response);
  bool onEdgesService(pcr_pro::GetEdges::Request& request, pcr_pro::GetEdges::Response& response);
  /// Checks the agents' progress and queues an automatic merge when a pair is due (timer).
  void checkAutoMerge();
  /// Queues work for the merge worker. @return false when the node is shutting down
  bool enqueue(std::function<void()> job);
  void workerLoop();

  /// Runs one merge (on the worker): resolve, snapshot, check, pipeline, publish, record.
  pcr_pro::MergeMaps::Response merge(const MergeJob& job);
  /// The pipeline on two checked maps, then the outputs of a success; fills `timing` (but its total).
  pcr_pro::MergeMaps::Response mergeMaps(const MergeJob& job, const Snapshot& source, const AgentMap& source_map,
                                         const Snapshot& target, const AgentMap& target_map, MergeTiming* timing);
  Snapshot takeSnapshot(Agent* agent) const;
  /// @return NO_DATA / UNKNOWN_KEYFRAME answer when the snapshots cannot be merged as asked
  std::optional<pcr_pro::MergeMaps::Response> checkData(const MergeJob& job, const Snapshot& source,
                                                        const AgentMap& source_map, const Snapshot& target,
                                                        const AgentMap& target_map) const;
  /**
   * @brief The one place the node runs the merge pipeline (service and automatic merges alike),
   * on the node's one MergePipeline, whose feature cache keeps every keyframe's SIFT features
   * across merges (keyed by agent name and keyframe id).
   */
  MergeResult runPipeline(const AgentMap& source, const std::string& source_agent, const AgentMap& target,
                          const std::string& target_agent, const MergeRequest& request);
  /// Drops the cached features of keyframes that were replaced or left the agent's store.
  void forgetFeatures(const Agent& agent, long replaced_id, bool replaced, const std::vector<long>& dropped);
  /// Publishes the edge, clouds and tf of a successful merge and appends it to the history.
  void publishMerge(const MergeJob& job, const Snapshot& source, const AgentMap& source_map, const Snapshot& target,
                    const AgentMap& target_map, const RegistrationReport& report, const std::string& message,
                    pcr_pro::MapEdge* edge);
  void recordHistory(const MergeJob& job, const pcr_pro::MapEdge& edge, const std::string& message);
  /// `~g2o_file`: the pose graph of a successful merge (io/pose_graph.h); a write error is a warning.
  void writePoseGraph(const MergeJob& job, const AgentMap& source_map, const AgentMap& target_map,
                      const MergeResult& result) const;
  /// Logs a merge that did not succeed and counts every outcome for the diagnostics, with where
  /// its time went when the pipeline ran (`timing`, else the last such merge's stays).
  void noteOutcome(const MergeJob& job, const pcr_pro::MergeMaps::Response& response,
                   const std::optional<MergeTiming>& timing = std::nullopt);
  Agent* findAgent(const std::string& name) const;

  void agentDiagnostics(Agent* agent, diagnostic_updater::DiagnosticStatusWrapper& status);
  void mergeDiagnostics(diagnostic_updater::DiagnosticStatusWrapper& status);

  ros::NodeHandle nh_, pnh_;
  const NodeOptions options_;
  /// The merge, built once: its feature cache is thread-safe; merges run on the worker only.
  std::unique_ptr<MergePipeline> pipeline_;
  std::vector<std::unique_ptr<Agent>> agents_;

  ros::Publisher fused_pub_, aligned_pub_, edge_pub_, edge_pose_pub_, history_pub_;
  tf2_ros::StaticTransformBroadcaster static_tf_;
  diagnostic_updater::Updater diagnostics_;
  ros::Timer diagnostics_timer_, auto_merge_timer_;

  std::mutex merge_state_mutex_;
  MergeState merge_state_;

  // Automatic merging: the schedule, and whether an automatic merge is queued or running.
  std::mutex auto_mutex_;
  std::unique_ptr<AutoMergeSchedule> schedule_;
  bool auto_pending_ = false;

  // Every successful edge, oldest first (bounded per pair by max_history_per_pair).
  std::mutex history_mutex_;
  std::vector<pcr_pro::MergeRecord> history_;

  // The merge service has its own callback queue and thread: a merge never blocks data callbacks.
  ros::CallbackQueue service_queue_;
  ros::ServiceServer merge_service_, edges_service_;
  std::unique_ptr<ros::AsyncSpinner> service_spinner_;

  // The worker thread running the pipeline, one merge at a time.
  std::mutex jobs_mutex_;
  std::condition_variable jobs_cv_;
  std::deque<std::function<void()>> jobs_;
  bool stop_ = false;
  std::thread worker_;
};

}  // namespace ros_bridge
}  // namespace pcr_pro
