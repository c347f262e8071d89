// A similarity written in a test case's YAML (truth files of the generated worlds and of the real
// LSD-SLAM bags): one reader for their spellings.
#pragma once

#include <yaml-cpp/yaml.h>

#include <Eigen/Geometry>

#include "pcr_pro/geometry/sim3.h"

namespace pcr_pro {
namespace test {

/**
 * @brief The similarity of a YAML map: the scale under "s" or "scale" (1 when neither is there),
 * the quaternion [x, y, z, w] under `rotation_key` (normalised by Sim3), the translation under
 * "t" or "translation".
 * @throw YAML::Exception when a key is missing or not a number
 */
inline Sim3 sim3FromYaml(const YAML::Node& n, const char* rotation_key = "rotation") {
  const YAML::Node q = n[rotation_key], t = n["t"] ? n["t"] : n["translation"];
  const double s = n["s"] ? n["s"].as<double>() : (n["scale"] ? n["scale"].as<double>() : 1.0);
  return Sim3(s, Eigen::Quaterniond(q[3].as<double>(), q[0].as<double>(), q[1].as<double>(), q[2].as<double>()),
              Eigen::Vector3d(t[0].as<double>(), t[1].as<double>(), t[2].as<double>()));
}

}  // namespace test
}  // namespace pcr_pro
