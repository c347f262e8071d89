#include "peers.h"

#ifdef PCR_PRO_BENCH_OPEN3D
#include <open3d/Open3D.h>
#endif

#include "bench_common.h"

namespace pcr_pro {
namespace bench {

#ifdef PCR_PRO_BENCH_OPEN3D
namespace {

std::shared_ptr<open3d::geometry::PointCloud> toOpen3d(const Cloud& c) {
  auto out = std::make_shared<open3d::geometry::PointCloud>();
  out->points_.reserve(static_cast<std::size_t>(c.cols()));
  for (Eigen::Index i = 0; i < c.cols(); ++i) out->points_.emplace_back(c.col(i));
  return out;
}

}  // namespace

bool haveOpen3d() { return true; }
std::string open3dVersion() { return OPEN3D_VERSION; }

PeerResult runOpen3d(const Cloud& source, const Cloud& target, const PeerParams& p) {
  namespace reg = open3d::pipelines::registration;
  using open3d::geometry::KDTreeSearchParamHybrid;
  PeerResult r;
  const auto src = toOpen3d(source), tgt = toOpen3d(target);
  const double t0 = nowMs();
  // The usual global-registration recipe (Open3D tutorial), with every length relative to each
  // cloud's own size: the clouds are in different, unknown units.
  const double vt = p.target_size / 40.0, vs = p.source_size / 40.0;
  auto tgt_down = tgt->VoxelDownSample(vt);
  auto src_down = src->VoxelDownSample(vs);
  tgt_down->EstimateNormals(KDTreeSearchParamHybrid(2.0 * vt, 30));
  src_down->EstimateNormals(KDTreeSearchParamHybrid(2.0 * vs, 30));
  const auto tgt_fpfh = reg::ComputeFPFHFeature(*tgt_down, KDTreeSearchParamHybrid(5.0 * vt, 100));
  const auto src_fpfh = reg::ComputeFPFHFeature(*src_down, KDTreeSearchParamHybrid(5.0 * vs, 100));
  const reg::CorrespondenceCheckerBasedOnDistance distance_check(1.5 * vt);
  const auto global = reg::RegistrationRANSACBasedOnFeatureMatching(
      *src_down, *tgt_down, *src_fpfh, *tgt_fpfh, false, 1.5 * vt, reg::TransformationEstimationPointToPoint(true), 3,
      {distance_check}, reg::RANSACConvergenceCriteria(100000, 0.999));
  const auto refined = reg::RegistrationICP(*src, *tgt, 1.0 * vt, global.transformation_,
                                            reg::TransformationEstimationPointToPoint(true),
                                            reg::ICPConvergenceCriteria(1e-7, 1e-7, 60));
  r.ms = nowMs() - t0;
  const Eigen::Matrix4d m = refined.transformation_;
  if (m.allFinite()) {
    try {
      r.transform = Sim3::fromMatrix(m);
      r.ran = true;
    } catch (const std::exception&) {
      r.ran = false;
    }
  }
  return r;
}
#else
bool haveOpen3d() { return false; }
std::string open3dVersion() { return "not built"; }
PeerResult runOpen3d(const Cloud&, const Cloud&, const PeerParams&) { return PeerResult(); }
#endif

}  // namespace bench
}  // namespace pcr_pro
