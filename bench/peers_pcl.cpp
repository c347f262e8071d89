#include <pcl/point_cloud.h>
#include <pcl/point_types.h>
#include <pcl/registration/gicp.h>
#include <pcl/registration/icp.h>
#include <pcl/registration/ndt.h>

#include "bench_common.h"
#include "pcr_pro/pcl.h"
#include "peers.h"

namespace pcr_pro {
namespace bench {
namespace {

// Runs a rigid PCL registration of `start`'s scale applied to the source, from start's rigid
// part; the result keeps start's scale.
template <class Reg>
PeerResult runReg(Reg& reg, const Cloud& source, const Cloud& target, const Sim3& start) {
  PeerResult r;
  const auto src = toPcl(start.scale() * source), tgt = toPcl(target);
  Eigen::Matrix4f guess = Eigen::Matrix4f::Identity();
  guess.topLeftCorner<3, 3>() = start.rotation().cast<float>();
  guess.topRightCorner<3, 1>() = start.translation().cast<float>();
  const double t0 = nowMs();
  reg.setInputSource(src);
  reg.setInputTarget(tgt);
  pcl::PointCloud<pcl::PointXYZ> aligned;
  reg.align(aligned, guess);
  r.ms = nowMs() - t0;
  const Eigen::Matrix4d m = reg.getFinalTransformation().template cast<double>();
  if (m.allFinite() && reg.hasConverged()) {
    try {
      r.transform = Sim3::fromMatrix(m) * Sim3(start.scale(), Eigen::Matrix3d::Identity(), Eigen::Vector3d::Zero());
      r.ran = true;
    } catch (const std::exception&) {
      r.ran = false;
    }
  }
  return r;
}

}  // namespace

std::string pclVersion() { return PCL_VERSION_PRETTY; }

std::vector<std::string> pclMethods() {
  return {"PCL IterativeClosestPoint", "PCL GeneralizedIterativeClosestPoint", "PCL NormalDistributionsTransform"};
}

PeerResult runPcl(int index, const Cloud& source, const Cloud& target, const PeerParams& p, const Sim3& start) {
  // Thresholds as a user refining a start would set them without knowing the answer, relative to
  // the target size: a correspondence gate of 3 % of the map, wider than the start's expected error
  // (the keyframe estimate is within a few % of the extent) and narrower than the parts of a
  // partially overlapping map that have no counterpart.
  const double max_corr = 0.03 * p.target_size;
  // ICP and GICP take the same three settings.
  const auto icpLike = [&](auto& reg) {
    reg.setMaxCorrespondenceDistance(max_corr);
    reg.setMaximumIterations(100);
    reg.setTransformationEpsilon(1e-10);
    return runReg(reg, source, target, start);
  };
  if (index == 0) {
    pcl::IterativeClosestPoint<pcl::PointXYZ, pcl::PointXYZ> icp;
    return icpLike(icp);
  }
  if (index == 1) {
    pcl::GeneralizedIterativeClosestPoint<pcl::PointXYZ, pcl::PointXYZ> gicp;
    return icpLike(gicp);
  }
  pcl::NormalDistributionsTransform<pcl::PointXYZ, pcl::PointXYZ> ndt;
  ndt.setResolution(static_cast<float>(p.target_size / 20.0));
  ndt.setStepSize(0.05 * p.target_size);
  ndt.setTransformationEpsilon(1e-6 * p.target_size);
  ndt.setMaximumIterations(100);
  return runReg(ndt, source, target, start);
}

}  // namespace bench
}  // namespace pcr_pro
