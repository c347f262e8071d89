#include "pcr_pro/frontend/relative_pose_covariance.h"

#include <Eigen/Cholesky>
#include <Eigen/Geometry>

#include <cmath>

#include "pcr_pro/geometry/sim3.h"

namespace pcr_pro {
namespace {

using Vector5d = Eigen::Matrix<double, 5, 1>;

// Sampson error of one correspondence (normalised image coordinates, z = 1) for E = [t]x R.
double sampson(const Eigen::Matrix3d& e, const Eigen::Vector3d& xt, const Eigen::Vector3d& xs) {
  const Eigen::Vector3d es = e * xs;
  const Eigen::Vector3d et = e.transpose() * xt;
  const double denom = es.x() * es.x() + es.y() * es.y() + et.x() * et.x() + et.y() * et.y();
  if (!(denom > 0.0)) return 0.0;
  return xt.dot(es) / std::sqrt(denom);
}

// E of the pose perturbed by p = (ω, α): R' = exp(ω) R, t' = normalize(t + B α).
Eigen::Matrix3d essential(const Eigen::Matrix3d& r, const Eigen::Vector3d& t, const Eigen::Matrix<double, 3, 2>& b,
                          const Vector5d& p) {
  const Eigen::Vector3d tp = (t + b * p.tail<2>()).normalized();
  return skew(tp) * expSO3(p.head<3>()) * r;
}

}  // namespace

Eigen::Matrix3d relativeRotationCovariance(const std::vector<Eigen::Vector3d>& bearings_target,
                                           const std::vector<Eigen::Vector3d>& bearings_source,
                                           const RelativePoseResult& pose, double focal_px, double pixel_floor) {
  const Eigen::Matrix3d unknown = Eigen::Matrix3d::Identity();
  std::vector<Eigen::Vector3d> xt, xs;
  for (int k : pose.inliers) {
    const auto ku = static_cast<std::size_t>(k);
    if (ku >= bearings_target.size() || ku >= bearings_source.size()) continue;
    const Eigen::Vector3d& bt = bearings_target[ku];
    const Eigen::Vector3d& bs = bearings_source[ku];
    if (!(bt.z() > 1e-6) || !(bs.z() > 1e-6)) continue;
    xt.push_back(bt / bt.z());
    xs.push_back(bs / bs.z());
  }
  const auto n = static_cast<int>(xt.size());
  const Eigen::Vector3d t = pose.translation_direction;
  if (n < 6 || !(t.norm() > 0.5) || !(focal_px > 0.0)) return unknown;
  // Two unit vectors orthogonal to t.
  Eigen::Matrix<double, 3, 2> b;
  const Eigen::Vector3d any = std::abs(t.x()) < 0.9 ? Eigen::Vector3d::UnitX() : Eigen::Vector3d::UnitY();
  b.col(0) = t.cross(any).normalized();
  b.col(1) = t.cross(b.col(0)).normalized();
  const Eigen::Matrix3d e0 = essential(pose.rotation, t, b, Vector5d::Zero());
  Eigen::MatrixXd j(n, 5);
  double sum2 = 0.0;
  constexpr double kStep = 1e-6;
  for (int i = 0; i < n; ++i) {
    const double r0 = sampson(e0, xt[static_cast<std::size_t>(i)], xs[static_cast<std::size_t>(i)]);
    sum2 += r0 * r0;
    for (int k = 0; k < 5; ++k) {
      Vector5d p = Vector5d::Zero();
      p(k) = kStep;
      const double rp = sampson(essential(pose.rotation, t, b, p), xt[static_cast<std::size_t>(i)],
                                xs[static_cast<std::size_t>(i)]);
      p(k) = -kStep;
      const double rm = sampson(essential(pose.rotation, t, b, p), xt[static_cast<std::size_t>(i)],
                                xs[static_cast<std::size_t>(i)]);
      j(i, k) = (rp - rm) / (2.0 * kStep);
    }
  }
  const double floor = pixel_floor / focal_px;
  const double sigma2 = std::max(sum2 / (n - 5), floor * floor);
  const Eigen::Matrix<double, 5, 5> h = j.transpose() * j;
  const Eigen::LDLT<Eigen::Matrix<double, 5, 5>> ldlt(h);
  if (ldlt.info() != Eigen::Success || !ldlt.isPositive()) return unknown;
  const Eigen::Matrix<double, 5, 5> cov = sigma2 * ldlt.solve(Eigen::Matrix<double, 5, 5>::Identity());
  const Eigen::Matrix3d rot = 0.5 * (cov.topLeftCorner<3, 3>() + cov.topLeftCorner<3, 3>().transpose());
  return rot.allFinite() ? rot : unknown;
}

}  // namespace pcr_pro
