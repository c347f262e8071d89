#include "pcr_pro/io/truth_comparison.h"

#include <Eigen/Cholesky>

#include <cmath>
#include <iomanip>
#include <sstream>

#include "pcr_pro/geometry/similarity_fit.h"

namespace pcr_pro {
namespace {

constexpr double kDegPerRad = 180.0 / M_PI;

std::optional<double> finite(double v) { return std::isfinite(v) ? std::optional<double>(v) : std::nullopt; }

}  // namespace

TruthErrors compareWithTruth(const Sim3& estimate, const Sim3& truth, const std::optional<Matrix6d>& covariance,
                             const std::optional<double>& scale_stddev) {
  TruthErrors e;
  const Eigen::Matrix<double, 7, 1> delta = similarityDifference(truth, estimate);
  e.rotation_deg = rotationDistance(truth.rotation(), estimate.rotation()) * kDegPerRad;
  e.translation = delta.head<3>().norm();
  e.scale_percent = 100.0 * (estimate.scale() / truth.scale() - 1.0);
  if (covariance && covariance->allFinite()) {
    e.rotation_sigma_deg = finite(std::sqrt(std::max(0.0, covariance->bottomRightCorner<3, 3>().trace())) * kDegPerRad);
    e.translation_sigma = finite(std::sqrt(std::max(0.0, covariance->topLeftCorner<3, 3>().trace())));
    // The pose part of δ in the covariance's order (x y z rx ry rz); its rotation is log(R_t R_eᵀ).
    const Eigen::Matrix<double, 6, 1> pose = delta.head<6>();
    const Eigen::LLT<Matrix6d> llt(*covariance);
    if (llt.info() == Eigen::Success) e.pose_chi2 = finite(pose.dot(llt.solve(pose)));
  }
  if (scale_stddev) e.scale_sigma_percent = finite(100.0 * *scale_stddev / estimate.scale());
  return e;
}

std::string truthErrorsYaml(const TruthErrors& e, const std::string& truth_file) {
  std::ostringstream os;
  os << std::setprecision(4);
  os << "errors_vs_truth:  # against " << truth_file << "; truth = exp(d) * estimate, the covariance's convention\n";
  os << "  rotation_deg: " << e.rotation_deg << "\n";
  os << "  translation: " << e.translation << "  # target units\n";
  os << "  scale_percent: " << e.scale_percent << "\n";
  if (e.rotation_sigma_deg || e.translation_sigma || e.scale_sigma_percent) {
    std::string sep;
    const auto item = [&](const char* key, const std::optional<double>& v) {
      if (!v) return;
      os << sep << key << ": " << *v;
      sep = ", ";
    };
    os << "  reported_sigma: {";
    item("rotation_deg", e.rotation_sigma_deg);
    item("translation", e.translation_sigma);
    item("scale_percent", e.scale_sigma_percent);
    os << "}  # the uncertainty the estimate reports (1 sigma)\n";
  }
  if (e.pose_chi2) {
    os << "  pose_chi2: " << *e.pose_chi2
       << "  # d' inv(covariance) d over the 6 pose dimensions: 6 on average for an honest covariance, < 12.6 in 95 %\n";
  }
  return os.str();
}

}  // namespace pcr_pro
