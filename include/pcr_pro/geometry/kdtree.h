/**
 * @file kdtree.h
 * @brief Exact nearest-neighbour search on a Cloud (nanoflann k-d tree).
 */
#pragma once

#include <memory>
#include <vector>

#include "pcr_pro/geometry/types.h"

namespace pcr_pro {

/**
 * @brief A k-d tree over the columns of a cloud. The tree keeps its own copy of the points,
 * so the cloud passed in may go away. Queries are const and thread-safe.
 */
class KdTree {
 public:
  /// @param[in] cloud points to index (may be empty; queries then find nothing)
  explicit KdTree(const Cloud& cloud);
  ~KdTree();
  KdTree(const KdTree&) = delete;
  KdTree& operator=(const KdTree&) = delete;

  /// @return number of indexed points
  Eigen::Index size() const;
  /// @return the indexed points
  const Cloud& points() const;

  /**
   * @brief Nearest neighbour of a query point.
   * @param[in] query point [cloud units]
   * @param[out] squared_distance squared distance to it [cloud units²]
   * @return index of the nearest point, or -1 when the tree is empty
   */
  Eigen::Index nearest(const Eigen::Vector3d& query, double* squared_distance) const;

  /**
   * @brief Nearest neighbour, with a point known to be near: the search starts from its distance
   * and prunes everything farther (the result is the same as nearest()'s, found sooner when the
   * hint is close, e.g. last iteration's neighbour of a point that moved little).
   * @param[in] query point [cloud units]
   * @param[out] squared_distance squared distance to the nearest point [cloud units²]
   * @param[in] hint index of any point of the tree, or -1 for none
   * @return index of the nearest point, or -1 when the tree is empty
   */
  Eigen::Index nearest(const Eigen::Vector3d& query, double* squared_distance, Eigen::Index hint) const;

  /**
   * @brief Whether some point lies closer to the query than a given distance (strictly). The
   * search stops at the first such point, and prunes by the distance from the start: cheaper than
   * nearest() when only the comparison matters.
   * @param[in] query point [cloud units]
   * @param[in] squared_radius squared distance [cloud units²]; <= 0 gives false
   * @return true when a point's squared distance is below squared_radius
   */
  bool anyCloserThan(const Eigen::Vector3d& query, double squared_radius) const;

  /**
   * @brief k nearest neighbours, closest first.
   * @param[in] query point
   * @param[in] k number of neighbours wanted
   * @param[out] indices found indices (at most k)
   * @param[out] squared_distances matching squared distances
   */
  void knn(const Eigen::Vector3d& query, int k, std::vector<Eigen::Index>* indices,
           std::vector<double>* squared_distances) const;

 private:
  struct Impl;
  std::unique_ptr<Impl> impl_;
};

}  // namespace pcr_pro
