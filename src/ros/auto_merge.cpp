// When the merge node merges on its own (see auto_merge.h).
#include "pcr_pro/ros/auto_merge.h"

#include <cmath>

#include "pcr_pro/geometry/types.h"

namespace pcr_pro {

template <>
const ParamSchema<ros_bridge::AutoMergeOptions>& paramSchema<ros_bridge::AutoMergeOptions>() {
  using O = ros_bridge::AutoMergeOptions;
  using R = ParamRange;
  static const ParamSchema<O> schema{"auto_merge", {
      {"enabled", &O::enabled, R::any(), "", "merge automatically as the maps grow"},
      {"target", &O::target, R::any(), "", "the agent every other one is merged into, one of agents; empty = the first"},
      {"min_keyframes", &O::min_keyframes, R::atLeast(1), "keyframes",
       "keyframes each map needs (with map points) before its first merge"},
      {"new_keyframes", &O::new_keyframes, R::atLeast(1), "keyframes",
       "new keyframe ids in the two maps together that make a pair merge again"},
      {"after_graph_update", &O::after_graph_update, R::any(), "",
       "merge a pair again when a graph update or a re-sent keyframe moved keyframes of either map"},
      {"period", &O::period, R::closed(0.05, 60), "s", "how often the node checks whether a pair is due"},
  }, ParamMessage::kNode, '/'};
  return schema;
}

namespace ros_bridge {

void validate(const AutoMergeOptions& o) {
  checkRanges(paramSchema<AutoMergeOptions>(), o);
}

AutoMergeSchedule::AutoMergeSchedule(AutoMergeOptions options, std::string target, std::vector<std::string> sources)
    : options_(std::move(options)), target_(std::move(target)), sources_(std::move(sources)) {}

std::string AutoMergeSchedule::reasonDue(const PairState& pair, const MapProgress& source,
                                         const MapProgress& target) const {
  const auto enough = [this](const MapProgress& p) {
    return p.has_cloud && p.keyframes >= static_cast<std::size_t>(options_.min_keyframes);
  };
  if (!enough(source) || !enough(target)) return "";
  if (!pair.attempted) return "first merge";
  const std::uint64_t grown = (source.added - pair.source.added) + (target.added - pair.target.added);
  if (grown >= static_cast<std::uint64_t>(options_.new_keyframes)) return std::to_string(grown) + " new keyframes";
  if (options_.after_graph_update && (source.moved != pair.source.moved || target.moved != pair.target.moved)) {
    return "keyframes moved";
  }
  return "";
}

DueMerge AutoMergeSchedule::due(const std::map<std::string, MapProgress>& progress) {
  const auto target = progress.find(target_);
  if (target == progress.end() || sources_.empty()) return {};
  for (std::size_t i = 0; i < sources_.size(); ++i) {
    const std::size_t k = (next_ + i) % sources_.size();
    const auto source = progress.find(sources_[k]);
    if (source == progress.end()) continue;
    const std::string reason = reasonDue(pairs_[sources_[k]], source->second, target->second);
    if (!reason.empty()) {
      next_ = (k + 1) % sources_.size();
      return {sources_[k], reason};
    }
  }
  return {};
}

void AutoMergeSchedule::attempted(const std::string& source, const MapProgress& source_progress,
                                  const MapProgress& target_progress) {
  PairState& pair = pairs_[source];
  pair.attempted = true;
  pair.source = source_progress;
  pair.target = target_progress;
}

}  // namespace ros_bridge
}  // namespace pcr_pro
