/**
 * @file node_options.h
 * @brief Every parameter of the merge node, its default (in the struct, written once), loading
 * from the parameter server and validation. The node refuses to start when loadNodeOptions()
 * throws; the message names the parameter at fault.
 */
#pragma once

#include <ros/node_handle.h>

#include <cstdint>
#include <string>
#include <vector>

#include "pcr_pro/io/lsd_keyframe.h"
#include "pcr_pro/merge/agent_store.h"
#include "pcr_pro/merge/merge_pipeline.h"
#include "pcr_pro/ros/auto_merge.h"

namespace pcr_pro {
namespace ros_bridge {

/// Which messages the node takes per agent.
enum class InputMode {
  kPcrPro,   ///< `X/keyframes` (pcr_pro/Keyframe) + `X/cloud` (sensor_msgs/PointCloud2)
  kLsdSlam,  ///< `X/lsd_slam/keyframes` + `X/lsd_slam/graph` as published by LSD-SLAM
};

/// @return "pcr_pro" or "lsd_slam"
const char* inputModeName(InputMode mode);

/// One agent: topics live under its name (relative, so they remap).
struct AgentOptions {
  std::string name;      ///< e.g. "agent_a"; topics X/keyframes, X/cloud, X/lsd_slam/...
  std::string frame_id;  ///< its map frame, default "<name>/map", no leading slash
};

/**
 * @brief The frame of a source map scaled into target units: `<frame_id>_scaled` (e.g.
 * agent_b/map_scaled). Its origin and axes are those of the source map, its unit the target's:
 * a point p of the source map is s * p there, so that the rigid part of S_target_source is its
 * tf from the target map (tf carries no scale). `~aligned_cloud` is stamped with it.
 */
std::string scaledFrame(const std::string& frame_id);

/// Parameters of the merge node (private namespace `~`).
struct NodeOptions {
  /// `~agents`: the agents; the first is the default merge target, the second the default source.
  std::vector<AgentOptions> agents{{"agent_a", "agent_a/map"}, {"agent_b", "agent_b/map"}};
  /// `~input`: "pcr_pro" or "lsd_slam".
  InputMode input = InputMode::kPcrPro;
  /// `~queue_size`: subscriber queue length per topic [messages], >= 1.
  int queue_size = 10;
  /// `~publish_tf`: broadcast target_map -> scaledFrame(source_map) (static tf, rigid) after each merge.
  bool publish_tf = true;
  /// `~merge_config`: merge configuration file (config/merge.yaml format); empty = defaults.
  std::string merge_config;
  /// `~icp_config`: registration configuration file (config/icp.yaml format) whose blocks
  /// replace the geometric stages of merge_config; empty = keep merge_config's.
  std::string icp_config;
  /// `~lsd/...`: LSD viewer filters of LSD-SLAM keyframe points.
  LsdFilterOptions lsd;
  /// `~max_keyframes_per_agent`, `~max_cloud_points_per_agent`: memory bounds of each agent's store.
  StoreLimits limits;
  /// `~seed`: seed of every random stage of the merge (setSeed()), in [0, 2147483647]: equal data
  /// and seed give bit-for-bit equal edges.
  std::int64_t seed = static_cast<std::int64_t>(kDefaultSeed);
  /// `~diagnostic_period`: period of the diagnostics on /diagnostics [s], in [0.1, 60].
  double diagnostic_period = 1.0;
  /// `~auto_merge/...`: automatic merging as the maps grow.
  AutoMergeOptions auto_merge;
  /// `~max_history_per_pair`: most successful edges kept per agent pair in the merge history
  /// (`~edge_history`, `~edges`); beyond it the oldest goes [edges], >= 1.
  int max_history_per_pair = 1000;
  /// `~g2o_file`: after each successful merge, the merge's pose graph (io/pose_graph.h: both
  /// agents' keyframes in the target map, the edge with its information) is written to this g2o
  /// file, replacing the previous one (the latest merge); empty = off.
  std::string g2o_file;
  /// The pipeline configuration read from merge_config / icp_config, seeded with `seed`.
  MergeOptions merge;

  /// @return the agent every other one is merged into automatically (auto_merge.target or the first)
  const std::string& autoMergeTarget() const { return auto_merge.target.empty() ? agents[0].name : auto_merge.target; }
};

}  // namespace ros_bridge

/// The node's own parameters (NodeOptions' scalars: `~input`, `~queue_size`, ...; the agents, the
/// lsd filters, the store limits and auto_merge have schemas of their own).
template <>
const ParamSchema<ros_bridge::NodeOptions>& paramSchema<ros_bridge::NodeOptions>();

namespace ros_bridge {

/// @throw InputError "~key: what" for the first invalid option (agents: at least two, unique
/// valid relative names; frame ids non-empty, unique, no leading slash, none the scaled frame of
/// another; queue_size >= 1; lsd filters; store limits; seed; diagnostic_period; auto_merge, whose
/// target must be an agent; max_history_per_pair; g2o_file not a directory and in an
/// existing directory)
void validate(const NodeOptions& options);

/**
 * @brief Reads every parameter from the node's private namespace, loads the configuration
 * files and validates everything. Keys that are absent keep the struct defaults; keys of the
 * wrong type, unknown keys (typos) and out-of-range values are errors. A list parameter given as
 * a string (`_agents:="[r1, r2]"` on the command line, which roscpp stores as a string) is read
 * as a YAML list.
 * @param[in] pnh private node handle ("~")
 * @throw InputError "~key: what is wrong" (or the configuration file's own error)
 */
NodeOptions loadNodeOptions(const ros::NodeHandle& pnh);

/**
 * @brief The README's table of the node's parameters, printed from their schemas (the agents and
 * their frames, NodeOptions, StoreLimits, LsdFilterOptions, AutoMergeOptions).
 * @return a Markdown table (parameter_tables.h)
 */
std::string nodeParameterTable();

}  // namespace ros_bridge
}  // namespace pcr_pro
