#include "pcr_pro/geometry/normals.h"

#include <Eigen/Eigenvalues>

#include <algorithm>
#include <cmath>
#include <vector>

#include "pcr_pro/geometry/median.h"

namespace pcr_pro {

namespace {

// Unit normal of the k nearest neighbours of a point (smallest PCA axis); zero with < 3. With
// `thickness2`, the neighbours' variance along it.
Eigen::Vector3d normalAt(const KdTree& tree, const Eigen::Vector3d& query, int k, std::vector<Eigen::Index>* idx,
                         std::vector<double>* d2, double* thickness2 = nullptr, Eigen::Vector3d* mean_out = nullptr) {
  const Cloud& pts = tree.points();
  tree.knn(query, k, idx, d2);
  if (idx->size() < 3) return Eigen::Vector3d::Zero();
  Eigen::Vector3d mean = Eigen::Vector3d::Zero();
  for (Eigen::Index j : *idx) mean += pts.col(j);
  mean /= static_cast<double>(idx->size());
  if (mean_out != nullptr) *mean_out = mean;
  Eigen::Matrix3d cov = Eigen::Matrix3d::Zero();
  for (Eigen::Index j : *idx) {
    const Eigen::Vector3d d = pts.col(j) - mean;
    cov += d * d.transpose();
  }
  Eigen::SelfAdjointEigenSolver<Eigen::Matrix3d> eig;
  eig.computeDirect(cov);
  if (thickness2 != nullptr) *thickness2 = std::max(0.0, eig.eigenvalues()(0)) / static_cast<double>(idx->size());
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

Cloud estimateNormalsAt(const KdTree& tree, const std::vector<Eigen::Index>& indices, int k, Cloud* centroids,
                        Eigen::VectorXd* thickness2) {
  const Cloud& pts = tree.points();
  const auto n = static_cast<Eigen::Index>(indices.size());
  Cloud normals = Cloud::Zero(3, n);
  if (centroids != nullptr) *centroids = Cloud::Zero(3, n);
  if (thickness2 != nullptr) *thickness2 = Eigen::VectorXd::Zero(n);
#pragma omp parallel
  {
    std::vector<Eigen::Index> idx;
    std::vector<double> d2;
    Eigen::Vector3d mean;
#pragma omp for schedule(dynamic, 256)
    for (Eigen::Index i = 0; i < n; ++i) {
      const Eigen::Vector3d p = pts.col(indices[static_cast<std::size_t>(i)]);
      double t2 = 0.0;
      normals.col(i) = normalAt(tree, p, k, &idx, &d2, &t2, &mean);
      if (thickness2 != nullptr) (*thickness2)(i) = t2;
      if (centroids != nullptr) centroids->col(i) = normals.col(i).squaredNorm() > 0.0 ? mean : p;
    }
  }
  return normals;
}

double surfaceThickness2(const KdTree& tree, int k, Eigen::Index samples) {
  const Cloud& pts = tree.points();
  const Eigen::Index n = pts.cols();
  if (n < 3 || samples < 1) return 0.0;
  const Eigen::Index step = std::max<Eigen::Index>(1, n / samples);
  std::vector<double> values;
  std::vector<Eigen::Index> idx;
  std::vector<double> d2;
  for (Eigen::Index i = 0; i < n; i += step) {
    double t2 = 0.0;
    if (normalAt(tree, pts.col(i), k, &idx, &d2, &t2).squaredNorm() > 0.0) values.push_back(t2);
  }
  return upperMedian(&values);
}

double noiseRatio(double scale, double source_thickness2, double target_thickness2) {
  if (!(source_thickness2 > 0.0) || !(target_thickness2 > 0.0)) return 1.0;
  const double ratio = scale * std::sqrt(source_thickness2 / target_thickness2);
  return std::isfinite(ratio) ? ratio : 1.0;
}

}  // namespace pcr_pro
