#include "pcr_pro/frontend/relative_pose_covariance.h"

#include <Eigen/Cholesky>
#include <Eigen/Geometry>

#include <cmath>

#include "pcr_pro/geometry/sim3.h"

namespace pcr_pro {
namespace {

using Vector5d = Eigen::Matrix<double, 5, 1>;

// refineOnSampsonError(): Levenberg-Marquardt iterations at most, damping raises per iteration
// before giving up, and the relative cost decrease below which it has settled.
constexpr int kSampsonIterations = 50;
constexpr int kSampsonDampingAttempts = 10;
constexpr double kSampsonRelativeDecrease = 1e-10;

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

// Two unit vectors orthogonal to t (the tangent plane of the direction's sphere).
Eigen::Matrix<double, 3, 2> tangentBasis(const Eigen::Vector3d& t) {
  Eigen::Matrix<double, 3, 2> b;
  const Eigen::Vector3d any = std::abs(t.x()) < 0.9 ? Eigen::Vector3d::UnitX() : Eigen::Vector3d::UnitY();
  b.col(0) = t.cross(any).normalized();
  b.col(1) = t.cross(b.col(0)).normalized();
  return b;
}

// The inliers as normalised image coordinates (z = 1) of both cameras.
struct NormalisedInliers {
  std::vector<Eigen::Vector3d> xt, xs;
  int size() const { return static_cast<int>(xt.size()); }
};

NormalisedInliers normalisedInliers(const std::vector<Eigen::Vector3d>& bearings_target,
                                    const std::vector<Eigen::Vector3d>& bearings_source,
                                    const std::vector<int>& inliers) {
  NormalisedInliers out;
  for (int k : inliers) {
    const auto ku = static_cast<std::size_t>(k);
    if (k < 0 || ku >= bearings_target.size() || ku >= bearings_source.size()) continue;
    const Eigen::Vector3d& bt = bearings_target[ku];
    const Eigen::Vector3d& bs = bearings_source[ku];
    if (!(bt.z() > 1e-6) || !(bs.z() > 1e-6)) continue;
    out.xt.push_back(bt / bt.z());
    out.xs.push_back(bs / bs.z());
  }
  return out;
}

// The Sampson residuals at (r, t) and their Jacobian over the five degrees of freedom (central
// differences), with b = tangentBasis(t).
void sampsonSystem(const NormalisedInliers& x, const Eigen::Matrix3d& r, const Eigen::Vector3d& t,
                   const Eigen::Matrix<double, 3, 2>& b, Eigen::VectorXd* residuals, Eigen::MatrixXd* jacobian) {
  const int n = x.size();
  residuals->resize(n);
  jacobian->resize(n, 5);
  const Eigen::Matrix3d e0 = essential(r, t, b, Vector5d::Zero());
  constexpr double kStep = 1e-6;
  for (int i = 0; i < n; ++i) {
    const auto iu = static_cast<std::size_t>(i);
    (*residuals)(i) = sampson(e0, x.xt[iu], x.xs[iu]);
    for (int k = 0; k < 5; ++k) {
      Vector5d p = Vector5d::Zero();
      p(k) = kStep;
      const double rp = sampson(essential(r, t, b, p), x.xt[iu], x.xs[iu]);
      p(k) = -kStep;
      const double rm = sampson(essential(r, t, b, p), x.xt[iu], x.xs[iu]);
      (*jacobian)(i, k) = (rp - rm) / (2.0 * kStep);
    }
  }
}

double sampsonCost(const NormalisedInliers& x, const Eigen::Matrix3d& r, const Eigen::Vector3d& t) {
  const Eigen::Matrix3d e = skew(t) * r;
  double cost = 0.0;
  for (int i = 0; i < x.size(); ++i) {
    const double v = sampson(e, x.xt[static_cast<std::size_t>(i)], x.xs[static_cast<std::size_t>(i)]);
    cost += v * v;
  }
  return cost;
}

}  // namespace

Eigen::Matrix3d relativeRotationCovariance(const std::vector<Eigen::Vector3d>& bearings_target,
                                           const std::vector<Eigen::Vector3d>& bearings_source,
                                           const RelativePoseResult& pose, double focal_px, double pixel_floor) {
  const Eigen::Matrix3d unknown = Eigen::Matrix3d::Identity();
  const NormalisedInliers x = normalisedInliers(bearings_target, bearings_source, pose.inliers);
  const int n = x.size();
  const Eigen::Vector3d t = pose.translation_direction;
  if (n < 6 || !(t.norm() > 0.5) || !(focal_px > 0.0)) return unknown;
  Eigen::VectorXd res;
  Eigen::MatrixXd j;
  sampsonSystem(x, pose.rotation, t, tangentBasis(t), &res, &j);
  const double floor = pixel_floor / focal_px;
  const double sigma2 = std::max(res.squaredNorm() / (n - 5), floor * floor);
  const Eigen::Matrix<double, 5, 5> h = j.transpose() * j;
  const Eigen::LDLT<Eigen::Matrix<double, 5, 5>> ldlt(h);
  if (ldlt.info() != Eigen::Success || !ldlt.isPositive()) return unknown;
  const Eigen::Matrix<double, 5, 5> cov = sigma2 * ldlt.solve(Eigen::Matrix<double, 5, 5>::Identity());
  const Eigen::Matrix3d rot = 0.5 * (cov.topLeftCorner<3, 3>() + cov.topLeftCorner<3, 3>().transpose());
  return rot.allFinite() ? rot : unknown;
}

bool refineOnSampsonError(const std::vector<Eigen::Vector3d>& bearings_target,
                          const std::vector<Eigen::Vector3d>& bearings_source, RelativePoseResult* pose) {
  const NormalisedInliers x = normalisedInliers(bearings_target, bearings_source, pose->inliers);
  Eigen::Matrix3d r = pose->rotation;
  Eigen::Vector3d t = pose->translation_direction;
  if (x.size() < 6 || !(t.norm() > 0.5) || !r.allFinite() || !t.allFinite()) return false;
  t.normalize();
  double cost = sampsonCost(x, r, t);
  if (!std::isfinite(cost)) return false;
  const double start = cost;
  // Levenberg-Marquardt: a step is taken only when it lowers the cost, so the result is never
  // worse than OpenGV's on the cost whose curvature relativeRotationCovariance() reports.
  double lambda = 1e-3;
  bool settled = false;
  for (int iteration = 0; iteration < kSampsonIterations && !settled; ++iteration) {
    const Eigen::Matrix<double, 3, 2> b = tangentBasis(t);
    Eigen::VectorXd res;
    Eigen::MatrixXd j;
    sampsonSystem(x, r, t, b, &res, &j);
    const Eigen::Matrix<double, 5, 5> h = j.transpose() * j;
    const Vector5d g = j.transpose() * res;
    bool stepped = false;
    for (int attempt = 0; attempt < kSampsonDampingAttempts && !stepped; ++attempt) {
      Eigen::Matrix<double, 5, 5> damped = h;
      damped.diagonal() *= 1.0 + lambda;
      const Vector5d step = -damped.ldlt().solve(g);
      if (!step.allFinite()) break;
      const Eigen::Matrix3d r_next = expSO3(step.head<3>()) * r;
      const Eigen::Vector3d t_next = (t + b * step.tail<2>()).normalized();
      const double next = sampsonCost(x, r_next, t_next);
      if (std::isfinite(next) && next < cost) {
        settled = cost - next <= kSampsonRelativeDecrease * cost;
        r = r_next;
        t = t_next;
        cost = next;
        lambda = std::max(1e-12, 0.1 * lambda);
        stepped = true;
      } else {
        lambda *= 10.0;
      }
    }
    if (!stepped) break;
  }
  if (!(cost < start)) return false;
  pose->rotation = projectToRotation(r);
  pose->translation_direction = t;
  return true;
}

}  // namespace pcr_pro
