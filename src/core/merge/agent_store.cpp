// One agent's data in the merge node (see agent_store.h).
#include "pcr_pro/merge/agent_store.h"

#include <algorithm>
#include <cmath>
#include <limits>
#include <sstream>

#include "pcr_pro/registration/filters.h"
#include "pcr_pro/io/input_limits.h"
#include "pcr_pro/geometry/types.h"

namespace pcr_pro {

template <>
const ParamSchema<StoreLimits>& paramSchema<StoreLimits>() {
  using O = StoreLimits;
  using R = ParamRange;
  static const ParamSchema<O> schema{"", {
      {"max_keyframes_per_agent", &O::max_keyframes, R::atLeast(1), "keyframes",
       "most keyframes kept per agent; beyond it the keyframe received longest ago is dropped"},
      {"max_cloud_points_per_agent", &O::max_cloud_points, R::closed(1000, static_cast<double>(kMaxCloudPointsCeiling)),
       "points", "most map points per agent; a larger map cloud is voxelised with the smallest leaf that fits"},
  }, ParamMessage::kNode};
  return schema;
}

void validate(const StoreLimits& l) {
  checkRanges(paramSchema<StoreLimits>(), l);
}

Cloud capCloud(const Cloud& cloud, std::int64_t max_points, CloudCap* info) {
  CloudCap c;
  c.input_points = cloud.cols();
  const auto done = [&](Cloud out) {
    c.kept_points = out.cols();
    if (info) *info = c;
    return out;
  };
  max_points = std::max<std::int64_t>(1, max_points);
  if (cloud.cols() <= max_points) return done(cloud);

  // Voxel count vs leaf is about C * leaf^-d (d ~ 3 for a filled volume, 2 for surfaces, 1 for
  // lines). Start from the leaf that would fill the bounding box with max_points cells, then take
  // secant steps in log-log, keeping the largest result that fits. Never below extent / 2^20,
  // the voxel grid's key range.
  const Eigen::Vector3d extent = cloud.rowwise().maxCoeff() - cloud.rowwise().minCoeff();
  const double largest = extent.maxCoeff();  // inf when the coordinates span more than a double
  // The smallest leaf: extent / 2^20 keeps every voxel index (p - min) / leaf within 2^20, so the
  // voxel grid's integer conversion stays defined (found by fuzz_ros_cloud: a denormal extent
  // made 1 / leaf infinite). Extents that small or that large are left to the subsample below.
  const double min_leaf = largest / double(1 << 20);
  double leaf = 0.0;
  if (std::isfinite(largest) && min_leaf >= 1e-290) {
    const double floor_extent = largest * 1e-3;
    const double volume = std::max(extent.x(), floor_extent) * std::max(extent.y(), floor_extent) *
                          std::max(extent.z(), floor_extent);
    leaf = std::max(std::cbrt(volume / static_cast<double>(max_points)), min_leaf);
  }
  const double target = static_cast<double>(max_points);
  Cloud best;
  double best_leaf = 0.0;
  double prev_leaf = 0.0, prev_count = 0.0;
  for (int iteration = 0; iteration < 8 && std::isfinite(leaf) && leaf > 0.0 && std::isfinite(1.0 / leaf);
       ++iteration) {
    VoxelGridOptions o;
    o.leaf_size = leaf;
    Cloud out = voxelGridFilter(cloud, o);
    const double count = static_cast<double>(out.cols());
    if (count <= target && count > static_cast<double>(best.cols())) {
      best = std::move(out);
      best_leaf = leaf;
      if (count >= 0.75 * target) break;  // close enough to the cap
    }
    // Next leaf: aim at 0.95 * target with the local exponent (clamped to [1, 3]).
    double d = 2.0;
    if (prev_leaf > 0.0 && prev_count > 0.0 && count > 0.0 && std::abs(std::log(leaf / prev_leaf)) > 1e-9) {
      d = -std::log(count / prev_count) / std::log(leaf / prev_leaf);
      if (!std::isfinite(d)) d = 2.0;
      d = std::min(3.0, std::max(1.0, d));
    }
    prev_leaf = leaf;
    prev_count = count;
    double factor = std::pow(std::max(count, 1.0) / (0.95 * target), 1.0 / d);
    // Step at least 2 % and at most 8x either way.
    if (std::abs(factor - 1.0) < 0.02) factor = count > target ? 1.02 : 0.98;
    factor = std::min(8.0, std::max(0.125, factor));
    const double next = std::max(leaf * factor, min_leaf);
    if (next == leaf) break;  // at the smallest leaf already
    leaf = next;
  }
  if (best.cols() > 0) {
    c.leaf = best_leaf;
    return done(std::move(best));
  }
  // The voxel grid did not get there (degenerate extent): a uniform random subsample.
  MaxPointsOptions o;
  o.max_points = static_cast<int>(std::min<std::int64_t>(max_points, std::numeric_limits<int>::max()));
  o.seed = 1;
  c.subsampled = true;
  return done(maxPointsFilter(cloud, o));
}

AgentStore::AgentStore(std::string frame_id, StoreLimits limits)
    : frame_id_(std::move(frame_id)), limits_(limits) {
  validate(limits_);
}

void AgentStore::checkCamera(const PinholeCamera& c, long id) {
  if (!has_camera_ || keyframeCount() == 0) {
    camera_ = c;
    has_camera_ = true;
    return;
  }
  const auto close = [](double a, double b) { return std::abs(a - b) <= 1e-6 * std::max(1.0, std::abs(b)); };
  if (c.width != camera_.width || c.height != camera_.height || !close(c.fx, camera_.fx) ||
      !close(c.fy, camera_.fy) || !close(c.cx, camera_.cx) || !close(c.cy, camera_.cy)) {
    std::ostringstream s;
    s << "keyframe " << id << ": camera (fx " << c.fx << ", fy " << c.fy << ", cx " << c.cx << ", cy " << c.cy
      << ", " << c.width << "x" << c.height << ") differs from the agent's camera (fx " << camera_.fx << ", fy "
      << camera_.fy << ", cx " << camera_.cx << ", cy " << camera_.cy << ", " << camera_.width << "x"
      << camera_.height << ")";
    throw InputError(s.str());
  }
}

void AgentStore::noteArrival(long id, std::vector<long>* dropped) {
  arrival_[id] = ++arrivals_;
  while (keyframeCount() > static_cast<std::size_t>(limits_.max_keyframes)) {
    // The keyframe received longest ago (never the one just added: it has the newest arrival).
    auto oldest = arrival_.begin();
    for (auto it = arrival_.begin(); it != arrival_.end(); ++it) {
      if (it->second < oldest->second) oldest = it;
    }
    const long victim = oldest->first;
    arrival_.erase(oldest);
    keyframes_.erase(victim);
    lsd_keyframes_.erase(victim);
    if (dropped) dropped->push_back(victim);
  }
}

bool AgentStore::setKeyframe(const MapKeyframe& keyframe, const PinholeCamera& camera, std::vector<long>* dropped) {
  checkCamera(camera, keyframe.id);
  const bool replaced = keyframes_.count(keyframe.id) > 0;
  keyframes_[keyframe.id] = keyframe;
  noteArrival(keyframe.id, dropped);
  return replaced;
}

CloudCap AgentStore::setCloud(Cloud cloud) {
  CloudCap cap;
  cloud_ = capCloud(cloud, limits_.max_cloud_points, &cap);
  return cap;
}

bool AgentStore::setLsdKeyframe(const LsdKeyframe& keyframe, std::vector<long>* dropped) {
  checkCamera(keyframe.camera, keyframe.id);
  const bool replaced = lsd_keyframes_.count(keyframe.id) > 0;
  lsd_keyframes_[keyframe.id] = keyframe;
  noteArrival(keyframe.id, dropped);
  return replaced;
}

int AgentStore::updateLsdPoses(const std::vector<std::pair<long, Sim3>>& poses) {
  int updated = 0;
  for (const auto& [id, pose] : poses) {
    const auto it = lsd_keyframes_.find(id);
    if (it == lsd_keyframes_.end()) continue;
    it->second.cam_to_world = pose;
    ++updated;
  }
  return updated;
}

std::vector<long> AgentStore::keyframeIds() const {
  std::vector<long> ids;
  for (const auto& entry : keyframes_) ids.push_back(entry.first);
  for (const auto& entry : lsd_keyframes_) ids.push_back(entry.first);
  std::sort(ids.begin(), ids.end());
  return ids;
}

bool AgentStore::keyframePose(long id, Sim3* pose) const {
  if (const auto it = keyframes_.find(id); it != keyframes_.end()) {
    *pose = it->second.pose;
    return true;
  }
  if (const auto it = lsd_keyframes_.find(id); it != lsd_keyframes_.end()) {
    *pose = it->second.cam_to_world;
    return true;
  }
  return false;
}

AgentMap AgentStore::toAgentMap(const LsdFilterOptions& lsd_filters, CloudCap* cap) const {
  AgentMap map;
  map.frame_id = frame_id_;
  map.camera = camera_;
  for (const auto& entry : keyframes_) map.keyframes.push_back(entry.second);
  if (lsd_keyframes_.empty()) {
    map.cloud = cloud_;
    return map;
  }
  std::vector<Cloud> parts;
  Eigen::Index total = 0;
  for (const auto& entry : lsd_keyframes_) {
    const LsdPoints points = extractPoints(entry.second, lsd_filters);
    map.keyframes.push_back(toKeyframe(entry.second));
    parts.push_back(entry.second.cam_to_world.apply(points.camera_points));
    total += parts.back().cols();
  }
  map.cloud.resize(3, total);
  Eigen::Index at = 0;
  for (const Cloud& part : parts) {
    map.cloud.middleCols(at, part.cols()) = part;
    at += part.cols();
  }
  map.cloud = capCloud(map.cloud, limits_.max_cloud_points, cap);
  return map;
}

}  // namespace pcr_pro
