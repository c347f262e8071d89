// Shared by the unit tests and the benchmarks: the synthetic room, the real car pair's ground
// truth, the errors of an estimated similarity against its truth, and its rotation's NEES.
#pragma once

#include <Eigen/Cholesky>
#include <Eigen/Geometry>

#include <cmath>
#include <fstream>
#include <random>
#include <sstream>
#include <stdexcept>
#include <string>

#include "pcr_pro/geometry/sim3.h"
#include "pcr_pro/geometry/similarity_fit.h"
#include "pcr_pro/geometry/types.h"

namespace pcr_pro {
namespace test {

/// A sparse, non-degenerate synthetic "room": points on a floor, two walls, a box, a sphere and a
/// partial wall, with varying density, n points, about `size` across. Every call draws a new
/// independent sample from rng.
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

/// The ground truth 401 -> 400 of the libpointmatcher car pair, read from its carCloudList.csv
/// (4x4 row-major after the file name). @throw std::runtime_error when the row is missing
inline Sim3 carGroundTruth(const std::string& car_cloud_list) {
  std::ifstream in(car_cloud_list);
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
  throw std::runtime_error(car_cloud_list + ": no line for car_cloud401.csv");
}

/// Errors of an estimated S_target_source against the truth.
struct Errors {
  double rotation_deg = 0.0;  ///< angle of R_est R_trueᵀ [deg]
  double translation = 0.0;   ///< |t_est - t_true| [target units]
  double scale_rel = 0.0;     ///< |s / s_true - 1| [-]
};

inline Errors errors(const Sim3& est, const Sim3& truth) {
  Errors e;
  e.rotation_deg = rotationDistance(est.rotation(), truth.rotation()) * 180.0 / M_PI;
  e.translation = (est.translation() - truth.translation()).norm();
  e.scale_rel = std::abs(est.scale() / truth.scale() - 1.0);
  return e;
}

/// The 3-DoF NEES of an estimate's rotation against a truth that is itself only good to
/// truth_sd [rad] per axis: the rotation block of the estimate's 6-DoF covariance (similarity_fit.h's
/// convention, about the estimate) plus truth_sd² on each axis.
inline double rotationNees(const Sim3& estimate, const Sim3& truth, const Matrix6d& covariance, double truth_sd) {
  const Eigen::Vector3d r = similarityDifference(estimate, truth).segment<3>(3);
  const Eigen::Matrix3d c = covariance.block<3, 3>(3, 3) + truth_sd * truth_sd * Eigen::Matrix3d::Identity();
  return r.dot(c.ldlt().solve(r));
}

}  // namespace test
}  // namespace pcr_pro
