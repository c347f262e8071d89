// Tests of the simulator (pcr_pro/sim): the renderer's geometry and depth against independent
// computations, determinism, the semi-dense sampler's statistics, the bundle writer round trip,
// the drift model, the truth, and merges of generated pairs against that truth.
#include <gtest/gtest.h>
#include <unistd.h>

#include <algorithm>
#include <cmath>
#include <filesystem>
#include <fstream>
#include <functional>
#include <iterator>
#include <map>
#include <numeric>
#include <opencv2/imgproc.hpp>
#include <sstream>
#include <string>
#include <vector>

#include "common/bench_worlds.h"
#include "pcr_pro/io/bundle.h"
#include "pcr_pro/io/bundle_writer.h"
#include "pcr_pro/merge/merge_pipeline.h"
#include "pcr_pro/sim/simulator.h"

namespace fs = std::filesystem;

namespace pcr_pro {
namespace {

constexpr double kDeg = M_PI / 180.0;

// A small 2-agent world: the default room, three keyframes per agent, a sparse cloud.
SimulatorOptions quickOptions(std::uint64_t seed = 3) {
  SimulatorOptions o;
  o.seed = seed;
  o.trajectory.max_keyframes = 3;
  o.map.cloud_fraction = 0.05;
  return o;
}

// Camera looking along `forward` from `position` (world z up), optical frame.
Sim3 lookFrom(const Eigen::Vector3d& position, const Eigen::Vector3d& forward, double roll_deg = 0.0) {
  const Eigen::Vector3d f = forward.normalized();
  const Eigen::Vector3d right = f.cross(Eigen::Vector3d::UnitZ()).normalized();
  Eigen::Matrix3d r;
  r << right, f.cross(right), f;
  return Sim3(1.0, Eigen::Matrix3d(r * Eigen::AngleAxisd(roll_deg * kDeg, Eigen::Vector3d::UnitZ())), position);
}

fs::path tempDir(const std::string& name) {
  const fs::path d = fs::temp_directory_path() / ("pcr_pro_sim_" + name + "_" + std::to_string(::getpid()));
  fs::remove_all(d);
  return d;
}

std::string readFile(const fs::path& p) {
  std::ifstream in(p, std::ios::binary);
  return std::string(std::istreambuf_iterator<char>(in), {});
}

// --- world ---------------------------------------------------------------------------------------

TEST(SimWorld, FacesPointIntoTheRoomAndOutOfTheBoxes) {
  WorldOptions wo;
  const World w = makeRoomWorld(wo, 5);
  ASSERT_EQ(w.boxes.size(), static_cast<std::size_t>(wo.boxes));
  ASSERT_EQ(w.quads.size(), 6u + 5u * w.boxes.size());
  const Eigen::Vector3d room_centre = 0.5 * (w.room_min + w.room_max);
  for (std::size_t k = 0; k < w.quads.size(); ++k) {
    const WorldQuad& q = w.quads[k];
    EXPECT_NEAR(q.axis_u.dot(q.axis_v), 0.0, 1e-12) << q.name;
    const Eigen::Vector3d mid = q.origin + 0.5 * (q.axis_u + q.axis_v);
    if (k < 6) {
      EXPECT_GT(q.normal().dot(room_centre - mid), 0.0) << q.name << " must face the room";
    } else {
      const WorldBox& b = w.boxes[(k - 6) / 5];
      EXPECT_GT(q.normal().dot(mid - 0.5 * (b.min + b.max)), 0.0) << q.name << " must face out of its box";
    }
    // Every texture has contrast for features and gradients: a grey-level spread of at least
    // 10 (the shapes are drawn with random greys over the whole range).
    cv::Scalar mean, stddev;
    cv::meanStdDev(w.textures[static_cast<std::size_t>(q.texture)].levels[0], mean, stddev);
    EXPECT_GT(stddev[0], 10.0) << q.name;
  }
  for (std::size_t i = 0; i < w.boxes.size(); ++i) {
    for (int a = 0; a < 3; ++a) {
      EXPECT_GE(w.boxes[i].min[a], w.room_min[a] - 1e-12);
      EXPECT_LE(w.boxes[i].max[a], w.room_max[a] + 1e-12);
    }
    for (std::size_t j = i + 1; j < w.boxes.size(); ++j) {
      const bool apart = w.boxes[i].max.x() <= w.boxes[j].min.x() || w.boxes[j].max.x() <= w.boxes[i].min.x() ||
                         w.boxes[i].max.y() <= w.boxes[j].min.y() || w.boxes[j].max.y() <= w.boxes[i].min.y();
      EXPECT_TRUE(apart) << "boxes " << i << " and " << j << " intersect";
    }
  }
  EXPECT_TRUE(w.isFree(Eigen::Vector3d(0.0, 0.0, 2.2), 0.3));
  EXPECT_FALSE(w.isFree(Eigen::Vector3d(0.0, 0.0, 2.7), 0.3));  // 10 cm under the ceiling
  EXPECT_FALSE(w.isFree(0.5 * (w.boxes[0].min + w.boxes[0].max), 0.0));
}

TEST(SimWorld, InvalidOptionsNameTheKey) {
  WorldOptions wo;
  wo.room_length = 1.0;
  try {
    makeRoomWorld(wo, 1);
    FAIL() << "no error";
  } catch (const InputError& e) {
    EXPECT_NE(std::string(e.what()).find("world.room_length"), std::string::npos) << e.what();
  }
  wo = WorldOptions();
  wo.room_length = wo.room_width = 2.0;
  wo.boxes = 100;  // cannot fit
  EXPECT_THROW(makeRoomWorld(wo, 1), InputError);
}

// --- renderer geometry --------------------------------------------------------------------------

// Dark dots on a bright tilted plane: the centroid of each rendered dot must be the projection of
// its world centre through the camera pose. A dot of radius 4 texels (2 cm, ~5 px at 2 m): the
// 2x2 samples of a pixel estimate its coverage to 1/8, which over the ~20 edge pixels of a dot
// moves the centroid by a few hundredths of a pixel; the perspective bias of a 5 px disc on a
// plane seen 30-60 deg obliquely is below 0.01 px. So 0.1 px; the usual renderer bugs are 0.5 px
// (pixel-centre convention) or many pixels (intrinsics, axes, pose direction).
TEST(SimRender, DotsLandWhereTheyProject) {
  constexpr double kTexel = 0.005;
  constexpr int kSide = 400;  // 2 m x 2 m
  cv::Mat image(kSide, kSide, CV_8UC1, cv::Scalar(230));
  std::vector<cv::Point> dots;
  for (int y = 60; y < kSide; y += 70) {
    for (int x = 50; x < kSide; x += 75) dots.emplace_back(x + (y % 3), y);
  }
  for (const cv::Point& d : dots) cv::circle(image, d, 4, cv::Scalar(20), cv::FILLED, cv::LINE_AA);
  World world;
  WorldQuad quad;
  // A plane 2 m ahead, tilted 30 deg about the vertical.
  const Eigen::Matrix3d tilt(Eigen::AngleAxisd(30.0 * kDeg, Eigen::Vector3d::UnitZ()));
  quad.origin = tilt * Eigen::Vector3d(2.0, -1.0, -1.0) + Eigen::Vector3d(0.0, 0.0, 1.5);
  quad.axis_u = tilt * Eigen::Vector3d(0.0, kSide * kTexel, 0.0);
  quad.axis_v = Eigen::Vector3d(0.0, 0.0, kSide * kTexel);
  addTexturedQuad(&world, quad, image, kTexel);
  const PinholeCamera cam{525.0, 520.0, 318.3, 241.7, 640, 480};
  const Sim3 pose = lookFrom(Eigen::Vector3d(0.1, 0.2, 1.45), Eigen::Vector3d(1.0, 0.25, 0.05), 4.0);
  RenderOptions ro;
  ro.image_noise = 0.0;
  const RenderedView view = render(world, cam, pose, ro, 1);
  int checked = 0;
  double worst = 0.0;
  for (const cv::Point& d : dots) {
    // Texel (x, y) is centred at quad coordinates ((x + 0.5) / side, (y + 0.5) / side).
    const Eigen::Vector3d x = quad.origin + (d.x + 0.5) / kSide * quad.axis_u + (d.y + 0.5) / kSide * quad.axis_v;
    double u = 0.0, v = 0.0;
    if (!cam.project(pose.inverse().apply(x), &u, &v) || u < 15 || v < 15 || u > cam.width - 16 || v > cam.height - 16) continue;
    double sw = 0.0, su = 0.0, sv = 0.0;
    for (int r = static_cast<int>(v) - 12; r <= static_cast<int>(v) + 12; ++r) {
      for (int c = static_cast<int>(u) - 12; c <= static_cast<int>(u) + 12; ++c) {
        const double w = std::max(0.0, 229.5 - view.image.at<std::uint8_t>(r, c));
        sw += w, su += w * c, sv += w * r;
      }
    }
    ASSERT_GT(sw, 0.0) << "dot at texel " << d << " not rendered";
    EXPECT_NEAR(su / sw, u, 0.1) << "dot " << d;
    EXPECT_NEAR(sv / sw, v, 0.1) << "dot " << d;
    worst = std::max({worst, std::abs(su / sw - u), std::abs(sv / sw - v)});
    ++checked;
  }
  std::printf("%d dots, largest centroid offset %.4f px\n", checked, worst);
  EXPECT_GE(checked, 15);
}

// Independent ray casting: for a sample of pixels, intersect the pixel-centre ray with every quad
// (in the world frame, solving for the ray parameter and the quad coordinates) and take the
// nearest hit. The rendered depth must be its distance along the optical axis to float precision
// (1e-6 relative), and the rendered surface the same quad (or one at the same depth, at an edge).
TEST(SimRender, DepthIsTheNearestRayQuadDistance) {
  const World world = makeRoomWorld(WorldOptions(), 11);
  const PinholeCamera cam{525.0, 525.0, 319.5, 239.5, 640, 480};
  int checked = 0, on_box = 0;
  for (const Sim3& pose : {lookFrom(Eigen::Vector3d(-1.0, 0.5, 1.6), Eigen::Vector3d(1.0, -0.3, -0.25), -3.0),
                           lookFrom(Eigen::Vector3d(1.2, -0.4, 1.3), Eigen::Vector3d(-0.4, 1.0, -0.5), 5.0)}) {
    RenderOptions ro;
    const RenderedView view = render(world, cam, pose, ro, 2);
    for (int r = 0; r < cam.height; r += 9) {
      for (int c = 0; c < cam.width; c += 7) {
        const Eigen::Vector3d dir = pose.rotation() * Eigen::Vector3d((c - cam.cx) / cam.fx, (r - cam.cy) / cam.fy, 1.0);
        double best = 1e300;
        int best_quad = -1;
        for (std::size_t k = 0; k < world.quads.size(); ++k) {
          const WorldQuad& q = world.quads[k];
          // pose.t + t * dir = q.origin + a * u + b * v
          Eigen::Matrix3d m;
          m << dir, -q.axis_u, -q.axis_v;
          if (std::abs(m.determinant()) < 1e-12) continue;
          const Eigen::Vector3d s = m.inverse() * (q.origin - pose.translation());
          if (s.x() <= 0.0 || s.y() < 0.0 || s.y() > 1.0 || s.z() < 0.0 || s.z() > 1.0) continue;
          if (s.x() < best) best = s.x(), best_quad = static_cast<int>(k);
        }
        ASSERT_GE(best_quad, 0) << "a closed room: every ray hits a face";
        const double depth = view.depth.at<float>(r, c);
        EXPECT_NEAR(depth, best, 1e-6 * best) << "pixel " << c << ", " << r;
        const int quad = view.quad.at<int>(r, c);
        if (quad != best_quad) {
          // Only at an edge, where two faces meet at the same depth.
          EXPECT_NEAR(depth, best, 1e-6 * best) << "pixel " << c << ", " << r << ": quad " << quad << " vs " << best_quad;
        }
        on_box += best_quad >= 6;
        ++checked;
      }
    }
  }
  EXPECT_GT(checked, 8000);
  EXPECT_GT(on_box, 100) << "the views should see furniture, not only walls";
}

TEST(SimRender, RejectsBadInput) {
  const World world;
  const PinholeCamera cam{525.0, 525.0, 319.5, 239.5, 640, 480};
  RenderOptions ro;
  EXPECT_THROW(render(world, cam, Sim3(2.0, Eigen::Matrix3d::Identity(), Eigen::Vector3d::Zero()), ro, 0), InputError);
  ro.supersampling = 0;
  EXPECT_THROW(render(world, cam, Sim3(), ro, 0), InputError);
  ro = RenderOptions();
  PinholeCamera bad = cam;
  bad.fx = 0.0;
  EXPECT_THROW(render(world, bad, Sim3(), ro, 0), InputError);
  // An empty world renders an empty (black, no depth) image.
  const RenderedView v = render(world, cam, Sim3(), ro, 0);
  EXPECT_EQ(cv::countNonZero(v.depth), 0);
}

// --- determinism --------------------------------------------------------------------------------

TEST(SimDeterminism, SameSeedSameBytesOtherSeedOtherWorld) {
  const Simulation a = simulate(quickOptions(21));
  const Simulation b = simulate(quickOptions(21));
  const Simulation c = simulate(quickOptions(22));
  ASSERT_EQ(a.agents.size(), 2u);
  for (std::size_t i = 0; i < a.agents.size(); ++i) {
    ASSERT_EQ(a.agents[i].keyframes.size(), b.agents[i].keyframes.size());
    for (std::size_t k = 0; k < a.agents[i].keyframes.size(); ++k) {
      EXPECT_EQ(cv::norm(a.agents[i].keyframes[k].image, b.agents[i].keyframes[k].image, cv::NORM_INF), 0.0);
    }
    EXPECT_TRUE(a.agents[i].map.cloud == b.agents[i].map.cloud);
  }
  // Same bytes on disk.
  const fs::path da = tempDir("det_a"), db = tempDir("det_b");
  writeSimulation(da.string(), a);
  writeSimulation(db.string(), b);
  int files = 0;
  for (const auto& entry : fs::recursive_directory_iterator(da)) {
    if (!entry.is_regular_file()) continue;
    const fs::path rel = fs::relative(entry.path(), da);
    EXPECT_EQ(readFile(entry.path()), readFile(db / rel)) << rel;
    ++files;
  }
  EXPECT_GT(files, 10);
  fs::remove_all(da);
  fs::remove_all(db);
  // Another seed: other textures, other paths.
  const cv::Mat& ta = a.world.textures[0].levels[0];
  const cv::Mat& tc = c.world.textures[0].levels[0];
  ASSERT_EQ(ta.size(), tc.size());
  EXPECT_GT(cv::norm(ta, tc, cv::NORM_L1) / static_cast<double>(ta.total()), 10.0);
  EXPECT_GT(cv::norm(a.agents[0].keyframes[1].image, c.agents[0].keyframes[1].image, cv::NORM_L1), 0.0);
}

// --- semi-dense sampling -------------------------------------------------------------------------

class SemiDense : public ::testing::Test {
 protected:
  static void SetUpTestSuite() {
    world_ = new World(makeRoomWorld(WorldOptions(), 13));
    RenderOptions ro;
    view_ = new RenderedView(
        render(*world_, camera(), lookFrom(Eigen::Vector3d(-0.5, 0.3, 1.5), Eigen::Vector3d(1.0, 0.4, -0.3)), ro, 3));
  }
  static void TearDownTestSuite() {
    delete view_;
    delete world_;
  }
  static PinholeCamera camera() { return PinholeCamera{525.0, 525.0, 319.5, 239.5, 640, 480}; }
  static World* world_;
  static RenderedView* view_;
};
World* SemiDense::world_ = nullptr;
RenderedView* SemiDense::view_ = nullptr;

// Only gradient pixels get a depth; the noise has the configured law; the outlier fraction is
// the configured one, within 4 binomial standard deviations.
TEST_F(SemiDense, StatisticsFollowTheOptions) {
  SemiDenseOptions o;
  o.idepth_noise = 0.02;
  o.outlier_fraction = 0.1;
  o.noise_correlation = 0.0;  // independent pixels: the standard errors below hold
  const SemiDenseKeyframe sd = sampleSemiDense(view_->image, view_->depth, camera(), o, 5);
  // The gradient, recomputed: 3x3 Gaussian, central differences.
  cv::Mat smooth;
  cv::GaussianBlur(view_->image, smooth, cv::Size(3, 3), 0.0);
  smooth.convertTo(smooth, CV_64F);
  long candidates = 0, kept = 0, outliers = 0, inliers = 0;
  double sum_idepth = 0.0, sum_z = 0.0, sum_z2 = 0.0;
  for (int r = 1; r + 1 < smooth.rows; ++r) {
    for (int c = 1; c + 1 < smooth.cols; ++c) {
      const double gx = 0.5 * (smooth.at<double>(r, c + 1) - smooth.at<double>(r, c - 1));
      const double gy = 0.5 * (smooth.at<double>(r + 1, c) - smooth.at<double>(r - 1, c));
      const double g = std::hypot(gx, gy);
      const bool has = sd.idepth.at<float>(r, c) > 0.0f;
      // 1e-3 of slack for float rounding at the threshold.
      if (g < o.min_gradient - 1e-3) {
        EXPECT_FALSE(has) << "pixel " << c << ", " << r << " has depth at gradient " << g;
        continue;
      }
      if (g < o.min_gradient + 1e-3) continue;
      ++candidates;
      sum_idepth += 1.0 / view_->depth.at<float>(r, c);
      if (!has) continue;
      ++kept;
      EXPECT_NEAR(sd.depth.at<float>(r, c), 1.0f / sd.idepth.at<float>(r, c), 1e-5f * sd.depth.at<float>(r, c));
      if (sd.outlier.at<std::uint8_t>(r, c)) {
        ++outliers;
        const double factor = sd.idepth.at<float>(r, c) * view_->depth.at<float>(r, c);
        EXPECT_GE(factor, 1.0 / 3.0 - 1e-5);
        EXPECT_LE(factor, 3.0 + 1e-5);
      } else {
        const double mean_idepth = sd.mean_true_idepth;
        const double sigma = o.idepth_noise * std::clamp(o.reference_gradient / g, 0.5, 4.0) * mean_idepth;
        EXPECT_NEAR(sd.idepth_var.at<float>(r, c), sigma * sigma, 1e-3 * sigma * sigma);
        const double z = (sd.idepth.at<float>(r, c) - 1.0 / view_->depth.at<float>(r, c)) / sigma;
        sum_z += z, sum_z2 += z * z;
        ++inliers;
      }
    }
  }
  ASSERT_GT(candidates, 20000) << "a textured room view has many gradient pixels";
  EXPECT_NEAR(sd.mean_true_idepth, sum_idepth / candidates, 1e-3 * sd.mean_true_idepth);
  // Kept: every candidate whose noisy inverse depth stayed positive (all, at 2 % noise).
  EXPECT_GT(static_cast<double>(kept), 0.999 * candidates);
  EXPECT_EQ(cv::countNonZero(sd.idepth > 0.0f), sd.points.cols());
  EXPECT_EQ(cv::countNonZero(sd.outlier), sd.outliers);
  const double p = o.outlier_fraction, n = static_cast<double>(kept);
  EXPECT_NEAR(outliers / n, p, 4.0 * std::sqrt(p * (1 - p) / n));
  // Normalised noise: mean 0 and standard deviation 1, each within 4 standard errors.
  const double mean = sum_z / inliers, sd_z = std::sqrt(sum_z2 / inliers - mean * mean);
  EXPECT_NEAR(mean, 0.0, 4.0 / std::sqrt(static_cast<double>(inliers)));
  EXPECT_NEAR(sd_z, 1.0, 4.0 / std::sqrt(2.0 * inliers));
}

// Correlated noise (LSD's regularisation): unit variance per pixel, and neighbours' normalised
// errors correlate as exp(-d^2 / (4 sigma^2)) (white noise blurred by a Gaussian of sigma), 0.895
// at one pixel for sigma 1.5. The estimate over ~10^5 pairs of a 640x480 field of correlation
// length 1.5 px has a standard error of ~0.01: 0.05.
TEST_F(SemiDense, NoiseIsSpatiallyCorrelated) {
  SemiDenseOptions o;
  o.outlier_fraction = 0.0;
  o.min_gradient = 1e-6;  // every pixel: a dense field to correlate
  const SemiDenseKeyframe sd = sampleSemiDense(view_->image, view_->depth, camera(), o, 7);
  const cv::Mat& z = view_->depth;
  auto err = [&](int r, int c) {
    return (sd.idepth.at<float>(r, c) - 1.0 / z.at<float>(r, c)) / std::sqrt(sd.idepth_var.at<float>(r, c));
  };
  double s1 = 0.0, s2 = 0.0, sxy = 0.0;
  long n = 0;
  for (int r = 1; r + 1 < z.rows; ++r) {
    for (int c = 1; c + 2 < z.cols; ++c) {
      if (!(sd.idepth.at<float>(r, c) > 0.0f && sd.idepth.at<float>(r, c + 1) > 0.0f)) continue;
      const double a = err(r, c), b = err(r, c + 1);
      s1 += a, s2 += a * a, sxy += a * b, ++n;
    }
  }
  ASSERT_GT(n, 200000);
  const double mean = s1 / n, var = s2 / n - mean * mean;
  EXPECT_NEAR(var, 1.0, 0.05);
  EXPECT_NEAR((sxy / n - mean * mean) / var, std::exp(-1.0 / (4.0 * 1.5 * 1.5)), 0.05);
}

TEST_F(SemiDense, SubsampleAndValidation) {
  SemiDenseOptions o;
  const SemiDenseKeyframe all = sampleSemiDense(view_->image, view_->depth, camera(), o, 5);
  o.subsample = 4;
  const SemiDenseKeyframe quarter = sampleSemiDense(view_->image, view_->depth, camera(), o, 5);
  const double n = static_cast<double>(all.points.cols());
  // One in four, within 4 binomial standard deviations.
  EXPECT_NEAR(quarter.points.cols() / n, 0.25, 4.0 * std::sqrt(0.25 * 0.75 / n));
  o = SemiDenseOptions();
  o.outlier_fraction = 0.7;
  EXPECT_THROW(sampleSemiDense(view_->image, view_->depth, camera(), o, 5), InputError);
  EXPECT_THROW(sampleSemiDense(view_->image, cv::Mat(10, 10, CV_32FC1), camera(), SemiDenseOptions(), 5), InputError);
}

// --- bundle writer -------------------------------------------------------------------------------

// writeBundle -> loadBundle gives back the map: images exactly (PNG is lossless), poses to the
// 12 significant digits written, depth to the 16-bit quantisation (half a step of 1 / depth_scale),
// the cloud to float precision (PCD stores float32: 2^-23 relative).
TEST(SimBundle, WriterRoundTrip) {
  SimulatorOptions o = quickOptions(31);
  o.agents = 2;
  const Simulation sim = simulate(o);
  const fs::path dir = tempDir("bundle");
  writeSimulation(dir.string(), sim);
  for (const SimAgent& agent : sim.agents) {
    const AgentMap back = loadBundle((dir / agent.name).string());
    EXPECT_EQ(back.frame_id, agent.map.frame_id);
    EXPECT_EQ(back.camera.fx, agent.map.camera.fx);
    EXPECT_EQ(back.camera.width, agent.map.camera.width);
    ASSERT_EQ(back.keyframes.size(), agent.map.keyframes.size());
    for (std::size_t k = 0; k < back.keyframes.size(); ++k) {
      const MapKeyframe& a = agent.map.keyframes[k];
      const MapKeyframe& b = back.keyframes[k];
      EXPECT_EQ(a.id, b.id);
      EXPECT_EQ(cv::norm(a.image, b.image, cv::NORM_INF), 0.0);
      EXPECT_LT((a.pose.matrix() - b.pose.matrix()).cwiseAbs().maxCoeff(), 1e-10 * (1.0 + a.pose.translation().norm()));
      ASSERT_FALSE(b.depth.empty());
      double max_depth = 0.0;
      cv::minMaxLoc(a.depth, nullptr, &max_depth);
      const double step = max_depth / 60000.0;  // the writer's automatic depth scale
      cv::Mat diff;
      cv::absdiff(a.depth, b.depth, diff);
      double worst = 0.0;
      cv::minMaxLoc(diff, nullptr, &worst);
      EXPECT_LE(worst, 0.5 * step * 1.001 + 1e-6 * max_depth);
    }
    ASSERT_EQ(back.cloud.cols(), agent.map.cloud.cols());
    const double scale = agent.map.cloud.cwiseAbs().maxCoeff();
    EXPECT_LE((back.cloud - agent.map.cloud).cwiseAbs().maxCoeff(), scale * std::pow(2.0, -23));
  }
  // The truth files read back.
  const BundleTruth t = loadBundleTruth((dir / "truth.yaml").string());
  const SimPairTruth& p = sim.pair(0, 1);
  EXPECT_EQ(t.target_agent, "agent_a");
  EXPECT_EQ(t.source_agent, "agent_b");
  EXPECT_NEAR(t.target_source.scale(), p.target_source.scale(), 1e-10);
  EXPECT_LT((t.target_source.matrix() - p.target_source.matrix()).cwiseAbs().maxCoeff(), 1e-9);
  EXPECT_EQ(t.world_poses.size(), sim.agents[0].keyframes.size() + sim.agents[1].keyframes.size());
  const BundleTruth r = loadBundleTruth((dir / "truth_agent_b_agent_a.yaml").string());
  EXPECT_EQ(r.target_agent, "agent_b");
  EXPECT_LT((r.target_source.matrix() - sim.pair(1, 0).target_source.matrix()).cwiseAbs().maxCoeff(), 1e-9);
  // simulation.yaml reproduces the options.
  const SimulatorOptions again = loadSimulatorConfig((dir / "simulation.yaml").string());
  EXPECT_EQ(simulatorConfigYaml(again), simulatorConfigYaml(o));
  // Without depth images.
  const fs::path nodepth = tempDir("bundle_nodepth");
  writeSimulation(nodepth.string(), sim, false);
  EXPECT_TRUE(loadBundle((nodepth / "agent_a").string()).keyframes[0].depth.empty());
  EXPECT_EQ(loadSimulatorConfig((nodepth / "simulation.yaml").string()).map.depth_images, "none");
  fs::remove_all(dir);
  fs::remove_all(nodepth);
}

TEST(SimBundle, WriterRefusesBadMapsNamingTheField) {
  AgentMap map;
  map.camera = PinholeCamera{525.0, 525.0, 319.5, 239.5, 64, 48};
  map.cloud = Cloud::Random(3, 10);
  MapKeyframe kf;
  kf.id = 4;
  kf.image = cv::Mat(48, 64, CV_8UC1, cv::Scalar(100));
  map.keyframes = {kf, kf};
  const fs::path dir = tempDir("bad_bundle");
  const std::vector<std::pair<std::function<void(AgentMap*)>, std::string>> cases{
      {[](AgentMap*) {}, "keyframes[1].id: duplicate id 4"},
      {[](AgentMap* m) { m->keyframes.resize(1), m->keyframes[0].image = cv::Mat(10, 10, CV_8UC1); }, "keyframes[0].image"},
      {[](AgentMap* m) { m->keyframes.resize(1), m->keyframes[0].pose = Sim3(0.0, Eigen::Matrix3d::Identity(), Eigen::Vector3d::Zero()); },
       "keyframes[0].pose"},
      {[](AgentMap* m) { m->keyframes.resize(1), m->keyframes[0].depth = cv::Mat(48, 64, CV_16UC1); }, "keyframes[0].depth"},
      {[](AgentMap* m) { m->camera.fx = 0.0; }, "camera"},
  };
  for (const auto& [spoil, field] : cases) {
    AgentMap bad = map;
    spoil(&bad);
    try {
      writeBundle(dir.string(), bad);
      ADD_FAILURE() << "accepted, expected an error naming " << field;
    } catch (const InputError& e) {
      EXPECT_NE(std::string(e.what()).find(field), std::string::npos) << e.what();
    }
  }
  EXPECT_THROW(writeBundle("/proc/pcr_pro_no_such_dir/x", map), InputError);
  fs::remove_all(dir);
}

// --- drift ---------------------------------------------------------------------------------------

TEST(SimDrift, WithoutDriftTheMapPosesAreTheTruth) {
  const Simulation sim = simulate(quickOptions(41));
  for (const SimAgent& a : sim.agents) {
    for (const SimKeyframe& kf : a.keyframes) {
      const Sim3 expected = a.world_to_map * kf.true_pose;
      EXPECT_LT((kf.map_pose.matrix() - expected.matrix()).cwiseAbs().maxCoeff(), 1e-12 * (1.0 + expected.translation().norm()));
      EXPECT_LT((kf.tracked_pose.matrix() - kf.map_pose.matrix()).cwiseAbs().maxCoeff(), 1e-15);
    }
    // The map frame is the first keyframe's camera frame (LSD-SLAM), scaled.
    EXPECT_LT((a.keyframes[0].map_pose.matrix() -
               Sim3(a.world_to_map.scale(), Eigen::Matrix3d::Identity(), Eigen::Vector3d::Zero()).matrix())
                  .cwiseAbs()
                  .maxCoeff(),
              1e-12);
  }
}

// The accumulated error tracked_k * true_k⁻¹ * world_to_map⁻¹ (a similarity of the map) grows
// along the path to exactly the configured scale drift and bend (about the world vertical), while
// consecutive keyframes agree to within their step's share.
TEST(SimDrift, ScaleAndBendBuildUpAlongThePath) {
  SimulatorOptions o = quickOptions(43);
  o.trajectory.max_keyframes = 6;
  o.drift.scale_drift = 0.04;
  o.drift.bend_deg = 6.0;
  o.per_agent.resize(2);
  o.per_agent[1].scale_drift = -0.03;
  o.per_agent[1].bend_deg = 0.0;
  const Simulation sim = simulate(o);
  for (std::size_t i = 0; i < 2; ++i) {
    const SimAgent& a = sim.agents[i];
    const double drift = i == 0 ? 0.04 : -0.03, bend = i == 0 ? 6.0 : 0.0;
    ASSERT_GE(a.keyframes.size(), 4u);
    const SimKeyframe& last = a.keyframes.back();
    const Sim3 error = last.tracked_pose * last.true_pose.inverse() * a.world_to_map.inverse();
    EXPECT_NEAR(error.scale(), 1.0 + drift, 1e-9);
    EXPECT_NEAR(last.tracked_pose.scale() / a.keyframes[0].tracked_pose.scale(), 1.0 + drift, 1e-9);
    EXPECT_NEAR(error.rotationAngle() / kDeg, bend, 1e-7);
    if (bend > 0.0) {
      const Eigen::Vector3d up_in_map = a.world_to_map.rotation() * Eigen::Vector3d::UnitZ();
      EXPECT_GT(std::abs(Eigen::AngleAxisd(error.rotation()).axis().dot(up_in_map)), 1.0 - 1e-9);
    }
    // Neighbours agree locally: their relative pose differs from the true one by this step's share.
    for (std::size_t k = 1; k < a.keyframes.size(); ++k) {
      const SimKeyframe& p = a.keyframes[k - 1];
      const SimKeyframe& q = a.keyframes[k];
      const Sim3 est = p.tracked_pose.inverse() * q.tracked_pose;
      const Sim3 truth = p.true_pose.inverse() * q.true_pose;
      const double share = (q.motion - p.motion) / last.motion;
      EXPECT_NEAR(est.scale(), std::pow(1.0 + drift, share), 1e-9);
      EXPECT_NEAR(rotationDistance(est.rotation(), truth.rotation()) / kDeg, share * bend, 1e-7);
    }
  }
  // The map scale is the agent's scale times the drift: far keyframes disagree.
  EXPECT_GT(std::abs(sim.agents[0].keyframes.back().tracked_pose.scale() - sim.agents[0].keyframes[0].tracked_pose.scale()),
            0.03);
}

// per_agent[i].idepth_noise: one agent's keyframes get another inverse-depth noise, the other
// agent's nothing changes. The same pixels are drawn with the same random numbers, so the
// variance of every pixel scales by the square of the ratio and the points move along their rays.
TEST(SimNoise, PerAgentInverseDepthNoiseChangesOnlyThatAgent) {
  SimulatorOptions o = quickOptions(44);
  o.trajectory.max_keyframes = 3;
  o.map.semi_dense.outlier_fraction = 0.0;
  const Simulation plain = simulate(o);
  o.per_agent.resize(2);
  const double base = o.map.semi_dense.idepth_noise, own = 3.0 * base;
  o.per_agent[1].idepth_noise = own;
  const Simulation noisy = simulate(o);
  EXPECT_DOUBLE_EQ(noisy.agents[0].idepth_noise, base);
  EXPECT_DOUBLE_EQ(noisy.agents[1].idepth_noise, own);
  for (std::size_t i = 0; i < 2; ++i) {
    ASSERT_EQ(plain.agents[i].keyframes.size(), noisy.agents[i].keyframes.size());
    for (std::size_t k = 0; k < plain.agents[i].keyframes.size(); ++k) {
      const SemiDenseKeyframe& a = plain.agents[i].keyframes[k].semi_dense;
      const SemiDenseKeyframe& b = noisy.agents[i].keyframes[k].semi_dense;
      int both = 0, moved = 0;
      for (int r = 0; r < a.idepth.rows; ++r) {
        for (int c = 0; c < a.idepth.cols; ++c) {
          if (!(a.idepth.at<float>(r, c) > 0.0f && b.idepth.at<float>(r, c) > 0.0f)) continue;
          ++both;
          const double ratio = b.idepth_var.at<float>(r, c) / a.idepth_var.at<float>(r, c);
          const double expected = i == 0 ? 1.0 : (own / base) * (own / base);
          EXPECT_NEAR(ratio, expected, 1e-4 * ratio) << "agent " << i << " keyframe " << k;
          if (a.idepth.at<float>(r, c) != b.idepth.at<float>(r, c)) ++moved;
        }
      }
      ASSERT_GT(both, 1000);
      if (i == 0) {
        EXPECT_EQ(moved, 0);
      } else {
        EXPECT_GT(moved, both / 2);
      }
    }
  }
  // The maps: agent_a's cloud is the same, agent_b's is not.
  ASSERT_EQ(plain.agents[0].map.cloud.cols(), noisy.agents[0].map.cloud.cols());
  EXPECT_EQ((plain.agents[0].map.cloud - noisy.agents[0].map.cloud).cwiseAbs().maxCoeff(), 0.0);
  EXPECT_FALSE(plain.agents[1].map.cloud.cols() == noisy.agents[1].map.cloud.cols() &&
               plain.agents[1].map.cloud.isApprox(noisy.agents[1].map.cloud, 1e-6));
}

TEST(SimDrift, LoopClosureMovesThePosesBackAndTheGraphSaysSo) {
  SimulatorOptions o = quickOptions(47);
  o.agents = 1;
  o.trajectory.max_keyframes = 4;
  o.drift.scale_drift = 0.05;
  o.drift.bend_deg = 4.0;
  o.drift.pose_noise_rotation_deg = 0.5;
  o.drift.loop_closure = 1.0;
  const Simulation full = simulate(o);
  const SimAgent& a = full.agents[0];
  for (const SimKeyframe& kf : a.keyframes) {
    const Sim3 truth = a.world_to_map * kf.true_pose;
    EXPECT_LT((kf.map_pose.matrix() - truth.matrix()).cwiseAbs().maxCoeff(), 1e-12 * (1.0 + truth.translation().norm()));
  }
  EXPECT_GT(rotationDistance(a.keyframes.back().tracked_pose.rotation(), a.keyframes.back().map_pose.rotation()), 0.01);
  // Graph snapshots: one per keyframe with the tracked poses so far, then the map poses.
  ASSERT_EQ(a.graph_snapshots.size(), a.keyframes.size() + 1);
  for (std::size_t k = 0; k < a.keyframes.size(); ++k) {
    ASSERT_EQ(a.graph_snapshots[k].size(), k + 1);
    const SimKeyframe& kf = a.keyframes[k];
    const Sim3 lsd = a.graph_snapshots[k].back().second;
    EXPECT_EQ(a.graph_snapshots[k].back().first, kf.id);
    EXPECT_NEAR(lsd.scale(), kf.tracked_pose.scale() * kf.lsd_scale, 1e-12 * lsd.scale());
    const Sim3 closed = a.graph_snapshots.back()[k].second;
    EXPECT_NEAR(closed.scale(), kf.map_pose.scale() * kf.lsd_scale, 1e-12 * closed.scale());
  }
  // Half way: component-wise half of the way (scale geometric).
  o.drift.loop_closure = 0.5;
  const Simulation half = simulate(o);
  const SimAgent& h = half.agents[0];
  const SimKeyframe& last = h.keyframes.back();
  const double truth_scale = (h.world_to_map * last.true_pose).scale();
  EXPECT_NEAR(last.map_pose.scale(), std::sqrt(last.tracked_pose.scale() * truth_scale), 1e-12);
}

// --- LSD-SLAM keyframes ----------------------------------------------------------------------------

TEST(SimLsd, NormalisedKeyframesMapToTheSamePoints) {
  const Simulation sim = simulate(quickOptions(51));
  const SimAgent& a = sim.agents[1];
  for (std::size_t k = 0; k < a.keyframes.size(); ++k) {
    const SimKeyframe& kf = a.keyframes[k];
    const LsdKeyframe lsd = toLsdKeyframe(kf, sim.options.camera, static_cast<double>(k));
    EXPECT_EQ(lsd.id, kf.id);
    EXPECT_NEAR(cv::mean(lsd.idepth, lsd.idepth > 0.0f)[0], 1.0, 1e-5);
    // A pixel's LSD point mapped by camToWorld = its metric point mapped by the tracked pose.
    for (int r = 7; r < lsd.idepth.rows; r += 37) {
      for (int c = 5; c < lsd.idepth.cols; c += 41) {
        const float id = lsd.idepth.at<float>(r, c);
        if (!(id > 0.0f)) continue;
        const auto& cam = sim.options.camera;
        const Eigen::Vector3d ray((c - cam.cx) / cam.fx, (r - cam.cy) / cam.fy, 1.0);
        const Eigen::Vector3d a_pt = lsd.cam_to_world.apply(Eigen::Vector3d(ray / id));
        const Eigen::Vector3d b_pt = kf.tracked_pose.apply(Eigen::Vector3d(ray / kf.semi_dense.idepth.at<float>(r, c)));
        EXPECT_LT((a_pt - b_pt).norm(), 1e-5 * (1.0 + b_pt.norm()));
        EXPECT_NEAR(lsd.idepth_var.at<float>(r, c), kf.semi_dense.idepth_var.at<float>(r, c) * kf.lsd_scale * kf.lsd_scale,
                    1e-5 * lsd.idepth_var.at<float>(r, c));
      }
    }
  }
}

// The bench's third source of keyframe depth (common/bench_worlds.h): each keyframe's own
// semi-dense depth as LSD-SLAM publishes it, in LSD-SLAM's normalised units. Mapped by the
// keyframe's pose it must land where the map pose puts the same pixel's metric semi-dense point
// (a pose left unscaled would put it at 1 / lsd_scale of its distance), with a standard deviation
// wherever there is a depth, and nothing where the keyframe has none.
TEST(SimLsd, BenchKeyframeDepthLandsWhereTheMapPosePutsIt) {
  SimulatorOptions o = quickOptions(52);
  o.drift.scale_drift = 0.05;
  o.drift.loop_closure = 0.5;  // map poses differ from the tracked ones
  const Simulation sim = simulate(o);
  const SimAgent& agent = sim.agents[0];
  const AgentMap map = test::withLsdKeyframeDepth(agent, sim.options.camera);
  ASSERT_EQ(map.keyframes.size(), agent.keyframes.size());
  const auto& cam = sim.options.camera;
  int checked = 0;
  for (std::size_t k = 0; k < agent.keyframes.size(); ++k) {
    const SimKeyframe& s = agent.keyframes[k];
    const MapKeyframe& kf = map.keyframes[k];
    ASSERT_EQ(kf.id, s.id);
    ASSERT_EQ(kf.depth.type(), CV_32FC1);
    ASSERT_EQ(kf.depth_stddev.size(), kf.depth.size());
    EXPECT_GT(std::abs(s.lsd_scale - 1.0), 1e-3);  // the normalisation is not the identity here
    for (int r = 3; r < kf.depth.rows; r += 7) {
      for (int c = 3; c < kf.depth.cols; c += 7) {
        const float id = s.semi_dense.idepth.at<float>(r, c);
        const float d = kf.depth.at<float>(r, c);
        if (!(id > 0.0f)) {
          EXPECT_EQ(d, 0.0f);
          continue;
        }
        ASSERT_GT(d, 0.0f);
        EXPECT_GT(kf.depth_stddev.at<float>(r, c), 0.0f);
        const Eigen::Vector3d ray((c - cam.cx) / cam.fx, (r - cam.cy) / cam.fy, 1.0);
        const Eigen::Vector3d lsd_point = kf.pose.apply(Eigen::Vector3d(d * ray));
        const Eigen::Vector3d map_point = s.map_pose.apply(Eigen::Vector3d(ray / id));
        EXPECT_LT((lsd_point - map_point).norm(), 1e-4 * (1.0 + map_point.norm()));
        ++checked;
      }
    }
  }
  EXPECT_GT(checked, 100);
}

// --- truth ---------------------------------------------------------------------------------------

// Without drift every kind of truth is the drift-free S_target_source, and it maps the source's
// cloud points (their true positions) exactly onto the target's.
TEST(SimTruth, WithoutDriftEveryTruthIsExact) {
  SimulatorOptions o = quickOptions(61);
  o.agents = 3;
  o.trajectory.max_keyframes = 4;
  const Simulation sim = simulate(o);
  const SimPairTruth& ab = sim.pair(0, 1);
  EXPECT_TRUE(ab.overlap);
  EXPECT_GT(ab.points, 100);
  EXPECT_LT((ab.target_source.matrix() - ab.start.matrix()).cwiseAbs().maxCoeff(), 1e-9);
  EXPECT_LT(ab.rms, 1e-9);
  EXPECT_NEAR(ab.start.scale(), 2.5, 1e-12);  // default scales 1 and 0.4
  ASSERT_FALSE(ab.keyframe_pairs.empty());
  for (const SimKeyframePair& p : ab.keyframe_pairs) {
    EXPECT_LT((p.target_source.matrix() - ab.start.matrix()).cwiseAbs().maxCoeff(), 1e-9);
    EXPECT_GE(p.covisible, o.min_overlap);
  }
  const SimAgent& a = sim.agents[0];
  const SimAgent& b = sim.agents[1];
  const Cloud in_b = b.world_to_map.apply(b.cloud_world);
  const Cloud in_a = a.world_to_map.apply(b.cloud_world);
  EXPECT_LT((ab.target_source.apply(in_b) - in_a).cwiseAbs().maxCoeff(), 1e-9 * (1.0 + in_a.cwiseAbs().maxCoeff()));
  // The map cloud is the true surface up to the inverse-depth noise: its median distance to the
  // true points is about idepth_noise times the depth (1 % of ~2.5 m, in map units).
  const Cloud diff = b.map.cloud - in_b;
  std::vector<double> d(static_cast<std::size_t>(diff.cols()));
  for (Eigen::Index i = 0; i < diff.cols(); ++i) d[static_cast<std::size_t>(i)] = diff.col(i).norm();
  std::nth_element(d.begin(), d.begin() + static_cast<std::ptrdiff_t>(d.size() / 2), d.end());
  const double median_m = d[d.size() / 2] / b.world_to_map.scale();
  EXPECT_GT(median_m, 0.001);
  EXPECT_LT(median_m, 0.05);
  // agent_c, across the room, shares nothing with agent_a.
  EXPECT_FALSE(sim.pair(0, 2).overlap);
  EXPECT_EQ(sim.pair(0, 2).overlap_fraction, 0.0);
  EXPECT_TRUE(sim.pair(0, 2).keyframe_pairs.empty());
  EXPECT_THROW(sim.pair(1, 1), InputError);
}

// With drift one similarity no longer fits the maps: the least-squares truth moves away from
// the drift-free frames and has a residual, and local keyframe-pair truths differ from each other.
TEST(SimTruth, WithDriftTheTruthIsLocal) {
  SimulatorOptions o = quickOptions(63);
  o.trajectory.max_keyframes = 6;
  o.drift.scale_drift = 0.05;
  o.drift.bend_deg = 5.0;
  const Simulation sim = simulate(o);
  const SimPairTruth& ab = sim.pair(0, 1);
  ASSERT_TRUE(ab.overlap);
  EXPECT_GT(std::abs(ab.target_source.scale() / ab.start.scale() - 1.0), 1e-3);
  EXPECT_GT(ab.rms, 1e-4);
  double min_scale = 1e300, max_scale = 0.0;
  for (const SimKeyframePair& p : ab.keyframe_pairs) {
    min_scale = std::min(min_scale, p.target_source.scale());
    max_scale = std::max(max_scale, p.target_source.scale());
  }
  EXPECT_GT(max_scale / min_scale - 1.0, 0.005);
}

// The truth of a -> b is the inverse of the truth of b -> a, as a merge's estimates must be: both
// are fitted over the co-visible points of both maps. Fitted over the source's points alone (as
// before 2026-12-03), on the bench's world of this cell (15 % overlap, 5 % scale drift, seed 0,
// there with its third agent) the two were 1.74 deg and 0.55 % apart; fitted over both, Umeyama's
// fit is symmetric up to the second order of its residual (measured there: below 0.005 deg,
// 0.04 % in scale, 0.03 % of the extent at the centroid).
TEST(SimTruth, TheTruthsOfBothDirectionsAreInverses) {
  const Simulation sim = simulate(test::benchWorldOptions(0.15, 0.05, 0.01, 0, false));
  const Sim3& ab = sim.pair(0, 1).target_source;
  const Sim3 ba_inverse = sim.pair(1, 0).target_source.inverse();
  ASSERT_GT(sim.pair(0, 1).rms, 1e-3);  // the maps drift: no similarity fits them exactly
  EXPECT_LT(rotationDistance(ab.rotation(), ba_inverse.rotation()), 0.05 * kDeg);
  EXPECT_LT(std::abs(ab.scale() / ba_inverse.scale() - 1.0), 0.002);
  const Eigen::Vector3d centroid = sim.agents[1].map.cloud.rowwise().mean();
  const Cloud& target = sim.agents[0].map.cloud;
  const double extent = (target.rowwise().maxCoeff() - target.rowwise().minCoeff()).norm();
  EXPECT_LT((ab.apply(centroid) - ba_inverse.apply(centroid)).norm(), 0.002 * extent);
}

// The layout places agent_b so that the measured overlap is the requested one. The layout
// measures it on low-resolution renders (every pixel), the truth on the map points (gradient
// pixels): 0.08 allows for that difference.
TEST(SimTruth, OverlapIsControllable) {
  for (double wanted : {0.3, 0.8}) {
    SimulatorOptions o = quickOptions(67);
    o.trajectory.max_keyframes = 5;
    o.layout.overlap = wanted;
    const Simulation sim = simulate(o);
    EXPECT_NEAR(sim.pair(0, 1).overlap_fraction, wanted, 0.08) << "requested " << wanted;
  }
}

// The view-angle difference is controllable: the most co-visible keyframe pair of agent_a and
// agent_b looks at the walls from directions that far apart. Each camera's yaw and pitch wobble
// (6 and 4 deg by default) and the pair not sharing exactly one looked-at point allow 15 deg.
TEST(SimTruth, ViewAngleIsControllable) {
  for (double wanted : {10.0, 60.0}) {
    SimulatorOptions o = quickOptions(69);
    o.trajectory.max_keyframes = 6;
    o.layout.view_angle_difference_deg = wanted;
    const Simulation sim = simulate(o);
    const auto& pairs = sim.pair(0, 1).keyframe_pairs;
    ASSERT_FALSE(pairs.empty());
    const auto best = std::max_element(pairs.begin(), pairs.end(), [](const SimKeyframePair& a, const SimKeyframePair& b) {
      return a.covisible < b.covisible;
    });
    EXPECT_NEAR(best->view_angle_deg, wanted, 15.0) << "requested " << wanted;
  }
}

// --- configuration ---------------------------------------------------------------------------------

TEST(SimConfig, ShippedConfigIsTheDefaultsAndRoundTrips) {
  const SimulatorOptions shipped = loadSimulatorConfig(std::string(PCR_PRO_CONFIG_DIR) + "/simulator.yaml");
  EXPECT_EQ(simulatorConfigYaml(shipped), simulatorConfigYaml(SimulatorOptions()));
  const SimulatorOptions demo = loadSimulatorConfig(std::string(PCR_PRO_CONFIG_DIR) + "/sim_demo.yaml");
  EXPECT_EQ(demo.agents, 3);
  SimulatorOptions o;
  o.seed = 18446744073709551615ULL;
  o.agents = 3;
  o.layout.overlap = 0.123456789012345;
  o.map.depth_images = "semi_dense";
  o.per_agent.resize(2);
  o.per_agent[0].name = "robot_one";
  o.per_agent[1].scale = 0.1;
  o.per_agent[1].bend_deg = -2.5;
  o.per_agent[1].idepth_noise = 0.03;
  o.per_agent[1].camera = PinholeCamera{300.0, 301.5, 199.5, 149.25, 400, 300};
  const std::string yaml = simulatorConfigYaml(o);
  EXPECT_EQ(simulatorConfigYaml(parseSimulatorConfig(yaml, "test")), yaml);
  // An agent's camera takes the keys it does not give from the top-level camera.
  const SimulatorOptions partial = parseSimulatorConfig(
      "camera: {fx: 600, fy: 600, cx: 159.5, cy: 119.5, width: 320, height: 240}\nper_agent: [{}, {camera: {fx: 400, fy: 400}}]",
      "test");
  EXPECT_FALSE(partial.per_agent[0].camera.has_value());
  ASSERT_TRUE(partial.per_agent[1].camera.has_value());
  EXPECT_EQ(partial.per_agent[1].camera->fx, 400.0);
  EXPECT_EQ(partial.per_agent[1].camera->cx, 159.5);
  EXPECT_EQ(partial.per_agent[1].camera->width, 320);
}

TEST(SimConfig, DemoConfigChangesOnlyTheFieldsItMeansTo) {
  // config/sim_demo.yaml is the defaults but for a quick, drifting three-agent demo: compared field
  // by field (one line of simulatorConfigYaml() per field of the multi-line blocks), it changes
  // exactly these, each for the reason given; any other difference is a drift of the file.
  const std::map<std::string, std::string> changed{
      {"seed", "its own world"},
      {"agents", "a third agent (agent_c) for the multi-agent demo"},
      {"drift.scale_drift", "LSD-like scale drift along each path"},
      {"drift.bend_deg", "LSD-like rotation drift"},
      {"drift.pose_noise_rotation_deg", "per-keyframe jitter"},
      {"drift.pose_noise_translation", "per-keyframe jitter"},
      {"drift.loop_closure", "a final graph update that moves keyframes (auto_merge re-merges)"},
      {"trajectory.azimuth_span_deg", "a short path"},
      {"trajectory.keyframe_distance", "few keyframes: a quick demo"},
      {"trajectory.keyframe_angle_deg", "few keyframes: a quick demo"}};
  const auto fields = [](const SimulatorOptions& o) {
    std::map<std::string, std::string> out;
    std::istringstream in(simulatorConfigYaml(o));
    std::string block;
    for (std::string line; std::getline(in, line);) {
      const std::size_t colon = line.find(':');
      if (colon == std::string::npos) continue;
      const bool nested = line.rfind("  ", 0) == 0;
      const std::string key = line.substr(nested ? 2 : 0, colon - (nested ? 2 : 0));
      if (!nested) block = key;
      out[nested ? block + "." + key : key] = line.substr(colon + 1);
    }
    return out;
  };
  const auto demo = fields(loadSimulatorConfig(std::string(PCR_PRO_CONFIG_DIR) + "/sim_demo.yaml"));
  const auto defaults = fields(SimulatorOptions());
  ASSERT_EQ(demo.size(), defaults.size());
  ASSERT_GT(demo.size(), 40u) << "one entry per field of the multi-line blocks";
  for (const auto& [key, value] : defaults) {
    ASSERT_TRUE(demo.count(key)) << key;
    EXPECT_EQ(demo.at(key) != value, changed.count(key) == 1) << "sim_demo.yaml: " << key << ":" << demo.at(key);
  }
}

// Options built in C++ meet the same schema ranges as a file's (validate() runs them).
TEST(SimConfig, ValidateChecksTheSchemaRanges) {
  WorldOptions world;
  EXPECT_NO_THROW(validate(world));
  world.max_box_depth = 0.2;  // below the 0.25 m lower end of a box's depth draw
  EXPECT_THROW(validate(world), InputError);
  RenderOptions render;
  render.near = 0.0;
  EXPECT_THROW(validate(render), InputError);
  SemiDenseOptions semi_dense;
  semi_dense.outlier_fraction = 0.6;
  EXPECT_THROW(validate(semi_dense), InputError);
}

TEST(SimConfig, BadConfigsNameTheKey) {
  const std::vector<std::pair<std::string, std::string>> cases{
      {"layout: {overlap: 2}", "layout.overlap"},
      {"trajectory: {distanse: 2}", "trajectory.distanse"},
      {"drift:\n  bend_deg: 1\n  bend_deg: 2\n", "drift.bend_deg: duplicate key"},
      {"map: {depth_images: lidar}", "map.depth_images"},
      {"map: {semi_dense: {outlier_fraction: 0.9}}", "map.semi_dense.outlier_fraction"},
      {"agents: 2\nper_agent: [{}, {}, {}]", "per_agent"},
      {"per_agent: [{name: a/b}]", "per_agent[0].name"},
      {"per_agent: [{name: x}, {name: x}]", "per_agent[1].name"},
      {"per_agent: [{}, {idepth_noise: -0.01}]", "per_agent[1].idepth_noise: must be >= 0 and finite, got -0.01"},
      {"per_agent: [{}, {camera: {width: 8}}]", "per_agent[1].camera: fx, fy must be finite and > 0, width and height in [16, 4096]"},
      {"per_agent: [{camera: {fz: 8}}]", "per_agent[0].camera.fz"},
      {"world: {texture: {texel: 0}}", "world.texture.texel"},
      {"agents: two", "agents"},
      {"camera: {width: 0}", "camera"},
      {"trajectory: {camera_height: 2.7}", "trajectory.camera_height"},
      // per-field ranges from the schemas (world.h documents the same), cross-field ones from validate()
      {"world: {max_box_depth: 0.2}", "world.max_box_depth: must be in [0.25, 2], got 0.2 (line 1)"},
      {"render: {supersampling: 9}", "render.supersampling: must be in [1, 4], got 9 (line 1)"},
      {"map: {semi_dense: {subsample: 0}}", "map.semi_dense.subsample: must be >= 1, got 0 (line 1)"},
      {"world: {room_height: 2.5, max_wall_box_height: 2.45}", "world.max_wall_box_height: must be <= room_height - 0.1 = 2.4"},
      {"world: {texture: {texel: 0.01, min_shape_size: 0.015}}", "world.texture.min_shape_size: must be >= 2 texture.texel = 0.02"},
  };
  for (const auto& [text, key] : cases) {
    try {
      parseSimulatorConfig(text, "cfg.yaml");
      ADD_FAILURE() << "accepted: " << text;
    } catch (const InputError& e) {
      const std::string m = e.what();
      EXPECT_EQ(m.rfind("cfg.yaml: ", 0), 0u) << m;
      EXPECT_NE(m.find(key), std::string::npos) << "message '" << m << "' does not name " << key;
      EXPECT_EQ(m.find('\n'), std::string::npos) << m;
    }
  }
}

// --- merges of generated pairs against the truth -----------------------------------------------------

// Errors of an estimate of S_target_source: rotation [deg], relative scale, and the displacement
// of the source cloud's centroid [target units] (independent of where the map origin is).
struct MergeErrors {
  double rotation_deg = 0.0, scale = 0.0, displacement = 0.0;
};

MergeErrors errorsOf(const Sim3& estimate, const Sim3& truth, const Cloud& source) {
  const Eigen::Vector3d centroid = source.rowwise().mean();
  return {rotationDistance(estimate.rotation(), truth.rotation()) / kDeg, std::abs(estimate.scale() / truth.scale() - 1.0),
          (estimate.apply(centroid) - truth.apply(centroid)).norm()};
}

// The rendering noise of a pair, in the target's units: one map point's depth noise at the mean
// depth of the target keyframes (semi_dense.idepth_noise times that depth, or the pixel footprint
// if larger), and the target cloud's RMS radius. A merge is "within the rendering noise" when it
// displaces the overlap by less than one point's noise and turns / scales it by less than that
// noise over the map's radius: the errors of ~10^4 matched points average far below one point's.
struct NoiseBound {
  double point_noise = 0.0;  // [target units]
  double radius = 0.0;       // [target units]
};

NoiseBound noiseBound(const Simulation& sim, int target) {
  const SimAgent& a = sim.agents[static_cast<std::size_t>(target)];
  double sum = 0.0;
  for (const SimKeyframe& kf : a.keyframes) sum += 1.0 / kf.semi_dense.mean_true_idepth;
  const double depth = sum / a.keyframes.size();  // [m]
  const double noise_m = std::max(sim.options.map.semi_dense.idepth_noise * depth, depth / sim.options.camera.focal());
  const Eigen::Vector3d c = a.map.cloud.rowwise().mean();
  const double radius = std::sqrt((a.map.cloud.colwise() - c).colwise().squaredNorm().mean());
  return {noise_m * a.world_to_map.scale(), radius};
}

// A world for the merges: the default room, 3 agents, shorter paths (5-6 keyframes each).
SimulatorOptions mergeOptions(double overlap) {
  SimulatorOptions o;
  o.seed = 5;
  o.agents = 3;
  o.layout.overlap = overlap;
  o.trajectory.azimuth_span_deg = 60.0;
  o.trajectory.keyframe_angle_deg = 15.0;
  o.trajectory.keyframe_distance = 0.45;
  return o;
}

class SimMerge : public ::testing::Test {
 protected:
  static void SetUpTestSuite() { sim_ = new Simulation(simulate(mergeOptions(0.9))); }
  static void TearDownTestSuite() { delete sim_; }
  static MergeResult merge(int source, int target) {
    std::srand(1);  // OpenCV's FLANN draws from std::rand()
    return mergeMaps(sim_->agents[static_cast<std::size_t>(source)].map, sim_->agents[static_cast<std::size_t>(target)].map,
                     MergeRequest(), MergeOptions());
  }
  static Simulation* sim_;
};
Simulation* SimMerge::sim_ = nullptr;

TEST_F(SimMerge, NoDriftRecoversTheExactTruth) {
  const MergeResult r = merge(1, 0);
  ASSERT_EQ(r.report.status, Status::kOk) << r.report.message;
  const SimPairTruth& truth = sim_->pair(0, 1);
  const NoiseBound bound = noiseBound(*sim_, 0);
  const MergeErrors e = errorsOf(*r.report.transform, truth.target_source, sim_->agents[1].map.cloud);
  const MergeErrors g = errorsOf(r.diagnostics.initial, truth.target_source, sim_->agents[1].map.cloud);
  std::printf("no drift, overlap %.2f: merge rotation %.3f deg, scale %.4f %%, displacement %.4f; keyframe guess %.3f deg, "
              "%.4f %%, %.4f; bound %.3f deg, %.3f %%, %.4f\n",
              truth.overlap_fraction, e.rotation_deg, 100 * e.scale, e.displacement, g.rotation_deg, 100 * g.scale,
              g.displacement, bound.point_noise / bound.radius / kDeg, 100 * bound.point_noise / bound.radius,
              bound.point_noise);
  EXPECT_LT(e.rotation_deg * kDeg, bound.point_noise / bound.radius);
  EXPECT_LT(e.scale, bound.point_noise / bound.radius);
  EXPECT_LT(e.displacement, bound.point_noise);
}

TEST_F(SimMerge, NonOverlappingPairIsRefused) {
  ASSERT_FALSE(sim_->pair(0, 2).overlap);
  const MergeResult r = merge(2, 0);
  EXPECT_NE(r.report.status, Status::kOk) << r.report.message;
}

// With drift the truth is the least-squares similarity over the overlap, which itself fits the
// maps only to truth.rms: the bound adds that residual to the rendering noise.
TEST(SimMergeDrift, DriftPairRecoversTheOverlapTruth) {
  SimulatorOptions o = mergeOptions(0.9);
  o.agents = 2;
  o.drift.scale_drift = 0.03;
  o.drift.bend_deg = 3.0;
  o.drift.pose_noise_rotation_deg = 0.2;
  o.drift.pose_noise_translation = 0.005;
  const Simulation sim = simulate(o);
  std::srand(1);
  const MergeResult r = mergeMaps(sim.agents[1].map, sim.agents[0].map, MergeRequest(), MergeOptions());
  ASSERT_EQ(r.report.status, Status::kOk) << r.report.message;
  const SimPairTruth& truth = sim.pair(0, 1);
  const NoiseBound bound = noiseBound(sim, 0);
  const double noise = bound.point_noise + truth.rms;
  const MergeErrors e = errorsOf(*r.report.transform, truth.target_source, sim.agents[1].map.cloud);
  std::printf("drift 3 %% / 3 deg, overlap %.2f, truth rms %.4f: merge rotation %.3f deg, scale %.4f %%, displacement "
              "%.4f; bound %.3f deg, %.3f %%, %.4f\n",
              truth.overlap_fraction, truth.rms, e.rotation_deg, 100 * e.scale, e.displacement,
              noise / bound.radius / kDeg, 100 * noise / bound.radius, noise);
  EXPECT_LT(e.rotation_deg * kDeg, noise / bound.radius);
  EXPECT_LT(e.scale, noise / bound.radius);
  EXPECT_LT(e.displacement, noise);
}

// At the demo's 50 % overlap the keyframe stage (SIFT, relative pose, Kalman scale) is within the
// rendering noise, and so is the full merge (below).
TEST(SimMergeHalf, KeyframeGuessAtHalfOverlapIsWithinTheNoise) {
  const Simulation sim = simulate(mergeOptions(0.5));
  std::srand(1);
  const MergeResult r = mergeMaps(sim.agents[1].map, sim.agents[0].map, MergeRequest(), MergeOptions());
  ASSERT_GT(r.diagnostics.relative_pose_inliers, 0) << r.report.message;
  const NoiseBound bound = noiseBound(sim, 0);
  const SimPairTruth& truth = sim.pair(0, 1);
  const MergeErrors g = errorsOf(r.diagnostics.initial, truth.target_source, sim.agents[1].map.cloud);
  std::printf("overlap %.2f: keyframe guess %.3f deg, %.4f %%, %.4f (status %s: %s)\n", truth.overlap_fraction, g.rotation_deg,
              100 * g.scale, g.displacement, statusName(r.report.status), r.report.message.c_str());
  EXPECT_LT(g.rotation_deg * kDeg, bound.point_noise / bound.radius);
  EXPECT_LT(g.scale, bound.point_noise / bound.radius);
  EXPECT_LT(g.displacement, bound.point_noise);
}

TEST(SimMergeHalf, FullMergeAtHalfOverlapIsWithinTheNoise) {
  const Simulation sim = simulate(mergeOptions(0.5));
  std::srand(1);
  const MergeResult r = mergeMaps(sim.agents[1].map, sim.agents[0].map, MergeRequest(), MergeOptions());
  ASSERT_EQ(r.report.status, Status::kOk) << r.report.message;
  const NoiseBound bound = noiseBound(sim, 0);
  const MergeErrors e = errorsOf(*r.report.transform, sim.pair(0, 1).target_source, sim.agents[1].map.cloud);
  EXPECT_LT(e.rotation_deg * kDeg, bound.point_noise / bound.radius);
  EXPECT_LT(e.scale, bound.point_noise / bound.radius);
  EXPECT_LT(e.displacement, bound.point_noise);
}

// per_agent[i].camera: each agent renders, samples and maps through its own camera, and the truth
// sees through each observer's. agent_b here has 400 x 300 pixels and a 67 deg field of view
// (agent_a: 640 x 480, 62 deg). agent_a's map is the one it has with the shared camera, and the
// two maps merge within the rendering noise, as at equal cameras (FullMergeAtHalfOverlap...).
TEST(SimCamera, EachAgentTakesItsOwnCamera) {
  SimulatorOptions o = mergeOptions(0.5);
  o.agents = 2;
  const Simulation shared = simulate(o);
  const PinholeCamera own{300.0, 300.0, 199.5, 149.5, 400, 300};
  o.per_agent.resize(2);
  o.per_agent[1].camera = own;
  const Simulation sim = simulate(o);
  ASSERT_EQ(sim.agents[1].map.camera.width, own.width);
  EXPECT_EQ(sim.agents[1].map.camera.fx, own.fx);
  EXPECT_EQ(sim.agents[0].map.camera.width, o.camera.width);
  for (const MapKeyframe& k : sim.agents[1].map.keyframes) {
    EXPECT_EQ(k.image.cols, own.width);
    EXPECT_EQ(k.depth.rows, own.height);
  }
  EXPECT_EQ(sim.agents[1].keyframes.front().semi_dense.idepth.cols, own.width);
  ASSERT_EQ(shared.agents[0].map.cloud.cols(), sim.agents[0].map.cloud.cols());
  EXPECT_EQ((shared.agents[0].map.cloud - sim.agents[0].map.cloud).cwiseAbs().maxCoeff(), 0.0);
  // The layout still reaches the requested overlap (OverlapIsControllable's tolerance).
  const SimPairTruth& truth = sim.pair(0, 1);
  EXPECT_NEAR(truth.overlap_fraction, o.layout.overlap, 0.08);
  std::srand(1);
  const MergeResult r = mergeMaps(sim.agents[1].map, sim.agents[0].map, MergeRequest(), MergeOptions());
  ASSERT_EQ(r.report.status, Status::kOk) << r.report.message;
  const NoiseBound bound = noiseBound(sim, 0);
  const MergeErrors e = errorsOf(*r.report.transform, truth.target_source, sim.agents[1].map.cloud);
  std::printf("agent_b 400x300, 67 deg; overlap %.2f: merge %.3f deg, %.4f %%, %.4f; bound %.3f deg, %.3f %%, %.4f\n",
              truth.overlap_fraction, e.rotation_deg, 100 * e.scale, e.displacement,
              bound.point_noise / bound.radius / kDeg, 100 * bound.point_noise / bound.radius, bound.point_noise);
  EXPECT_LT(e.rotation_deg * kDeg, bound.point_noise / bound.radius);
  EXPECT_LT(e.scale, bound.point_noise / bound.radius);
  EXPECT_LT(e.displacement, bound.point_noise);
}

}  // namespace
}  // namespace pcr_pro
