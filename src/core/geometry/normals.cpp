#include "pcr_pro/geometry/normals.h"

#include <Eigen/Eigenvalues>

#include <vector>

namespace pcr_pro {

namespace {

// Unit normal of the k nearest neighbours of a point (smallest PCA axis); zero with < 3.
Eigen::Vector3d normalAt(const KdTree& tree, const Eigen::Vector3d& query, int k, std::vector<Eigen::Index>* idx,
                         std::vector<double>* d2) {
  const Cloud& pts = tree.points();
  tree.knn(query, k, idx, d2);
  if (idx->size() < 3) return Eigen::Vector3d::Zero();
  Eigen::Vector3d mean = Eigen::Vector3d::Zero();
  for (Eigen::Index j : *idx) mean += pts.col(j);
  mean /= static_cast<double>(idx->size());
  Eigen::Matrix3d cov = Eigen::Matrix3d::Zero();
  for (Eigen::Index j : *idx) {
    const Eigen::Vector3d d = pts.col(j) - mean;
    cov += d * d.transpose();
  }
  Eigen::SelfAdjointEigenSolver<Eigen::Matrix3d> eig;
  eig.computeDirect(cov);
  return eig.eigenvectors().col(0).normalized();
}

}  // namespace

Cloud estimateNormals(const KdTree& tree, int k) {
  const Cloud& pts = tree.points();
  Cloud normals = Cloud::Zero(3, pts.cols());
#pragma omp parallel
  {
    std::vector<Eigen::Index> idx;
    std::vector<double> d2;
#pragma omp for schedule(dynamic, 256)
    for (Eigen::Index i = 0; i < pts.cols(); ++i) normals.col(i) = normalAt(tree, pts.col(i), k, &idx, &d2);
  }
  return normals;
}

Cloud estimateNormalsAt(const KdTree& tree, const std::vector<Eigen::Index>& indices, int k) {
  const Cloud& pts = tree.points();
  const auto n = static_cast<Eigen::Index>(indices.size());
  Cloud normals = Cloud::Zero(3, n);
#pragma omp parallel
  {
    std::vector<Eigen::Index> idx;
    std::vector<double> d2;
#pragma omp for schedule(dynamic, 256)
    for (Eigen::Index i = 0; i < n; ++i) {
      normals.col(i) = normalAt(tree, pts.col(indices[static_cast<std::size_t>(i)]), k, &idx, &d2);
    }
  }
  return normals;
}

}  // namespace pcr_pro
