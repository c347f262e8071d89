#include <gtest/gtest.h>

#include <limits>

#include "pcr_pro/registration/filters.h"
#include "pcr_pro/registration/scale_detection.h"
#include "test_helpers.h"

namespace pcr_pro {
namespace {

TEST(Filters, CropKeepsTheRequestedFractionOfTheRequestedSide) {
  Cloud c(3, 100);
  for (int i = 0; i < 100; ++i) c.col(i) << 0.0, static_cast<double>(99 - i), 1.0;
  CropOptions o;
  o.axis = 1;
  o.keep_fraction = 0.3;
  const Cloud low = cropFilter(c, o);
  ASSERT_EQ(low.cols(), 30);
  EXPECT_LE(low.row(1).maxCoeff(), 29.0);
  o.keep_lower = false;
  const Cloud high = cropFilter(c, o);
  ASSERT_EQ(high.cols(), 30);
  EXPECT_GE(high.row(1).minCoeff(), 70.0);
}

TEST(Filters, VoxelGridLeavesOnePointPerOccupiedVoxel) {
  std::mt19937 rng(1);
  std::uniform_real_distribution<double> u(0.0, 1.0);
  Cloud c(3, 10000);
  for (int i = 0; i < c.cols(); ++i) c.col(i) << u(rng), u(rng), u(rng);
  VoxelGridOptions o;
  o.leaf_size = 0.25;
  const Cloud v = voxelGridFilter(c, o);
  EXPECT_EQ(v.cols(), 64);  // 4 x 4 x 4 voxels, all occupied
  // Each output point is a centroid inside its voxel, near the voxel centre for uniform data.
  for (int i = 0; i < v.cols(); ++i) {
    const Eigen::Vector3d frac = (v.col(i) / 0.25).array() - (v.col(i) / 0.25).array().floor();
    EXPECT_LT((frac - Eigen::Vector3d::Constant(0.5)).cwiseAbs().maxCoeff(), 0.15);
  }
  o.leaf_size = 0.0;
  EXPECT_EQ(voxelGridFilter(c, o).cols(), c.cols());
}

TEST(Filters, VoxelGridRefusesALeafTooSmallForTheCloudAndKeepsFarCellsApart) {
  Cloud c(3, 4);
  c << 0.0, 1.0, 2.0, 3.0,  //
      0.0, 0.5, 1.0, 1.5,   //
      0.0, -1.0, -2.0, -3.0;
  VoxelGridOptions o;
  o.leaf_size = 1e-30;  // 3e30 voxels across: the indices cannot be integers
  EXPECT_THROW(voxelGridFilter(c, o), InputError);
  // 3e9 voxels across (beyond 2^31 per axis): the four points keep four cells, none wraps.
  o.leaf_size = 1e-9;
  EXPECT_EQ(voxelGridFilter(c, o).cols(), 4);
  // Points 2^21 voxels apart on every axis used to share a cell (21-bit wrapped keys).
  Cloud w(3, 2);
  w << 0.0, 2097152.5, 0.0, 2097152.5, 0.0, 2097152.5;
  o.leaf_size = 1.0;
  EXPECT_EQ(voxelGridFilter(w, o).cols(), 2);
  c(1, 2) = std::numeric_limits<double>::quiet_NaN();
  EXPECT_THROW(voxelGridFilter(c, o), InputError);
}

TEST(Filters, OutlierRemovalDropsIsolatedPoints) {
  std::mt19937 rng(2);
  Cloud scene = test::syntheticScene(3000, 2.0, rng);
  Cloud c(3, scene.cols() + 20);
  c << scene, Cloud::Constant(3, 20, 0.0);
  std::uniform_real_distribution<double> far(5.0, 50.0);
  for (int i = 0; i < 20; ++i) c.col(scene.cols() + i) << far(rng), -far(rng), far(rng);
  const Cloud f = outlierRemovalFilter(c, OutlierRemovalOptions());
  EXPECT_LE(f.cols(), scene.cols());
  EXPECT_GE(f.cols(), scene.cols() * 95 / 100);
  EXPECT_LT(f.cwiseAbs().maxCoeff(), 5.0);
}

TEST(Filters, RandomSamplingKeepsAboutTheRatio) {
  Cloud c = Cloud::Random(3, 20000);
  RandomSamplingOptions o;
  o.keep_ratio = 0.25;
  const Cloud s = randomSamplingFilter(c, o);
  EXPECT_NEAR(static_cast<double>(s.cols()) / 20000.0, 0.25, 0.02);
  EXPECT_EQ(randomSamplingFilter(c, o).cols(), s.cols());  // deterministic seed
}

// The ICP's whole_source mode moves the sample's columns of the whole source: the indices must be
// the columns the filter keeps, distinct and increasing, and all of them when the cap is off or not reached.
TEST(Filters, MaxPointsIndicesAreTheColumnsTheFilterKeeps) {
  Cloud c(3, 1000);
  for (int i = 0; i < 1000; ++i) c.col(i) << static_cast<double>(i), 0.5 * i, -1.0 * i;
  MaxPointsOptions o;
  o.max_points = 137;
  o.seed = 9;
  const std::vector<Eigen::Index> idx = maxPointsIndices(c.cols(), o);
  const Cloud kept = maxPointsFilter(c, o);
  ASSERT_EQ(static_cast<Eigen::Index>(idx.size()), kept.cols());
  ASSERT_EQ(kept.cols(), 137);
  for (std::size_t k = 0; k < idx.size(); ++k) {
    EXPECT_EQ(kept.col(static_cast<Eigen::Index>(k)), c.col(idx[k])) << "entry " << k;
    if (k > 0) {
      EXPECT_LT(idx[k - 1], idx[k]);
    }
  }
  o.max_points = 0;
  EXPECT_EQ(maxPointsIndices(c.cols(), o).size(), 1000u);
  o.max_points = 5000;
  EXPECT_EQ(maxPointsIndices(c.cols(), o).size(), 1000u);
}

TEST(Filters, ChainAppliesInOrderAndValidates) {
  FilterChainOptions chain;
  FilterStep crop;
  crop.type = FilterStep::Type::kCrop;
  crop.crop.keep_fraction = 0.5;
  FilterStep sample;
  sample.type = FilterStep::Type::kRandomSampling;
  sample.random_sampling.keep_ratio = 0.5;
  chain.steps = {crop, sample};
  const Cloud c = Cloud::Random(3, 10000);
  EXPECT_NEAR(applyFilterChain(c, chain).cols(), 2500, 200);
  chain.steps[0].crop.keep_fraction = 1.5;
  EXPECT_THROW(applyFilterChain(c, chain), InputError);
}

TEST(ScaleDetection, RatioOfScaledRealCloud) {
  std::mt19937 rng(3);
  const Cloud a = test::syntheticScene(5000, 3.0, rng);
  for (double s : {0.1, 0.5, 1.0, 2.0, 10.0}) {
    const Sim3 t(s, test::randomRotation(rng, 1.0), Eigen::Vector3d(5, -2, 1));
    const ScaleDetectionResult r = detectScale(a, t.apply(a), ScaleDetectionOptions());
    // The robust centre (coordinate-wise median) is not rotation-equivariant: ~0.2 % spread.
    EXPECT_NEAR(r.ratio, s, 0.01 * s);
    EXPECT_EQ(r.scale_difference_detected, std::abs(std::log(s)) > std::log(1.2));
  }
}

TEST(ScaleDetection, RobustToOutliers) {
  std::mt19937 rng(4);
  const Cloud a = test::syntheticScene(5000, 3.0, rng);
  Cloud b = 2.0 * test::syntheticScene(5000, 3.0, rng);
  for (int i = 0; i < 50; ++i) b.col(i) *= 100.0;  // 1 % far outliers
  const ScaleDetectionResult r = detectScale(a, b, ScaleDetectionOptions());
  EXPECT_NEAR(r.ratio, 2.0, 0.1);
  EXPECT_TRUE(r.scale_difference_detected);
}

}  // namespace
}  // namespace pcr_pro
