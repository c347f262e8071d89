// The registration tools a user would pick instead of pcr_pro, behind one interface: PCL's
// IterativeClosestPoint, GeneralizedIterativeClosestPoint and NormalDistributionsTransform,
// and Open3D's FPFH + RANSAC global registration with scaling followed by ICP with scaling.
// Each TU includes only its own library (PCL and Open3D headers do not mix well).
#pragma once

#include <string>
#include <vector>

#include "pcr_pro/geometry/sim3.h"

namespace pcr_pro {
namespace bench {

struct PeerResult {
  bool ran = false;       ///< the method returned a transform
  Sim3 transform;         ///< S_target_source
  double ms = 0.0;        ///< wall time [ms]
};

/// Parameters shared by the peers, derived per case from the clouds (never from the truth).
struct PeerParams {
  double target_size = 1.0;  ///< robust size of the target cloud [target units]
  double source_size = 1.0;  ///< robust size of the source cloud [source units]
};

/// The PCL version string.
std::string pclVersion();
/// PCL method names, in the order of runPcl().
std::vector<std::string> pclMethods();
/// Runs PCL method `index` from identity.
PeerResult runPcl(int index, const Cloud& source, const Cloud& target, const PeerParams& params);

/// @return true when the benchmark was built with Open3D
bool haveOpen3d();
/// Open3D FPFH + RANSAC (with scaling) + ICP (with scaling). ran = false without Open3D.
PeerResult runOpen3d(const Cloud& source, const Cloud& target, const PeerParams& params);
/// The Open3D version string, or "not built".
std::string open3dVersion();

}  // namespace bench
}  // namespace pcr_pro
