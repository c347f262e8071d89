#include "pcr_pro/core/scale_detection.h"

#include <Eigen/Eigenvalues>

#include <algorithm>
#include <cmath>
#include <vector>

namespace pcr_pro {
namespace {

double quantileRange(std::vector<double>* values, double trim) {
  const std::size_t n = values->size();
  if (n == 1) return 0.0;
  const auto lo = static_cast<std::size_t>(std::floor(trim * static_cast<double>(n - 1)));
  const auto hi = static_cast<std::size_t>(std::ceil((1.0 - trim) * static_cast<double>(n - 1)));
  std::nth_element(values->begin(), values->begin() + static_cast<std::ptrdiff_t>(lo), values->end());
  const double vlo = (*values)[lo];
  std::nth_element(values->begin(), values->begin() + static_cast<std::ptrdiff_t>(hi), values->end());
  return (*values)[hi] - vlo;
}

}  // namespace

CloudExtent robustExtent(const Cloud& cloud, double trim_fraction) {
  if (cloud.cols() == 0) throw InputError("scale detection: empty cloud");
  if (!(trim_fraction >= 0.0 && trim_fraction <= 0.45)) {
    throw InputError("scale_detection.trim_fraction must be in [0, 0.45]");
  }
  CloudExtent e;
  e.centroid = cloud.rowwise().mean();
  const Cloud centred = cloud.colwise() - e.centroid;
  const Eigen::Matrix3d cov = centred * centred.transpose() / static_cast<double>(cloud.cols());
  Eigen::SelfAdjointEigenSolver<Eigen::Matrix3d> eig(cov);
  // Eigen sorts eigenvalues ascending: reverse so the largest axis comes first.
  for (int k = 0; k < 3; ++k) e.axes.col(k) = eig.eigenvectors().col(2 - k);
  if (e.axes.determinant() < 0) e.axes.col(2) = -e.axes.col(2);
  std::vector<double> proj(static_cast<std::size_t>(cloud.cols()));
  for (int k = 0; k < 3; ++k) {
    const Eigen::RowVectorXd p = e.axes.col(k).transpose() * centred;
    std::copy(p.data(), p.data() + p.size(), proj.begin());
    e.extents(k) = quantileRange(&proj, trim_fraction);
  }
  e.size = e.extents.norm();
  return e;
}

ScaleDetectionResult detectScale(const Cloud& source, const Cloud& target, const ScaleDetectionOptions& options) {
  if (!(options.ratio_threshold > 1.0)) throw InputError("scale_detection.ratio_threshold must be > 1");
  ScaleDetectionResult r;
  r.source = robustExtent(source, options.trim_fraction);
  r.target = robustExtent(target, options.trim_fraction);
  if (!(r.source.size > 0.0) || !(r.target.size > 0.0)) {
    r.ratio = 1.0;
    r.scale_difference_detected = false;
    return r;
  }
  r.ratio = r.target.size / r.source.size;
  r.scale_difference_detected = r.ratio > options.ratio_threshold || r.ratio < 1.0 / options.ratio_threshold;
  return r;
}

}  // namespace pcr_pro
