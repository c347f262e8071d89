// The simulated worlds of `make bench` (bench/section_simulated.cpp), shared with the tests that
// check a finding of the bench on one of them, so that both build the same world.
#pragma once

#include <cstdint>

#include "pcr_pro/sim/simulator.h"

namespace pcr_pro {
namespace test {

/**
 * One bench world: agents a and b with the cell's overlap, scale drift and inverse-depth noise;
 * with `apart`, a third agent that does not overlap a. 320x240 keyframes as the real LSD-SLAM
 * runs give (and a quarter of the rendering and SIFT cost of 640x480); paths of about 5 keyframes
 * as in the merge tests (60 deg of azimuth, a keyframe every 15 deg or 0.45 m).
 * @param[in] seed the world's index within its cell (simulator seed 1000 + seed)
 */
inline SimulatorOptions benchWorldOptions(double overlap, double drift, double noise, int seed, bool apart) {
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
  return o;
}

}  // namespace test
}  // namespace pcr_pro
