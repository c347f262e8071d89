// When the merge node merges on its own (see auto_merge.h).
#include "pcr_pro/ros/auto_merge.h"

#include <cmath>

#include "pcr_pro/geometry/types.h"

namespace pcr_pro {
namespace ros_bridge {

void validate(const AutoMergeOptions& o) {
  const auto fail = [](const std::string& key, const std::string& what) {
    throw InputError("auto_merge/" + key + ": " + what);
  };
  if (o.min_keyframes < 1) fail("min_keyframes", "must be >= 1, got " + std::to_string(o.min_keyframes));
  if (o.new_keyframes < 1) fail("new_keyframes", "must be >= 1, got " + std::to_string(o.new_keyframes));
  if (!(o.period >= 0.05 && o.period <= 60.0)) fail("period", "must be in [0.05, 60] s, got " + std::to_string(o.period));
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
