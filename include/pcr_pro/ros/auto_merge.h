/**
 * @file auto_merge.h
 * @brief When the merge node merges on its own (`~auto_merge/...`): each pair (target agent, one
 * other agent) once both maps have enough keyframes, and again once they have grown by a given
 * number of keyframes or once a graph update (or a re-sent keyframe) has moved keyframes of
 * either. ROS-free, not thread-safe (the node guards it); the node runs what it chooses one at a
 * time on its merge worker.
 */
#pragma once

#include <cstdint>
#include <map>
#include <string>
#include <vector>

#include "pcr_pro/io/param_schema.h"

namespace pcr_pro {
namespace ros_bridge {

/// Parameters `~auto_merge/...`; the defaults are written here once.
struct AutoMergeOptions {
  /// `enabled`: merge automatically as the maps grow.
  bool enabled = false;
  /// `target`: the agent every other agent is merged into; empty = the first of `~agents`.
  std::string target;
  /// `min_keyframes`: each agent of a pair needs at least this many keyframes (and its map
  /// cloud) before the first merge [keyframes], >= 1.
  int min_keyframes = 3;
  /// `new_keyframes`: merge a pair again once its two maps together received this many keyframes
  /// (new ids) since the pair's last merge attempt [keyframes], >= 1.
  int new_keyframes = 5;
  /// `after_graph_update`: merge a pair again once a graph update (LSD-SLAM) or a re-sent
  /// keyframe id (pcr_pro input) moved keyframes of either map since the last attempt.
  bool after_graph_update = true;
  /// `period`: how often the node checks whether a pair is due [s], in [0.05, 60].
  double period = 1.0;
};

/// @throw InputError "auto_merge/<key>: ..." for the first option out of range
void validate(const AutoMergeOptions& options);

}  // namespace ros_bridge

/// Every parameter of AutoMergeOptions (ROS parameters `~auto_merge/...`).
template <>
const ParamSchema<ros_bridge::AutoMergeOptions>& paramSchema<ros_bridge::AutoMergeOptions>();

namespace ros_bridge {

/// What the node has received of one agent's map so far (monotonic counters).
struct MapProgress {
  std::size_t keyframes = 0;      ///< keyframes in the agent's store now
  bool has_cloud = false;         ///< the agent has map points (its cloud, or LSD keyframes)
  std::uint64_t added = 0;        ///< keyframes with a new id received so far
  std::uint64_t moved = 0;        ///< graph updates / re-sent keyframes that moved keyframes so far
};

/// A pair due for a merge and why.
struct DueMerge {
  std::string source;  ///< empty: no pair is due
  std::string reason;  ///< e.g. "first merge", "7 new keyframes", "keyframes moved"
};

class AutoMergeSchedule {
 public:
  /**
   * @param[in] options validated options
   * @param[in] target the target agent
   * @param[in] sources every other agent, in the order of `~agents`
   */
  AutoMergeSchedule(AutoMergeOptions options, std::string target, std::vector<std::string> sources);

  const std::string& target() const { return target_; }

  /**
   * @brief The next pair due, round robin over the sources (after the one chosen last).
   * @param[in] progress every agent's progress now (agents missing from it are not due)
   */
  DueMerge due(const std::map<std::string, MapProgress>& progress);

  /// Records a merge attempt of (source -> target) on maps with this progress (the snapshot the
  /// merge worked on), whatever its outcome and whoever asked for it.
  void attempted(const std::string& source, const MapProgress& source_progress, const MapProgress& target_progress);

 private:
  struct PairState {
    bool attempted = false;
    MapProgress source, target;  // at the last attempt
  };
  std::string reasonDue(const PairState& pair, const MapProgress& source, const MapProgress& target) const;

  AutoMergeOptions options_;
  std::string target_;
  std::vector<std::string> sources_;
  std::map<std::string, PairState> pairs_;
  std::size_t next_ = 0;  // round robin position in sources_
};

}  // namespace ros_bridge
}  // namespace pcr_pro
