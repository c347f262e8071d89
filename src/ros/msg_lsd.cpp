// LSD-SLAM keyframe and graph messages <-> core types (see msg_conversion.h).
#include "pcr_pro/ros/msg_conversion.h"

#include <algorithm>
#include <cstring>
#include <map>

#include "msg_checks.h"

namespace pcr_pro {
namespace ros_bridge {

using namespace detail;

// --- LSD-SLAM ---------------------------------------------------------------------------------

namespace {
constexpr std::size_t kLsdPointBytes = 12;  // float idepth, float idepth_var, uchar color[4]
constexpr std::size_t kLsdFramePoseBytes = 32;  // int32 id, float camToWorld[7]
constexpr std::size_t kLsdConstraintBytes = 12;  // int32 from, int32 to, float err
}  // namespace

Sim3 sim3FromLsd(const float* v) {
  for (int i = 0; i < 7; ++i) {
    if (!std::isfinite(v[i])) fail("camToWorld", "element " + str(i) + " is not finite");
  }
  const Eigen::Quaterniond q(v[3], v[0], v[1], v[2]);
  const double s = q.norm();
  if (!(s > 1e-9)) fail("camToWorld", "degenerate similarity: quaternion part (scale) is zero");
  checkScale(s, "camToWorld");
  checkTranslation(v[4], v[5], v[6], "camToWorld");
  return Sim3(s, q.normalized(), Eigen::Vector3d(v[4], v[5], v[6]));
}

std::array<float, 7> sim3ToLsd(const Sim3& sim3) {
  const Eigen::Quaterniond q = sim3.quaternion().normalized();
  const double s = sim3.scale();
  return {static_cast<float>(s * q.x()), static_cast<float>(s * q.y()), static_cast<float>(s * q.z()),
          static_cast<float>(s * q.w()), static_cast<float>(sim3.translation().x()),
          static_cast<float>(sim3.translation().y()), static_cast<float>(sim3.translation().z())};
}

LsdKeyframe lsdKeyframeFromMsg(const lsd_slam_viewer::keyframeMsg& msg) {
  LsdKeyframe kf;
  kf.id = msg.id;
  kf.time = msg.time;
  if (msg.width == 0 || msg.height == 0 || msg.width > kMaxImageSide || msg.height > kMaxImageSide) {
    fail("width/height", "image size must be > 0 and <= " + str(kMaxImageSide) + " a side, got " + str(msg.width) +
                             "x" + str(msg.height));
  }
  kf.camera.fx = msg.fx;
  kf.camera.fy = msg.fy;
  kf.camera.cx = msg.cx;
  kf.camera.cy = msg.cy;
  kf.camera.width = static_cast<int>(msg.width);
  kf.camera.height = static_cast<int>(msg.height);
  if (!kf.camera.valid() || !std::isfinite(msg.cx) || !std::isfinite(msg.cy)) {
    fail("fx/fy/cx/cy", "invalid intrinsics (fx " + str(msg.fx) + ", fy " + str(msg.fy) + ", cx " + str(msg.cx) +
                            ", cy " + str(msg.cy) + ")");
  }
  const std::size_t n = static_cast<std::size_t>(msg.width) * msg.height;
  if (msg.pointcloud.size() != n * kLsdPointBytes) {
    fail("pointcloud", "size " + str(msg.pointcloud.size()) + " != width * height * 12 = " + str(n * kLsdPointBytes) +
                           (msg.pointcloud.empty() ? " (a keyframe without depth)" : ""));
  }
  kf.cam_to_world = sim3FromLsd(msg.camToWorld.data());
  const int rows = static_cast<int>(msg.height), cols = static_cast<int>(msg.width);
  kf.idepth.create(rows, cols, CV_32FC1);
  kf.idepth_var.create(rows, cols, CV_32FC1);
  kf.image.create(rows, cols, CV_8UC1);
  const std::uint8_t* p = msg.pointcloud.data();
  for (int r = 0; r < rows; ++r) {
    float* id_row = kf.idepth.ptr<float>(r);
    float* var_row = kf.idepth_var.ptr<float>(r);
    std::uint8_t* img_row = kf.image.ptr<std::uint8_t>(r);
    for (int c = 0; c < cols; ++c, p += kLsdPointBytes) {
      std::memcpy(&id_row[c], p, 4);
      std::memcpy(&var_row[c], p + 4, 4);
      img_row[c] = p[8];
    }
  }
  return kf;
}

lsd_slam_viewer::keyframeMsg lsdKeyframeToMsg(const LsdKeyframe& kf) {
  lsd_slam_viewer::keyframeMsg msg;
  msg.id = static_cast<std::int32_t>(kf.id);
  msg.time = kf.time;
  msg.isKeyframe = true;
  const std::array<float, 7> c = sim3ToLsd(kf.cam_to_world);
  std::copy(c.begin(), c.end(), msg.camToWorld.begin());
  msg.fx = static_cast<float>(kf.camera.fx);
  msg.fy = static_cast<float>(kf.camera.fy);
  msg.cx = static_cast<float>(kf.camera.cx);
  msg.cy = static_cast<float>(kf.camera.cy);
  msg.width = static_cast<std::uint32_t>(kf.idepth.cols);
  msg.height = static_cast<std::uint32_t>(kf.idepth.rows);
  msg.pointcloud.resize(static_cast<std::size_t>(msg.width) * msg.height * kLsdPointBytes);
  std::uint8_t* p = msg.pointcloud.data();
  for (int r = 0; r < kf.idepth.rows; ++r) {
    for (int c2 = 0; c2 < kf.idepth.cols; ++c2, p += kLsdPointBytes) {
      const float idepth = kf.idepth.at<float>(r, c2);
      const float var = kf.idepth_var.at<float>(r, c2);
      const std::uint8_t grey = kf.image.empty() ? 0 : kf.image.at<std::uint8_t>(r, c2);
      std::memcpy(p, &idepth, 4);
      std::memcpy(p + 4, &var, 4);
      p[8] = p[9] = p[10] = p[11] = grey;
    }
  }
  return msg;
}

LsdGraph lsdGraphFromMsg(const lsd_slam_viewer::keyframeGraphMsg& msg) {
  if (msg.frameData.size() != static_cast<std::size_t>(msg.numFrames) * kLsdFramePoseBytes) {
    fail("frameData", "size " + str(msg.frameData.size()) + " != numFrames * 32 = " + str(msg.numFrames) + " * 32");
  }
  if (msg.constraintsData.size() != static_cast<std::size_t>(msg.numConstraints) * kLsdConstraintBytes) {
    fail("constraintsData",
         "size " + str(msg.constraintsData.size()) + " != numConstraints * 12 = " + str(msg.numConstraints) + " * 12");
  }
  LsdGraph graph;
  std::map<std::int32_t, std::uint32_t> first_of;  // keyframe id -> its first frameData entry
  for (std::uint32_t i = 0; i < msg.numFrames; ++i) {
    const std::uint8_t* p = &msg.frameData[i * kLsdFramePoseBytes];
    std::int32_t id;
    float v[7];
    std::memcpy(&id, p, 4);
    std::memcpy(v, p + 4, 28);
    // Two poses for one keyframe: which one holds is undefined, so the message is refused.
    const auto [it, fresh] = first_of.emplace(id, i);
    if (!fresh) {
      fail("frameData[" + str(i) + "]", "duplicate keyframe id " + str(id) + " (also frameData[" + str(it->second) + "])");
    }
    try {
      graph.poses.emplace_back(id, sim3FromLsd(v));
    } catch (const InputError& e) {
      fail("frameData[" + str(i) + "] (keyframe " + str(id) + ")", e.what());
    }
  }
  for (std::uint32_t i = 0; i < msg.numConstraints; ++i) {
    const std::uint8_t* p = &msg.constraintsData[i * kLsdConstraintBytes];
    LsdConstraint c;
    std::int32_t from, to;
    std::memcpy(&from, p, 4);
    std::memcpy(&to, p + 4, 4);
    std::memcpy(&c.error, p + 8, 4);
    c.from = from;
    c.to = to;
    graph.constraints.push_back(c);
  }
  return graph;
}

lsd_slam_viewer::keyframeGraphMsg lsdGraphToMsg(const LsdGraph& graph) {
  lsd_slam_viewer::keyframeGraphMsg msg;
  msg.numFrames = static_cast<std::uint32_t>(graph.poses.size());
  msg.frameData.resize(graph.poses.size() * kLsdFramePoseBytes);
  for (std::size_t i = 0; i < graph.poses.size(); ++i) {
    const std::int32_t id = static_cast<std::int32_t>(graph.poses[i].first);
    const std::array<float, 7> v = sim3ToLsd(graph.poses[i].second);
    std::memcpy(&msg.frameData[i * kLsdFramePoseBytes], &id, 4);
    std::memcpy(&msg.frameData[i * kLsdFramePoseBytes + 4], v.data(), 28);
  }
  msg.numConstraints = static_cast<std::uint32_t>(graph.constraints.size());
  msg.constraintsData.resize(graph.constraints.size() * kLsdConstraintBytes);
  for (std::size_t i = 0; i < graph.constraints.size(); ++i) {
    const std::int32_t from = graph.constraints[i].from, to = graph.constraints[i].to;
    std::memcpy(&msg.constraintsData[i * kLsdConstraintBytes], &from, 4);
    std::memcpy(&msg.constraintsData[i * kLsdConstraintBytes + 4], &to, 4);
    std::memcpy(&msg.constraintsData[i * kLsdConstraintBytes + 8], &graph.constraints[i].error, 4);
  }
  return msg;
}

}  // namespace ros_bridge
}  // namespace pcr_pro
