// Shared helpers for the unit tests: synthetic clouds, transforms and error measures.
#pragma once

#include <Eigen/Geometry>

#include <cmath>
#include <fstream>
#include <random>
#include <sstream>
#include <string>

#include "common/data_dir.h"
#include "pcr_pro/geometry/sim3.h"

namespace pcr_pro {
namespace test {

inline double deg(double rad) { return rad * 180.0 / M_PI; }
inline double rad(double deg) { return deg * M_PI / 180.0; }

/// Rotation of `angle` about a random axis drawn from rng.
inline Eigen::Matrix3d randomRotation(std::mt19937& rng, double angle) {
  std::normal_distribution<double> n(0.0, 1.0);
  const Eigen::Vector3d axis = Eigen::Vector3d(n(rng), n(rng), n(rng)).normalized();
  return Eigen::AngleAxisd(angle, axis).toRotationMatrix();
}

/// A sparse, non-degenerate synthetic "room": points on several planes and a sphere, with
/// varying density, n points, about `size` across.
inline Cloud syntheticScene(int n, double size, std::mt19937& rng) {
  std::uniform_real_distribution<double> u(-0.5, 0.5);
  std::uniform_int_distribution<int> pick(0, 5);
  Cloud c(3, n);
  for (int i = 0; i < n; ++i) {
    Eigen::Vector3d p;
    switch (pick(rng)) {
      case 0: p << u(rng), u(rng), -0.5; break;                        // floor
      case 1: p << -0.5, u(rng), u(rng); break;                        // wall
      case 2: p << u(rng), 0.5, u(rng) ; break;                        // wall
      case 3: p << 0.2 + 0.15 * u(rng), -0.2 + 0.15 * u(rng), -0.5 + 0.3 * (u(rng) + 0.5); break;  // box
      case 4: {                                                        // sphere
        Eigen::Vector3d d(u(rng), u(rng), u(rng));
        p = Eigen::Vector3d(-0.15, 0.1, -0.25) + 0.18 * d.normalized();
        break;
      }
      default: p << 0.35 * u(rng) - 0.1, -0.45, 0.8 * u(rng); break;  // partial wall
    }
    c.col(i) = size * p;
  }
  return c;
}

/// Reads the ground truth gT (401 -> 400) from the real data's libpointmatcher_car/carCloudList.csv
/// (callers skip first with PCR_PRO_REQUIRE_DATA).
inline Sim3 carGroundTruth() {
  std::ifstream in(dataPath("libpointmatcher_car/carCloudList.csv"));
  std::string line;
  while (std::getline(in, line)) {
    if (line.rfind("car_cloud401.csv", 0) != 0) continue;
    for (char& ch : line) {
      if (ch == ',') ch = ' ';
    }
    std::istringstream ls(line);
    std::string name;
    ls >> name;
    Eigen::Matrix4d m;
    for (int i = 0; i < 16; ++i) ls >> m(i / 4, i % 4);
    return Sim3::fromMatrix(m);
  }
  throw std::runtime_error("carCloudList.csv has no car_cloud401.csv row");
}

}  // namespace test
}  // namespace pcr_pro
