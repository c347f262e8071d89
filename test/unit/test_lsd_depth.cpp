// LSD-SLAM depth with its variance: the keyframe conversion, the variance-weighted depth lookup,
// and the keyframe-to-keyframe edge's algebra (similarityAdjoint) and YAML.
#include <gtest/gtest.h>

#include <cmath>
#include <limits>
#include <random>
#include <string>

#include "common/option_checks.h"
#include "pcr_pro/frontend/keyframe_depth.h"
#include "pcr_pro/geometry/similarity_fit.h"
#include "pcr_pro/io/lsd_keyframe.h"
#include "pcr_pro/io/report.h"

namespace pcr_pro {
namespace {

PinholeCamera smallCamera() { return {100.0, 100.0, 31.5, 23.5, 64, 48}; }  // fx fy cx cy width height

LsdKeyframe emptyLsdKeyframe() {
  LsdKeyframe kf;
  kf.id = 4;
  kf.camera = smallCamera();
  kf.cam_to_world = Sim3(2.0, expSO3(Eigen::Vector3d(0.1, 0.2, -0.1)), Eigen::Vector3d(1.0, 2.0, 3.0));
  kf.idepth = cv::Mat::zeros(48, 64, CV_32FC1);
  kf.idepth_var = cv::Mat::zeros(48, 64, CV_32FC1);
  kf.image = cv::Mat(48, 64, CV_8UC1, cv::Scalar(100));
  return kf;
}

TEST(LsdKeyframeToKeyframe, CarriesEverySemiDensePixelWithItsStddev) {
  LsdKeyframe lsd = emptyLsdKeyframe();
  // An isolated pixel: the viewer's near-support filter drops it, the keyframe depth keeps it.
  lsd.idepth.at<float>(10, 20) = 0.5f;
  lsd.idepth_var.at<float>(10, 20) = 1e-4f;
  // No variance, a negative and a NaN inverse depth: unknown.
  lsd.idepth.at<float>(11, 20) = 0.5f;
  lsd.idepth.at<float>(12, 20) = -1.0f;
  lsd.idepth_var.at<float>(12, 20) = 1e-4f;
  lsd.idepth.at<float>(13, 20) = std::numeric_limits<float>::quiet_NaN();
  lsd.idepth_var.at<float>(13, 20) = 1e-4f;
  EXPECT_EQ(extractPoints(lsd, LsdFilterOptions()).camera_points.cols(), 0);
  const MapKeyframe kf = toKeyframe(lsd);
  ASSERT_EQ(kf.depth.type(), CV_32FC1);
  ASSERT_EQ(kf.depth_stddev.type(), CV_32FC1);
  EXPECT_EQ(cv::countNonZero(kf.depth), 1);
  EXPECT_EQ(cv::countNonZero(kf.depth_stddev), 1);
  EXPECT_FLOAT_EQ(kf.depth.at<float>(10, 20), 2.0f);
  // sigma_z = sqrt(var) / idepth^2 = 0.01 / 0.25.
  EXPECT_FLOAT_EQ(kf.depth_stddev.at<float>(10, 20), 0.04f);
  EXPECT_EQ(kf.id, lsd.id);
  EXPECT_LT((kf.pose.matrix() - lsd.cam_to_world.matrix()).norm(), 1e-12);
}

// A keyframe whose pixels hold the inverse depths `rho` with standard deviations `sigma` where
// `mask` is set.
MapKeyframe keyframeWith(const cv::Mat& rho, const cv::Mat& sigma) {
  LsdKeyframe lsd = emptyLsdKeyframe();
  lsd.idepth = rho.clone();
  cv::multiply(sigma, sigma, lsd.idepth_var);
  return toKeyframe(lsd);
}

TEST(KeyframeDepthUncertainty, NeighbourhoodIsWeighedByItsVariance) {
  const PinholeCamera cam = smallCamera();
  cv::Mat rho = cv::Mat::zeros(48, 64, CV_32FC1), sigma = cv::Mat::zeros(48, 64, CV_32FC1);
  // A vertical edge at column 30 with inverse depth 0.5 +- 1 %, and one pixel beside it that
  // claims the same surface at 0.52 with a 2.5 times larger standard deviation.
  for (int r = 0; r < 48; ++r) {
    rho.at<float>(r, 30) = 0.5f;
    sigma.at<float>(r, 30) = 0.005f;
  }
  rho.at<float>(20, 31) = 0.52f;
  sigma.at<float>(20, 31) = 0.0125f;
  const KeyframeDepth depth(keyframeWith(rho, sigma), cam, Cloud(3, 0));
  ASSERT_TRUE(depth.hasUncertainty());
  DepthSample s;
  // A feature between the edge and the single pixel: within 3 sigma of each other, one surface.
  ASSERT_TRUE(depth.sampleAt(30.5, 20.0, &s));
  // Weights exp(-d^2/2) / sigma^2: the edge's pixels dominate; the mean inverse depth lies
  // between 0.5 and 0.52, much closer to 0.5.
  EXPECT_GT(s.depth, 1.0 / 0.52);
  EXPECT_LT(s.depth, 1.0 / 0.5);
  EXPECT_LT(std::abs(1.0 / s.depth - 0.5), 0.25 * 0.02);
  // The standard deviation is at least the pixels' own (not divided by their number: LSD's
  // neighbours are correlated), propagated to depth: 0.005 / 0.5^2 = 0.02.
  EXPECT_GE(s.stddev, 0.02 * (1.0 - 1e-6));
  EXPECT_LT(s.stddev, 0.0125 / (0.5 * 0.5));
  double z = 0.0;
  ASSERT_TRUE(depth.depthAt(30.5, 20.0, &z));
  EXPECT_EQ(z, s.depth);
  Eigen::Vector3d p;
  double sp = 0.0;
  ASSERT_TRUE(depth.pointAt(30.5, 20.0, &p, &sp));
  EXPECT_NEAR(p.z(), 2.0 * s.depth, 1e-12);  // pose scale 2
  EXPECT_NEAR(sp, 2.0 * s.stddev, 1e-12);
  // Far from any pixel: unknown.
  EXPECT_FALSE(depth.sampleAt(10.0, 20.0, &s));
}

TEST(KeyframeDepthUncertainty, DepthEdgesAndUncertainPixelsAreRefused) {
  const PinholeCamera cam = smallCamera();
  cv::Mat rho = cv::Mat::zeros(48, 64, CV_32FC1), sigma = cv::Mat::zeros(48, 64, CV_32FC1);
  // Two surfaces, inverse depth 0.5 and 1.0 (+- 1 %), at equal distance from the query: no
  // surface holds half of the weight.
  rho.at<float>(20, 29) = 0.5f;
  sigma.at<float>(20, 29) = 0.005f;
  rho.at<float>(20, 31) = 1.0f;
  sigma.at<float>(20, 31) = 0.01f;
  // A lone pixel whose relative standard deviation is 10 %.
  rho.at<float>(40, 10) = 0.5f;
  sigma.at<float>(40, 10) = 0.05f;
  const MapKeyframe kf = keyframeWith(rho, sigma);
  // Relative: sigma / rho = 1 % for both surfaces, so their weights are 1 / (rho sigma_rel)^2:
  // the nearer surface (larger rho) weighs 4 times less, the far one holds 80 % and wins.
  DepthSample s;
  const KeyframeDepth depth(kf, cam, Cloud(3, 0));
  ASSERT_TRUE(depth.sampleAt(30.0, 20.0, &s));
  EXPECT_NEAR(s.depth, 2.0, 1e-5);
  // With equal absolute variances neither holds more than half: refused.
  cv::Mat sigma_equal = sigma.clone();
  sigma_equal.at<float>(20, 31) = 0.005f;
  EXPECT_FALSE(KeyframeDepth(keyframeWith(rho, sigma_equal), cam, Cloud(3, 0)).sampleAt(30.0, 20.0, &s));
  // 10 % is above keyframe_depth.max_relative_stddev (5 %); a looser bound takes it.
  EXPECT_FALSE(depth.sampleAt(10.0, 40.0, &s));
  KeyframeDepthOptions loose;
  loose.max_relative_stddev = 0.2;
  ASSERT_TRUE(KeyframeDepth(kf, cam, Cloud(3, 0), loose).sampleAt(10.0, 40.0, &s));
  EXPECT_NEAR(s.depth, 2.0, 1e-5);
  EXPECT_NEAR(s.stddev, 0.05 / 0.25, 1e-5);
}

TEST(KeyframeDepthUncertainty, StddevCoversTheErrorOfNoisyPixels) {
  // Independent Gaussian inverse-depth noise of a known sigma on a slanted plane: the looked-up
  // depth's error never exceeds 4 of its reported standard deviations and its mean square
  // normalised error is at most 1 (the mixture variance does not assume independent pixels, so it
  // is conservative when they are).
  const PinholeCamera cam = smallCamera();
  std::mt19937_64 rng(5);
  std::normal_distribution<double> noise(0.0, 1.0);
  double sum_nees = 0.0;
  int n = 0;
  for (int trial = 0; trial < 20; ++trial) {
    cv::Mat rho = cv::Mat::zeros(48, 64, CV_32FC1), sigma = cv::Mat::zeros(48, 64, CV_32FC1);
    const auto truth = [](double u, double v) { return 0.5 + 0.004 * u - 0.002 * v; };
    for (int r = 0; r < 48; ++r) {
      for (int c = 0; c < 64; c += 3) {  // every third column: semi-dense
        const double sd = 0.01 * truth(c, r);
        rho.at<float>(r, c) = static_cast<float>(truth(c, r) + sd * noise(rng));
        sigma.at<float>(r, c) = static_cast<float>(sd);
      }
    }
    const KeyframeDepth depth(keyframeWith(rho, sigma), cam, Cloud(3, 0));
    for (double u = 5.3; u < 58.0; u += 7.1) {
      for (double v = 5.7; v < 42.0; v += 6.3) {
        DepthSample s;
        if (!depth.sampleAt(u, v, &s)) continue;
        const double e = (s.depth - 1.0 / truth(u, v)) / s.stddev;
        EXPECT_LT(std::abs(e), 4.0) << "at (" << u << ", " << v << ")";
        sum_nees += e * e;
        ++n;
      }
    }
  }
  ASSERT_GT(n, 500);
  RecordProperty("mean_nees", std::to_string(sum_nees / n));
  EXPECT_LE(sum_nees / n, 1.0);
}

TEST(KeyframeDepthUncertainty, BadStddevImagesThrow) {
  const PinholeCamera cam = smallCamera();
  MapKeyframe kf = toKeyframe(emptyLsdKeyframe());
  kf.depth_stddev = cv::Mat::zeros(47, 64, CV_32FC1);
  EXPECT_THROW(KeyframeDepth(kf, cam, Cloud(3, 0)), InputError);
  kf.depth_stddev = cv::Mat::zeros(48, 64, CV_64FC1);
  EXPECT_THROW(KeyframeDepth(kf, cam, Cloud(3, 0)), InputError);
  kf.depth = cv::Mat();
  kf.depth_stddev = cv::Mat::zeros(48, 64, CV_32FC1);
  EXPECT_THROW(KeyframeDepth(kf, cam, Cloud(3, 0)), InputError);
  test::expectEachRefused<KeyframeDepthOptions>({
      {[](KeyframeDepthOptions* o) { o->max_relative_stddev = 1.0; }, "keyframe_depth.max_relative_stddev"},
      {[](KeyframeDepthOptions* o) { o->spatial_sigma_px = 0.0; }, "keyframe_depth.spatial_sigma_px"},
  });
}

TEST(SimilarityAdjoint, ConjugatesSmallPerturbations) {
  // G exp(d) G^-1 = exp(Ad_G d) to first order: with |d| = 1e-6 the two differ by O(1e-12).
  std::mt19937_64 rng(3);
  std::normal_distribution<double> g(0.0, 1.0);
  for (int trial = 0; trial < 10; ++trial) {
    const Sim3 big(std::exp(g(rng)), expSO3(Eigen::Vector3d(g(rng), g(rng), g(rng))),
                   Eigen::Vector3d(3 * g(rng), 3 * g(rng), 3 * g(rng)));
    Eigen::Matrix<double, 7, 1> d;
    for (int k = 0; k < 7; ++k) d(k) = 1e-6 * g(rng);
    const Sim3 left = big * applyDelta(d, Sim3()) * big.inverse();
    const Sim3 right = applyDelta(similarityAdjoint(big) * d, Sim3());
    EXPECT_LT((left.matrix() - right.matrix()).cwiseAbs().maxCoeff(), 1e-10 * (1.0 + big.matrix().norm()));
  }
}

TEST(ReportYaml, KeyframeEdgeIsWritten) {
  RegistrationReport r;
  r.status = Status::kOk;
  KeyframeEdge e;
  e.source_keyframe = 148;
  e.target_keyframe = 161;
  e.transform = Sim3(1.5, Eigen::Matrix3d::Identity(), Eigen::Vector3d(0.1, 0.2, 0.3));
  e.covariance = Matrix7d::Identity() * 0.25;
  r.keyframe_edge = e;
  const std::string yaml = toYaml(r);
  EXPECT_NE(yaml.find("keyframe_edge:\n  source_keyframe: 148\n  target_keyframe: 161\n  scale: 1.5\n"), std::string::npos)
      << yaml;
  // 49 numbers.
  const std::size_t at = yaml.find("  covariance: [");
  ASSERT_NE(at, std::string::npos);
  const std::string row = yaml.substr(at, yaml.find(']', at) - at);
  EXPECT_EQ(std::count(row.begin(), row.end(), ','), 48);
}

}  // namespace
}  // namespace pcr_pro
