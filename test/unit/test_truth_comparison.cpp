// compareWithTruth() / truthErrorsYaml() (pcr_pro/io/truth_comparison.h): the errors of an estimate
// in the covariance's convention (truth = exp(δ) · estimate), the reported uncertainty beside them,
// and the squared Mahalanobis distance, on estimates made here from a known δ.
#include <gtest/gtest.h>
#include <yaml-cpp/yaml.h>

#include <cmath>

#include "pcr_pro/geometry/similarity_fit.h"
#include "pcr_pro/io/truth_comparison.h"
#include "test_helpers.h"

namespace pcr_pro {
namespace {

using Vector7d = Eigen::Matrix<double, 7, 1>;

const Sim3 kTruth(2.5, Eigen::Quaterniond(Eigen::AngleAxisd(0.9, Eigen::Vector3d(0.3, -1.0, 0.2).normalized())),
                  Eigen::Vector3d(4.0, -1.5, 0.7));

// An estimate with truth = exp(δ) · estimate exactly: exp(δ) = (e^δs, exp(δr), δt) as applyDelta() has it.
Sim3 estimateOff(const Vector7d& delta) {
  const Sim3 step = applyDelta(delta, Sim3());
  return step.inverse() * kTruth;
}

TEST(TruthComparison, TheTruthItselfHasNoError) {
  Matrix6d cov = Matrix6d::Identity() * 1e-4;
  const TruthErrors e = compareWithTruth(kTruth, kTruth, cov, 0.01);
  EXPECT_NEAR(e.rotation_deg, 0.0, 1e-6);
  EXPECT_NEAR(e.translation, 0.0, 1e-12);
  EXPECT_NEAR(e.scale_percent, 0.0, 1e-12);
  ASSERT_TRUE(e.pose_chi2);
  EXPECT_NEAR(*e.pose_chi2, 0.0, 1e-12);
}

// Each part of δ shows in its own error: the rotation angle, |δ translation| (not |t_truth -
// t_estimate|, which the rotation error would inflate by |t| times its angle) and the scale.
TEST(TruthComparison, ErrorsAreTheCovariancesDelta) {
  Vector7d d;
  d << 0.03, -0.04, 0.0, 0.0, 0.002, -0.001, 0.004;  // 5 cm, 0.128 deg, 0.4 % (log scale)
  const Sim3 est = estimateOff(d);
  const TruthErrors e = compareWithTruth(est, kTruth, std::nullopt, std::nullopt);
  EXPECT_NEAR(e.rotation_deg, test::deg(std::sqrt(0.002 * 0.002 + 0.001 * 0.001)), 1e-9);
  EXPECT_NEAR(e.translation, 0.05, 1e-12);
  EXPECT_NEAR(e.scale_percent, 100.0 * (std::exp(-0.004) - 1.0), 1e-9);  // the estimate is 0.4 % small
  EXPECT_GT((est.translation() - kTruth.translation()).norm(), 0.05 + 0.001)
      << "the plain translation difference would not be the covariance's δ";
  EXPECT_FALSE(e.rotation_sigma_deg || e.translation_sigma || e.scale_sigma_percent || e.pose_chi2);
}

// Moving the source frame by G moves estimate and truth alike (S G⁻¹): δ does not change.
TEST(TruthComparison, ErrorsDoNotDependOnTheSourceFrame) {
  Vector7d d;
  d << 0.01, 0.02, -0.03, 0.003, 0.0, 0.002, -0.01;
  const Sim3 est = estimateOff(d);
  const Sim3 g(0.3, Eigen::Quaterniond(Eigen::AngleAxisd(-1.2, Eigen::Vector3d(1.0, 0.5, 0.1).normalized())),
               Eigen::Vector3d(-7.0, 3.0, 2.0));
  const TruthErrors a = compareWithTruth(est, kTruth, std::nullopt, std::nullopt);
  const TruthErrors b = compareWithTruth(est * g.inverse(), kTruth * g.inverse(), std::nullopt, std::nullopt);
  EXPECT_NEAR(a.rotation_deg, b.rotation_deg, 1e-9);
  EXPECT_NEAR(a.translation, b.translation, 1e-9);
  EXPECT_NEAR(a.scale_percent, b.scale_percent, 1e-9);
}

// The reported sigmas and the squared Mahalanobis distance of a δ drawn against a known covariance.
TEST(TruthComparison, UncertaintyAndMahalanobisDistance) {
  Matrix6d cov = Matrix6d::Zero();
  cov.diagonal() << 4e-4, 1e-4, 1e-4, 1e-6, 4e-6, 1e-6;  // σ: 2 cm, 1 cm, 1 cm; 1, 2, 1 mrad
  cov(0, 1) = cov(1, 0) = 1e-4;                           // correlated x and y
  Vector7d d;
  d << 0.02, 0.0, -0.01, 0.001, -0.002, 0.0, 0.0;
  const TruthErrors e = compareWithTruth(estimateOff(d), kTruth, cov, 0.025);
  ASSERT_TRUE(e.rotation_sigma_deg && e.translation_sigma && e.scale_sigma_percent && e.pose_chi2);
  EXPECT_NEAR(*e.rotation_sigma_deg, test::deg(std::sqrt(6e-6)), 1e-9);
  EXPECT_NEAR(*e.translation_sigma, std::sqrt(6e-4), 1e-12);
  EXPECT_NEAR(*e.scale_sigma_percent, 100.0 * 0.025 / kTruth.scale(), 1e-9);
  const Eigen::Matrix<double, 6, 1> pose = d.head<6>();
  EXPECT_NEAR(*e.pose_chi2, pose.dot(cov.ldlt().solve(pose)), 1e-9 * *e.pose_chi2);
  // Not positive definite (a direction without information): no chi2, the sigmas stay.
  Matrix6d singular = cov;
  singular.row(5).setZero();
  singular.col(5).setZero();
  const TruthErrors s = compareWithTruth(estimateOff(d), kTruth, singular, std::nullopt);
  EXPECT_FALSE(s.pose_chi2);
  EXPECT_TRUE(s.rotation_sigma_deg);
  EXPECT_FALSE(s.scale_sigma_percent);
  // A non-finite covariance gives no uncertainty at all rather than NaN.
  Matrix6d nan = cov;
  nan(2, 2) = std::nan("");
  const TruthErrors n = compareWithTruth(estimateOff(d), kTruth, nan, std::nullopt);
  EXPECT_FALSE(n.rotation_sigma_deg || n.translation_sigma || n.pose_chi2);
}

TEST(TruthComparison, YamlBlockReadsBack) {
  Vector7d d;
  d << 0.02, 0.0, -0.01, 0.001, -0.002, 0.0, 0.003;
  const TruthErrors e = compareWithTruth(estimateOff(d), kTruth, Matrix6d::Identity() * 1e-4, 0.01);
  const std::string text = truthErrorsYaml(e, "/some/truth.yaml");
  EXPECT_NE(text.find("/some/truth.yaml"), std::string::npos);
  const YAML::Node y = YAML::Load(text)["errors_vs_truth"];
  ASSERT_TRUE(y.IsMap()) << text;
  EXPECT_NEAR(y["rotation_deg"].as<double>(), e.rotation_deg, 1e-3 * e.rotation_deg);
  EXPECT_NEAR(y["translation"].as<double>(), e.translation, 1e-3 * e.translation);
  EXPECT_NEAR(y["scale_percent"].as<double>(), e.scale_percent, 1e-3 * std::abs(e.scale_percent));
  EXPECT_NEAR(y["reported_sigma"]["rotation_deg"].as<double>(), *e.rotation_sigma_deg, 1e-3 * *e.rotation_sigma_deg);
  EXPECT_NEAR(y["reported_sigma"]["translation"].as<double>(), *e.translation_sigma, 1e-3 * *e.translation_sigma);
  EXPECT_NEAR(y["reported_sigma"]["scale_percent"].as<double>(), *e.scale_sigma_percent, 1e-3 * *e.scale_sigma_percent);
  EXPECT_NEAR(y["pose_chi2"].as<double>(), *e.pose_chi2, 1e-3 * *e.pose_chi2);
  // Without uncertainty the block has the errors only.
  const YAML::Node bare =
      YAML::Load(truthErrorsYaml(compareWithTruth(kTruth, kTruth, std::nullopt, std::nullopt), "t.yaml"));
  EXPECT_FALSE(bare["errors_vs_truth"]["reported_sigma"]);
  EXPECT_FALSE(bare["errors_vs_truth"]["pose_chi2"]);
}

}  // namespace
}  // namespace pcr_pro
