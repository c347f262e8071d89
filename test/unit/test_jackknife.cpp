// The spatial jackknife of a registration (registration/jackknife.h) and its use by registerClouds().
#include <gtest/gtest.h>

#include <Eigen/Eigenvalues>

#include <cmath>
#include <random>

#include "pcr_pro/geometry/similarity_fit.h"
#include "pcr_pro/merge/merge_options.h"
#include "pcr_pro/registration/cloud_registration.h"
#include "pcr_pro/registration/covariance.h"
#include "pcr_pro/registration/jackknife.h"
#include "pcr_pro/sim/simulator.h"
#include "common/bench_worlds.h"

namespace pcr_pro {
namespace {

// χ² 95 % bound with 6 degrees of freedom.
constexpr double kChi2_6 = 12.59;

Matrix7d reportCovariance7(const RegistrationReport& r) {
  // The report's 6x6 pose block and its scale's standard deviation; the NEES below uses the pose.
  Matrix7d c = Matrix7d::Zero();
  c.topLeftCorner<6, 6>() = *r.covariance;
  return c;
}

double nees6(const Sim3& estimate, const Sim3& truth, const Matrix7d& covariance) {
  const Eigen::Matrix<double, 6, 1> d = similarityDifference(estimate, truth).head<6>();
  return d.dot(covariance.topLeftCorner<6, 6>().ldlt().solve(d));
}

// A simulated semi-dense two-agent world (35 % overlap, 2.5 % scale drift, inverse-depth noise
// 0.01), registered with its scale from the exact truth as `pcr_pro_icp --estimate-scale
// --initial` would: the estimate stays near the truth (0.24 deg), but the blocks model's
// covariance claims it to within a few hundredths of a degree (6-DoF NEES far beyond the bound).
// The jackknife's covariance covers it.
TEST(Jackknife, ANoisySemiDenseRegistrationsCovarianceCoversItsErrorWithTheJackknife) {
  const Simulation sim = simulate(test::benchWorldOptions(0.35, 0.025, 0.01, 1, false));
  const Sim3 truth = sim.pair(0, 1).target_source;
  RegistrationOptions options = MergeOptions().registration;
  options.icp.estimate_scale = true;
  const RegistrationReport plain = registerClouds(sim.agents[1].map.cloud, sim.agents[0].map.cloud, truth, options);
  options.covariance.jackknife_blocks = 8;
  const RegistrationReport jack = registerClouds(sim.agents[1].map.cloud, sim.agents[0].map.cloud, truth, options);
  ASSERT_EQ(plain.status, Status::kOk) << plain.message;
  ASSERT_EQ(jack.status, Status::kOk) << jack.message;
  // The same estimate: the jackknife changes the covariance only.
  EXPECT_TRUE(jack.transform->matrix().isApprox(plain.transform->matrix(), 1e-12));
  EXPECT_NE(jack.message.find("jackknife over 8 spatial blocks"), std::string::npos) << jack.message;
  const double before = nees6(*plain.transform, truth, reportCovariance7(plain));
  const double after = nees6(*jack.transform, truth, reportCovariance7(jack));
  EXPECT_GT(before, 3 * kChi2_6) << "the defect the jackknife addresses is gone: revisit the test";
  EXPECT_LT(after, kChi2_6);
  // It only ever raises the covariance: C_plain^-1/2 C_jack C_plain^-1/2 >= I.
  const Eigen::LLT<Matrix6d> llt(*plain.covariance);
  ASSERT_EQ(llt.info(), Eigen::Success);
  const Matrix6d l_inv = Matrix6d(llt.matrixL()).inverse();
  const Eigen::SelfAdjointEigenSolver<Matrix6d> eig(l_inv * *jack.covariance * l_inv.transpose());
  EXPECT_GT(eig.eigenvalues().minCoeff(), 1.0 - 1e-6);
  ASSERT_TRUE(jack.information && jack.scale_stddev);
  EXPECT_TRUE(jack.information->allFinite());
  EXPECT_GE(*jack.scale_stddev, *plain.scale_stddev);
  EXPECT_TRUE((*jack.information * *jack.covariance).isApprox(Matrix6d::Identity(), 1e-6));
}

TEST(Jackknife, TooFewPointsForThreeBlocksLeaveTheCovarianceAsItIsAndSaySo) {
  // 150 points on a tilted, curved patch make two blocks of at least 50 points, not three.
  std::mt19937 rng(3);
  std::uniform_real_distribution<double> u(-1.0, 1.0);
  Cloud target(3, 150);
  for (Eigen::Index i = 0; i < target.cols(); ++i) {
    const double x = u(rng), y = u(rng);
    target.col(i) << x, y, 0.3 * x * x - 0.2 * y * y + 0.1 * x * y;
  }
  const Sim3 moved(1.0, expSO3(Eigen::Vector3d(0.01, -0.02, 0.015)), Eigen::Vector3d(0.02, 0.0, -0.01));
  const Cloud source = moved.inverse().apply(target);
  const JackknifeSpread spread = jackknifeCovariance(source, target, moved, IcpOptions(), 8);
  EXPECT_FALSE(spread.ok);
  EXPECT_NE(spread.message.find("fewer than 3"), std::string::npos) << spread.message;
  EXPECT_THROW(jackknifeCovariance(source, target, moved, IcpOptions(), 2), InputError);
}

TEST(Jackknife, ARigidRegistrationsSpreadHasNoScaleAndBlocksFewerThanThreeAreRefused) {
  const Simulation sim = simulate(test::benchWorldOptions(0.6, 0.0, 0.01, 0, false));
  const Sim3 truth = sim.pair(0, 1).target_source;
  // The source in the target's units, so that a rigid registration can hold it.
  const Cloud source =
      Sim3(truth.scale(), Eigen::Matrix3d::Identity(), Eigen::Vector3d::Zero()).apply(sim.agents[1].map.cloud);
  const Sim3 rigid(1.0, truth.rotation(), truth.translation());
  const JackknifeSpread spread = jackknifeCovariance(source, sim.agents[0].map.cloud, rigid, IcpOptions(), 4);
  ASSERT_TRUE(spread.ok) << spread.message;
  EXPECT_EQ(spread.blocks + spread.failed, 4);
  EXPECT_TRUE(spread.covariance.row(6).isZero());
  EXPECT_TRUE(spread.covariance.col(6).isZero());
  const Matrix6d pose = spread.covariance.topLeftCorner<6, 6>();
  EXPECT_GT(pose.trace(), 0.0);
  CovarianceOptions options;
  options.jackknife_blocks = 2;
  EXPECT_THROW(validate(options), InputError);
  options.jackknife_blocks = 3;
  EXPECT_NO_THROW(validate(options));
}

}  // namespace
}  // namespace pcr_pro
