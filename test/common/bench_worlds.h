// The simulated worlds of `make bench` (bench/section_simulated.cpp), shared with the tests that
// check a finding of the bench on one of them, so that both build the same world.
#pragma once

#include <cstdint>

#include "pcr_pro/io/lsd_keyframe.h"
#include "pcr_pro/sim/simulator.h"

namespace pcr_pro {
namespace test {

/**
 * One bench world: agents a and b with the cell's overlap, scale drift and inverse-depth noise;
 * with `apart`, a third agent that does not overlap a. 320x240 keyframes as the real LSD-SLAM
 * runs give (and a quarter of the rendering and SIFT cost of 640x480); paths of about 5 keyframes
 * as in the merge tests (60 deg of azimuth, a keyframe every 15 deg or 0.45 m).
 * @param[in] seed the world's index within its cell (simulator seed 1000 + seed)
 * @param[in] source_noise agent_b's (the merges' source's) own inverse-depth noise; < 0 = `noise`
 */
inline SimulatorOptions benchWorldOptions(double overlap, double drift, double noise, int seed, bool apart,
                                          double source_noise = -1.0) {
  SimulatorOptions o;
  o.seed = static_cast<std::uint64_t>(1000 + seed);
  o.agents = apart ? 3 : 2;
  o.camera = PinholeCamera{262.5, 262.5, 159.5, 119.5, 320, 240};
  o.layout.overlap = overlap;
  o.trajectory.azimuth_span_deg = 60.0;
  o.trajectory.keyframe_angle_deg = 15.0;
  o.trajectory.keyframe_distance = 0.45;
  // Drift of either sign (alternating with the seed), and the map bend that comes with it.
  o.drift.scale_drift = (seed % 2 ? -1.0 : 1.0) * drift;
  o.drift.bend_deg = 40.0 * drift;
  o.map.semi_dense.idepth_noise = noise;
  if (source_noise >= 0.0) {  // agent_b (the merges' source) at its own inverse-depth noise
    o.per_agent.resize(2);
    o.per_agent[1].idepth_noise = source_noise;
  }
  return o;
}

/// The map without its keyframes' depth images: keyframe depth then comes from the map cloud.
inline AgentMap withoutDepthImages(const AgentMap& map) {
  AgentMap out = map;
  for (MapKeyframe& k : out.keyframes) k.depth = cv::Mat();
  return out;
}

/**
 * The agent's map with each keyframe's depth as LSD-SLAM hands it to the merge node: the
 * keyframe's own semi-dense inverse depth with its variance (toKeyframe() of toLsdKeyframe()),
 * in LSD-SLAM's normalised units, the pose scaled to match (map pose * Sim3(lsd_scale)). Besides
 * dense depth images and the map cloud projected into the keyframe, the third source of keyframe
 * depth a merge meets.
 */
inline AgentMap withLsdKeyframeDepth(const SimAgent& agent, const PinholeCamera& camera) {
  AgentMap out = agent.map;
  for (MapKeyframe& k : out.keyframes) {
    for (const SimKeyframe& s : agent.keyframes) {
      if (s.id != k.id) continue;
      const MapKeyframe lsd = toKeyframe(toLsdKeyframe(s, camera, 0.0));
      k.depth = lsd.depth;
      k.depth_stddev = lsd.depth_stddev;
      k.pose = k.pose * Sim3(s.lsd_scale, Eigen::Matrix3d::Identity(), Eigen::Vector3d::Zero());
      break;
    }
  }
  return out;
}

}  // namespace test
}  // namespace pcr_pro
