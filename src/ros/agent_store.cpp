// One agent's data in the merge node (see agent_store.h).
#include "pcr_pro/ros/agent_store.h"

#include <algorithm>
#include <cmath>
#include <sstream>

#include "pcr_pro/core/types.h"

namespace pcr_pro {
namespace ros_bridge {

AgentStore::AgentStore(std::string frame_id) : frame_id_(std::move(frame_id)) {}

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

bool AgentStore::setKeyframe(const MapKeyframe& keyframe, const PinholeCamera& camera) {
  checkCamera(camera, keyframe.id);
  const bool replaced = keyframes_.count(keyframe.id) > 0;
  keyframes_[keyframe.id] = keyframe;
  return replaced;
}

bool AgentStore::setLsdKeyframe(const LsdKeyframe& keyframe) {
  checkCamera(keyframe.camera, keyframe.id);
  const bool replaced = lsd_keyframes_.count(keyframe.id) > 0;
  lsd_keyframes_[keyframe.id] = keyframe;
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

AgentMap AgentStore::toAgentMap(const LsdFilterOptions& lsd_filters) const {
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
    map.keyframes.push_back(toKeyframe(entry.second, points));
    parts.push_back(entry.second.cam_to_world.apply(points.camera_points));
    total += parts.back().cols();
  }
  map.cloud.resize(3, total);
  Eigen::Index at = 0;
  for (const Cloud& part : parts) {
    map.cloud.middleCols(at, part.cols()) = part;
    at += part.cols();
  }
  return map;
}

}  // namespace ros_bridge
}  // namespace pcr_pro
