// The registration tools a user would pick instead of pcr_pro, behind one interface: PCL's
// IterativeClosestPoint, GeneralizedIterativeClosestPoint and NormalDistributionsTransform
// (rigid refiners: they need a start and cannot find a scale), and Open3D's FPFH + RANSAC
// global registration followed by ICP with scaling, on clouds normalised by their own extent. Each TU includes only its own library (PCL and Open3D headers do not mix well).
#pragma once

#include <string>
#include <vector>

#include "pcr_pro/geometry/sim3.h"

namespace pcr_pro {
namespace bench {

struct PeerResult {
  bool ran = false;       ///< the method returned a transform
  Sim3 transform;         ///< S_target_source
  double fitness = 0.0;   ///< the method's own inlier fraction, where it has one [-]
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
/**
 * Runs PCL method `index` from `start` (a similarity: the source is scaled by start's scale first,
 * the rigid method refines rotation and translation, the scale stays). Thresholds relative to the
 * target size.
 */
PeerResult runPcl(int index, const Cloud& source, const Cloud& target, const PeerParams& params,
                  const Sim3& start = Sim3());

/// One setting of the Open3D recipe, every length relative to the normalised clouds (extent 1).
struct Open3dSetting {
  double voxel = 0.03;           ///< voxel size of the down-sampling (normals at 2x, RANSAC gate at 1.5x, ICP gate at 1x)
  double feature_radius = 5.0;   ///< FPFH radius in voxels
  std::string name() const;      ///< e.g. "voxel 0.030 / FPFH 5 voxels"
};

/// The settings the benchmark sweeps (the best per case family is reported and used).
std::vector<Open3dSetting> open3dSettings();

/// @return true when the benchmark was built with Open3D
bool haveOpen3d();
/**
 * Open3D FPFH + RANSAC (rigid, on the normalised clouds) + ICP with scaling. Each cloud is first centred and
 * divided by its own size (params), so that one setting fits clouds in any units; the result is
 * mapped back. Deterministic for a seed. ran = false without Open3D.
 */
PeerResult runOpen3d(const Cloud& source, const Cloud& target, const PeerParams& params, const Open3dSetting& setting,
                     int seed = 1);
/// The Open3D version string, or "not built".
std::string open3dVersion();

}  // namespace bench
}  // namespace pcr_pro
