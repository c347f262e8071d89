/**
 * @file cloud_registration.h
 * @brief The geometric half of PCR-Pro on two clouds: scale detection, filters, ICP (optionally
 * with scale) and closed-form covariance / information.
 */
#pragma once

#include <optional>

#include "pcr_pro/registration/config.h"
#include "pcr_pro/geometry/kdtree.h"
#include "pcr_pro/io/report.h"
#include "pcr_pro/geometry/sim3.h"

namespace pcr_pro {

/**
 * @brief Registers source onto target.
 *
 * Without an initial guess the ICP starts from identity; when the scale is estimated
 * (options.icp.estimate_scale) and the scale detection flags a difference, it starts instead
 * from the detected size ratio with the cloud centroids aligned.
 *
 * @param[in] source cloud in the source frame
 * @param[in] target cloud in the target frame
 * @param[in] initial initial S_target_source, if known
 * @param[in] options configuration of every stage
 * @param[in] target_tree optional k-d tree of `target`, built by the caller to query the target
 *            again afterwards; only with an empty filter chain (the ICP then uses it as is)
 * Error rule (pcr_pro.h): the clouds are data, so an empty one is a status, INVALID_INPUT, the
 * same status as when the filters empty a cloud: a caller handles one outcome for "no points",
 * whether the sensor or the filters removed them. Invalid options and a target_tree that does
 * not belong to `target` are the caller's mistakes and throw.
 *
 * @return the report; status OK, ICP_NOT_CONVERGED or DEGENERATE, or INVALID_INPUT when a cloud
 *         is empty or the filters leave it empty (report.message says which), with timings
 * @throw InputError on invalid options, or a target_tree with filters or of another size than
 *        target
 */
RegistrationReport registerClouds(const Cloud& source, const Cloud& target, const std::optional<Sim3>& initial,
                                  const RegistrationOptions& options, const KdTree* target_tree = nullptr);

}  // namespace pcr_pro
