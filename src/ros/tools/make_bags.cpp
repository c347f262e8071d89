// pcr_pro_make_bags: writes the two shipped two-agent bags from the real frames of a map bundle
// case (test/data/bundles/<case>, made from real Kinect frames, see its README.md):
//   pcr_pro_two_agents.bag      pcr_pro/Keyframe (grey image, CameraInfo, pose, 16UC1 depth [mm])
//                               + sensor_msgs/PointCloud2 map cloud per agent
//   lsd_slam_two_agents.bag     lsd_slam_viewer/keyframeMsg + keyframeGraphMsg per agent, as an
//                               unmodified LSD-SLAM publishes them (see lsdKeyframe() below)
// Usage: pcr_pro_make_bags --case DIR --output DIR
// Deterministic: fixed time base, no randomness.
#include <opencv2/imgproc.hpp>
#include <rosbag/bag.h>

#include <cmath>
#include <iostream>
#include <string>
#include <vector>

#include "pcr_pro/io/bundle.h"
#include "pcr_pro/ros/msg_conversion.h"

namespace {

using namespace pcr_pro;
using namespace pcr_pro::ros_bridge;

const ros::Time kStart(1600000000, 0);  // fixed time base: the bags are reproducible
const double kStep = 0.25;              // seconds between messages

// Semi-dense selection like LSD-SLAM's: pixels with enough image gradient (Sobel 3x3 magnitude,
// grey 0..255) and a measured depth, widened by one pixel as LSD's depth propagation and
// regularisation do.
constexpr double kMinGradient = 25.0;
constexpr double kMinDepth = 0.3, kMaxDepth = 10.0;  // [m]
constexpr int kBorder = 8;                           // [px]
// Kinect-like depth noise: sigma_z = kNoiseQuadratic * z^2, plus the depth spread of the 3x3
// neighbourhood (large at depth edges, where LSD's variance is large too).
constexpr double kNoiseQuadratic = 0.0012;  // [1/m]
// Pose error of an LSD keyframe before pose-graph optimisation; the graph message corrects it.
constexpr double kPreGraphRotationDeg = 2.0;
constexpr double kPreGraphScaleError = 0.04;

// LSD-SLAM keyframe from a bundle keyframe with a depth image. LSD-SLAM normalises every new
// keyframe to a mean inverse depth of 1 and puts the factor into its camToWorld scale: here the
// LSD depth is z / c with c = 1 / mean(1 / z), and camToWorld = pose scaled by c.
LsdKeyframe lsdKeyframe(const MapKeyframe& kf, const PinholeCamera& camera, double time) {
  if (kf.depth.empty()) throw InputError("keyframe " + std::to_string(kf.id) + " has no depth image");
  const int h = kf.image.rows, w = kf.image.cols;
  cv::Mat gx, gy, mag;
  cv::Sobel(kf.image, gx, CV_32F, 1, 0, 3);
  cv::Sobel(kf.image, gy, CV_32F, 0, 1, 3);
  cv::magnitude(gx, gy, mag);
  cv::Mat mask = cv::Mat::zeros(h, w, CV_8UC1);
  for (int y = kBorder; y < h - kBorder; ++y) {
    for (int x = kBorder; x < w - kBorder; ++x) {
      const float z = kf.depth.at<float>(y, x);
      if (mag.at<float>(y, x) > kMinGradient && z > kMinDepth && z < kMaxDepth) mask.at<std::uint8_t>(y, x) = 255;
    }
  }
  cv::dilate(mask, mask, cv::Mat::ones(3, 3, CV_8UC1));
  double sum_inverse = 0.0;
  int n = 0;
  for (int y = 0; y < h; ++y) {
    for (int x = 0; x < w; ++x) {
      const float z = kf.depth.at<float>(y, x);
      if (!mask.at<std::uint8_t>(y, x) || !(z > kMinDepth && z < kMaxDepth)) continue;
      sum_inverse += 1.0 / z;
      ++n;
    }
  }
  if (n == 0) throw InputError("keyframe " + std::to_string(kf.id) + ": no semi-dense pixel");
  const double c = 1.0 / (sum_inverse / n);

  LsdKeyframe lsd;
  lsd.id = kf.id;
  lsd.time = time;
  lsd.camera = camera;
  lsd.cam_to_world = kf.pose * Sim3(c, Eigen::Matrix3d::Identity(), Eigen::Vector3d::Zero());
  lsd.image = kf.image.clone();
  lsd.idepth = cv::Mat::zeros(h, w, CV_32FC1);
  lsd.idepth_var = cv::Mat::zeros(h, w, CV_32FC1);
  for (int y = 1; y < h - 1; ++y) {
    for (int x = 1; x < w - 1; ++x) {
      const float z = kf.depth.at<float>(y, x);
      if (!mask.at<std::uint8_t>(y, x) || !(z > kMinDepth && z < kMaxDepth)) continue;
      float zmin = z, zmax = z;
      for (int dy = -1; dy <= 1; ++dy) {
        for (int dx = -1; dx <= 1; ++dx) {
          const float zn = kf.depth.at<float>(y + dy, x + dx);
          if (zn > 0.0f) zmin = std::min(zmin, zn), zmax = std::max(zmax, zn);
        }
      }
      const double sigma_z = kNoiseQuadratic * z * z + (zmax - zmin);  // [m]
      const double sigma_idepth = c * sigma_z / (static_cast<double>(z) * z);  // d(c / z) = c dz / z^2
      lsd.idepth.at<float>(y, x) = static_cast<float>(c / z);
      lsd.idepth_var.at<float>(y, x) = static_cast<float>(sigma_idepth * sigma_idepth);
    }
  }
  return lsd;
}

// The camToWorld a keyframe had before the pose graph corrected it (first keyframe exact).
Sim3 preGraphPose(const Sim3& pose, std::size_t index) {
  if (index == 0) return pose;
  const double sign = index % 2 ? 1.0 : -1.0;
  const Eigen::Vector3d axis = Eigen::Vector3d(0.3, -0.8, 0.5).normalized();
  const Sim3 error(1.0 + sign * kPreGraphScaleError,
                   Eigen::Quaterniond(Eigen::AngleAxisd(sign * kPreGraphRotationDeg * M_PI / 180.0, axis)),
                   Eigen::Vector3d::Zero());
  return pose * error;  // an error in the camera frame, as odometry drift would give
}

int run(int argc, char** argv) {
  std::string case_dir, output;
  for (int i = 1; i + 1 < argc; i += 2) {
    const std::string key = argv[i];
    if (key == "--case") {
      case_dir = argv[i + 1];
    } else if (key == "--output") {
      output = argv[i + 1];
    } else {
      throw InputError("unknown option " + key);
    }
  }
  if (case_dir.empty() || output.empty()) throw InputError("usage: pcr_pro_make_bags --case DIR --output DIR");
  const BundleTruth truth = loadBundleTruth(case_dir + "/truth.yaml");
  const std::vector<std::string> agents{truth.target_agent, truth.source_agent};

  rosbag::Bag ours(output + "/pcr_pro_two_agents.bag", rosbag::bagmode::Write);
  rosbag::Bag lsd(output + "/lsd_slam_two_agents.bag", rosbag::bagmode::Write);
  ours.setCompression(rosbag::compression::BZ2);
  lsd.setCompression(rosbag::compression::BZ2);
  ros::Time t = kStart;
  const auto next = [&t] { return t = t + ros::Duration(kStep); };
  for (const std::string& agent : agents) {
    const AgentMap map = loadBundle(case_dir + "/" + agent);
    const std::string ns = "/" + agent;
    // Our format: the map cloud, then the keyframes (16UC1 depth in mm, as the bundle's PNGs).
    ours.write(ns + "/cloud", next(), cloudToMsg(map.cloud, map.frame_id, t));
    for (const MapKeyframe& kf : map.keyframes) {
      ours.write(ns + "/keyframes", next(), keyframeToMsg(kf, map.camera, map.frame_id, t, true));
    }
    // LSD-SLAM: keyframes with their pre-optimisation poses, then a graph message with the
    // optimised ones (the true poses) and a constraint between consecutive keyframes.
    LsdGraph graph;
    for (std::size_t i = 0; i < map.keyframes.size(); ++i) {
      LsdKeyframe kf = lsdKeyframe(map.keyframes[i], map.camera, static_cast<double>(i));
      graph.poses.emplace_back(kf.id, kf.cam_to_world);
      if (i > 0) graph.constraints.push_back({static_cast<int>(map.keyframes[i - 1].id), static_cast<int>(kf.id), 0.01f});
      kf.cam_to_world = preGraphPose(kf.cam_to_world, i);
      lsd.write(ns + "/lsd_slam/keyframes", next(), lsdKeyframeToMsg(kf));
    }
    lsd.write(ns + "/lsd_slam/graph", next(), lsdGraphToMsg(graph));
    std::cerr << "pcr_pro_make_bags: " << agent << ": " << map.keyframes.size() << " keyframes, "
              << map.cloud.cols() << " cloud points\n";
  }
  ours.close();
  lsd.close();
  return 0;
}

}  // namespace

int main(int argc, char** argv) {
  try {
    return run(argc, argv);
  } catch (const std::exception& e) {
    std::cerr << "pcr_pro_make_bags: " << e.what() << "\n";
    return 2;
  }
}
