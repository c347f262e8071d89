#include <gtest/gtest.h>

#include "pcr_pro/geometry/sim3.h"
#include "test_helpers.h"

namespace pcr_pro {
namespace {

Sim3 randomSim3(std::mt19937& rng) {
  std::uniform_real_distribution<double> u(-5.0, 5.0);
  std::uniform_real_distribution<double> ls(std::log(0.1), std::log(10.0));
  std::uniform_real_distribution<double> ang(0.0, M_PI);
  return Sim3(std::exp(ls(rng)), test::randomRotation(rng, ang(rng)), Eigen::Vector3d(u(rng), u(rng), u(rng)));
}

TEST(Sim3, ComposeMatchesSequentialApplication) {
  std::mt19937 rng(1);
  for (int k = 0; k < 100; ++k) {
    const Sim3 a = randomSim3(rng), b = randomSim3(rng);
    const Eigen::Vector3d p(0.3, -1.2, 2.5);
    EXPECT_LT(((a * b).apply(p) - a.apply(b.apply(p))).norm(), 1e-9 * (1 + p.norm()) * a.scale() * b.scale() * 10);
    EXPECT_LT(((a * b).matrix() - a.matrix() * b.matrix()).norm(), 1e-9 * a.matrix().norm() * b.matrix().norm());
  }
}

TEST(Sim3, InverseRoundTrips) {
  std::mt19937 rng(2);
  for (int k = 0; k < 100; ++k) {
    const Sim3 a = randomSim3(rng);
    const Sim3 id1 = a * a.inverse(), id2 = a.inverse() * a;
    EXPECT_NEAR(id1.scale(), 1.0, 1e-12);
    EXPECT_NEAR(id2.scale(), 1.0, 1e-12);
    EXPECT_LT(id1.translation().norm(), 1e-9);
    EXPECT_LT(id2.translation().norm(), 1e-9);
    EXPECT_LT(rotationDistance(id1.rotation(), Eigen::Matrix3d::Identity()), 1e-9);
    const Eigen::Vector3d p(1.0, 2.0, -3.0);
    EXPECT_LT((a.inverse().apply(a.apply(p)) - p).norm(), 1e-9);
  }
}

TEST(Sim3, MatrixRoundTrips) {
  std::mt19937 rng(3);
  for (int k = 0; k < 100; ++k) {
    const Sim3 a = randomSim3(rng);
    const Sim3 b = Sim3::fromMatrix(a.matrix());
    EXPECT_NEAR(b.scale(), a.scale(), 1e-10 * a.scale());
    EXPECT_LT(rotationDistance(a.rotation(), b.rotation()), 1e-9);
    EXPECT_LT((a.translation() - b.translation()).norm(), 1e-9);
    const Eigen::Quaterniond q = a.quaternion();
    const Sim3 c(a.scale(), q, a.translation());
    EXPECT_LT(rotationDistance(a.rotation(), c.rotation()), 1e-9);
  }
}

TEST(Sim3, CloudApplyMatchesPointApply) {
  std::mt19937 rng(4);
  const Sim3 a = randomSim3(rng);
  Cloud c = Cloud::Random(3, 50);
  const Cloud moved = a.apply(c);
  for (int i = 0; i < c.cols(); ++i) EXPECT_LT((moved.col(i) - a.apply(Eigen::Vector3d(c.col(i)))).norm(), 1e-12);
}

TEST(Sim3, FromMatrixRejectsReflectionsAndBadRows) {
  Eigen::Matrix4d m = Eigen::Matrix4d::Identity();
  m(0, 0) = -1;
  EXPECT_THROW(Sim3::fromMatrix(m), InputError);
  m = Eigen::Matrix4d::Identity();
  m(3, 0) = 0.5;
  EXPECT_THROW(Sim3::fromMatrix(m), InputError);
  m = Eigen::Matrix4d::Zero();
  m(3, 3) = 1;
  EXPECT_THROW(Sim3::fromMatrix(m), InputError);
}

TEST(Sim3, ExpSo3MatchesAngleAxis) {
  const Eigen::Vector3d w(0.1, -0.4, 0.25);
  EXPECT_LT((expSO3(w) - Eigen::AngleAxisd(w.norm(), w.normalized()).toRotationMatrix()).norm(), 1e-12);
  EXPECT_NEAR(rotationDistance(expSO3(w), Eigen::Matrix3d::Identity()), w.norm(), 1e-12);
}

}  // namespace
}  // namespace pcr_pro
