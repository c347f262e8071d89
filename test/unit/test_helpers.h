// Shared helpers for the unit tests: synthetic clouds, transforms and error measures (those the
// benchmarks use too are in common/geometry_checks.h).
#pragma once

#include <Eigen/Geometry>

#include <cmath>
#include <fstream>
#include <random>
#include <sstream>
#include <string>

#include "common/data_dir.h"
#include "common/geometry_checks.h"
#include "pcr_pro/geometry/sim3.h"
#include "pcr_pro/sim/simulator.h"

namespace pcr_pro {
namespace test {

inline double deg(double rad) { return rad * 180.0 / M_PI; }
inline double rad(double deg) { return deg * M_PI / 180.0; }

/// The merge tests' simulated world: agents sweeping 60 deg of azimuth with a keyframe every
/// 15 deg or 0.45 m (about 5 keyframes each, as in the bench's worlds), no drift, depth images.
inline SimulatorOptions mergeTestWorld(std::uint64_t seed, int agents, double overlap) {
  SimulatorOptions o;
  o.seed = seed;
  o.agents = agents;
  o.layout.overlap = overlap;
  o.trajectory.azimuth_span_deg = 60.0;
  o.trajectory.keyframe_angle_deg = 15.0;
  o.trajectory.keyframe_distance = 0.45;
  return o;
}

/// Rotation of `angle` about a random axis drawn from rng.
inline Eigen::Matrix3d randomRotation(std::mt19937& rng, double angle) {
  std::normal_distribution<double> n(0.0, 1.0);
  const Eigen::Vector3d axis = Eigen::Vector3d(n(rng), n(rng), n(rng)).normalized();
  return Eigen::AngleAxisd(angle, axis).toRotationMatrix();
}

/// Ground truth gT (401 -> 400) of the real car pair (callers skip first with PCR_PRO_REQUIRE_DATA).
inline Sim3 carGroundTruth() { return carGroundTruth(dataPath("libpointmatcher_car/carCloudList.csv")); }

}  // namespace test
}  // namespace pcr_pro
