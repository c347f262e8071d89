#include "real_cases/agent_builder.h"

#include <algorithm>
#include <cmath>
#include <opencv2/imgproc.hpp>
#include <set>

namespace pcr_pro {
namespace real_cases {
namespace {

// A pixel is at a depth discontinuity when a 3x3 neighbour has no depth or the depths of its
// 3x3 neighbourhood span more than this fraction of its own depth. Kinect depth is quantised to
// well under 1 % of the depth at room range, so a 5 % step is an edge between two surfaces.
constexpr double kMaxLocalDepthStep = 0.05;

// The intrinsics of a crop of the images.
PinholeCamera cropCamera(const PinholeCamera& camera, const cv::Rect& crop) {
  if (crop.empty()) return camera;
  PinholeCamera c = camera;
  c.cx -= crop.x;
  c.cy -= crop.y;
  c.width = crop.width;
  c.height = crop.height;
  return c;
}

cv::Mat cropped(const cv::Mat& image, const cv::Rect& crop) {
  return crop.empty() ? image.clone() : image(crop).clone();
}

// Map scale at each frame: world_to_map scale times (1 + drift) ^ (path length so far / total).
std::vector<double> driftedScales(const std::vector<Eigen::Vector3d>& centres, double scale0, double drift,
                                  double* path_length) {
  std::vector<double> length(centres.size(), 0.0);
  for (std::size_t k = 1; k < centres.size(); ++k) length[k] = length[k - 1] + (centres[k] - centres[k - 1]).norm();
  *path_length = length.back();
  std::vector<double> scales(centres.size(), scale0);
  if (length.back() > 0.0) {
    for (std::size_t k = 0; k < centres.size(); ++k)
      scales[k] = scale0 * std::pow(1.0 + drift, length[k] / length.back());
  }
  return scales;
}

}  // namespace

std::uint64_t mixSeed(std::uint64_t seed, std::uint64_t value) {
  std::uint64_t z = seed + 0x9e3779b97f4a7c15ULL * (value + 1);
  z = (z ^ (z >> 30)) * 0xbf58476d1ce4e5b9ULL;
  z = (z ^ (z >> 27)) * 0x94d049bb133111ebULL;
  return z ^ (z >> 31);
}

void validate(const AgentSpec& spec) {
  const std::string where = "agent " + spec.name + ": ";
  if (spec.frames.empty()) throw InputError(where + "frames: empty");
  if (spec.keyframes.empty()) throw InputError(where + "keyframes: empty");
  const std::set<long> frames(spec.frames.begin(), spec.frames.end());
  if (frames.size() != spec.frames.size()) throw InputError(where + "frames: repeated frame");
  for (long id : spec.keyframes) {
    if (!frames.count(id))
      throw InputError(where + "keyframes: " + std::to_string(id) + " is not a frame of the window");
  }
  if (!(spec.scale_drift > -1.0) || !std::isfinite(spec.scale_drift))
    throw InputError(where + "scale_drift: must be > -1");
  if (!(spec.world_to_map.scale() > 0.0) || !spec.world_to_map.matrix().allFinite()) {
    throw InputError(where + "world_to_map: not a finite similarity");
  }
  validate(spec.semi_dense);
}

SemiDenseKeyframe sampleFrame(const cv::Mat& grey, const cv::Mat& depth, const PinholeCamera& camera,
                              double depth_colour_offset_m, const SemiDenseOptions& options, std::uint64_t seed) {
  const cv::Mat kernel = cv::Mat::ones(3, 3, CV_8U);
  cv::Mat valid = depth > 0.0f, all_valid, local_max, local_min;
  cv::erode(valid, all_valid, kernel, cv::Point(-1, -1), 1, cv::BORDER_CONSTANT, cv::Scalar(0));
  cv::dilate(depth, local_max, kernel);
  cv::erode(depth, local_min, kernel);
  // Distance of every pixel to the nearest discontinuity pixel (zeros of `smooth`) [px].
  cv::Mat smooth = all_valid & ((local_max - local_min) < depth * kMaxLocalDepthStep), distance;
  cv::distanceTransform(smooth, distance, cv::DIST_L2, cv::DIST_MASK_PRECISE);
  cv::Mat kept(depth.size(), CV_32FC1, cv::Scalar(0.0f));
  for (int r = 0; r < depth.rows; ++r) {
    for (int c = 0; c < depth.cols; ++c) {
      const float z = depth.at<float>(r, c);
      if (!(z > 0.0f)) continue;
      const double margin = std::max(1.0, camera.focal() * depth_colour_offset_m / z);
      if (distance.at<float>(r, c) >= margin) kept.at<float>(r, c) = z;
    }
  }
  return sampleSemiDense(grey, kept, camera, options, seed);
}

BuiltAgent buildAgent(RgbdSequence& sequence, const AgentSpec& spec) {
  validate(spec);
  BuiltAgent out;
  const PinholeCamera camera = cropCamera(sequence.camera(), spec.crop);
  out.map.frame_id = spec.name + "/map";
  out.map.camera = camera;
  std::vector<Eigen::Vector3d> centres;
  for (long id : spec.frames) centres.push_back(sequence.pose(id).translation());
  const std::vector<double> scales =
      driftedScales(centres, spec.world_to_map.scale(), spec.scale_drift, &out.path_length_m);

  // The drifted map: camera centres integrate the path with the scale of the moment (trapezoid
  // rule), so that G_k maps the world near frame k exactly into the map near frame k.
  const Eigen::Matrix3d& r_map = spec.world_to_map.rotation();
  Eigen::Vector3d centre_in_map = spec.world_to_map.apply(centres.front());
  const std::set<long> keyframes(spec.keyframes.begin(), spec.keyframes.end());
  std::vector<Eigen::Vector3d> map_points, world_points;
  for (std::size_t k = 0; k < spec.frames.size(); ++k) {
    const long id = spec.frames[k];
    if (k > 0) centre_in_map += 0.5 * (scales[k - 1] + scales[k]) * (r_map * (centres[k] - centres[k - 1]));
    const Sim3 g(scales[k], r_map, centre_in_map - scales[k] * (r_map * centres[k]));
    const Sim3& camera_to_world = sequence.pose(id);
    out.world_to_map[id] = g;
    out.camera_to_world[id] = camera_to_world;
    const RgbdFrame& frame = sequence.frame(id);
    const cv::Mat grey = cropped(frame.grey, spec.crop), depth = cropped(frame.depth, spec.crop);
    out.depth[id] = depth;
    const SemiDenseKeyframe semi = sampleFrame(grey, depth, camera, sequence.facts().depth_colour_offset_m,
                                               spec.semi_dense, mixSeed(spec.seed, static_cast<std::uint64_t>(id)));
    const Sim3 camera_to_map = g * camera_to_world;
    for (Eigen::Index i = 0; i < semi.points.cols(); ++i) {
      world_points.push_back(camera_to_world.apply(Eigen::Vector3d(semi.points.col(i))));
      map_points.push_back(camera_to_map.apply(Eigen::Vector3d(semi.points.col(i))));
      out.point_frames.push_back(id);
    }
    if (keyframes.count(id)) {
      MapKeyframe kf;
      kf.id = id;
      kf.image = grey;
      kf.depth = depth;
      kf.pose = camera_to_map;
      out.map.keyframes.push_back(kf);
    }
  }
  out.map.cloud.resize(3, static_cast<Eigen::Index>(map_points.size()));
  out.world_points.resize(3, static_cast<Eigen::Index>(world_points.size()));
  for (std::size_t i = 0; i < map_points.size(); ++i) {
    out.map.cloud.col(static_cast<Eigen::Index>(i)) = map_points[i];
    out.world_points.col(static_cast<Eigen::Index>(i)) = world_points[i];
  }
  return out;
}

}  // namespace real_cases
}  // namespace pcr_pro
