#include "pcr_pro/frontend/keyframe_depth.h"

#include <algorithm>
#include <cmath>
#include <limits>
#include <string>

#include "pcr_pro/geometry/median.h"

namespace pcr_pro {

namespace {

// Largest neighbourhood radius accepted: a larger window is no longer a "neighbourhood" and
// would make every lookup scan a big part of the image.
constexpr int kMaxNeighborhoodRadiusPx = 100;
// Largest image accepted [px]: guards the depth buffer allocation against absurd camera sizes.
constexpr long long kMaxPixels = 1LL << 28;

// Copies the keyframe's depth image (CV_32FC1 of the camera's size) into `depth`, keeping the depths
// in [min_depth, max_depth].
void copyDepthImage(const MapKeyframe& keyframe, const PinholeCamera& camera, double min_depth, double max_depth,
                    std::vector<float>* depth) {
  const int width = camera.width;
  const int height = camera.height;
  const cv::Mat& img = keyframe.depth;
  if (img.type() != CV_32FC1) {
    throw InputError("keyframe " + std::to_string(keyframe.id) + ": depth image must be CV_32FC1 (32-bit float)");
  }
  if (img.cols != width || img.rows != height) {
    throw InputError("keyframe " + std::to_string(keyframe.id) + ": depth image is " + std::to_string(img.cols) + "x" +
                     std::to_string(img.rows) + " but the camera is " + std::to_string(width) + "x" +
                     std::to_string(height));
  }
  for (int row = 0; row < height; ++row) {
    const float* src = img.ptr<float>(row);
    float* dst = depth->data() + static_cast<size_t>(row) * static_cast<size_t>(width);
    for (int col = 0; col < width; ++col) {
      const double z = src[col];
      if (std::isfinite(z) && z >= min_depth && z <= max_depth) dst[col] = src[col];
    }
  }
}

// Projects the map cloud (at most max_points of it, spread evenly; 0: all) into `depth`, the nearest
// depth in [min_depth, max_depth] per pixel.
void projectCloud(const Sim3& pose, const Cloud& map_cloud, const PinholeCamera& camera, Eigen::Index max_points,
                  double min_depth, double max_depth, std::vector<float>* depth) {
  const int width = camera.width;
  const int height = camera.height;
  const Sim3 map_to_camera = pose.inverse();
  const Eigen::Index n = map_cloud.cols();
  // Subsampling: max_points indices spread evenly over the cloud.
  Eigen::Index count = n;
  if (max_points > 0 && n > max_points) count = max_points;
  const double step = count > 0 ? static_cast<double>(n) / static_cast<double>(count) : 1.0;
  for (Eigen::Index k = 0; k < count; ++k) {
    const Eigen::Index i = count == n ? k : std::min(n - 1, static_cast<Eigen::Index>(static_cast<double>(k) * step));
    const Eigen::Vector3d p_map = map_cloud.col(i);
    if (!p_map.allFinite()) continue;
    const Eigen::Vector3d p_cam = map_to_camera.apply(p_map);
    const double z = p_cam.z();
    if (!(z >= min_depth && z <= max_depth)) continue;
    double u = 0.0;
    double v = 0.0;
    if (!camera.project(p_cam, &u, &v)) continue;
    // Pixel (col, row) covers [col - 0.5, col + 0.5); the comparisons also reject NaN.
    if (!(u >= -0.5 && u < width - 0.5 && v >= -0.5 && v < height - 0.5)) continue;
    const int col = std::min(width - 1, static_cast<int>(std::floor(u + 0.5)));
    const int row = std::min(height - 1, static_cast<int>(std::floor(v + 0.5)));
    float& cell = (*depth)[static_cast<size_t>(row) * static_cast<size_t>(width) + static_cast<size_t>(col)];
    const float zf = static_cast<float>(z);
    if (!(zf > 0.0f)) continue;  // below float resolution
    if (cell == 0.0f || zf < cell) cell = zf;
  }
}

// The robust relative depth noise of one pixel of `depth` (KeyframeDepth::projectedRelativeNoise()):
// the pairs of valid pixels at the forward `offsets` (each unordered pair once), 0 with fewer than
// min_pairs of them.
double relativeNoise(const std::vector<float>& depth, int width, int height,
                     const std::vector<Eigen::Vector2i>& offsets, std::size_t min_pairs) {
  std::vector<Eigen::Vector2i> forward;
  for (const Eigen::Vector2i& o : offsets) {
    if (o.y() > 0 || (o.y() == 0 && o.x() > 0)) forward.push_back(o);
  }
  std::vector<double> differences;
  for (int row = 0; row < height; ++row) {
    for (int col = 0; col < width; ++col) {
      const double z1 = depth[static_cast<size_t>(row) * static_cast<size_t>(width) + static_cast<size_t>(col)];
      if (!(z1 > 0.0)) continue;
      for (const Eigen::Vector2i& o : forward) {
        const int c = col + o.x(), r = row + o.y();
        if (c < 0 || c >= width || r >= height) continue;
        const double z2 = depth[static_cast<size_t>(r) * static_cast<size_t>(width) + static_cast<size_t>(c)];
        if (z2 > 0.0) differences.push_back(2.0 * std::abs(z1 - z2) / (z1 + z2));
      }
    }
  }
  if (differences.size() < min_pairs) return 0.0;
  // 1.4826 x median |d| is the standard deviation of a Gaussian d; d is two pixels' noise.
  return 1.4826 * upperMedian(&differences) / std::sqrt(2.0);
}

}  // namespace

template <>
const ParamSchema<KeyframeDepthOptions>& paramSchema<KeyframeDepthOptions>() {
  using O = KeyframeDepthOptions;
  using R = ParamRange;
  static const ParamSchema<O> schema{"keyframe_depth", {
      {"neighborhood_radius_px", &O::neighborhood_radius_px, R::closed(0, kMaxNeighborhoodRadiusPx), "px",
       "depth lookup neighbourhood radius"},
      {"min_depth", &O::min_depth, R::above(0), "camera units", "smaller depths are unknown"},
      {"max_depth", &O::max_depth, R::above(0).orZero(), "camera units",
       "larger depths are unknown; 0 = no limit, else > min_depth"},
      {"max_cloud_points_projected", &O::max_cloud_points_projected, R::atLeast(0), "",
       "cap on the map points projected into a keyframe without depth image; 0 = all"},
      {"depth_consistency", &O::depth_consistency, R::atLeast(0), "-",
       "largest relative depth spread in the neighbourhood (depth without per-pixel uncertainty)"},
      {"spatial_sigma_px", &O::spatial_sigma_px, R::above(0), "px",
       "depth with per-pixel uncertainty (LSD-SLAM): pixels weighted by exp(-d^2 / (2 sigma^2)) / var(inverse depth)"},
      {"max_relative_stddev", &O::max_relative_stddev, R::open(0, 1), "-",
       "depth with per-pixel uncertainty: a looked-up depth less certain than this (relative stddev) is unknown"},
  }};
  return schema;
}

void validate(const KeyframeDepthOptions& o) {
  checkRanges(paramSchema<KeyframeDepthOptions>(), o);
  if (!(o.max_depth == 0.0 || o.max_depth > o.min_depth)) {
    throw InputError("keyframe_depth.max_depth must be 0 (no limit) or finite and > keyframe_depth.min_depth");
  }
}

KeyframeDepth::KeyframeDepth(const MapKeyframe& keyframe, const PinholeCamera& camera, const Cloud& map_cloud,
                             const KeyframeDepthOptions& options)
    : camera_(camera), options_(options) {
  validate(options_);
  if (!camera_.valid()) throw InputError("keyframe depth: invalid camera (fx, fy, width, height must be > 0)");
  if (static_cast<long long>(camera_.width) * static_cast<long long>(camera_.height) > kMaxPixels) {
    throw InputError("keyframe depth: camera width x height is too large");
  }
  const Sim3& pose = keyframe.pose;
  pose_scale_ = pose.scale();
  if (!(pose_scale_ > 0.0 && std::isfinite(pose_scale_))) {
    throw InputError("keyframe " + std::to_string(keyframe.id) + ": pose scale must be finite and > 0");
  }
  if (!pose.rotation().allFinite() || !pose.translation().allFinite()) {
    throw InputError("keyframe " + std::to_string(keyframe.id) + ": pose has non-finite entries");
  }

  const double min_depth = options_.min_depth;
  const double max_depth = options_.max_depth > 0.0 ? options_.max_depth : std::numeric_limits<double>::infinity();
  depth_.assign(static_cast<size_t>(camera_.width) * static_cast<size_t>(camera_.height), 0.0f);
  if (!keyframe.depth.empty()) {
    copyDepthImage(keyframe, camera_, min_depth, max_depth, &depth_);
    uses_depth_image_ = true;
    if (!keyframe.depth_stddev.empty()) setUncertainty(keyframe);
  } else {
    if (!keyframe.depth_stddev.empty()) {
      throw InputError("keyframe " + std::to_string(keyframe.id) + ": depth_stddev given without a depth image");
    }
    uses_depth_image_ = false;
    projectCloud(pose, map_cloud, camera_, options_.max_cloud_points_projected, min_depth, max_depth, &depth_);
  }
  valid_pixels_ = static_cast<int>(std::count_if(depth_.begin(), depth_.end(), [](float z) { return z > 0.0f; }));

  const int r = options_.neighborhood_radius_px;
  for (int dy = -r; dy <= r; ++dy) {
    for (int dx = -r; dx <= r; ++dx) {
      if (dx * dx + dy * dy <= r * r) offsets_.emplace_back(dx, dy);
    }
  }
  if (!uses_depth_image_) {
    projected_relative_noise_ = relativeNoise(depth_, camera_.width, camera_.height, offsets_, kMinNoisePairs);
  }
}

bool KeyframeDepth::depthAt(double u, double v, double* depth) const {
  if (!hasUncertainty()) return nearestDepth(u, v, depth);
  DepthSample d;
  if (!sampleAt(u, v, &d)) return false;
  if (depth != nullptr) *depth = d.depth;
  return true;
}

bool KeyframeDepth::nearestDepth(double u, double v, double* depth) const {
  const int width = camera_.width;
  const int height = camera_.height;
  // Also false for NaN.
  if (!(u >= -0.5 && u < width - 0.5 && v >= -0.5 && v < height - 0.5)) return false;
  const int col0 = std::min(width - 1, static_cast<int>(std::floor(u + 0.5)));
  const int row0 = std::min(height - 1, static_cast<int>(std::floor(v + 0.5)));

  double best_d2 = std::numeric_limits<double>::infinity();
  double best_z = 0.0;
  double z_min = std::numeric_limits<double>::infinity();
  double z_max = 0.0;
  for (const Eigen::Vector2i& off : offsets_) {
    const int col = col0 + off.x();
    const int row = row0 + off.y();
    if (col < 0 || col >= width || row < 0 || row >= height) continue;
    const double z = depth_[static_cast<size_t>(row) * static_cast<size_t>(width) + static_cast<size_t>(col)];
    if (!(z > 0.0)) continue;
    z_min = std::min(z_min, z);
    z_max = std::max(z_max, z);
    const double du = col - u;
    const double dv = row - v;
    const double d2 = du * du + dv * dv;
    if (d2 < best_d2 || (d2 == best_d2 && z < best_z)) {
      best_d2 = d2;
      best_z = z;
    }
  }
  if (!(best_z > 0.0)) return false;
  if (z_max - z_min > options_.depth_consistency * z_min) return false;
  if (depth != nullptr) *depth = best_z;
  return true;
}

void KeyframeDepth::setUncertainty(const MapKeyframe& keyframe) {
  const cv::Mat& sd = keyframe.depth_stddev;
  if (sd.type() != CV_32FC1 || sd.size() != keyframe.depth.size()) {
    throw InputError("keyframe " + std::to_string(keyframe.id) +
                     ": depth_stddev must be CV_32FC1 of the depth image's size");
  }
  const int width = camera_.width, height = camera_.height;
  idepth_.assign(depth_.size(), 0.0f);
  idepth_stddev_.assign(depth_.size(), 0.0f);
  for (int row = 0; row < height; ++row) {
    const float* src = sd.ptr<float>(row);
    for (int col = 0; col < width; ++col) {
      const size_t k = static_cast<size_t>(row) * static_cast<size_t>(width) + static_cast<size_t>(col);
      const double z = depth_[k], sz = src[col];
      // A pixel without a usable standard deviation has no depth either: its weight is unknown.
      if (!(z > 0.0 && sz > 0.0 && std::isfinite(sz))) {
        depth_[k] = 0.0f;
        continue;
      }
      const auto rho = static_cast<float>(1.0 / z), sigma = static_cast<float>(sz / (z * z));
      if (!(rho > 0.0f && sigma > 0.0f && std::isfinite(rho) && std::isfinite(sigma))) {
        depth_[k] = 0.0f;
        continue;
      }
      idepth_[k] = rho;
      idepth_stddev_[k] = sigma;
    }
  }
}

bool KeyframeDepth::sampleAt(double u, double v, DepthSample* sample) const {
  if (!hasUncertainty()) {
    double z = 0.0;
    if (!nearestDepth(u, v, &z)) return false;
    if (sample != nullptr) *sample = DepthSample{z, 0.0};
    return true;
  }
  const int width = camera_.width;
  const int height = camera_.height;
  if (!(u >= -0.5 && u < width - 0.5 && v >= -0.5 && v < height - 0.5)) return false;  // also NaN
  const int col0 = std::min(width - 1, static_cast<int>(std::floor(u + 0.5)));
  const int row0 = std::min(height - 1, static_cast<int>(std::floor(v + 0.5)));
  struct Pixel {
    double rho, var, w;
  };
  std::vector<Pixel> pixels;
  pixels.reserve(offsets_.size());
  const double inv_two_h2 = 1.0 / (2.0 * options_.spatial_sigma_px * options_.spatial_sigma_px);
  double total = 0.0;
  for (const Eigen::Vector2i& off : offsets_) {
    const int col = col0 + off.x();
    const int row = row0 + off.y();
    if (col < 0 || col >= width || row < 0 || row >= height) continue;
    const size_t k = static_cast<size_t>(row) * static_cast<size_t>(width) + static_cast<size_t>(col);
    if (!(depth_[k] > 0.0f)) continue;
    const double du = col - u, dv = row - v;
    const double var = static_cast<double>(idepth_stddev_[k]) * idepth_stddev_[k];
    const double w = std::exp(-(du * du + dv * dv) * inv_two_h2) / var;
    if (!(w > 0.0 && std::isfinite(w))) continue;
    pixels.push_back({idepth_[k], var, w});
    total += w;
  }
  if (pixels.empty()) return false;
  // Weighted median of the inverse depths.
  std::sort(pixels.begin(), pixels.end(), [](const Pixel& a, const Pixel& b) { return a.rho < b.rho; });
  double acc = 0.0, median = pixels.back().rho;
  for (const Pixel& p : pixels) {
    acc += p.w;
    if (acc >= 0.5 * total) {
      median = p.rho;
      break;
    }
  }
  // One surface: the pixels within 3 σ of the median; their mixture mean and variance.
  double sw = 0.0, swr = 0.0;
  for (const Pixel& p : pixels) {
    if ((p.rho - median) * (p.rho - median) > 9.0 * p.var) continue;
    sw += p.w;
    swr += p.w * p.rho;
  }
  if (!(sw > 0.5 * total)) return false;
  const double mean = swr / sw;
  double swv = 0.0;
  for (const Pixel& p : pixels) {
    if ((p.rho - median) * (p.rho - median) > 9.0 * p.var) continue;
    swv += p.w * (p.var + (p.rho - mean) * (p.rho - mean));
  }
  const double sigma = std::sqrt(swv / sw);
  if (!(mean > 0.0) || !(sigma <= options_.max_relative_stddev * mean)) return false;
  const double z = 1.0 / mean;
  const double max_depth = options_.max_depth > 0.0 ? options_.max_depth : std::numeric_limits<double>::infinity();
  if (!(z >= options_.min_depth && z <= max_depth)) return false;
  if (sample != nullptr) *sample = DepthSample{z, sigma / (mean * mean)};
  return true;
}

bool KeyframeDepth::pointAt(double u, double v, Eigen::Vector3d* point, double* depth_stddev) const {
  DepthSample d;
  if (!sampleAt(u, v, &d)) return false;
  if (point != nullptr) {
    *point = (pose_scale_ * d.depth) *
             Eigen::Vector3d((u - camera_.cx) / camera_.fx, (v - camera_.cy) / camera_.fy, 1.0);
  }
  if (depth_stddev != nullptr) *depth_stddev = pose_scale_ * d.stddev;
  return true;
}

bool KeyframeDepth::pointAt(double u, double v, Eigen::Vector3d* point) const {
  double z = 0.0;
  if (!depthAt(u, v, &z)) return false;
  if (point != nullptr) {
    *point = (pose_scale_ * z) * Eigen::Vector3d((u - camera_.cx) / camera_.fx, (v - camera_.cy) / camera_.fy, 1.0);
  }
  return true;
}

}  // namespace pcr_pro
