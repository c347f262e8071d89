#include "pcr_pro/geometry/similarity_fit.h"

#include <Eigen/Cholesky>
#include <Eigen/Eigenvalues>
#include <Eigen/LU>

#include <algorithm>
#include <cmath>
#include <map>

namespace pcr_pro {
namespace {

using Vector7d = Eigen::Matrix<double, 7, 1>;
using Matrix37d = Eigen::Matrix<double, 3, 7>;

Eigen::Vector3d logSO3(const Eigen::Matrix3d& r) {
  const Eigen::AngleAxisd aa(r);
  return aa.angle() * aa.axis();
}

// Inverse of the active block (6 x 6 without scale), zero elsewhere; false when singular.
bool invertActive(const Matrix7d& h, int d, Matrix7d* inv) {
  inv->setZero();
  const Eigen::MatrixXd block = h.topLeftCorner(d, d);
  const Eigen::LDLT<Eigen::MatrixXd> ldlt(block);
  if (ldlt.info() != Eigen::Success || !ldlt.isPositive()) return false;
  const Eigen::MatrixXd solved = ldlt.solve(Eigen::MatrixXd::Identity(d, d));
  if (!solved.allFinite()) return false;
  // A positive LDLT can still hide a zero pivot: check the smallest eigenvalue.
  const Eigen::SelfAdjointEigenSolver<Eigen::MatrixXd> eig(block);
  if (!(eig.eigenvalues()(0) > 1e-14 * eig.eigenvalues()(d - 1))) return false;
  inv->topLeftCorner(d, d) = 0.5 * (solved + solved.transpose());
  return true;
}

struct Accumulated {
  Matrix7d h = Matrix7d::Zero();
  Vector7d g = Vector7d::Zero();
  double chi2 = 0.0;
  int inliers = 0;
  std::map<int, Vector7d> group_gradient;
};

// One pass over the data at S: robust (kernel) or final (inliers only, unit weights).
Accumulated accumulate(const std::vector<PointMatch3>& matches, const std::vector<Eigen::Matrix3d>& info,
                       const std::vector<RotationMeasurement>& rotations, const std::vector<Eigen::Matrix3d>& rot_info,
                       const Sim3& s, const SimilarityFitOptions& o, bool final_pass, std::vector<bool>* inliers) {
  Accumulated acc;
  const double c2 = o.kernel_width * o.kernel_width;
  for (std::size_t i = 0; i < matches.size(); ++i) {
    const Eigen::Vector3d y = s.apply(matches[i].source);
    const Eigen::Vector3d r = y - matches[i].target;
    const double m2 = r.dot(info[i] * r);
    double w = 1.0 / (1.0 + m2 / c2);
    if (final_pass) {
      const bool in = m2 <= o.outlier_chi2;
      (*inliers)[i] = in;
      if (!in) continue;
      w = 1.0;
      acc.chi2 += m2;
      ++acc.inliers;
    }
    const Matrix37d j = similarityJacobian(y);
    const Eigen::Matrix<double, 7, 3> jtw = j.transpose() * info[i];
    acc.h.noalias() += w * jtw * j;
    const Vector7d gi = w * jtw * r;
    acc.g += gi;
    if (final_pass) {
      auto it = acc.group_gradient.find(matches[i].group);
      if (it == acc.group_gradient.end()) it = acc.group_gradient.emplace(matches[i].group, Vector7d::Zero()).first;
      it->second += gi;
    }
  }
  for (std::size_t i = 0; i < rotations.size(); ++i) {
    // Residual ω - φ with φ = log(R_meas Rᵀ); the Jacobian w.r.t. δ is [0 I 0].
    const Eigen::Vector3d r = -logSO3(rotations[i].rotation * s.rotation().transpose());
    const double m2 = r.dot(rot_info[i] * r);
    const double w = final_pass ? 1.0 : 1.0 / (1.0 + m2 / c2);
    if (final_pass) acc.chi2 += m2;
    acc.h.block<3, 3>(3, 3) += w * rot_info[i];
    Vector7d gi = Vector7d::Zero();
    gi.segment<3>(3) = w * rot_info[i] * r;
    acc.g += gi;
    if (final_pass) {
      auto it = acc.group_gradient.find(rotations[i].group);
      if (it == acc.group_gradient.end()) it = acc.group_gradient.emplace(rotations[i].group, Vector7d::Zero()).first;
      it->second += gi;
    }
  }
  return acc;
}

}  // namespace

Eigen::Matrix<double, 3, 7> similarityJacobian(const Eigen::Vector3d& y) {
  Matrix37d j;
  j.block<3, 3>(0, 0).setIdentity();
  j.block<3, 3>(0, 3) = -skew(y);
  j.col(6) = y;
  return j;
}

Eigen::Matrix<double, 7, 1> similarityDifference(const Sim3& a, const Sim3& b) {
  const Eigen::Matrix3d dr = a.rotation() * b.rotation().transpose();
  Vector7d d;
  d.head<3>() = a.translation() - (a.scale() / b.scale()) * dr * b.translation();
  d.segment<3>(3) = logSO3(dr);
  d(6) = std::log(a.scale() / b.scale());
  return d;
}

Vector6d poseDifference(const Sim3& a, const Sim3& b) {
  const Eigen::Matrix3d dr = a.rotation() * b.rotation().transpose();
  Vector6d d;
  d.head<3>() = a.translation() - (a.scale() / b.scale()) * dr * b.translation();
  d.tail<3>() = logSO3(dr);
  return d;
}

Matrix7d similarityAdjoint(const Sim3& g) {
  Matrix7d ad = Matrix7d::Zero();
  const Eigen::Matrix3d& r = g.rotation();
  const Eigen::Vector3d& t = g.translation();
  ad.block<3, 3>(0, 0) = g.scale() * r;
  ad.block<3, 3>(0, 3) = skew(t) * r;
  ad.block<3, 1>(0, 6) = -t;
  ad.block<3, 3>(3, 3) = r;
  ad(6, 6) = 1.0;
  return ad;
}

double rmsMoveOfMatches(const std::vector<PointMatch3>& matches, const Sim3& a, const Sim3& b) {
  double sum = 0.0;
  for (const PointMatch3& m : matches) sum += (a.apply(m.source) - b.apply(m.source)).squaredNorm();
  return matches.empty() ? 0.0 : std::sqrt(sum / static_cast<double>(matches.size()));
}

Sim3 applyDelta(const Eigen::Matrix<double, 7, 1>& delta, const Sim3& s) {
  const Sim3 step(std::exp(delta(6)), expSO3(delta.segment<3>(3)), delta.head<3>());
  return step * s;
}

Matrix7d coveringCovariance(const Matrix7d& a, const Matrix7d& b, double* factor) {
  const int d = (a(6, 6) == 0.0 && b(6, 6) == 0.0) ? 6 : 7;
  const Eigen::MatrixXd ab = 0.5 * (a.topLeftCorner(d, d) + a.topLeftCorner(d, d).transpose());
  const Eigen::MatrixXd bb = 0.5 * (b.topLeftCorner(d, d) + b.topLeftCorner(d, d).transpose());
  const Eigen::SelfAdjointEigenSolver<Eigen::MatrixXd> ea(ab);
  const Eigen::VectorXd ev = ea.eigenvalues();
  const double floor = 1e-18 * std::max(1e-300, ev.cwiseAbs().maxCoeff());
  Eigen::VectorXd sq(d), isq(d);
  for (int k = 0; k < d; ++k) {
    const double v = std::max(ev(k), floor);
    sq(k) = std::sqrt(v);
    isq(k) = 1.0 / sq(k);
  }
  const Eigen::MatrixXd half = ea.eigenvectors() * sq.asDiagonal() * ea.eigenvectors().transpose();
  const Eigen::MatrixXd ihalf = ea.eigenvectors() * isq.asDiagonal() * ea.eigenvectors().transpose();
  const Eigen::MatrixXd m = ihalf * bb * ihalf;
  const Eigen::SelfAdjointEigenSolver<Eigen::MatrixXd> em(0.5 * (m + m.transpose()));
  Eigen::VectorXd lam = em.eigenvalues();
  if (factor) *factor = std::max(1.0, lam.maxCoeff());
  for (int k = 0; k < d; ++k) lam(k) = std::max(1.0, lam(k));
  const Eigen::MatrixXd out = half * em.eigenvectors() * lam.asDiagonal() * em.eigenvectors().transpose() * half;
  Matrix7d result = Matrix7d::Zero();
  result.topLeftCorner(d, d) = 0.5 * (out + out.transpose());
  return result;
}

SimilarityFit fitSimilarity(const std::vector<PointMatch3>& matches, const std::vector<RotationMeasurement>& rotations,
                            const Sim3& initial, const SimilarityFitOptions& o) {
  SimilarityFit fit;
  fit.estimate = initial;
  fit.inliers.assign(matches.size(), false);
  const int d = o.estimate_scale ? 7 : 6;
  std::vector<Eigen::Matrix3d> info(matches.size()), rot_info(rotations.size());
  for (std::size_t i = 0; i < matches.size(); ++i) info[i] = matches[i].covariance.inverse();
  for (std::size_t i = 0; i < rotations.size(); ++i) rot_info[i] = rotations[i].covariance.inverse();
  if (matches.size() < 3) return fit;

  Sim3 s = initial;
  for (int iter = 0; iter < o.max_iterations; ++iter) {
    const Accumulated acc = accumulate(matches, info, rotations, rot_info, s, o, false, nullptr);
    Matrix7d hinv;
    if (!invertActive(acc.h, d, &hinv)) return fit;
    const Vector7d delta = -hinv * acc.g;
    if (!delta.allFinite()) return fit;
    s = applyDelta(delta, s);
    // Stop when the step is far inside the noise: δᵀ H δ is the step's own Mahalanobis length.
    if (delta.dot(acc.h * delta) < 1e-10 * std::max<double>(1.0, static_cast<double>(matches.size()))) break;
  }
  // Polish on the inliers with unit weights (the least-squares solution the covariance describes).
  std::vector<bool> inliers(matches.size(), false);
  Matrix7d hinv;
  for (int iter = 0; iter < 5; ++iter) {
    const Accumulated acc = accumulate(matches, info, rotations, rot_info, s, o, true, &inliers);
    if (acc.inliers < 3 || !invertActive(acc.h, d, &hinv)) return fit;
    const Vector7d delta = -hinv * acc.g;
    if (!delta.allFinite()) return fit;
    s = applyDelta(delta, s);
    if (delta.dot(acc.h * delta) < 1e-10 * std::max<double>(1.0, static_cast<double>(matches.size()))) break;
  }
  const Accumulated fin = accumulate(matches, info, rotations, rot_info, s, o, true, &inliers);
  if (fin.inliers < 3 || !invertActive(fin.h, d, &hinv) || !s.matrix().allFinite()) return fit;
  fit.estimate = s;
  fit.inliers = inliers;
  fit.inlier_count = fin.inliers;
  fit.chi2 = fin.chi2;
  fit.dof = 3 * fin.inliers + 3 * static_cast<int>(rotations.size()) - d;
  fit.variance_factor = fit.dof > 0 ? std::max(1.0, fit.chi2 / fit.dof) : 1.0;
  fit.information = fin.h;
  Matrix7d cov = fit.variance_factor * hinv;
  fit.groups = static_cast<int>(fin.group_gradient.size());
  if (fit.groups >= 3) {
    Matrix7d meat = Matrix7d::Zero();
    for (const auto& entry : fin.group_gradient) meat += entry.second * entry.second.transpose();
    meat *= static_cast<double>(fit.groups) / (fit.groups - 1);
    const Matrix7d sandwich = hinv * meat * hinv;
    cov = coveringCovariance(cov, sandwich, &fit.group_spread_factor);
  }
  fit.covariance = cov;
  fit.ok = cov.allFinite();
  return fit;
}

}  // namespace pcr_pro
