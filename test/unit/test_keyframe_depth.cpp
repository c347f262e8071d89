// Keyframe depth: lookups against a synthetic keyframe whose scene is known exactly.
#include <gtest/gtest.h>

#include <cmath>
#include <limits>
#include <random>
#include <string>
#include <vector>

#include "common/option_checks.h"
#include "pcr_pro/frontend/keyframe_depth.h"

namespace pcr_pro {
namespace {

constexpr double kPoseScale = 2.5;
constexpr int kGridStep = 4;  // map points every kGridStep pixels
// The plane covers this pixel rectangle; the rest of the image sees nothing.
constexpr int kPlaneU0 = 40, kPlaneU1 = 200, kPlaneV0 = 40, kPlaneV1 = 160;

PinholeCamera testCamera() { return {400.0, 410.0, 159.5, 119.5, 320, 240}; }  // fx fy cx cy width height

MapKeyframe testKeyframe() {
  MapKeyframe kf;
  kf.id = 7;
  kf.pose = Sim3(kPoseScale, expSO3(Eigen::Vector3d(0.1, -0.2, 0.3)), Eigen::Vector3d(1.0, -2.0, 0.5));
  return kf;
}

// Depth [camera units] of the slanted scene plane seen at pixel (u, v).
double planeDepth(const PinholeCamera& cam, double u, double v) {
  // Plane n·p = d in the camera frame.
  const Eigen::Vector3d n = Eigen::Vector3d(0.1, -0.15, 1.0).normalized();
  const double d = 4.0;
  const Eigen::Vector3d ray((u - cam.cx) / cam.fx, (v - cam.cy) / cam.fy, 1.0);
  return d / n.dot(ray);
}

Eigen::Vector3d cameraPoint(const PinholeCamera& cam, double u, double v, double z) {
  return z * Eigen::Vector3d((u - cam.cx) / cam.fx, (v - cam.cy) / cam.fy, 1.0);
}

// Map cloud: the plane sampled on the pixel grid, in the map frame [map units].
std::vector<Eigen::Vector3d> planeCameraPoints(const PinholeCamera& cam) {
  std::vector<Eigen::Vector3d> pts;
  for (int v = kPlaneV0; v <= kPlaneV1; v += kGridStep) {
    for (int u = kPlaneU0; u <= kPlaneU1; u += kGridStep) pts.push_back(cameraPoint(cam, u, v, planeDepth(cam, u, v)));
  }
  return pts;
}

Cloud toMapCloud(const MapKeyframe& kf, const std::vector<Eigen::Vector3d>& camera_points) {
  Cloud cloud(3, static_cast<Eigen::Index>(camera_points.size()));
  for (size_t i = 0; i < camera_points.size(); ++i)
    cloud.col(static_cast<Eigen::Index>(i)) = kf.pose.apply(camera_points[i]);
  return cloud;
}

// The expected result of pointAt at (u, v) when the looked-up depth is z [camera units].
Eigen::Vector3d expectedPoint(const PinholeCamera& cam, double u, double v, double z) {
  return kPoseScale * cameraPoint(cam, u, v, z);
}

void expectNear(const Eigen::Vector3d& actual, const Eigen::Vector3d& expected, double rel_tol,
                const std::string& what) {
  EXPECT_LE((actual - expected).norm(), rel_tol * expected.norm())
      << what << ": got " << actual.transpose() << ", expected " << expected.transpose();
}

TEST(KeyframeDepthTest, ProjectedCloudGivesCameraPointsInMapUnits) {
  const PinholeCamera cam = testCamera();
  const MapKeyframe kf = testKeyframe();
  const std::vector<Eigen::Vector3d> pts = planeCameraPoints(cam);
  const KeyframeDepth depth(kf, cam, toMapCloud(kf, pts), KeyframeDepthOptions());
  EXPECT_FALSE(depth.usesDepthImage());
  EXPECT_EQ(depth.validPixels(), static_cast<int>(pts.size()));

  int checked = 0;
  for (int v = kPlaneV0; v <= kPlaneV1; v += kGridStep) {
    for (int u = kPlaneU0; u <= kPlaneU1; u += kGridStep) {
      Eigen::Vector3d p;
      ASSERT_TRUE(depth.pointAt(u, v, &p)) << "pixel " << u << "," << v;
      // Exactly the (scaled) camera-frame point that was projected; float depth storage.
      expectNear(p, kPoseScale * cameraPoint(cam, u, v, planeDepth(cam, u, v)), 1e-6, "grid pixel");
      ++checked;
    }
  }
  EXPECT_EQ(checked, static_cast<int>(pts.size()));

  // Off-grid queries within the radius use the nearest projected pixel's depth along their own ray.
  const double u = kPlaneU0 + 5 * kGridStep + 1.3;  // 1.3 px right of a grid pixel
  const double v = kPlaneV0 + 3 * kGridStep - 0.4;
  const double z_grid = planeDepth(cam, kPlaneU0 + 5 * kGridStep, kPlaneV0 + 3 * kGridStep);
  Eigen::Vector3d p;
  ASSERT_TRUE(depth.pointAt(u, v, &p));
  expectNear(p, expectedPoint(cam, u, v, z_grid), 1e-6, "off-grid pixel");
  double z = 0.0;
  ASSERT_TRUE(depth.depthAt(u, v, &z));
  EXPECT_NEAR(z, z_grid, 1e-6 * z_grid);
}

TEST(KeyframeDepthTest, PixelsWithoutNearbyProjectionFail) {
  const PinholeCamera cam = testCamera();
  const MapKeyframe kf = testKeyframe();
  const KeyframeDepth depth(kf, cam, toMapCloud(kf, planeCameraPoints(cam)), KeyframeDepthOptions());
  Eigen::Vector3d p(42.0, 42.0, 42.0);
  // Far from the plane's pixel rectangle.
  EXPECT_FALSE(depth.pointAt(280.0, 210.0, &p));
  EXPECT_FALSE(depth.pointAt(10.0, 10.0, &p));
  // Just outside the rectangle, farther than the 2 px radius.
  EXPECT_FALSE(depth.pointAt(kPlaneU1 + 3.0, 100.0, &p));
  // In the middle of a grid cell: the nearest grid pixels are 2.83 px away (> 2 px).
  EXPECT_FALSE(depth.pointAt(kPlaneU0 + 2.0, kPlaneV0 + 2.0, &p));
  // The output is untouched on failure.
  EXPECT_EQ(p, Eigen::Vector3d(42.0, 42.0, 42.0));

  // A wider neighbourhood reaches the grid pixel diagonally 2.83 px away.
  KeyframeDepthOptions wide;
  wide.neighborhood_radius_px = 3;
  const KeyframeDepth depth_wide(kf, cam, toMapCloud(kf, planeCameraPoints(cam)), wide);
  EXPECT_TRUE(depth_wide.pointAt(kPlaneU0 + 2.0, kPlaneV0 + 2.0, &p));
  // A zero radius only looks at the pixel itself.
  KeyframeDepthOptions zero;
  zero.neighborhood_radius_px = 0;
  const KeyframeDepth depth_zero(kf, cam, toMapCloud(kf, planeCameraPoints(cam)), zero);
  EXPECT_TRUE(depth_zero.pointAt(kPlaneU0 + 0.4, kPlaneV0 - 0.4, &p));
  EXPECT_FALSE(depth_zero.pointAt(kPlaneU0 + 1.0, kPlaneV0, &p));
}

TEST(KeyframeDepthTest, NearerPointsWinTheZBuffer) {
  const PinholeCamera cam = testCamera();
  const MapKeyframe kf = testKeyframe();
  const std::vector<Eigen::Vector3d> plane = planeCameraPoints(cam);
  // Occluded points behind the plane on the same rays, before and after the plane in the cloud.
  std::vector<Eigen::Vector3d> pts;
  for (const Eigen::Vector3d& q : plane) pts.push_back(2.0 * q);
  pts.insert(pts.end(), plane.begin(), plane.end());
  for (const Eigen::Vector3d& q : plane) pts.push_back(1.5 * q);
  // An occluder in front of the plane at one grid pixel.
  const int occ_u = kPlaneU0 + 10 * kGridStep;
  const int occ_v = kPlaneV0 + 10 * kGridStep;
  const double occ_z = 0.5 * planeDepth(cam, occ_u, occ_v);
  pts.push_back(cameraPoint(cam, occ_u, occ_v, occ_z));

  KeyframeDepthOptions options;
  options.neighborhood_radius_px = 1;  // only the pixel itself and its 4-neighbours (no other grid pixel)
  const KeyframeDepth depth(kf, cam, toMapCloud(kf, pts), options);
  EXPECT_EQ(depth.validPixels(), static_cast<int>(plane.size()));
  for (int v = kPlaneV0; v <= kPlaneV1; v += kGridStep) {
    for (int u = kPlaneU0; u <= kPlaneU1; u += kGridStep) {
      Eigen::Vector3d p;
      ASSERT_TRUE(depth.pointAt(u, v, &p));
      const double z = (u == occ_u && v == occ_v) ? occ_z : planeDepth(cam, u, v);
      expectNear(p, expectedPoint(cam, u, v, z), 1e-6, "z-buffer winner");
    }
  }
}

TEST(KeyframeDepthTest, InconsistentNeighbourhoodIsRejected) {
  const PinholeCamera cam = testCamera();
  const MapKeyframe kf = testKeyframe();
  // Two neighbouring pixels outside the plane: a near point and a far one (a depth edge).
  std::vector<Eigen::Vector3d> pts = planeCameraPoints(cam);
  pts.push_back(cameraPoint(cam, 260.0, 60.0, 2.0));
  pts.push_back(cameraPoint(cam, 261.0, 60.0, 6.0));
  const Cloud cloud = toMapCloud(kf, pts);

  const KeyframeDepth strict(kf, cam, cloud, KeyframeDepthOptions());
  EXPECT_FALSE(strict.pointAt(260.3, 60.0, nullptr));
  EXPECT_FALSE(strict.pointAt(261.0, 60.0, nullptr));
  // Alone in its neighbourhood, the near point is found.
  Eigen::Vector3d p;
  EXPECT_TRUE(strict.pointAt(258.0, 60.0, &p));
  expectNear(p, expectedPoint(cam, 258.0, 60.0, 2.0), 1e-6, "isolated near point");

  KeyframeDepthOptions lenient;
  lenient.depth_consistency = 10.0;
  const KeyframeDepth relaxed(kf, cam, cloud, lenient);
  ASSERT_TRUE(relaxed.pointAt(260.3, 60.0, &p));  // nearest pixel: (260, 60)
  expectNear(p, expectedPoint(cam, 260.3, 60.0, 2.0), 1e-6, "nearest of two");
  ASSERT_TRUE(relaxed.pointAt(260.8, 60.0, &p));  // nearest pixel: (261, 60)
  expectNear(p, expectedPoint(cam, 260.8, 60.0, 6.0), 1e-6, "nearest of two");
}

// The scene rendered as a depth image [camera units], 0 outside the plane, NaN in one spot.
cv::Mat renderDepth(const PinholeCamera& cam) {
  cv::Mat img(cam.height, cam.width, CV_32FC1, cv::Scalar(0.0f));
  for (int v = kPlaneV0; v <= kPlaneV1; ++v) {
    for (int u = kPlaneU0; u <= kPlaneU1; ++u) img.at<float>(v, u) = static_cast<float>(planeDepth(cam, u, v));
  }
  return img;
}

TEST(KeyframeDepthTest, DepthImageAgreesWithProjectedCloud) {
  const PinholeCamera cam = testCamera();
  MapKeyframe kf = testKeyframe();
  const Cloud cloud = toMapCloud(kf, planeCameraPoints(cam));
  const KeyframeDepth projected(kf, cam, cloud, KeyframeDepthOptions());
  kf.depth = renderDepth(cam);
  kf.depth.at<float>(kPlaneV0 + 8, kPlaneU0 + 8) = std::numeric_limits<float>::quiet_NaN();
  kf.depth.at<float>(kPlaneV0 + 9, kPlaneU0 + 8) = -1.0f;
  // The cloud is ignored when there is a depth image: pass an empty one.
  const KeyframeDepth from_image(kf, cam, Cloud(3, 0), KeyframeDepthOptions());
  EXPECT_TRUE(from_image.usesDepthImage());
  EXPECT_EQ(from_image.validPixels(), (kPlaneU1 - kPlaneU0 + 1) * (kPlaneV1 - kPlaneV0 + 1) - 2);

  for (int v = kPlaneV0; v <= kPlaneV1; v += kGridStep) {
    for (int u = kPlaneU0; u <= kPlaneU1; u += kGridStep) {
      if (u == kPlaneU0 + 8 && v == kPlaneV0 + 8) continue;  // NaN in the image, checked below
      Eigen::Vector3d p_img;
      Eigen::Vector3d p_cloud;
      ASSERT_TRUE(projected.pointAt(u, v, &p_cloud));
      ASSERT_TRUE(from_image.pointAt(u, v, &p_img)) << "pixel " << u << "," << v;
      expectNear(p_img, p_cloud, 1e-6, "image vs cloud");
      expectNear(p_img, expectedPoint(cam, u, v, planeDepth(cam, u, v)), 1e-6, "image vs truth");
    }
  }
  // Every pixel of the plane has a depth in the image, the pixels in between too.
  Eigen::Vector3d p;
  ASSERT_TRUE(from_image.pointAt(kPlaneU0 + 2.0, kPlaneV0 + 2.0, &p));
  expectNear(p, expectedPoint(cam, kPlaneU0 + 2.0, kPlaneV0 + 2.0, planeDepth(cam, kPlaneU0 + 2, kPlaneV0 + 2)), 1e-6,
             "between grid pixels");
  // The NaN pixel falls back to its nearest valid neighbour (1 px away, depth 0.04 % off).
  ASSERT_TRUE(from_image.pointAt(kPlaneU0 + 8, kPlaneV0 + 8, &p));
  expectNear(p, expectedPoint(cam, kPlaneU0 + 8, kPlaneV0 + 8, planeDepth(cam, kPlaneU0 + 8, kPlaneV0 + 8)), 5e-3,
             "invalid pixel");
  EXPECT_FALSE(from_image.pointAt(280.0, 210.0, &p));

  // With a zero radius the invalid pixels have no depth.
  KeyframeDepthOptions zero;
  zero.neighborhood_radius_px = 0;
  const KeyframeDepth from_image_zero(kf, cam, Cloud(3, 0), zero);
  EXPECT_FALSE(from_image_zero.pointAt(kPlaneU0 + 8, kPlaneV0 + 8, &p));
  EXPECT_FALSE(from_image_zero.pointAt(kPlaneU0 + 8, kPlaneV0 + 9, &p));
  EXPECT_TRUE(from_image_zero.pointAt(kPlaneU0 + 9, kPlaneV0 + 9, &p));
}

// The plane seen at every pixel, each point moved along its ray by a relative depth error of
// standard deviation `sigma` (as a semi-dense map's inverse-depth noise moves it); pixels with
// u >= step_u lie `step` times farther (a depth edge), when step != 1.
std::vector<Eigen::Vector3d> noisyDensePlane(const PinholeCamera& cam, double sigma, int step_u, double step) {
  std::mt19937 rng(5);
  std::normal_distribution<double> g(0.0, sigma);
  std::vector<Eigen::Vector3d> pts;
  for (int v = kPlaneV0; v <= kPlaneV1; ++v) {
    for (int u = kPlaneU0; u <= kPlaneU1; ++u) {
      const double z = planeDepth(cam, u, v) * (u >= step_u ? step : 1.0) * (1.0 + g(rng));
      pts.push_back(cameraPoint(cam, u, v, z));
    }
  }
  return pts;
}

// The projected cloud's depth noise, measured between pixels within the lookup radius, is the
// noise each point was given; a depth edge through the middle of the plane does not move it;
// a depth image, or a cloud too sparse for pixel pairs within the radius, measures none.
TEST(KeyframeDepthTest, TheProjectedCloudMeasuresItsOwnDepthNoise) {
  const PinholeCamera cam = testCamera();
  const MapKeyframe kf = testKeyframe();
  for (const double sigma : {0.005, 0.02, 0.06}) {
    const KeyframeDepth depth(kf, cam, toMapCloud(kf, noisyDensePlane(cam, sigma, kPlaneU1 + 1, 1.0)));
    EXPECT_NEAR(depth.projectedRelativeNoise(), sigma, 0.05 * sigma) << "sigma " << sigma;
    const KeyframeDepth edge(kf, cam, toMapCloud(kf, noisyDensePlane(cam, sigma, (kPlaneU0 + kPlaneU1) / 2, 1.5)));
    EXPECT_NEAR(edge.projectedRelativeNoise(), sigma, 0.1 * sigma) << "sigma " << sigma << " with a depth edge";
  }
  // The noise-free plane: only its slope over 1-2 pixels (0.03 %).
  const KeyframeDepth clean(kf, cam, toMapCloud(kf, noisyDensePlane(cam, 0.0, kPlaneU1 + 1, 1.0)));
  EXPECT_GT(clean.projectedRelativeNoise(), 0.0);
  EXPECT_LT(clean.projectedRelativeNoise(), 1e-3);
  // A point every 4 pixels: no two within the 2-pixel radius.
  const KeyframeDepth sparse(kf, cam, toMapCloud(kf, planeCameraPoints(cam)));
  EXPECT_EQ(sparse.projectedRelativeNoise(), 0.0);
  MapKeyframe with_image = kf;
  with_image.depth = renderDepth(cam);
  EXPECT_EQ(KeyframeDepth(with_image, cam, Cloud(3, 0)).projectedRelativeNoise(), 0.0);
}

TEST(KeyframeDepthTest, DepthRangeLimitsApply) {
  const PinholeCamera cam = testCamera();
  MapKeyframe kf = testKeyframe();
  KeyframeDepthOptions options;
  options.min_depth = 4.0;  // the plane's depth spans about [3.91, 4.26]
  options.max_depth = 4.15;
  const Cloud cloud = toMapCloud(kf, planeCameraPoints(cam));
  const KeyframeDepth projected(kf, cam, cloud, options);
  kf.depth = renderDepth(cam);
  const KeyframeDepth from_image(kf, cam, cloud, options);
  int inside = 0;
  for (int v = kPlaneV0; v <= kPlaneV1; v += kGridStep) {
    for (int u = kPlaneU0; u <= kPlaneU1; u += kGridStep) {
      const double z = planeDepth(cam, u, v);
      double z_cloud = 0.0;
      double z_img = 0.0;
      const bool ok_cloud = projected.depthAt(u, v, &z_cloud);
      const bool ok_img = from_image.depthAt(u, v, &z_img);
      if (z >= options.min_depth && z <= options.max_depth) {
        ++inside;
        EXPECT_TRUE(ok_cloud);
        EXPECT_TRUE(ok_img);
      }
      if (ok_cloud) {
        EXPECT_TRUE(z_cloud >= options.min_depth && z_cloud <= options.max_depth);
      }
      if (ok_img) {
        EXPECT_TRUE(z_img >= options.min_depth && z_img <= options.max_depth);
      }
    }
  }
  EXPECT_GT(inside, 10);
  EXPECT_LT(projected.validPixels(), static_cast<int>(planeCameraPoints(cam).size()));
}

TEST(KeyframeDepthTest, CloudSubsamplingAndPointsBehindCamera) {
  const PinholeCamera cam = testCamera();
  const MapKeyframe kf = testKeyframe();
  std::vector<Eigen::Vector3d> pts = planeCameraPoints(cam);
  const size_t n_plane = pts.size();
  // Behind the camera, and non-finite: never projected.
  pts.push_back(Eigen::Vector3d(0.1, 0.1, -3.0));
  pts.push_back(Eigen::Vector3d(0.0, 0.0, 0.0));
  Cloud cloud = toMapCloud(kf, pts);
  Eigen::Vector3d nan_point = Eigen::Vector3d::Constant(std::numeric_limits<double>::quiet_NaN());
  cloud.conservativeResize(3, cloud.cols() + 1);
  cloud.col(cloud.cols() - 1) = nan_point;
  const KeyframeDepth all(kf, cam, cloud, KeyframeDepthOptions());
  EXPECT_EQ(all.validPixels(), static_cast<int>(n_plane));

  KeyframeDepthOptions options;
  options.max_cloud_points_projected = static_cast<int>(n_plane / 4);
  const KeyframeDepth sub(kf, cam, cloud, options);
  EXPECT_LE(sub.validPixels(), options.max_cloud_points_projected);
  EXPECT_GE(sub.validPixels(), options.max_cloud_points_projected - 3);

  const KeyframeDepth empty(kf, cam, Cloud(3, 0), KeyframeDepthOptions());
  EXPECT_EQ(empty.validPixels(), 0);
  EXPECT_FALSE(empty.pointAt(100.0, 100.0, nullptr));
}

TEST(KeyframeDepthTest, LookupsAreBoundsSafe) {
  const PinholeCamera cam = testCamera();
  MapKeyframe kf = testKeyframe();
  kf.depth = cv::Mat(cam.height, cam.width, CV_32FC1, cv::Scalar(3.0f));  // every pixel valid
  KeyframeDepthOptions options;
  options.neighborhood_radius_px = 5;
  const KeyframeDepth depth(kf, cam, Cloud(3, 0), options);
  EXPECT_EQ(depth.validPixels(), cam.width * cam.height);
  const double nan = std::numeric_limits<double>::quiet_NaN();
  const double inf = std::numeric_limits<double>::infinity();
  Eigen::Vector3d p;
  for (double u : {nan, inf, -inf, -1e300, 1e300, -0.51, 319.5, 320.0, 1e9}) {
    EXPECT_FALSE(depth.pointAt(u, 100.0, &p)) << "u = " << u;
    EXPECT_FALSE(depth.pointAt(100.0, u, &p)) << "v = " << u;
  }
  // The image corners, with the neighbourhood reaching outside the image.
  for (double u : {-0.5, 0.0, 319.49}) {
    for (double v : {-0.5, 0.0, 239.49}) {
      ASSERT_TRUE(depth.pointAt(u, v, &p)) << u << "," << v;
      expectNear(p, expectedPoint(cam, u, v, 3.0), 1e-6, "corner");
    }
  }
}

TEST(KeyframeDepthTest, InvalidInputThrows) {
  const PinholeCamera cam = testCamera();
  MapKeyframe kf = testKeyframe();
  const Cloud cloud = toMapCloud(kf, planeCameraPoints(cam));

  kf.depth = cv::Mat(cam.height, cam.width + 1, CV_32FC1, cv::Scalar(1.0f));
  EXPECT_THROW(KeyframeDepth(kf, cam, cloud, KeyframeDepthOptions()), InputError);
  kf.depth = cv::Mat(cam.height - 1, cam.width, CV_32FC1, cv::Scalar(1.0f));
  EXPECT_THROW(KeyframeDepth(kf, cam, cloud, KeyframeDepthOptions()), InputError);
  kf.depth = cv::Mat(cam.height, cam.width, CV_16UC1, cv::Scalar(1000));
  EXPECT_THROW(KeyframeDepth(kf, cam, cloud, KeyframeDepthOptions()), InputError);
  kf.depth = cv::Mat();

  PinholeCamera bad_cam = cam;
  bad_cam.fx = 0.0;
  EXPECT_THROW(KeyframeDepth(kf, bad_cam, cloud, KeyframeDepthOptions()), InputError);

  MapKeyframe bad_pose = kf;
  bad_pose.pose = Sim3(0.0, Eigen::Matrix3d::Identity(), Eigen::Vector3d::Zero());
  EXPECT_THROW(KeyframeDepth(bad_pose, cam, cloud, KeyframeDepthOptions()), InputError);
  bad_pose.pose = Sim3(std::nan(""), Eigen::Matrix3d::Identity(), Eigen::Vector3d::Zero());
  EXPECT_THROW(KeyframeDepth(bad_pose, cam, cloud, KeyframeDepthOptions()), InputError);
}

TEST(KeyframeDepthTest, OptionValidationNamesTheKey) {
  using O = KeyframeDepthOptions;
  test::expectEachRefused<O>(
      {
          {[](O* o) { o->neighborhood_radius_px = -1; }, "keyframe_depth.neighborhood_radius_px"},
          {[](O* o) { o->min_depth = 0.0; }, "keyframe_depth.min_depth"},
          {[](O* o) { o->max_depth = 1e-7; }, "keyframe_depth.max_depth"},  // below min_depth
          {[](O* o) { o->max_cloud_points_projected = -5; }, "keyframe_depth.max_cloud_points_projected"},
          {[](O* o) { o->depth_consistency = std::nan(""); }, "keyframe_depth.depth_consistency"},
      },
      [](const O& o) {  // the constructor validates too
        EXPECT_THROW(KeyframeDepth(testKeyframe(), testCamera(), Cloud(3, 0), o), InputError);
      });
}

}  // namespace
}  // namespace pcr_pro
