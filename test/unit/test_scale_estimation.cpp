// Scale by Kalman filter: synthetic matches with a known scale, baseline, noise and outliers.
#include <gtest/gtest.h>

#include <algorithm>
#include <cmath>
#include <limits>
#include <random>
#include <string>
#include <vector>

#include "common/option_checks.h"
#include "pcr_pro/frontend/scale_estimation.h"
#include "pcr_pro/geometry/sim3.h"

namespace pcr_pro {
namespace {

constexpr double kFocal = 500.0;
constexpr int kWidth = 640, kHeight = 480;

// A synthetic set of matches between two keyframe cameras.
struct Scenario {
  Eigen::Matrix3d R;
  Eigen::Vector3d t_hat;
  double scale = 1.0;
  double lambda = 1.0;
  std::vector<Eigen::Vector3d> source;
  std::vector<Eigen::Vector3d> target;
  std::vector<bool> is_outlier;
};

// Camera-frame point seen at a random pixel at a random depth in [z_min, z_max].
Eigen::Vector3d randomCameraPoint(std::mt19937* rng, double z_min, double z_max) {
  std::uniform_real_distribution<double> pu(0.0, kWidth), pv(0.0, kHeight), pz(z_min, z_max);
  const double z = pz(*rng);
  return z * Eigen::Vector3d((pu(*rng) - 0.5 * kWidth) / kFocal, (pv(*rng) - 0.5 * kHeight) / kFocal, 1.0);
}

// Adds the noise of the estimator's model: relative sigma_d along the ray, sigma_l across.
Eigen::Vector3d addNoise(const Eigen::Vector3d& p, double sigma_d, double sigma_l, std::mt19937* rng) {
  std::normal_distribution<double> g(0.0, 1.0);
  const double d = p.norm();
  const Eigen::Vector3d b = p / d;
  const Eigen::Vector3d e1 = b.unitOrthogonal();
  const Eigen::Vector3d e2 = b.cross(e1);
  return p + d * (sigma_d * g(*rng) * b + sigma_l * (g(*rng) * e1 + g(*rng) * e2));
}

Scenario makeScenario(double scale, int n, double outlier_fraction, double sigma_d, double sigma_l, unsigned seed) {
  std::mt19937 rng(seed);
  std::uniform_real_distribution<double> unit(-1.0, 1.0);
  Scenario s;
  s.scale = scale;
  s.R = expSO3(Eigen::Vector3d(0.15 * unit(rng), 0.3 * unit(rng), 0.1 * unit(rng)));
  s.t_hat = Eigen::Vector3d(1.0, 0.2 * unit(rng), 0.3 * unit(rng)).normalized();
  s.lambda = scale * (0.8 + 0.4 * (unit(rng) + 1.0) / 2.0);  // baseline of ~1 source unit
  const int n_outliers = static_cast<int>(std::round(outlier_fraction * n));
  for (int i = 0; i < n; ++i) {
    const Eigen::Vector3d ps = randomCameraPoint(&rng, 2.0, 8.0);
    const Eigen::Vector3d pt = scale * (s.R * ps) + s.lambda * s.t_hat;
    s.source.push_back(addNoise(ps, sigma_d, sigma_l, &rng));
    const bool outlier = i < n_outliers;
    s.is_outlier.push_back(outlier);
    // An outlier: a random wrong 3D point in front of the target camera.
    s.target.push_back(outlier ? randomCameraPoint(&rng, 2.0 * scale, 8.0 * scale)
                               : addNoise(pt, sigma_d, sigma_l, &rng));
  }
  // Shuffle so that the outliers are not all first.
  std::vector<size_t> perm(static_cast<size_t>(n));
  for (size_t i = 0; i < perm.size(); ++i) perm[i] = i;
  std::shuffle(perm.begin(), perm.end(), rng);
  Scenario shuffled = s;
  for (size_t i = 0; i < perm.size(); ++i) {
    shuffled.source[i] = s.source[perm[i]];
    shuffled.target[i] = s.target[perm[i]];
    shuffled.is_outlier[i] = s.is_outlier[perm[i]];
  }
  return shuffled;
}

ScaleEstimate run(const Scenario& s, const ScaleEstimationOptions& options = ScaleEstimationOptions()) {
  return estimateScale(s.source, s.target, s.R, s.t_hat, options);
}

class ScaleWithOutliersTest : public ::testing::TestWithParam<double> {};

TEST_P(ScaleWithOutliersTest, RecoversScaleWithThirtyPercentOutliersAndDepthNoise) {
  const double true_scale = GetParam();
  for (unsigned seed = 1; seed <= 5; ++seed) {
    // The estimator is scale-equivariant: different data per scale, not the same data rescaled.
    const Scenario s =
        makeScenario(true_scale, 100, 0.3, 0.02, 0.002, seed + static_cast<unsigned>(std::lround(100.0 * true_scale)));
    const ScaleEstimate e = run(s);
    ASSERT_EQ(e.status, Status::kOk) << e.message;
    EXPECT_NEAR(e.scale, true_scale, 0.02 * true_scale) << "seed " << seed << ": " << e.message;
    EXPECT_GT(e.scale_stddev, 0.0);
    EXPECT_LE(std::abs(e.scale - true_scale), 3.0 * e.scale_stddev)
        << "seed " << seed << ": scale " << e.scale << " +- " << e.scale_stddev;
    EXPECT_NEAR(e.lambda, s.lambda, 3.0 * e.lambda_stddev + 1e-12) << "seed " << seed;
    EXPECT_NEAR(e.covariance(0, 0), e.scale_stddev * e.scale_stddev, 1e-15 + 1e-9 * e.covariance(0, 0));
    EXPECT_EQ(e.used, 100);

    ASSERT_EQ(e.inlier_mask.size(), s.source.size());
    int outliers = 0, outliers_flagged = 0, inliers = 0, inliers_kept = 0, mask_count = 0;
    for (size_t i = 0; i < s.source.size(); ++i) {
      mask_count += e.inlier_mask[i] ? 1 : 0;
      if (s.is_outlier[i]) {
        ++outliers;
        outliers_flagged += e.inlier_mask[i] ? 0 : 1;
      } else {
        ++inliers;
        inliers_kept += e.inlier_mask[i] ? 1 : 0;
      }
    }
    EXPECT_EQ(mask_count, e.inliers);
    EXPECT_GE(outliers_flagged, 0.9 * outliers) << "seed " << seed;
    EXPECT_GE(inliers_kept, 0.9 * inliers) << "seed " << seed;
  }
}

INSTANTIATE_TEST_SUITE_P(TrueScales, ScaleWithOutliersTest, ::testing::Values(0.1, 1.0, 10.0));

TEST(ScaleEstimationTest, ExactDataGivesExactScale) {
  const Scenario s = makeScenario(3.7, 20, 0.0, 0.0, 0.0, 11);
  const ScaleEstimate e = run(s);
  ASSERT_EQ(e.status, Status::kOk) << e.message;
  EXPECT_NEAR(e.scale, 3.7, 1e-6 * 3.7);
  EXPECT_NEAR(e.lambda, s.lambda, 1e-6 * s.lambda);
  EXPECT_EQ(e.inliers, 20);
}

// Normalised errors (s - s_true) / scale_stddev over random outlier-free trials with n matches.
std::vector<double> normalisedErrors(int trials, int n, unsigned seed) {
  std::mt19937 rng(seed);
  std::uniform_real_distribution<double> log_scale(std::log(0.1), std::log(10.0));
  std::vector<double> normalised;
  for (int trial = 0; trial < trials; ++trial) {
    const double true_scale = std::exp(log_scale(rng));
    const Scenario s = makeScenario(true_scale, n, 0.0, 0.02, 0.002, seed + 1u + static_cast<unsigned>(trial));
    const ScaleEstimate e = run(s);
    EXPECT_EQ(e.status, Status::kOk) << "trial " << trial << ": " << e.message;
    if (e.status == Status::kOk) normalised.push_back((e.scale - true_scale) / e.scale_stddev);
  }
  return normalised;
}

void meanAndVariance(const std::vector<double>& values, double* mean, double* var) {
  *mean = 0.0;
  for (double v : values) *mean += v;
  *mean /= static_cast<double>(values.size());
  *var = 0.0;
  for (double v : values) *var += (v - *mean) * (v - *mean);
  *var /= static_cast<double>(values.size() - 1);
}

// Checks that 200 normalised errors look standard normal (and records their mean and variance):
// variance in [0.5, 2], mean within +-0.3, about 4 of the standard deviations of a mean of 200.
void expectStandardNormal(const std::vector<double>& normalised) {
  ASSERT_EQ(normalised.size(), 200u);
  double mean = 0.0, var = 0.0;
  meanAndVariance(normalised, &mean, &var);
  ::testing::Test::RecordProperty("normalised_error_mean", std::to_string(mean));
  ::testing::Test::RecordProperty("normalised_error_variance", std::to_string(var));
  EXPECT_GE(var, 0.5);
  EXPECT_LE(var, 2.0);
  EXPECT_LT(std::abs(mean), 0.3);
}

TEST(ScaleEstimationTest, NormalisedErrorIsConsistent) {
  // Without outliers the reported standard deviation must match the actual error spread.
  expectStandardNormal(normalisedErrors(200, 40, 1000));
}

TEST(ScaleEstimationTest, NoErrorsInVariablesBiasWithManyMatches) {
  // The noise of the source points biases a plain filter towards a smaller scale by ~0.1 %;
  // with 300 matches that is ~0.7 standard deviations, so an uncorrected filter fails here.
  expectStandardNormal(normalisedErrors(200, 300, 7000));
}

// Per-match covariances (e.g. from LSD-SLAM's inverse-depth variance): half the matches are ten
// times noisier along the ray than the other half, and each match is given its own covariance.
struct MixedNoise {
  Scenario scenario;
  std::vector<Eigen::Matrix3d> cov_source, cov_target;
};

Eigen::Matrix3d rayCovariance(const Eigen::Vector3d& p, double sigma_d, double sigma_l) {
  const Eigen::Vector3d b = p.normalized();
  const Eigen::Matrix3d along = b * b.transpose();
  return p.squaredNorm() * (sigma_d * sigma_d * along + sigma_l * sigma_l * (Eigen::Matrix3d::Identity() - along));
}

MixedNoise mixedNoise(double scale, int n, unsigned seed) {
  MixedNoise m;
  m.scenario = makeScenario(scale, n, 0.0, 0.0, 0.0, seed);
  std::mt19937 rng(seed + 17);
  for (std::size_t i = 0; i < m.scenario.source.size(); ++i) {
    const double sigma_d = i % 2 == 0 ? 0.005 : 0.05;
    Eigen::Vector3d& ps = m.scenario.source[i];
    Eigen::Vector3d& pt = m.scenario.target[i];
    m.cov_source.push_back(rayCovariance(ps, sigma_d, 0.002));
    m.cov_target.push_back(rayCovariance(pt, sigma_d, 0.002));
    ps = addNoise(ps, sigma_d, 0.002, &rng);
    pt = addNoise(pt, sigma_d, 0.002, &rng);
  }
  return m;
}

TEST(ScaleEstimationTest, GivenCovariancesAreTheMeasurementNoise) {
  // With each match's own covariance the filter weighs the precise half; its reported standard
  // deviation then matches the spread of its error (normalised errors of unit variance), and it
  // is tighter than with one noise model for all (which must take the noisier half's level to
  // keep it, relative_depth_noise 0.05).
  std::vector<double> normalised;
  double rms_given = 0.0, rms_model = 0.0;
  const int trials = 200;
  for (int t = 0; t < trials; ++t) {
    const MixedNoise m = mixedNoise(2.0, 40, 3000 + static_cast<unsigned>(t));
    const Scenario& s = m.scenario;
    const ScaleEstimate given = estimateScale(s.source, s.target, s.R, s.t_hat, ScaleEstimationOptions(),
                                              &m.cov_source, &m.cov_target);
    ScaleEstimationOptions wide;
    wide.relative_depth_noise = 0.05;
    const ScaleEstimate model = estimateScale(s.source, s.target, s.R, s.t_hat, wide);
    ASSERT_EQ(given.status, Status::kOk) << given.message;
    ASSERT_EQ(model.status, Status::kOk) << model.message;
    normalised.push_back((given.scale - s.scale) / given.scale_stddev);
    rms_given += std::pow(given.scale - s.scale, 2) / trials;
    rms_model += std::pow(model.scale - s.scale, 2) / trials;
  }
  double mean = 0.0, var = 0.0;
  meanAndVariance(normalised, &mean, &var);
  RecordProperty("normalised_error_variance", std::to_string(var));
  // 200 unit-variance errors: the sample variance is within [0.7, 1.3] at about 3 of its
  // standard deviations (sqrt(2 / 199) = 0.1), the mean within +-0.25 (3.5 of its 0.07).
  EXPECT_GE(var, 0.7);
  EXPECT_LE(var, 1.3);
  EXPECT_LT(std::abs(mean), 0.25);
  // The precise half alone has ten times less noise: the error shrinks by well over half.
  EXPECT_LT(std::sqrt(rms_given), 0.5 * std::sqrt(rms_model));
}

TEST(ScaleEstimationTest, UnusableGivenCovariancesFallBackToTheModel) {
  const Scenario s = makeScenario(1.5, 30, 0.0, 0.02, 0.002, 77);
  std::vector<Eigen::Matrix3d> zero(s.source.size(), Eigen::Matrix3d::Zero());
  std::vector<Eigen::Matrix3d> nan = zero;
  for (Eigen::Matrix3d& c : nan) c(0, 0) = std::numeric_limits<double>::quiet_NaN();
  const ScaleEstimate model = run(s);
  for (const std::vector<Eigen::Matrix3d>* given : {&zero, &nan}) {
    const ScaleEstimate e = estimateScale(s.source, s.target, s.R, s.t_hat, ScaleEstimationOptions(), given, given);
    ASSERT_EQ(e.status, Status::kOk) << e.message;
    EXPECT_EQ(e.scale, model.scale);
    EXPECT_EQ(e.scale_stddev, model.scale_stddev);
  }
  const std::vector<Eigen::Matrix3d> short_list(s.source.size() - 1, Eigen::Matrix3d::Identity());
  EXPECT_THROW(estimateScale(s.source, s.target, s.R, s.t_hat, ScaleEstimationOptions(), &short_list, nullptr),
               InputError);
  EXPECT_THROW(estimateScale(s.source, s.target, s.R, s.t_hat, ScaleEstimationOptions(), nullptr, &short_list),
               InputError);
}

TEST(ScaleEstimationTest, TooFewPointsIsNotEnoughMatches) {
  const Scenario s = makeScenario(2.0, 5, 0.0, 0.02, 0.002, 3);
  const ScaleEstimate e = run(s);
  EXPECT_EQ(e.status, Status::kNotEnoughMatches);
  EXPECT_FALSE(e.message.empty());
  EXPECT_EQ(e.inlier_mask.size(), 5u);

  const std::vector<Eigen::Vector3d> none;
  EXPECT_EQ(estimateScale(none, none, s.R, s.t_hat, ScaleEstimationOptions()).status, Status::kNotEnoughMatches);
}

TEST(ScaleEstimationTest, AllOutliersFail) {
  for (unsigned seed = 1; seed <= 20; ++seed) {
    const Scenario s = makeScenario(1.5, 60, 1.0, 0.02, 0.002, 100 + seed);
    const ScaleEstimate e = run(s);
    EXPECT_NE(e.status, Status::kOk) << "seed " << seed << ": " << e.message;
    EXPECT_FALSE(e.message.empty());
  }
}

TEST(ScaleEstimationTest, NonFinitePointsAreSkipped) {
  Scenario s = makeScenario(0.5, 40, 0.0, 0.02, 0.002, 5);
  const double nan = std::numeric_limits<double>::quiet_NaN();
  const double inf = std::numeric_limits<double>::infinity();
  s.source[0] = Eigen::Vector3d(nan, 1.0, 1.0);
  s.target[1] = Eigen::Vector3d(1.0, inf, 1.0);
  s.source[2] = Eigen::Vector3d::Zero();
  s.target[3] = Eigen::Vector3d(1e300, 1e300, 1e300);  // squared norm overflows
  const ScaleEstimate e = run(s);
  ASSERT_EQ(e.status, Status::kOk) << e.message;
  EXPECT_EQ(e.used, 36);
  for (size_t i = 0; i < 4; ++i) EXPECT_FALSE(e.inlier_mask[i]);
  EXPECT_NEAR(e.scale, 0.5, 0.02 * 0.5);

  // Only non-finite points: not enough usable matches.
  std::vector<Eigen::Vector3d> bad(s.target.size(), Eigen::Vector3d(nan, nan, nan));
  const ScaleEstimate e_bad = estimateScale(bad, s.target, s.R, s.t_hat, ScaleEstimationOptions());
  EXPECT_EQ(e_bad.status, Status::kNotEnoughMatches);
  EXPECT_EQ(e_bad.used, 0);
}

TEST(ScaleEstimationTest, DegenerateAndExtremeInputsDoNotCrash) {
  const Scenario s = makeScenario(1.0, 30, 0.0, 0.02, 0.002, 9);
  // Every point identical: one constraint repeated; either a failure or a finite estimate.
  std::vector<Eigen::Vector3d> same_s(30, s.source[0]);
  std::vector<Eigen::Vector3d> same_t(30, s.target[0]);
  const ScaleEstimate e1 = estimateScale(same_s, same_t, s.R, s.t_hat, ScaleEstimationOptions());
  if (e1.status == Status::kOk) {
    EXPECT_TRUE(std::isfinite(e1.scale) && e1.scale > 0.0);
  }

  // Points all on the baseline: the scale is not observable.
  std::vector<Eigen::Vector3d> src, tgt;
  for (int i = 1; i <= 30; ++i) {
    const Eigen::Vector3d ps = s.R.transpose() * s.t_hat * (0.5 * i);
    src.push_back(ps);
    tgt.push_back(2.0 * (s.R * ps) + 1.0 * s.t_hat);
  }
  const ScaleEstimate e2 = estimateScale(src, tgt, s.R, s.t_hat, ScaleEstimationOptions());
  EXPECT_NE(e2.status, Status::kOk) << e2.message;

  // Tiny and huge magnitudes.
  std::vector<Eigen::Vector3d> tiny_s, huge_t;
  for (size_t i = 0; i < s.source.size(); ++i) {
    tiny_s.push_back(1e-200 * s.source[i]);
    huge_t.push_back(1e200 * s.target[i]);
  }
  const ScaleEstimate e3 = estimateScale(tiny_s, huge_t, s.R, s.t_hat, ScaleEstimationOptions());
  EXPECT_FALSE(e3.message.empty());
  // Target points all at the origin are unusable.
  std::vector<Eigen::Vector3d> zeros(30, Eigen::Vector3d::Zero());
  EXPECT_EQ(estimateScale(s.source, zeros, s.R, s.t_hat, ScaleEstimationOptions()).status, Status::kNotEnoughMatches);
}

TEST(ScaleEstimationTest, InvalidInputThrows) {
  const Scenario s = makeScenario(1.0, 20, 0.0, 0.02, 0.002, 4);
  std::vector<Eigen::Vector3d> shorter(s.target.begin(), s.target.end() - 1);
  EXPECT_THROW(estimateScale(s.source, shorter, s.R, s.t_hat, ScaleEstimationOptions()), InputError);
  EXPECT_THROW(estimateScale(s.source, s.target, s.R, 2.0 * s.t_hat, ScaleEstimationOptions()), InputError);
  EXPECT_THROW(estimateScale(s.source, s.target, s.R, Eigen::Vector3d::Zero(), ScaleEstimationOptions()), InputError);
  EXPECT_THROW(
      estimateScale(s.source, s.target, s.R, Eigen::Vector3d::Constant(std::nan("")), ScaleEstimationOptions()),
      InputError);
  EXPECT_THROW(estimateScale(s.source, s.target, 2.0 * s.R, s.t_hat, ScaleEstimationOptions()), InputError);
  EXPECT_THROW(estimateScale(s.source, s.target, -s.R, s.t_hat, ScaleEstimationOptions()), InputError);
  // Sizes are checked before anything else, even for too few points.
  std::vector<Eigen::Vector3d> one(1, Eigen::Vector3d::UnitZ());
  EXPECT_THROW(estimateScale(one, {}, s.R, s.t_hat, ScaleEstimationOptions()), InputError);
}

TEST(ScaleEstimationTest, OptionValidationNamesTheKey) {
  using O = ScaleEstimationOptions;
  test::expectEachRefused<O>({
      {[](O* o) { o->relative_depth_noise = 0.0; }, "scale_estimation.relative_depth_noise"},
      {[](O* o) { o->relative_lateral_noise = -1.0; }, "scale_estimation.relative_lateral_noise"},
      {[](O* o) { o->gating_chi2 = std::nan(""); }, "scale_estimation.gating_chi2"},
      {[](O* o) { o->min_inliers = 1; }, "scale_estimation.min_inliers"},
      {[](O* o) { o->min_inlier_ratio = 1.5; }, "scale_estimation.min_inlier_ratio"},
      {[](O* o) { o->max_relative_stddev = 0.0; }, "scale_estimation.max_relative_stddev"},
      {[](O* o) { o->passes = 0; }, "scale_estimation.passes"},
      {[](O* o) { o->prior_relative_stddev = 0.0; }, "scale_estimation.prior_relative_stddev"},
  });
}

TEST(ScaleEstimationTest, StrictLimitsTurnIntoScaleFailed) {
  const Scenario s = makeScenario(1.0, 30, 0.0, 0.02, 0.002, 21);
  ScaleEstimationOptions o;
  o.max_relative_stddev = 1e-6;  // no estimate from 30 noisy matches is that certain
  const ScaleEstimate e = run(s, o);
  EXPECT_EQ(e.status, Status::kScaleFailed);
  EXPECT_GT(e.scale, 0.0);  // the numbers reached are still reported
  o = ScaleEstimationOptions();
  o.min_inliers = 30;
  o.gating_chi2 = 1e-3;  // gate so tight almost everything is rejected
  EXPECT_EQ(run(s, o).status, Status::kScaleFailed);
  // One pass works too.
  o = ScaleEstimationOptions();
  o.passes = 1;
  const ScaleEstimate one_pass = run(s, o);
  ASSERT_EQ(one_pass.status, Status::kOk) << one_pass.message;
  EXPECT_NEAR(one_pass.scale, 1.0, 0.02);
}

}  // namespace
}  // namespace pcr_pro
