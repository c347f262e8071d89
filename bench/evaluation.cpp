#include "evaluation.h"

#include <Eigen/Cholesky>

#include <algorithm>
#include <cmath>
#include <cstdio>
#include <limits>

#include "pcr_pro/geometry/similarity_fit.h"

namespace pcr_pro {
namespace bench {

Matrix7d truthCovariance(const TruthAccuracy& a) {
  Matrix7d about_centre = Matrix7d::Zero();
  about_centre.diagonal() << Eigen::Vector3d::Constant(a.translation * a.translation),
      Eigen::Vector3d::Constant(a.rotation * a.rotation), a.scale_rel * a.scale_rel;
  // A perturbation (tc, dr, ds) about the centre c is, about the origin, t0 = tc + [c]x dr - c ds.
  Matrix7d j = Matrix7d::Identity();
  j.block<3, 3>(0, 3) = skew(a.centre);
  j.block<3, 1>(0, 6) = -a.centre;
  return j * about_centre * j.transpose();
}

namespace {

// d' P^-1 d, or +inf when P is not positive definite.
template <int N>
double mahalanobis(const Eigen::Matrix<double, N, 1>& d, const Eigen::Matrix<double, N, N>& p) {
  const Eigen::LLT<Eigen::Matrix<double, N, N>> llt(p);
  if (llt.info() != Eigen::Success || !p.allFinite()) return std::numeric_limits<double>::infinity();
  return d.dot(llt.solve(d));
}

void nees(const Eigen::Matrix<double, 7, 1>& d, const Matrix7d& p, double& rot, double& six, double& scale) {
  rot = mahalanobis<3>(d.segment<3>(3), p.block<3, 3>(3, 3));
  six = mahalanobis<6>(d.head<6>(), p.topLeftCorner<6, 6>());
  scale = p(6, 6) > 0.0 ? d(6) * d(6) / p(6, 6) : std::numeric_limits<double>::infinity();
}

}  // namespace

Score score(const Sim3& estimate, const Matrix7d& covariance, const Sim3& truth, const Matrix7d& truth_covariance,
            const Eigen::Vector3d& source_centroid, double extent, const Floors& floors) {
  Score s;
  s.has = true;
  s.rotation_deg = rotationDistance(estimate.rotation(), truth.rotation()) * 180.0 / M_PI;
  s.translation_pct = 100.0 * (estimate.apply(source_centroid) - truth.apply(source_centroid)).norm() / extent;
  s.scale_pct = 100.0 * (estimate.scale() / truth.scale() - 1.0);
  s.within_floors = s.rotation_deg < floors.rotation_deg && s.translation_pct < floors.translation_pct &&
                    std::abs(s.scale_pct) < floors.scale_pct;
  s.has_covariance = covariance.allFinite() && Eigen::LLT<Matrix7d>(covariance).info() == Eigen::Success &&
                     covariance.diagonal().minCoeff() > 0.0;
  if (s.has_covariance) {
    const Eigen::Matrix<double, 7, 1> d = similarityDifference(estimate, truth);
    nees(d, covariance + truth_covariance, s.nees_rot, s.nees6, s.nees_scale);
    nees(d, covariance, s.raw_rot, s.raw6, s.raw_scale);
  }
  return s;
}

double boxDiagonal(const Cloud& cloud) {
  if (cloud.cols() == 0) return 0.0;
  Eigen::Vector3d lo, hi;
  std::vector<double> v(static_cast<std::size_t>(cloud.cols()));
  for (int axis = 0; axis < 3; ++axis) {
    for (Eigen::Index i = 0; i < cloud.cols(); ++i) v[static_cast<std::size_t>(i)] = cloud(axis, i);
    std::sort(v.begin(), v.end());
    lo(axis) = v[v.size() / 20];
    hi(axis) = v[v.size() - 1 - v.size() / 20];
  }
  return (hi - lo).norm();
}

NeesPool pool(const std::vector<Score>& scores) {
  NeesPool p;
  for (const Score& s : scores) {
    if (!s.has || !s.has_covariance) continue;
    ++p.n;
    p.anees_rot += s.nees_rot / 3.0;
    p.anees6 += s.nees6 / 6.0;
    p.anees_scale += s.nees_scale;
    p.under_rot += s.nees_rot < kChi2_95_3;
    p.under6 += s.nees6 < kChi2_95_6;
    p.under_scale += s.nees_scale < kChi2_95_1;
    p.raw_anees_rot += s.raw_rot / 3.0;
    p.raw_anees6 += s.raw6 / 6.0;
    p.raw_anees_scale += s.raw_scale;
    p.raw_under6 += s.raw6 < kChi2_95_6;
    p.raw_under_scale += s.raw_scale < kChi2_95_1;
  }
  if (p.n == 0) return p;
  for (double* v : {&p.anees_rot, &p.anees6, &p.anees_scale, &p.under_rot, &p.under6, &p.under_scale, &p.raw_anees_rot,
                    &p.raw_anees6, &p.raw_anees_scale, &p.raw_under6, &p.raw_under_scale}) {
    *v /= p.n;
  }
  return p;
}

bool neesFloorsMet(const NeesPool& p) {
  const auto in = [](double anees) { return anees >= 0.7 && anees <= 1.5; };
  return p.n > 0 && in(p.anees6) && in(p.anees_scale) && p.under6 >= 0.9 && p.under_scale >= 0.9;
}

std::string neesCell(double anees, double under) {
  char b[64];
  if (!std::isfinite(anees)) {
    std::snprintf(b, sizeof b, "inf (%.0f %%)", 100.0 * under);
  } else {
    std::snprintf(b, sizeof b, "%.2f (%.0f %%)", anees, 100.0 * under);
  }
  return b;
}

}  // namespace bench
}  // namespace pcr_pro
