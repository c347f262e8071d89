#include "pcr_pro/core/normals.h"

#include <Eigen/Eigenvalues>

#include <vector>

namespace pcr_pro {

Cloud estimateNormals(const KdTree& tree, int k) {
  const Cloud& pts = tree.points();
  Cloud normals = Cloud::Zero(3, pts.cols());
#pragma omp parallel
  {
    std::vector<Eigen::Index> idx;
    std::vector<double> d2;
#pragma omp for schedule(static)
    for (Eigen::Index i = 0; i < pts.cols(); ++i) {
      tree.knn(pts.col(i), k, &idx, &d2);
      if (idx.size() < 3) continue;
      Eigen::Vector3d mean = Eigen::Vector3d::Zero();
      for (Eigen::Index j : idx) mean += pts.col(j);
      mean /= static_cast<double>(idx.size());
      Eigen::Matrix3d cov = Eigen::Matrix3d::Zero();
      for (Eigen::Index j : idx) {
        const Eigen::Vector3d d = pts.col(j) - mean;
        cov += d * d.transpose();
      }
      Eigen::SelfAdjointEigenSolver<Eigen::Matrix3d> eig;
      eig.computeDirect(cov);
      normals.col(i) = eig.eigenvectors().col(0).normalized();
    }
  }
  return normals;
}

}  // namespace pcr_pro
