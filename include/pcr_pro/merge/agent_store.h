/**
 * @file agent_store.h
 * @brief What the merge node keeps of one agent: keyframes by id (a re-sent id replaces the old
 * keyframe), the latest map cloud, or, in LSD-SLAM mode, LSD keyframes whose poses graph
 * messages update. Bounded in memory by StoreLimits: beyond max_keyframes the keyframe received
 * longest ago is dropped, and a map cloud above max_cloud_points is voxelised until it fits.
 * ROS-free and not thread-safe: the node guards each store with a mutex and merges on a copy
 * (copies share the images, which are never written in place).
 */
#pragma once

#include <cstdint>
#include <map>
#include <string>
#include <utility>
#include <vector>

#include "pcr_pro/geometry/map_types.h"
#include "pcr_pro/io/lsd_keyframe.h"
#include "pcr_pro/io/param_schema.h"

namespace pcr_pro {

/// Per-agent memory bounds of the merge node (parameters `~max_keyframes_per_agent`,
/// `~max_cloud_points_per_agent`); the defaults are written here once.
struct StoreLimits {
  /// Most keyframes kept per agent [-], >= 1. A keyframe beyond it makes the store drop the
  /// keyframe received longest ago (a re-sent id counts as received anew): the map follows the
  /// robot instead of freezing at its first keyframes. In LSD-SLAM mode the dropped keyframe's
  /// points leave the map cloud with it.
  int max_keyframes = 50;
  /// Most map points per agent [points], in [1000, 200 000 000]. A larger map cloud (the received
  /// cloud, or in LSD-SLAM mode the union of the keyframes' points) is voxelised with the
  /// smallest leaf found that brings it under the cap (never subsampled blindly unless the
  /// voxel grid cannot get there).
  int max_cloud_points = 1'000'000;
};

/// Every parameter of StoreLimits (ROS parameters `~max_keyframes_per_agent`, `~max_cloud_points_per_agent`): key, type, default (the member initialiser), range, unit, doc.
template <>
const ParamSchema<StoreLimits>& paramSchema<StoreLimits>();

/// @throw InputError "max_keyframes_per_agent: ..." / "max_cloud_points_per_agent: ..." when out of range
void validate(const StoreLimits& limits);

/// What capCloud() did.
struct CloudCap {
  std::int64_t input_points = 0;  ///< points before [points]
  std::int64_t kept_points = 0;   ///< points after [points]
  double leaf = 0.0;              ///< voxel leaf used [cloud units]; 0 = the cloud was within the cap
  bool subsampled = false;        ///< the voxel grid could not reach the cap: uniform subsampling was used
  bool capped() const { return kept_points < input_points; }
};

/**
 * @brief Keeps a cloud within `max_points`: unchanged when it already is, otherwise voxelised with
 * a leaf searched (at most 8 voxel-grid passes, secant steps on log(points) vs log(leaf), done once
 * a pass keeps 75 % to 100 % of the cap) to be close to the smallest one that leaves at most
 * max_points; the best pass under the cap otherwise, and a uniform random subsample as a last
 * resort (no pass under the cap, or extents a voxel grid cannot index).
 * @param[in] cloud finite points [cloud units]
 * @param[in] max_points cap [points], >= 1
 * @param[out] info what was done (optional)
 * @return at most max_points points
 */
Cloud capCloud(const Cloud& cloud, std::int64_t max_points, CloudCap* info = nullptr);

class AgentStore {
 public:
  /// @param[in] frame_id the agent's map frame (no leading slash)
  /// @param[in] limits memory bounds. @throw InputError when invalid
  explicit AgentStore(std::string frame_id = "map", StoreLimits limits = StoreLimits());

  const std::string& frameId() const { return frame_id_; }
  const StoreLimits& limits() const { return limits_; }

  /**
   * @brief Adds a keyframe, or replaces the one with the same id.
   * @param[in] keyframe keyframe (image CV_8UC1, optional depth CV_32FC1)
   * @param[in] camera its camera; all keyframes of an agent share one camera
   * @param[out] dropped ids of keyframes dropped to stay within limits().max_keyframes (optional)
   * @return true when a keyframe with this id was replaced
   * @throw InputError when the camera differs from the agent's earlier keyframes' (nothing changes)
   */
  bool setKeyframe(const MapKeyframe& keyframe, const PinholeCamera& camera, std::vector<long>* dropped = nullptr);

  /// Replaces the agent's map cloud [map units], voxelised to limits().max_cloud_points if larger.
  /// @return what the cap did
  CloudCap setCloud(Cloud cloud);

  /// As setKeyframe() for an LSD-SLAM keyframe. @throw InputError on a different camera
  bool setLsdKeyframe(const LsdKeyframe& keyframe, std::vector<long>* dropped = nullptr);

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
  /// @return number of points of the kept map cloud (plain mode)
  std::size_t cloudPoints() const { return static_cast<std::size_t>(cloud_.cols()); }
  /// @return the camera pose of keyframe `id` (plain or LSD), false when unknown
  bool keyframePose(long id, Sim3* pose) const;

  /**
   * @brief The agent's map for the merge pipeline. Plain keyframes come with the latest map
   * cloud; LSD keyframes become keyframes (grey image, their whole semi-dense depth with its
   * standard deviation from the inverse-depth variance, toKeyframe()) and the map
   * cloud is the union of their filtered points mapped by their current camToWorld, voxelised to
   * limits().max_cloud_points if larger.
   * @param[in] lsd_filters LSD viewer filters for LSD keyframes
   * @param[out] cap what the cap did to the LSD union cloud (optional; untouched in plain mode)
   */
  AgentMap toAgentMap(const LsdFilterOptions& lsd_filters, CloudCap* cap = nullptr) const;

 private:
  void checkCamera(const PinholeCamera& camera, long id);
  void noteArrival(long id, std::vector<long>* dropped);

  std::string frame_id_;
  StoreLimits limits_;
  bool has_camera_ = false;
  PinholeCamera camera_;
  std::map<long, MapKeyframe> keyframes_;
  Cloud cloud_ = Cloud(3, 0);
  std::map<long, LsdKeyframe> lsd_keyframes_;
  // Arrival order of every kept keyframe id (plain or LSD), for dropping the oldest.
  std::uint64_t arrivals_ = 0;
  std::map<long, std::uint64_t> arrival_;
};

}  // namespace pcr_pro
