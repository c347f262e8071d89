#include <gtest/gtest.h>

#include <Eigen/Cholesky>
#include <Eigen/Eigenvalues>
#include <Eigen/LU>
#include <Eigen/QR>

#include <cmath>
#include <cstdio>
#include <limits>
#include <random>

#include "pcr_pro/registration/covariance.h"
#include "pcr_pro/registration/icp.h"
#include "pcr_pro/geometry/kdtree.h"
#include "pcr_pro/geometry/normals.h"
#include "pcr_pro/geometry/similarity_fit.h"
#include "test_helpers.h"

namespace pcr_pro {
namespace {

Correspondences pairs(const Cloud& source, const Cloud& target) {
  Correspondences c;
  c.source = source;
  c.target = target;
  return c;
}

TEST(Covariance, ZeroResidualPointToPointMatchesClosedForm) {
  std::mt19937 rng(1);
  const Cloud x = test::syntheticScene(800, 3.0, rng);
  const Sim3 s(1.0, test::randomRotation(rng, 0.7), Eigen::Vector3d(2.0, -1.0, 4.0));
  const Cloud y = s.apply(x);
  CovarianceOptions o;
  o.model = CovarianceModel::kClosedForm;
  o.sensor_noise_stddev = 0.01;
  const CovarianceResult r = computeIcpCovariance(pairs(x, y), s, ErrorMetric::kPointToPoint, false, o);
  ASSERT_EQ(r.status, Status::kOk) << r.message;
  Matrix6d sum = Matrix6d::Zero();
  for (int i = 0; i < y.cols(); ++i) {
    Eigen::Matrix<double, 3, 6> a;
    a << Eigen::Matrix3d::Identity(), -skew(y.col(i));
    sum += a.transpose() * a;
  }
  const Matrix6d expected = 2.0 * 0.01 * 0.01 * sum.inverse();
  EXPECT_LT((r.covariance - expected).norm() / expected.norm(), 1e-9);
  EXPECT_LT((r.information * r.covariance - Matrix6d::Identity()).norm(), 1e-6);
  EXPECT_NEAR(r.noise_stddev, 0.01, 1e-15);
}

TEST(Covariance, ZeroResidualPointToPlaneMatchesClosedForm) {
  std::mt19937 rng(2);
  const Cloud x = test::syntheticScene(800, 3.0, rng);
  const Sim3 s(1.0, test::randomRotation(rng, 0.4), Eigen::Vector3d(-1.0, 0.5, 2.0));
  Correspondences c = pairs(x, s.apply(x));
  KdTree tree(c.target);
  c.target_normals = estimateNormals(tree, 10);
  CovarianceOptions o;
  o.model = CovarianceModel::kClosedForm;
  o.sensor_noise_stddev = 0.02;
  const CovarianceResult r = computeIcpCovariance(c, s, ErrorMetric::kPointToPlane, false, o);
  ASSERT_EQ(r.status, Status::kOk) << r.message;
  Matrix6d sum = Matrix6d::Zero();
  for (int i = 0; i < x.cols(); ++i) {
    Vector6d a;
    a << c.target_normals.col(i), Eigen::Vector3d(c.target.col(i)).cross(Eigen::Vector3d(c.target_normals.col(i)));
    sum += a * a.transpose();
  }
  const Matrix6d expected = 2.0 * 0.02 * 0.02 * sum.inverse();
  EXPECT_LT((r.covariance - expected).norm() / expected.norm(), 1e-9);
}

TEST(Covariance, MonteCarloNeesIsConsistentWithKnownCorrespondences) {
  std::mt19937 rng(3);
  std::normal_distribution<double> noise(0.0, 1.0);
  const double sigma = 0.01;
  const Cloud x = test::syntheticScene(400, 2.0, rng);
  const Sim3 truth(1.0, test::randomRotation(rng, 0.5), Eigen::Vector3d(0.5, 1.0, -0.3));
  const Cloud y_true = truth.apply(x);
  CovarianceOptions o;
  o.model = CovarianceModel::kClosedForm;
  o.sensor_noise_stddev = sigma;
  const int trials = 200;
  double nees_sum = 0.0, nees_rot = 0.0, nees_trans = 0.0;
  for (int t = 0; t < trials; ++t) {
    Cloud xs = x, yt = y_true;
    for (int i = 0; i < x.cols(); ++i) {
      xs.col(i) += sigma * Eigen::Vector3d(noise(rng), noise(rng), noise(rng));
      yt.col(i) += sigma * Eigen::Vector3d(noise(rng), noise(rng), noise(rng));
    }
    const Sim3 est = umeyama(xs, yt, false);
    const CovarianceResult r = computeIcpCovariance(pairs(xs, yt), est, ErrorMetric::kPointToPoint, false, o);
    ASSERT_EQ(r.status, Status::kOk);
    const Vector6d d = poseDifference(est, truth);
    nees_sum += d.dot(r.covariance.ldlt().solve(d));
    nees_trans += d.head<3>().dot(r.covariance.topLeftCorner<3, 3>().ldlt().solve(d.head<3>()));
    nees_rot += d.tail<3>().dot(r.covariance.bottomRightCorner<3, 3>().ldlt().solve(d.tail<3>()));
  }
  // Mean of 200 χ²(6) values: 95 % band [5.53, 6.49]; χ²(3) blocks: [2.66, 3.34].
  EXPECT_GT(nees_sum / trials, 5.53);
  EXPECT_LT(nees_sum / trials, 6.49);
  EXPECT_GT(nees_trans / trials, 2.66);
  EXPECT_LT(nees_trans / trials, 3.34);
  EXPECT_GT(nees_rot / trials, 2.66);
  EXPECT_LT(nees_rot / trials, 3.34);
}

TEST(Covariance, MonteCarloNeesWithScaleAndEstimatedNoise) {
  // Similarity with the noise estimated from the residuals: 7-DoF NEES of the mean over 200
  // trials inside the 95 % band of χ²(7)/200 ([6.48, 7.52]).
  std::mt19937 rng(4);
  std::normal_distribution<double> noise(0.0, 1.0);
  const double sigma = 0.005;  // target units; the source noise is sigma / scale in source units
  const Cloud x = test::syntheticScene(500, 2.0, rng);
  const Sim3 truth(2.5, test::randomRotation(rng, 0.9), Eigen::Vector3d(-2.0, 0.3, 1.0));
  const Cloud y_true = truth.apply(x);
  const int trials = 200;
  double nees_sum = 0.0;
  for (int t = 0; t < trials; ++t) {
    Cloud xs = x, yt = y_true;
    for (int i = 0; i < x.cols(); ++i) {
      xs.col(i) += (sigma / truth.scale()) * Eigen::Vector3d(noise(rng), noise(rng), noise(rng));
      yt.col(i) += sigma * Eigen::Vector3d(noise(rng), noise(rng), noise(rng));
    }
    const Sim3 est = umeyama(xs, yt, true);
    CovarianceOptions closed;
    closed.model = CovarianceModel::kClosedForm;
    const CovarianceResult r = computeIcpCovariance(pairs(xs, yt), est, ErrorMetric::kPointToPoint, true, closed);
    ASSERT_EQ(r.status, Status::kOk);
    EXPECT_NEAR(r.noise_stddev, sigma, 0.1 * sigma);
    Eigen::Matrix<double, 7, 1> d;
    d << poseDifference(est, truth), est.scale() - truth.scale();
    nees_sum += d.dot(r.covariance7.ldlt().solve(d));
  }
  EXPECT_GT(nees_sum / trials, 6.48);
  EXPECT_LT(nees_sum / trials, 7.52);
}

// Monte-Carlo with re-matched correspondences, as in use: both clouds are independent sparse
// samples of one scene with noise, the ICP (defaults: point-to-plane, symmetric, overlap-aware)
// starts from a perturbed guess and re-makes its nearest-neighbour correspondences. Returns the
// ANEES (mean NEES / 6) of the 6-DoF pose error under the plain closed form and under the
// default model (blocks), on the same trials.
struct Anees {
  double closed = 0.0, blocks = 0.0;
};

Anees rematchedAnees(int points, int trials, unsigned seed) {
  std::mt19937 rng(seed);
  std::normal_distribution<double> noise(0.0, 1.0);
  const double sigma = 0.01, size = 4.0;  // metres: ~10 cm point spacing at 2k points
  const Sim3 truth(1.0, test::randomRotation(rng, 0.6), Eigen::Vector3d(0.5, -0.3, 0.2));
  CovarianceOptions closed, blocks;
  closed.model = CovarianceModel::kClosedForm;
  blocks.model = CovarianceModel::kBlocks;
  Anees a;
  int used = 0;
  for (int t = 0; t < trials; ++t) {
    Cloud target = test::syntheticScene(points, size, rng);
    Cloud source_world = test::syntheticScene(points, size, rng);
    for (int i = 0; i < points; ++i) {
      target.col(i) += sigma * Eigen::Vector3d(noise(rng), noise(rng), noise(rng));
      source_world.col(i) += sigma * Eigen::Vector3d(noise(rng), noise(rng), noise(rng));
    }
    const Cloud source = truth.inverse().apply(source_world);
    const Sim3 guess = Sim3(1.0, expSO3(0.02 * Eigen::Vector3d(noise(rng), noise(rng), noise(rng))),
                            0.05 * Eigen::Vector3d(noise(rng), noise(rng), noise(rng))) *
                       truth;
    const IcpOptions io;
    const IcpResult icp = alignIcp(source, target, guess, io);
    if (icp.status != Status::kOk) continue;
    const CovarianceResult rc = computeIcpCovariance(icp.matches, icp.transform, io.error_metric, false, closed);
    const CovarianceResult rb = computeIcpCovariance(icp.matches, icp.transform, io.error_metric, false, blocks);
    if (rc.status != Status::kOk || rb.status != Status::kOk) continue;
    const Vector6d d = poseDifference(icp.transform, truth);
    a.closed += d.dot(rc.covariance.ldlt().solve(d)) / 6.0;
    a.blocks += d.dot(rb.covariance.ldlt().solve(d)) / 6.0;
    ++used;
  }
  EXPECT_GE(used, trials - 2);
  a.closed /= used;
  a.blocks /= used;
  std::printf("%d points, %d trials: ANEES closed form %.3f, blocks %.3f\n", points, used, a.closed, a.blocks);
  return a;
}

// The goal, ANEES in [0.8, 1.25], is measured by make bench over more trials. Over 60 trials
// the ANEES itself scatters by about ±0.2 from seed to seed, so these regression checks pool
// 60-100 trials. Measured here (blocks): 0.72 at 2k points, 1.12 at 10k (0.69 and 1.25 with
// planes through the matched points instead of their neighbours' centroids; before the pairs'
// shared noise was measured, Correspondences::redundancy, 0.83 and 1.51: the estimate got more
// over-confident the denser the clouds). At 2k points (1 cm noise on about 10 cm
// spacing) the residuals also hold how a sparse sample misses curved surfaces and edges, which
// inflates the noise estimate more than it moves the pose: the covariance errs on the wide side
// there, never the confident one.
TEST(Covariance, BlocksAreConsistentWithRematchedCorrespondences2k) {
  const Anees a = rematchedAnees(2000, 100, 21);
  EXPECT_GT(a.blocks, 0.6);
  EXPECT_LT(a.blocks, 1.3);
}

TEST(Covariance, BlocksAreCloserToConsistentThanTheClosedFormAt10k) {
  const Anees a = rematchedAnees(10000, 60, 22);
  EXPECT_GT(a.blocks, 0.8);
  EXPECT_LT(a.blocks, 1.4);
  EXPECT_LT(a.blocks, a.closed);
}

TEST(Covariance, ModelNamesRoundTrip) {
  for (CovarianceModel m : {CovarianceModel::kClosedForm, CovarianceModel::kCalibrated, CovarianceModel::kBlocks}) {
    CovarianceModel parsed = CovarianceModel::kClosedForm;
    ASSERT_TRUE(parseCovarianceModel(covarianceModelName(m), &parsed));
    EXPECT_EQ(parsed, m);
  }
  CovarianceModel unused;
  EXPECT_FALSE(parseCovarianceModel("censi", &unused));
  CovarianceOptions bad;
  bad.calibration_splits = 0;
  EXPECT_THROW(validate(bad), InputError);
}

TEST(Covariance, PlanarCloudIsDegenerate) {
  std::mt19937 rng(5);
  std::uniform_real_distribution<double> u(-1.0, 1.0);
  std::normal_distribution<double> noise(0.0, 0.001);
  Cloud target(3, 2000), source(3, 2000);
  for (int i = 0; i < 2000; ++i) {
    target.col(i) << u(rng), u(rng), noise(rng);
    source.col(i) << u(rng), u(rng), noise(rng);
  }
  for (ErrorMetric metric : {ErrorMetric::kPointToPlane, ErrorMetric::kPointToPoint}) {
    IcpOptions io;
    io.error_metric = metric;
    const IcpResult icp = alignIcp(source, target, Sim3(1.0, Eigen::Matrix3d::Identity(), Eigen::Vector3d(0, 0, 0.01)), io);
    // ICP may slide along the plane without settling; the covariance at its final matches is
    // what must flag the unobservable directions.
    ASSERT_GT(icp.correspondences, 1000) << icp.message;
    const CovarianceResult r =
        computeIcpCovariance(icp.matches, icp.transform, metric, false, CovarianceOptions());
    EXPECT_EQ(r.status, Status::kDegenerate) << errorMetricName(metric) << ": " << r.message;
    EXPECT_GT(r.condition_number, CovarianceOptions().degeneracy_condition_threshold);
    // (Almost) no information along in-plane translation or about the plane normal; plenty
    // along z and the tilts. The null directions come from noisy normals, so they are not
    // exactly axis-aligned: small leftovers remain.
    EXPECT_LT(r.information(0, 0), 1e-4 * r.information(2, 2));
    EXPECT_LT(r.information(1, 1), 1e-4 * r.information(2, 2));
    EXPECT_LT(r.information(5, 5), 1e-4 * r.information(3, 3));
    EXPECT_GT(r.covariance(0, 0), 1e3 * r.covariance(2, 2));
  }
}

TEST(Covariance, RealCarScanIsWellConditioned) {
  // A non-degenerate real scene must not be flagged: the threshold has to separate it from a plane.
  std::mt19937 rng(6);
  const Cloud scene = test::syntheticScene(3000, 10.0, rng);
  IcpOptions io;
  const IcpResult icp = alignIcp(scene, scene, Sim3(), io);
  ASSERT_EQ(icp.status, Status::kOk);
  const CovarianceResult r = computeIcpCovariance(icp.matches, icp.transform, io.error_metric, false, CovarianceOptions());
  EXPECT_EQ(r.status, Status::kOk) << r.message;
  EXPECT_LT(r.condition_number, 1e3);
}

TEST(Covariance, TooFewCorrespondences) {
  Correspondences c = pairs(Cloud::Random(3, 4), Cloud::Random(3, 4));
  const CovarianceResult r = computeIcpCovariance(c, Sim3(), ErrorMetric::kPointToPoint, false, CovarianceOptions());
  EXPECT_NE(r.status, Status::kOk);
}

// The scale ICP's errors-in-variables correction weighs the two clouds' noise by their surface
// thickness: it must compare two clouds by their noise (twice the noise along the normal: four
// times the thickness², within 10 %) and scale with the cloud's units. The noise here is below a
// third of the point spacing; at noise near the spacing the nearest neighbours are chosen
// partly by it, and the thicker cloud's thickness² is underestimated (3.0 instead of 4 at 20000
// points).
TEST(SurfaceThickness, ComparesCloudsByTheirNoiseAlongTheNormal) {
  std::mt19937 rng(5);
  std::uniform_real_distribution<double> u(-1.0, 1.0);
  std::normal_distribution<double> n(0.0, 1.0);
  const auto plane = [&](double sigma) {
    Cloud c(3, 5000);
    for (Eigen::Index i = 0; i < c.cols(); ++i) c.col(i) = Eigen::Vector3d(u(rng), u(rng), sigma * n(rng));
    return c;
  };
  const Cloud thin = plane(0.004), thick = plane(0.008);
  const double t_thin = surfaceThickness2(KdTree(thin), 10, 2000);
  const double t_thick = surfaceThickness2(KdTree(thick), 10, 2000);
  ASSERT_GT(t_thin, 0.0);
  EXPECT_NEAR(t_thick / t_thin, 4.0, 0.4);
  const Cloud scaled = 3.0 * thin;
  EXPECT_NEAR(surfaceThickness2(KdTree(scaled), 10, 2000) / t_thin, 9.0, 1e-6 * 9.0);
}

// The ICP's planes pass through the centroid of each point's k neighbours: on a noisy plane
// (noise a seventh of the spacing) that centroid's offset along the normal has about a k-th of
// one point's variance. Bounds: a point's own variance is σ² (within 10 % at 500 samples), the
// centroids' within a factor 2 of σ²/k (the neighbours are picked partly by the noise).
TEST(NormalsAt, CentroidsCarryAKthOfOnePointsNoise) {
  std::mt19937 rng(6);
  std::uniform_real_distribution<double> u(-1.0, 1.0);
  std::normal_distribution<double> n(0.0, 1.0);
  const double sigma = 0.004;
  const int k = 10;
  Cloud c(3, 5000);
  for (Eigen::Index i = 0; i < c.cols(); ++i) c.col(i) = Eigen::Vector3d(u(rng), u(rng), sigma * n(rng));
  std::vector<Eigen::Index> at;
  for (Eigen::Index i = 0; i < c.cols(); i += 10) at.push_back(i);
  Cloud centroids;
  estimateNormalsAt(KdTree(c), at, k, &centroids);
  ASSERT_EQ(centroids.cols(), static_cast<Eigen::Index>(at.size()));
  double points2 = 0.0, centroids2 = 0.0;
  for (std::size_t j = 0; j < at.size(); ++j) {
    const auto col = static_cast<Eigen::Index>(j);
    points2 += std::pow(c(2, at[j]), 2);
    centroids2 += std::pow(centroids(2, col), 2);
  }
  points2 /= static_cast<double>(at.size());
  centroids2 /= static_cast<double>(at.size());
  EXPECT_NEAR(points2, sigma * sigma, 0.1 * sigma * sigma);
  EXPECT_GT(centroids2, 0.5 * sigma * sigma / k);
  EXPECT_LT(centroids2, 2.0 * sigma * sigma / k);
}

// Each point's own thickness (estimateNormalsAt's thickness2, the ICP's local noise): on a plane
// whose right half is three times noisier, the medians of the two halves' values compare as the
// noise variances (9), each half's median matches surfaceThickness2() of a plane of its noise
// alone, and a point with no plane (fewer than 3 neighbours) has none.
TEST(NormalsAt, ThicknessFollowsTheLocalNoise) {
  std::mt19937 rng(7);
  std::uniform_real_distribution<double> u(-1.0, 1.0);
  std::normal_distribution<double> n(0.0, 1.0);
  const auto plane = [&](double left, double right) {
    Cloud c(3, 6000);
    for (Eigen::Index i = 0; i < c.cols(); ++i) {
      const double x = u(rng), y = u(rng);
      c.col(i) = Eigen::Vector3d(x, y, (x > 0.0 ? right : left) * n(rng));
    }
    return c;
  };
  const Cloud c = plane(0.003, 0.009);
  std::vector<Eigen::Index> at;
  for (Eigen::Index i = 0; i < c.cols(); ++i) {
    if (std::abs(c(0, i)) > 0.2) at.push_back(i);  // away from the seam
  }
  Eigen::VectorXd t2;
  estimateNormalsAt(KdTree(c), at, 10, nullptr, &t2);
  ASSERT_EQ(t2.size(), static_cast<Eigen::Index>(at.size()));
  std::vector<double> left, right;
  for (std::size_t j = 0; j < at.size(); ++j) {
    (c(0, at[j]) > 0.0 ? right : left).push_back(t2(static_cast<Eigen::Index>(j)));
  }
  const auto median = [](std::vector<double> v) {
    std::nth_element(v.begin(), v.begin() + static_cast<std::ptrdiff_t>(v.size() / 2), v.end());
    return v[v.size() / 2];
  };
  EXPECT_NEAR(median(right) / median(left), 9.0, 1.5);
  const double quiet = surfaceThickness2(KdTree(plane(0.003, 0.003)), 10, 2000);
  EXPECT_NEAR(median(left) / quiet, 1.0, 0.2);
  Cloud two(3, 2);
  two << 0, 1, 0, 0, 0, 0;
  Eigen::VectorXd none;
  estimateNormalsAt(KdTree(two), {0, 1}, 10, nullptr, &none);
  EXPECT_EQ(none.size(), 2);
  EXPECT_EQ(none.cwiseAbs().maxCoeff(), 0.0);
}


// invertCovarianceResult(): a registration run the other way round, of S = S_source_target,
// turned into one of S^-1. Against a Monte-Carlo of the inversion itself: perturbations δ ~ C
// of S (left, similarity_fit.h), each inverted and measured against S^-1. The similarity has a
// scale (2.5: a covariance7 moved with s where log s belongs would be off by s^4 in the scale's
// variance) and a far origin (the lever arm, and the scale's share of the translation).
TEST(Covariance, AResultOfTheInverseRegistrationIsMovedIntoTheAskedDirection) {
  const Sim3 s(2.5, Eigen::AngleAxisd(0.6, Eigen::Vector3d(1, -2, 0.5).normalized()).toRotationMatrix(),
               Eigen::Vector3d(12.0, -7.0, 3.0));
  const Sim3 forward = s.inverse();
  std::mt19937 rng(5);
  std::normal_distribution<double> n(0.0, 1.0);
  Matrix7d a;
  for (int i = 0; i < 7; ++i)
    for (int j = 0; j < 7; ++j) a(i, j) = n(rng);
  Eigen::Matrix<double, 7, 1> sd;
  sd << 0.01, 0.02, 0.015, 0.002, 0.003, 0.001, 0.004;  // translation, rotation [rad], log scale
  const Matrix7d l = sd.asDiagonal() * (0.3 * a * a.transpose() / 7.0 + Matrix7d::Identity()) * sd.asDiagonal();
  CovarianceResult res;
  res.with_scale = true;
  res.covariance = l.topLeftCorner<6, 6>();
  res.information = res.covariance.inverse();
  Eigen::Matrix<double, 7, 1> jd = Eigen::Matrix<double, 7, 1>::Ones();
  jd(6) = s.scale();
  res.covariance7 = jd.asDiagonal() * l * jd.asDiagonal();  // 7th variable s
  res.scale_stddev = std::sqrt(res.covariance7(6, 6));
  res.noise_stddev = 0.01;
  invertCovarianceResult(forward, &res);

  const Eigen::LLT<Matrix7d> llt(l);
  const int trials = 20000;
  Matrix7d mc = Matrix7d::Zero();
  double var_scale = 0.0;
  for (int k = 0; k < trials; ++k) {
    Eigen::Matrix<double, 7, 1> z;
    for (int i = 0; i < 7; ++i) z(i) = n(rng);
    const Sim3 inverted = applyDelta(llt.matrixL() * z, s).inverse();
    const Eigen::Matrix<double, 7, 1> d = similarityDifference(inverted, forward);
    mc += d * d.transpose() / trials;
    var_scale += std::pow(inverted.scale() - forward.scale(), 2) / trials;
  }
  const Matrix7d got = logScaleCovariance(res, forward.scale());
  for (int i = 0; i < 7; ++i) EXPECT_NEAR(got(i, i) / mc(i, i), 1.0, 0.05) << "variable " << i;
  EXPECT_NEAR(res.scale_stddev / std::sqrt(var_scale), 1.0, 0.03);
  EXPECT_TRUE((res.information * res.covariance).isApprox(Matrix6d::Identity(), 1e-8));
  EXPECT_NEAR(res.noise_stddev, 0.01 / 2.5, 1e-15);  // into the target's units
}

// A degenerate result's information is zero along its unobservable direction; inverted, it
// stays zero along that direction moved by the adjoint (and finite), instead of the inverse of a
// covariance that is singular there.
TEST(Covariance, AnInvertedDegenerateResultKeepsItsUnobservableDirection) {
  const Sim3 s(2.5, Eigen::AngleAxisd(0.6, Eigen::Vector3d(1, -2, 0.5).normalized()).toRotationMatrix(),
               Eigen::Vector3d(12.0, -7.0, 3.0));
  const Sim3 forward = s.inverse();
  CovarianceResult res;
  res.status = Status::kDegenerate;
  res.covariance = 1e-4 * Matrix6d::Identity();
  res.covariance(0, 0) = 0.0;  // the x translation is not constrained: no variance claimed, no information
  res.information = 1e4 * Matrix6d::Identity();
  res.information(0, 0) = 0.0;
  invertCovarianceResult(forward, &res);
  ASSERT_TRUE(res.information.allFinite());
  // δ along x about S is -Ad(S^-1) δ about S^-1; the information there is zero.
  Eigen::Matrix<double, 6, 1> e = Eigen::Matrix<double, 6, 1>::Zero();
  e(0) = 1.0;
  const Eigen::Matrix<double, 6, 1> moved = similarityAdjoint(forward).topLeftCorner<6, 6>() * e;
  EXPECT_NEAR(moved.dot(res.information * moved), 0.0, 1e-9 * res.information.norm());
  EXPECT_GT(res.information.norm(), 0.0);
}

// A random orthonormal 6x6 basis: the eigen-directions of a test covariance.
Matrix6d randomRotation6(unsigned seed) {
  std::mt19937 rng(seed);
  std::normal_distribution<double> g(0.0, 1.0);
  Matrix6d a;
  for (int i = 0; i < 36; ++i) a(i / 6, i % 6) = g(rng);
  return Eigen::HouseholderQR<Matrix6d>(a).householderQ();
}

// The information reported with a covariance that is not positive definite (a DEGENERATE merge
// that keeps the keyframe estimate): the inverse where the covariance is positive, nothing claimed
// along a zero or negative variance, nothing at all when it is not finite.
TEST(Covariance, PositivePartInformationClaimsNothingWhereTheCovarianceIsNotPositive) {
  const Matrix6d q = randomRotation6(7);
  // Mixed units, as a pose covariance has them: [m^2] and [rad^2].
  Eigen::Matrix<double, 6, 1> variances;
  variances << 4e-4, 1e-3, 2.5e-5, 1e-6, 3e-6, 5e-7;
  const Matrix6d pd = q * variances.asDiagonal() * q.transpose();
  const Matrix6d info = positivePartInformation(pd);
  EXPECT_LT((info * pd - Matrix6d::Identity()).norm(), 1e-8) << "a positive definite covariance is inverted";

  Eigen::Matrix<double, 6, 1> broken = variances;
  broken(1) = 0.0;    // no variance claimed
  broken(4) = -2e-6;  // not a variance
  const Matrix6d c = q * broken.asDiagonal() * q.transpose();
  const Matrix6d ic = positivePartInformation(c);
  ASSERT_TRUE(ic.allFinite());
  EXPECT_LT((ic - ic.transpose()).norm(), 1e-9 * ic.norm());
  for (int k : {1, 4}) {
    EXPECT_LT((ic * q.col(k)).norm(), 1e-6 * ic.norm()) << "information along direction " << k;
  }
  for (int k : {0, 2, 3, 5}) {
    EXPECT_NEAR(q.col(k).dot(ic * q.col(k)), 1.0 / variances(k), 1e-6 / variances(k)) << "direction " << k;
  }
  Matrix6d not_finite = pd;
  not_finite(2, 3) = std::numeric_limits<double>::quiet_NaN();
  EXPECT_EQ(positivePartInformation(not_finite), Matrix6d::Zero());
  EXPECT_EQ(positivePartInformation(Matrix6d::Zero()), Matrix6d::Zero());
}

// A DEGENERATE merge whose kept estimate is the ICP's reported the ICP closed form's information
// beside a covariance the gates had widened: more confident than that covariance. Its information
// is now the reported covariance's own; the closed form only stands in when there is no finite
// covariance.
TEST(Covariance, DegenerateUncertaintyReportsTheInformationOfTheCovarianceItReports) {
  const Matrix6d q = randomRotation6(11);
  Eigen::Matrix<double, 6, 1> variances;
  variances << 4e-4, 1e-3, 2.5e-5, 1e-6, 3e-6, 5e-7;
  Eigen::Matrix<double, 6, 1> widened = 9.0 * variances;  // the merge's covariance, widened by the gates
  widened(2) = -1e-6;                                     // and not positive along one direction
  const Matrix6d merged = q * widened.asDiagonal() * q.transpose();
  CovarianceResult icp;  // the ICP's own closed form: positive definite and tighter
  icp.covariance = q * variances.asDiagonal() * q.transpose();
  icp.information = q * variances.cwiseInverse().asDiagonal() * q.transpose();

  const ReportedUncertainty kept_icp = degenerateUncertainty(merged, &icp);
  ASSERT_TRUE(kept_icp.covariance.has_value());
  EXPECT_EQ(*kept_icp.covariance, merged);
  for (int k = 0; k < 6; ++k) {
    const double claimed = q.col(k).dot(kept_icp.information * q.col(k));
    if (k == 2) {
      EXPECT_LT(std::abs(claimed), 1e-6 / variances(k)) << "no information where the covariance is not positive";
    } else {
      EXPECT_NEAR(claimed, 1.0 / widened(k), 1e-6 / widened(k)) << "direction " << k << ": the reported covariance's";
    }
  }
  const ReportedUncertainty kept_keyframes = degenerateUncertainty(merged, nullptr);
  EXPECT_EQ(kept_keyframes.information, kept_icp.information);

  Matrix6d not_finite = merged;
  not_finite(0, 5) = std::numeric_limits<double>::infinity();
  const ReportedUncertainty fallback = degenerateUncertainty(not_finite, &icp);
  ASSERT_TRUE(fallback.covariance.has_value());
  EXPECT_EQ(*fallback.covariance, icp.covariance) << "the ICP's own pair when the merge's is not finite";
  EXPECT_EQ(fallback.information, icp.information);
  const ReportedUncertainty nothing = degenerateUncertainty(not_finite, nullptr);
  EXPECT_FALSE(nothing.covariance.has_value());
  EXPECT_EQ(nothing.information, Matrix6d::Zero());
}

// A spread of two estimates has rank 1 in each block; isotropicBlocksAt() keeps each block's size
// (its trace, with the translation taken at the centre) and spreads it over every axis, and drops
// the cross terms between the blocks, as blockDiagonalAt() does.
TEST(Covariance, IsotropicBlocksAtKeepsEachBlocksSizeOverEveryAxis) {
  Eigen::Matrix<double, 7, 1> d;
  d << 0.02, -0.01, 0.03, 0.004, 0.0, -0.002, 0.01;
  const Matrix7d spread = d * d.transpose();
  const Eigen::Vector3d centre(1.0, -2.0, 0.5);
  const Matrix7d iso = isotropicBlocksAt(spread, centre);
  // Back at the centre (u = K^-1 delta, the translation at the centre): isotropic blocks.
  Matrix7d k = Matrix7d::Identity();
  k.block<3, 3>(0, 3) = skew(centre);
  k.block<3, 1>(0, 6) = -centre;
  const Matrix7d kinv = k.inverse();
  const Matrix7d u_in = kinv * spread * kinv.transpose(), u_out = kinv * iso * kinv.transpose();
  for (int b = 0; b < 6; b += 3) {
    const Eigen::Matrix3d in = u_in.block(b, b, 3, 3), out = u_out.block(b, b, 3, 3);
    EXPECT_NEAR(out.trace(), in.trace(), 1e-12 * in.trace());
    EXPECT_TRUE(out.isApprox(Eigen::Matrix3d::Identity() * out(0, 0), 1e-12));
  }
  EXPECT_NEAR(u_out(6, 6), u_in(6, 6), 1e-12 * u_in(6, 6));
  const double cross = u_out.block(0, 3, 3, 3).norm() + u_out.block(0, 6, 6, 1).norm();
  EXPECT_LT(cross, 1e-12 * u_in.norm());
  // Full rank where the spread had rank 1.
  const Eigen::SelfAdjointEigenSolver<Matrix7d> eig(iso);
  EXPECT_GT(eig.eigenvalues().minCoeff(), 0.0);
}

}  // namespace
}  // namespace pcr_pro
