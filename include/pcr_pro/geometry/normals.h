/**
 * @file normals.h
 * @brief Surface normals from local PCA over k nearest neighbours.
 */
#pragma once

#include <vector>

#include "pcr_pro/geometry/kdtree.h"
#include "pcr_pro/geometry/types.h"

namespace pcr_pro {

/**
 * @brief Estimates a unit normal per point from its k nearest neighbours (smallest PCA axis).
 * Points with fewer than 3 neighbours get a zero normal.
 * @param[in] tree k-d tree over the cloud
 * @param[in] k neighbours used (>= 3)
 * @return one unit (or zero) normal per point, sign arbitrary
 */
Cloud estimateNormals(const KdTree& tree, int k);

/**
 * @brief Like estimateNormals(), for selected points of the tree only.
 * @param[in] tree k-d tree over the cloud
 * @param[in] indices points (columns of tree.points()) to estimate normals for
 * @param[in] k neighbours used (>= 3)
 * @param[out] centroids when given, the centroid of each point's neighbours (the point itself
 *             where the normal is zero), in the same order
 * @param[out] thickness2 when given, each point's neighbours' variance along its normal (the
 *             smallest PCA eigenvalue over k; 0 where the normal is zero) [cloud units²]
 * @return one normal per index, in the same order
 */
Cloud estimateNormalsAt(const KdTree& tree, const std::vector<Eigen::Index>& indices, int k,
                        Cloud* centroids = nullptr, Eigen::VectorXd* thickness2 = nullptr);

/**
 * @brief How thick the cloud's surfaces are: the median, over an even sample of its points, of
 * the variance along the normal of each point's k nearest neighbours (smallest PCA eigenvalue
 * over k). On a smooth surface it is the point noise's variance along the normal times a factor
 * that depends on k only (plus curvature at the neighbourhood's size), so two clouds measured
 * with the same k compare by their noise.
 * @param[in] tree k-d tree over the cloud
 * @param[in] k neighbours (>= 3)
 * @param[in] samples at most this many points are measured (>= 1)
 * @return the median variance [cloud units²]; 0 for fewer than 3 points
 */
double surfaceThickness2(const KdTree& tree, int k, Eigen::Index samples);

/// Points surfaceThickness2() measures for the ICP's noise correction and the merge's choice of
/// direction, which compare clouds by it: the median over this many is known to a few per cent.
inline constexpr Eigen::Index kThicknessSamples = 2000;

/// A source cloud counts as the noisier one when its surface thickness, as a variance in the
/// target's units, is at least this many times the target's [-] (noiseRatio()). Below it the
/// registration's other asymmetries (which cloud is sampled, which is used whole) outweigh the
/// noise: see IcpOptions::register_noisier_as_target.
inline constexpr double kNoisierVarianceRatio = 2.0;

/**
 * @brief How many times noisier the source is than the target, as a standard deviation in the
 * target's units: scale * sqrt(source_thickness2 / target_thickness2).
 * @param[in] scale the source-to-target scale the clouds are compared at [-]
 * @param[in] source_thickness2, target_thickness2 surfaceThickness2() of each cloud in its own units
 * @return the ratio; 1 when a thickness is not positive or the ratio is not finite
 */
double noiseRatio(double scale, double source_thickness2, double target_thickness2);

/// @return whether a source of this noiseRatio() is clearly the noisier cloud: its thickness
/// variance at least kNoisierVarianceRatio times the target's
inline bool clearlyNoisier(double noise_ratio) { return noise_ratio * noise_ratio >= kNoisierVarianceRatio; }

}  // namespace pcr_pro
