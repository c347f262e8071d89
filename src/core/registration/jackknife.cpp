#include "pcr_pro/registration/jackknife.h"

#include <sstream>
#include <string>

#include "pcr_pro/geometry/kdtree.h"
#include "pcr_pro/registration/covariance.h"

namespace pcr_pro {

Matrix7d jackknifeSpread(const std::vector<Eigen::Matrix<double, 7, 1>>& deltas) {
  const double k = static_cast<double>(deltas.size());
  Eigen::Matrix<double, 7, 1> mean = Eigen::Matrix<double, 7, 1>::Zero();
  for (const auto& d : deltas) mean += d / k;
  Matrix7d c = Matrix7d::Zero();
  for (const auto& d : deltas) c += (d - mean) * (d - mean).transpose();
  return c * (k - 1.0) / k;
}

JackknifeSpread jackknifeCovariance(const Cloud& source, const Cloud& target, const Sim3& estimate,
                                   const IcpOptions& options, int blocks, const std::vector<PointMatch3>* anchors) {
  if (blocks < 3) throw InputError("jackknifeCovariance: blocks must be >= 3, got " + std::to_string(blocks));
  JackknifeSpread out;
  const Cloud mapped = estimate.apply(source);
  const std::vector<std::vector<Eigen::Index>> parts = spatialBlocks(mapped, blocks);
  const int k = static_cast<int>(parts.size());
  if (k < 3) {
    out.message = "jackknife: the clouds make " + std::to_string(k) + " spatial block(s), fewer than 3";
    return out;
  }
  std::vector<int> source_block(static_cast<std::size_t>(source.cols()), 0);
  for (int b = 0; b < k; ++b) {
    for (Eigen::Index i : parts[static_cast<std::size_t>(b)]) source_block[static_cast<std::size_t>(i)] = b;
  }
  const KdTree mapped_tree(mapped);
  std::vector<int> target_block(static_cast<std::size_t>(target.cols()), 0);
  for (Eigen::Index i = 0; i < target.cols(); ++i) {
    double d2 = 0.0;
    const Eigen::Index nearest = mapped_tree.nearest(Eigen::Vector3d(target.col(i)), &d2);
    if (nearest >= 0) target_block[static_cast<std::size_t>(i)] = source_block[static_cast<std::size_t>(nearest)];
  }
  std::vector<Eigen::Matrix<double, 7, 1>> deltas;
  for (int b = 0; b < k; ++b) {
    std::vector<Eigen::Index> keep_source, keep_target;
    for (Eigen::Index i = 0; i < source.cols(); ++i) {
      if (source_block[static_cast<std::size_t>(i)] != b) keep_source.push_back(i);
    }
    for (Eigen::Index i = 0; i < target.cols(); ++i) {
      if (target_block[static_cast<std::size_t>(i)] != b) keep_target.push_back(i);
    }
    const Cloud s = source(Eigen::all, keep_source), t = target(Eigen::all, keep_target);
    if (s.cols() == 0 || t.cols() == 0) {
      ++out.failed;
      continue;
    }
    const KdTree tree(t);
    const IcpResult r = alignIcp(s, tree, estimate, options, anchors);
    const bool has = r.status == Status::kOk || r.correspondences >= options.min_correspondences;
    const Eigen::Matrix<double, 7, 1> d = similarityDifference(r.transform, estimate);
    if (!has || !d.allFinite()) {
      ++out.failed;
      continue;
    }
    if (r.status != Status::kOk) ++out.not_converged;
    deltas.push_back(d);
  }
  out.blocks = static_cast<int>(deltas.size());
  std::ostringstream msg;
  msg.precision(3);
  if (out.blocks < 3) {
    msg << "jackknife: " << out.blocks << " of " << k << " leave-one-block-out registrations gave an estimate, "
        << "fewer than 3";
    out.message = msg.str();
    return out;
  }
  const Eigen::Vector3d centre = mapped.rowwise().mean();
  out.covariance = blockDiagonalAt(jackknifeSpread(deltas), centre);
  if (!options.estimate_scale) {
    out.covariance.row(6).setZero();
    out.covariance.col(6).setZero();
  }
  out.ok = out.covariance.allFinite();
  msg << "jackknife over " << out.blocks << " spatial blocks";
  if (k < blocks) msg << " (" << blocks << " asked; a block keeps at least 50 points)";
  if (out.not_converged > 0) msg << ", " << out.not_converged << " of them not converged";
  if (out.failed > 0) msg << ", " << out.failed << " without an estimate";
  out.message = out.ok ? msg.str() : "jackknife: the spread is not finite";
  return out;
}

}  // namespace pcr_pro
