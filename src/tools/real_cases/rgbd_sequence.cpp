#include "real_cases/rgbd_sequence.h"

#include <cmath>
#include <cstdint>
#include <cstdio>
#include <filesystem>
#include <fstream>
#include <opencv2/imgcodecs.hpp>
#include <opencv2/imgproc.hpp>
#include <sstream>
#include <utility>

namespace pcr_pro {
namespace real_cases {
namespace {

namespace fs = std::filesystem;

cv::Mat readGrey(const std::string& path) {
  const cv::Mat colour = cv::imread(path, cv::IMREAD_COLOR);
  if (colour.empty()) throw InputError(path + ": cannot read image");
  cv::Mat grey;
  cv::cvtColor(colour, grey, cv::COLOR_BGR2GRAY);
  return grey;
}

// 16-bit depth in millimetres -> CV_32FC1 metres; 0 and 65535 (both "no depth") become 0.
cv::Mat readDepthMm(const std::string& path, const PinholeCamera& camera) {
  const cv::Mat mm = cv::imread(path, cv::IMREAD_UNCHANGED);
  if (mm.empty() || mm.type() != CV_16UC1) throw InputError(path + ": cannot read a 16-bit depth image");
  if (mm.cols != camera.width || mm.rows != camera.height) throw InputError(path + ": not of the camera's size");
  cv::Mat depth(mm.size(), CV_32FC1);
  for (int r = 0; r < mm.rows; ++r) {
    const std::uint16_t* in = mm.ptr<std::uint16_t>(r);
    float* out = depth.ptr<float>(r);
    for (int c = 0; c < mm.cols; ++c)
      out[c] = (in[c] == 0 || in[c] == 65535) ? 0.0f : static_cast<float>(in[c]) / 1000.0f;
  }
  return depth;
}

std::string frameStem(const std::string& dir, long id) {
  char name[64];
  std::snprintf(name, sizeof name, "frame-%06ld", id);
  return (fs::path(dir) / "frames" / name).string();
}

// A 4x4 camera -> world matrix, 16 numbers row by row. The files hold rigid transforms printed to
// about 8 digits, so their rotation blocks are orthonormal only to about 1e-4 (a determinant off
// 1 by that much would read as a scale): the rotation is projected onto the nearest rotation and
// the scale is 1.
Sim3 readPoseMatrix(const std::string& path) {
  std::ifstream in(path);
  Eigen::Matrix4d m;
  for (int i = 0; i < 16; ++i) {
    if (!(in >> m(i / 4, i % 4))) throw InputError(path + ": expected 16 numbers (4x4 camera -> world)");
  }
  if (!m.allFinite()) throw InputError(path + ": non-finite pose");
  const Eigen::Matrix3d r = m.topLeftCorner<3, 3>();
  if (std::abs(r.determinant() - 1.0) > 0.01) throw InputError(path + ": rotation block is not a rotation");
  return Sim3(1.0, projectToRotation(r), m.topRightCorner<3, 1>());
}

PinholeCamera readIntrinsics(const std::string& path, int width, int height) {
  std::ifstream in(path);
  Eigen::Matrix3d k;
  for (int i = 0; i < 9; ++i) {
    if (!(in >> k(i / 3, i % 3))) throw InputError(path + ": expected a 3x3 camera matrix");
  }
  const PinholeCamera camera{k(0, 0), k(1, 1), k(0, 2), k(1, 2), width, height};  // fx fy cx cy width height
  if (!camera.valid()) throw InputError(path + ": invalid camera matrix");
  return camera;
}

// The 7-Scenes colour camera. The data set publishes only the depth camera's intrinsics
// (camera-intrinsics.txt: fx = fy = 585, cx = 320, cy = 240); the Kinect's colour camera is
// another camera with a wider field of view. Measured on these frames with the data's own poses
// (KinectFusion, depth camera), two ways, over 640x480 colour frames:
//  - SIFT matches of 34 frame pairs 20-60 raw frames apart and the cross pairs of the cases
//    (5-75 deg, 0.1-1.6 m; fundamental-matrix RANSAC at 1 px, which does not depend on the
//    intrinsics, keeps the inliers): the Sampson error of the matches under the TRUE relative pose
//    is least at f = 515 px (bootstrap over pairs 5-95 %: 508-521; 519-521 with the principal
//    point free), 2.25 px RMS (truncated at 5 px) against 3.52 px at 585;
//  - photometric: each frame's depth registered to colour with f (registerDepth()), its
//    gradient pixels warped into the other frame of 52 pairs with the true poses: the grey-level
//    difference is least at f = 520 px (bootstrap 512-532), and 7 % larger at 585.
// Both put f at 515-520, not 585 (with the depth camera's 12 % longer focal, relative rotations
// estimated from the colour images came out about 13 % of the angle off). The principal point is
// not pinned down better than about 5 px: the image centre. The extrinsic between the two cameras
// (a baseline of about 2.5 cm and a small unknown rotation) is ignored: moving the colour centre
// 2.5 cm along any axis moves the Sampson minimum by at most 6 px of focal.
constexpr double kSevenScenesColourFocal = 520.0;
constexpr double kSevenScenesColourCx = 319.5, kSevenScenesColourCy = 239.5;

}  // namespace

cv::Mat registerDepth(const cv::Mat& depth, const PinholeCamera& depth_camera, const PinholeCamera& colour_camera) {
  if (!depth_camera.valid() || !colour_camera.valid()) throw InputError("registerDepth: invalid camera");
  if (depth.type() != CV_32FC1 || depth.cols != depth_camera.width || depth.rows != depth_camera.height) {
    throw InputError("registerDepth: depth must be CV_32FC1 of the depth camera's size");
  }
  cv::Mat out(colour_camera.height, colour_camera.width, CV_32FC1, cv::Scalar(0.0f));
  for (int r = 0; r < depth.rows; ++r) {
    for (int c = 0; c < depth.cols; ++c) {
      const float z = depth.at<float>(r, c);
      if (!std::isfinite(z) || !(z > 0.0f)) continue;
      const Eigen::Vector3d p(z * (c - depth_camera.cx) / depth_camera.fx, z * (r - depth_camera.cy) / depth_camera.fy,
                              z);
      double u = 0.0, v = 0.0;
      if (!colour_camera.project(p, &u, &v)) continue;
      const long uc = std::lround(u), vr = std::lround(v);
      if (uc < 0 || vr < 0 || uc >= colour_camera.width || vr >= colour_camera.height) continue;
      float& nearest = out.at<float>(static_cast<int>(vr), static_cast<int>(uc));
      if (nearest == 0.0f || z < nearest) nearest = z;
    }
  }
  return out;
}

RgbdSequence::RgbdSequence(PinholeCamera camera, PinholeCamera depth_camera, std::map<long, Sim3> poses,
                           SequenceFacts facts, Loader loader)
    : camera_(camera),
      depth_camera_(depth_camera),
      poses_(std::move(poses)),
      facts_(std::move(facts)),
      loader_(std::move(loader)) {}

std::vector<long> RgbdSequence::ids() const {
  std::vector<long> out;
  for (const auto& entry : poses_) out.push_back(entry.first);
  return out;
}

const Sim3& RgbdSequence::pose(long id) const {
  const auto it = poses_.find(id);
  if (it == poses_.end()) throw InputError(facts_.data_set + ": no frame " + std::to_string(id));
  return it->second;
}

const RgbdFrame& RgbdSequence::frame(long id) {
  pose(id);  // known id
  auto it = cache_.find(id);
  if (it == cache_.end()) it = cache_.emplace(id, loader_(id)).first;
  return it->second;
}

RgbdSequence openSevenScenes(const std::string& dir) {
  // 7-Scenes frames are 640x480 (SOURCE.txt); the depth camera's intrinsics come from the data
  // set's file, the colour camera's from the measurement above.
  const PinholeCamera depth_camera = readIntrinsics((fs::path(dir) / "camera-intrinsics.txt").string(), 640, 480);
  PinholeCamera camera = depth_camera;
  camera.fx = camera.fy = kSevenScenesColourFocal;
  camera.cx = kSevenScenesColourCx;
  camera.cy = kSevenScenesColourCy;
  std::map<long, Sim3> poses;
  for (const auto& entry : fs::directory_iterator(fs::path(dir) / "frames")) {
    const std::string name = entry.path().filename().string();
    long id = 0;
    char tail[32] = {0};
    if (std::sscanf(name.c_str(), "frame-%ld.%31s", &id, tail) == 2 && std::string(tail) == "pose.txt") {
      poses[id] = readPoseMatrix(entry.path().string());
    }
  }
  if (poses.empty()) throw InputError(dir + "/frames: no frame-NNNNNN.pose.txt");
  SequenceFacts facts;
  facts.data_set = "7scenes_redkitchen";
  // SOURCE.txt: KinectFusion tracking, "about centimetre / sub-degree"; depth not registered to
  // colour, the two cameras about 2.5 cm apart (registerDepth() ignores that baseline and their
  // small relative rotation).
  facts.pose_rotation_deg = 1.0;
  facts.pose_translation_m = 0.01;
  facts.depth_colour_offset_m = 0.025;
  facts.note =
      "7-Scenes poses: KinectFusion tracking on the depth camera (about 1 cm / below 1 deg); colour camera "
      "f = 520 px at (319.5, 239.5), measured on the frames (the data gives only the depth camera's 585 px); "
      "depth registered to colour through both intrinsics, their extrinsic ignored (about 2.5 cm of baseline "
      "and a small unknown rotation)";
  return RgbdSequence(camera, depth_camera, std::move(poses), facts, [dir, camera, depth_camera](long id) {
    RgbdFrame f;
    f.id = id;
    f.grey = readGrey(frameStem(dir, id) + ".color.jpg");
    if (f.grey.cols != camera.width || f.grey.rows != camera.height) {
      throw InputError(frameStem(dir, id) + ".color.jpg: not of the colour camera's size");
    }
    f.depth = registerDepth(readDepthMm(frameStem(dir, id) + ".depth.png", depth_camera), depth_camera, camera);
    return f;
  });
}

RgbdSequence openSlambook2(const std::string& dir) {
  // The intrinsics are not in the data's files: slambook2 ch5/rgbd/joinMap.cpp gives them
  // (quoted in SOURCE.txt), for 640x480 frames.
  const PinholeCamera camera{518.0, 519.0, 325.5, 253.5, 640, 480};  // fx fy cx cy width height
  const std::string pose_path = (fs::path(dir) / "pose.txt").string();
  std::ifstream in(pose_path);
  if (!in) throw InputError(pose_path + ": cannot open");
  std::map<long, Sim3> poses;
  std::string line;
  while (std::getline(in, line)) {
    std::istringstream ls(line);
    double v[7];
    int n = 0;
    while (n < 7 && ls >> v[n]) ++n;
    if (n == 0) continue;
    if (n != 7)
      throw InputError(pose_path + ": line " + std::to_string(poses.size() + 1) + ": expected tx ty tz qx qy qz qw");
    poses[static_cast<long>(poses.size()) + 1] =
        Sim3(1.0, Eigen::Quaterniond(v[6], v[3], v[4], v[5]), Eigen::Vector3d(v[0], v[1], v[2]));
  }
  SequenceFacts facts;
  facts.data_set = "slambook2_ch5_rgbd";
  // SOURCE.txt: pose.txt is approximate, "about 1 deg / a few cm"; depth registered to colour.
  facts.pose_rotation_deg = 1.0;
  facts.pose_translation_m = 0.05;
  facts.depth_colour_offset_m = 0.0;
  facts.note =
      "slambook2 pose.txt: approximate poses of undocumented origin (about 1 deg / a few cm), no motion "
      "capture; depth registered to colour";
  return RgbdSequence(camera, camera, std::move(poses), facts, [dir, camera](long id) {
    RgbdFrame f;
    f.id = id;
    f.grey = readGrey((fs::path(dir) / "color" / (std::to_string(id) + ".png")).string());
    f.depth = readDepthMm((fs::path(dir) / "depth" / (std::to_string(id) + ".pgm")).string(), camera);
    if (f.grey.size() != f.depth.size()) throw InputError(dir + "/color/" + std::to_string(id) + ".png: wrong size");
    return f;
  });
}

}  // namespace real_cases
}  // namespace pcr_pro
