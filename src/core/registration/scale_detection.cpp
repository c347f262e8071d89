#include "pcr_pro/registration/scale_detection.h"

#include <Eigen/Eigenvalues>
#include <Eigen/LU>

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

template <>
const ParamSchema<ScaleDetectionOptions>& paramSchema<ScaleDetectionOptions>() {
  using O = ScaleDetectionOptions;
  using R = ParamRange;
  static const ParamSchema<O> schema{"scale_detection", {
      {"trim_fraction", &O::trim_fraction, R::closed(0, 0.45), "-",
       "fraction of the points trimmed at each end of every principal axis"},
      {"ratio_threshold", &O::ratio_threshold, R::above(1), "-",
       "target/source size ratio beyond which a scale difference is flagged"},
  }};
  return schema;
}

void validate(const ScaleDetectionOptions& options) { checkRanges(paramSchema<ScaleDetectionOptions>(), options); }

CloudExtent robustExtent(const Cloud& cloud, double trim_fraction) {
  if (cloud.cols() == 0) throw InputError("scale detection: empty cloud");
  if (!(trim_fraction >= 0.0 && trim_fraction <= 0.45)) {
    throw InputError("scale_detection.trim_fraction must be in [0, 0.45]");
  }
  CloudExtent e;
  const Eigen::Index n = cloud.cols();
  // Robust centre and axes: coordinate-wise median, then PCA over the points nearest to it
  // (all but the farthest 2 * trim_fraction), so far outliers cannot turn the axes.
  std::vector<double> tmp(static_cast<std::size_t>(n));
  Eigen::Vector3d median;
  for (int k = 0; k < 3; ++k) {
    for (Eigen::Index i = 0; i < n; ++i) tmp[static_cast<std::size_t>(i)] = cloud(k, i);
    std::nth_element(tmp.begin(), tmp.begin() + n / 2, tmp.end());
    median(k) = tmp[static_cast<std::size_t>(n / 2)];
  }
  const Eigen::VectorXd dist = (cloud.colwise() - median).colwise().norm().transpose();
  std::copy(dist.data(), dist.data() + n, tmp.begin());
  const auto keep_n = std::max<Eigen::Index>(1, static_cast<Eigen::Index>((1.0 - 2.0 * trim_fraction) * n));
  std::nth_element(tmp.begin(), tmp.begin() + (keep_n - 1), tmp.end());
  const double radius = tmp[static_cast<std::size_t>(keep_n - 1)];
  Eigen::Vector3d sum = Eigen::Vector3d::Zero();
  Eigen::Matrix3d sq = Eigen::Matrix3d::Zero();
  Eigen::Index used = 0;
  for (Eigen::Index i = 0; i < n; ++i) {
    if (dist(i) > radius) continue;
    sum += cloud.col(i);
    sq += cloud.col(i) * cloud.col(i).transpose();
    ++used;
  }
  e.centroid = sum / static_cast<double>(used);
  const Eigen::Matrix3d cov = sq / static_cast<double>(used) - e.centroid * e.centroid.transpose();
  const Cloud centred = cloud.colwise() - e.centroid;
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
