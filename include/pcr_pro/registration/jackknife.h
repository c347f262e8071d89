/**
 * @file jackknife.h
 * @brief The spread of a registration between parts of the maps, measured by re-running it: the
 * overlap is cut into spatial blocks, and the registration is repeated from its estimate without
 * each block in turn (a delete-one jackknife over blocks). Where the closed-form covariance and
 * the linearised block spread (covariance.h) assume the correspondences and their normals are
 * right, this sees what the data does when part of it is taken away: a weak direction that noisy
 * normals hide, a block that pulls the estimate on its own, a map whose parts want different
 * similarities.
 */
#pragma once

#include <string>
#include <vector>

#include "pcr_pro/geometry/similarity_fit.h"
#include "pcr_pro/geometry/sim3.h"
#include "pcr_pro/geometry/types.h"
#include "pcr_pro/registration/icp.h"

namespace pcr_pro {

/// Outcome of jackknifeCovariance().
struct JackknifeSpread {
  bool ok = false;  ///< covariance is set (at least 3 blocks re-registered)
  int blocks = 0;   ///< blocks left out whose registration gave a finite estimate
  int not_converged = 0;  ///< of those, registrations that did not converge (kept: see below)
  int failed = 0;         ///< blocks whose registration gave no estimate (too few correspondences)
  /// Jackknife covariance (K - 1)/K Σ (δ_k - δ̄)(δ_k - δ̄)ᵀ of δ_k = similarityDifference(estimate
  /// without block k, estimate), without its cross terms between the translation at the
  /// overlap's centre, the rotation and the log scale (blockDiagonalAt(): K estimates resolve
  /// those correlations poorly; in a first probe, with them, the 6-DoF ANEES of the bench's 24
  /// simulated worlds was 5.1 instead of 1.5, while rotation and translation alone were 1.1 and
  /// 0.8).
  Matrix7d covariance = Matrix7d::Zero();
  std::string message;  ///< what was done, or why there is no covariance
};

/**
 * @brief The delete-one jackknife covariance (K - 1)/K Σ (δ_k - δ̄)(δ_k - δ̄)ᵀ of K leave-out
 * estimates' differences δ_k from the full estimate.
 * @param[in] deltas the δ_k (similarityDifference(estimate without part k, estimate)), at least one
 */
Matrix7d jackknifeSpread(const std::vector<Eigen::Matrix<double, 7, 1>>& deltas);

/**
 * @brief Delete-one-block jackknife of a registration.
 *
 * The source points, mapped by `estimate`, are cut into `blocks` spatial blocks (spatialBlocks():
 * median splits along the widest axis); each target point belongs to the block of its nearest
 * mapped source point. For each block, both clouds without it are registered again from
 * `estimate` with `options` (and the anchors, which are not spatial blocks of the clouds, whole).
 * A registration that stops at its iteration limit still says where the data without that block
 * leads, so its estimate counts; one without an estimate is counted as failed.
 *
 * @param[in] source, target the clouds as registered (after the filters) [source / target units]
 * @param[in] estimate the registration's S_target_source
 * @param[in] options the ICP options it ran with (estimate_scale included)
 * @param[in] blocks blocks to leave out, >= 3
 * @param[in] anchors optional anchor matches, as given to alignIcp()
 * @throw InputError when blocks < 3
 */
JackknifeSpread jackknifeCovariance(const Cloud& source, const Cloud& target, const Sim3& estimate,
                                   const IcpOptions& options, int blocks,
                                   const std::vector<PointMatch3>* anchors = nullptr);

}  // namespace pcr_pro
