// Shared helpers of the benchmark programs: timing, peak memory, error measures, the
// transformations that build the robustness sweep from the real two-agent bundles, and a
// small writer for the Markdown / CSV outputs that scripts/bench.sh assembles into
// docs/BENCHMARKS.md.
#pragma once

#include <sys/resource.h>

#include <opencv2/imgproc.hpp>

#include <algorithm>
#include <chrono>
#include <cmath>
#include <cstdio>
#include <fstream>
#include <functional>
#include <random>
#include <stdexcept>
#include <string>
#include <vector>

#include "common/geometry_checks.h"
#include "pcr_pro/registration/filters.h"
#include "pcr_pro/geometry/map_types.h"
#include "pcr_pro/geometry/sim3.h"

namespace pcr_pro {
namespace bench {

inline double nowMs() {
  return std::chrono::duration<double, std::milli>(std::chrono::steady_clock::now().time_since_epoch()).count();
}

/// Median of a list (copied).
inline double median(std::vector<double> v) {
  if (v.empty()) return std::nan("");
  std::sort(v.begin(), v.end());
  const std::size_t m = v.size() / 2;
  return v.size() % 2 ? v[m] : 0.5 * (v[m - 1] + v[m]);
}

/// Quantile q in [0, 1] of a list (nearest rank).
inline double quantile(std::vector<double> v, double q) {
  if (v.empty()) return std::nan("");
  std::sort(v.begin(), v.end());
  const auto i = static_cast<std::size_t>(std::min<double>(v.size() - 1, std::floor(q * (v.size() - 1) + 0.5)));
  return v[i];
}

/// Peak resident memory of this process so far [MiB].
inline double peakRssMiB() {
  rusage ru{};
  getrusage(RUSAGE_SELF, &ru);
  return ru.ru_maxrss / 1024.0;
}

/// Runs `command` (a fresh process: OpenMP and fork() do not mix) and reads the number it prints
/// on its last line of stdout; -1 on failure.
inline double runForNumber(const std::string& command) {
  std::FILE* p = popen(command.c_str(), "r");
  if (!p) return -1.0;
  double v = -1.0, x = 0.0;
  char line[256];
  while (std::fgets(line, sizeof line, p)) {
    if (std::sscanf(line, "%lf", &x) == 1) v = x;
  }
  return pclose(p) == 0 ? v : -1.0;
}

/// Errors of an estimated S_target_source against the truth (shared with the tests).
using test::Errors;
using test::errors;

/// The success criterion of the issues: rotation < 1°, translation < 1 % of the map extent,
/// scale < 1 %.
inline bool success(const Errors& e, double extent) {
  return e.rotation_deg < 1.0 && e.translation < 0.01 * extent && e.scale_rel < 0.01;
}

/// An agent's map expressed in units `factor` times larger: cloud × factor, poses Sim3(factor) ∘ pose.
inline AgentMap rescaled(const AgentMap& map, double factor) {
  AgentMap out = map;
  out.cloud *= factor;
  for (MapKeyframe& kf : out.keyframes) {
    kf.pose = Sim3(factor, Eigen::Matrix3d::Identity(), Eigen::Vector3d::Zero()) * kf.pose;
  }
  return out;
}

/// Rolls every keyframe camera of the map about its optical axis by `deg`: a pure camera
/// rotation R induces the exact homography H = K R K⁻¹ for any scene, so the image (and the
/// depth image: a roll keeps z) is warped with H and the pose becomes R_cam→map · R_rollᵀ.
inline AgentMap rolled(const AgentMap& map, double deg) {
  if (deg == 0.0) return map;
  AgentMap out = map;
  const double a = deg * M_PI / 180.0;
  // New camera frame: p' = R_roll p.
  const Eigen::Matrix3d r_roll = Eigen::AngleAxisd(a, Eigen::Vector3d::UnitZ()).toRotationMatrix();
  Eigen::Matrix3d k;
  k << map.camera.fx, 0, map.camera.cx, 0, map.camera.fy, map.camera.cy, 0, 0, 1;
  const Eigen::Matrix3d h = k * r_roll * k.inverse();
  cv::Mat hm(3, 3, CV_64F);
  for (int i = 0; i < 3; ++i) {
    for (int j = 0; j < 3; ++j) hm.at<double>(i, j) = h(i, j);
  }
  const cv::Size size(map.camera.width, map.camera.height);
  for (MapKeyframe& kf : out.keyframes) {
    cv::Mat img, depth;
    cv::warpPerspective(kf.image, img, hm, size, cv::INTER_LINEAR, cv::BORDER_CONSTANT, cv::Scalar(0));
    kf.image = img;
    if (!kf.depth.empty()) {
      cv::warpPerspective(kf.depth, depth, hm, size, cv::INTER_NEAREST, cv::BORDER_CONSTANT, cv::Scalar(0));
      kf.depth = depth;
    }
    kf.pose = Sim3(kf.pose.scale(), Eigen::Matrix3d(kf.pose.rotation() * r_roll.transpose()), kf.pose.translation());
  }
  return out;
}

/// Keeps a random fraction of a cloud (fixed seed).
inline Cloud sparsified(const Cloud& cloud, double keep, uint32_t seed) {
  if (keep >= 1.0) return cloud;
  RandomSamplingOptions o;
  o.keep_ratio = keep;
  o.seed = seed;
  return randomSamplingFilter(cloud, o);
}

/// Back-projects every valid depth pixel of every keyframe of the map into the map frame.
inline Cloud depthCloud(const AgentMap& map) {
  std::vector<Eigen::Vector3d> pts;
  for (const MapKeyframe& kf : map.keyframes) {
    if (kf.depth.empty()) continue;
    for (int v = 0; v < kf.depth.rows; ++v) {
      for (int u = 0; u < kf.depth.cols; ++u) {
        const float z = kf.depth.at<float>(v, u);
        if (!(z > 0.0f) || !std::isfinite(z)) continue;
        const Eigen::Vector3d p((u - map.camera.cx) / map.camera.fx * z, (v - map.camera.cy) / map.camera.fy * z, z);
        pts.push_back(kf.pose.apply(p));
      }
    }
  }
  Cloud c(3, static_cast<Eigen::Index>(pts.size()));
  for (std::size_t i = 0; i < pts.size(); ++i) c.col(static_cast<Eigen::Index>(i)) = pts[i];
  return c;
}

/// Caps a cloud at n points (uniform random subsample, fixed seed).
inline Cloud capped(const Cloud& cloud, int n) {
  MaxPointsOptions o;
  o.max_points = n;
  return maxPointsFilter(cloud, o);
}

/// Writes one output file of the run (Markdown fragment or CSV) into the output directory.
class Output {
 public:
  explicit Output(std::string dir) : dir_(std::move(dir)) {}
  std::FILE* open(const std::string& name) {
    std::FILE* f = std::fopen((dir_ + "/" + name).c_str(), "w");
    if (!f) throw std::runtime_error(dir_ + "/" + name + ": cannot write");
    return f;
  }
  const std::string& dir() const { return dir_; }

 private:
  std::string dir_;
};

}  // namespace bench
}  // namespace pcr_pro
