/**
 * @file agent_store.h
 * @brief What the merge node keeps of one agent: keyframes by id (a re-sent id replaces the old
 * keyframe), the latest map cloud, or, in LSD-SLAM mode, LSD keyframes whose poses graph
 * messages update. ROS-free and not thread-safe: the node guards each store with a mutex and
 * merges on a copy (copies share the images, which are never written in place).
 */
#pragma once

#include <map>
#include <string>
#include <utility>
#include <vector>

#include "pcr_pro/core/map_types.h"
#include "pcr_pro/ros/lsd_keyframe.h"

namespace pcr_pro {
namespace ros_bridge {

class AgentStore {
 public:
  /// @param[in] frame_id the agent's map frame (no leading slash)
  explicit AgentStore(std::string frame_id = "map");

  const std::string& frameId() const { return frame_id_; }

  /**
   * @brief Adds a keyframe, or replaces the one with the same id.
   * @param[in] keyframe keyframe (image CV_8UC1, optional depth CV_32FC1)
   * @param[in] camera its camera; all keyframes of an agent share one camera
   * @return true when a keyframe with this id was replaced
   * @throw InputError when the camera differs from the agent's earlier keyframes'
   */
  bool setKeyframe(const MapKeyframe& keyframe, const PinholeCamera& camera);

  /// Replaces the agent's map cloud [map units].
  void setCloud(Cloud cloud) { cloud_ = std::move(cloud); }

  /// As setKeyframe() for an LSD-SLAM keyframe. @throw InputError on a different camera
  bool setLsdKeyframe(const LsdKeyframe& keyframe);

  /**
   * @brief Applies the camToWorld poses of an LSD-SLAM graph message.
   * @param[in] poses (keyframe id, camToWorld)
   * @return how many known LSD keyframes got a new pose (unknown ids are ignored)
   */
  int updateLsdPoses(const std::vector<std::pair<long, Sim3>>& poses);

  /// @return number of keyframes (plain or LSD)
  std::size_t keyframeCount() const { return keyframes_.size() + lsd_keyframes_.size(); }
  /// @return ids of all keyframes, ascending
  std::vector<long> keyframeIds() const;
  /// @return number of points of the received map cloud (plain mode)
  std::size_t cloudPoints() const { return static_cast<std::size_t>(cloud_.cols()); }
  /// @return the camera pose of keyframe `id` (plain or LSD), false when unknown
  bool keyframePose(long id, Sim3* pose) const;

  /**
   * @brief The agent's map for the merge pipeline. Plain keyframes come with the latest map
   * cloud; LSD keyframes become keyframes (grey image, depth of the kept points) and the map
   * cloud is the union of their filtered points mapped by their current camToWorld.
   * @param[in] lsd_filters LSD viewer filters for LSD keyframes
   */
  AgentMap toAgentMap(const LsdFilterOptions& lsd_filters) const;

 private:
  void checkCamera(const PinholeCamera& camera, long id);

  std::string frame_id_;
  bool has_camera_ = false;
  PinholeCamera camera_;
  std::map<long, MapKeyframe> keyframes_;
  Cloud cloud_ = Cloud(3, 0);
  std::map<long, LsdKeyframe> lsd_keyframes_;
};

}  // namespace ros_bridge
}  // namespace pcr_pro
