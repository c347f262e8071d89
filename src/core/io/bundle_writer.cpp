#include "pcr_pro/io/bundle_writer.h"

#include <cmath>
#include <cstdint>
#include <filesystem>
#include <fstream>
#include <opencv2/imgcodecs.hpp>
#include <set>
#include <sstream>

#include "pcr_pro/io/cloud_io.h"

namespace pcr_pro {
namespace {

namespace fs = std::filesystem;

std::string num(double v) { return yamlNumber(v); }

std::string vec(std::initializer_list<double> values) {
  std::string out = "[";
  bool first = true;
  for (double v : values) {
    out += (first ? "" : ", ") + num(v);
    first = false;
  }
  return out + "]";
}

void writeImage(const std::string& path, const cv::Mat& image) {
  bool ok = false;
  try {
    ok = cv::imwrite(path, image);
  } catch (const cv::Exception&) {
    ok = false;
  }
  if (!ok) throw InputError(path + ": cannot write image");
}

// 16-bit depth image of a CV_32FC1 depth [camera units]; returns the depth scale used.
cv::Mat depthPng(const cv::Mat& depth, double requested_scale, double* scale_used) {
  double scale = requested_scale;
  if (!(scale > 0.0)) {
    double max_depth = 0.0;
    for (int r = 0; r < depth.rows; ++r) {
      const float* row = depth.ptr<float>(r);
      for (int c = 0; c < depth.cols; ++c) {
        if (std::isfinite(row[c]) && row[c] > max_depth) max_depth = row[c];
      }
    }
    scale = max_depth > 0.0 ? 60000.0 / max_depth : 1000.0;
  }
  cv::Mat out(depth.size(), CV_16UC1, cv::Scalar(0));
  for (int r = 0; r < depth.rows; ++r) {
    const float* in = depth.ptr<float>(r);
    std::uint16_t* o = out.ptr<std::uint16_t>(r);
    for (int c = 0; c < depth.cols; ++c) {
      const double v = std::round(static_cast<double>(in[c]) * scale);
      o[c] = (std::isfinite(v) && v > 0.0 && v <= 65535.0) ? static_cast<std::uint16_t>(v) : 0;
    }
  }
  *scale_used = scale;
  return out;
}

}  // namespace

std::string sim3FlowYaml(const Sim3& s) {
  const Eigen::Quaterniond q = s.quaternion();
  const Eigen::Vector3d& t = s.translation();
  return "{scale: " + num(s.scale()) + ", rotation: " + vec({q.x(), q.y(), q.z(), q.w()}) +
         ", translation: " + vec({t.x(), t.y(), t.z()}) + "}";
}

void writeBundle(const std::string& dir, const AgentMap& map, const BundleWriteOptions& options) {
  const std::string yaml_path = (fs::path(dir) / "bundle.yaml").string();
  if (!map.camera.valid()) throw InputError(yaml_path + ": camera: invalid intrinsics or image size");
  std::error_code ec;
  fs::create_directories(fs::path(dir) / "keyframes", ec);
  if (ec) throw InputError(dir + ": cannot create directory (" + ec.message() + ")");

  std::ostringstream y;
  if (!options.comment.empty()) y << "# " << options.comment << "\n";
  y << "frame_id: " << map.frame_id << "\n"
    << "cloud: map.pcd\n"
    << "camera:\n"
    << "  fx: " << num(map.camera.fx) << "\n  fy: " << num(map.camera.fy) << "\n"
    << "  cx: " << num(map.camera.cx) << "\n  cy: " << num(map.camera.cy) << "\n"
    << "  width: " << map.camera.width << "\n  height: " << map.camera.height << "\n"
    << "keyframes:\n";
  std::set<long> ids;
  for (std::size_t i = 0; i < map.keyframes.size(); ++i) {
    const MapKeyframe& kf = map.keyframes[i];
    const std::string field = "keyframes[" + std::to_string(i) + "]";
    if (!ids.insert(kf.id).second) throw InputError(yaml_path + ": " + field + ".id: duplicate id " + std::to_string(kf.id));
    if (kf.image.empty() || kf.image.type() != CV_8UC1 || kf.image.cols != map.camera.width ||
        kf.image.rows != map.camera.height) {
      throw InputError(yaml_path + ": " + field + ".image: must be 8-bit grey of the camera's size");
    }
    if (!(kf.pose.scale() > 0.0) || !kf.pose.matrix().allFinite()) {
      throw InputError(yaml_path + ": " + field + ".pose: not a finite similarity with scale > 0");
    }
    const std::string name = std::to_string(kf.id);
    writeImage((fs::path(dir) / "keyframes" / (name + ".png")).string(), kf.image);
    const Eigen::Quaterniond q = kf.pose.quaternion();
    const Eigen::Vector3d& t = kf.pose.translation();
    y << "  - id: " << kf.id << "\n"
      << "    image: keyframes/" << name << ".png\n"
      << "    pose:\n"
      << "      position: " << vec({t.x(), t.y(), t.z()}) << "\n"
      << "      orientation: " << vec({q.x(), q.y(), q.z(), q.w()}) << "\n"
      << "      scale: " << num(kf.pose.scale()) << "\n";
    if (options.write_depth && !kf.depth.empty()) {
      if (kf.depth.type() != CV_32FC1 || kf.depth.size() != kf.image.size()) {
        throw InputError(yaml_path + ": " + field + ".depth: must be CV_32FC1 of the image's size");
      }
      double scale_used = 0.0;
      const cv::Mat png = depthPng(kf.depth, options.depth_scale, &scale_used);
      writeImage((fs::path(dir) / "keyframes" / (name + "_depth.png")).string(), png);
      y << "    depth: keyframes/" << name << "_depth.png\n"
        << "    depth_scale: " << num(scale_used) << "\n";
    }
  }
  writePcd((fs::path(dir) / "map.pcd").string(), map.cloud);
  std::ofstream out(yaml_path);
  out << y.str();
  if (!out) throw InputError(yaml_path + ": cannot write file");
}

void writeBundleTruth(const std::string& path, const BundleTruth& truth, const std::string& comment,
                      const std::string& extra_yaml) {
  std::ostringstream y;
  std::istringstream lines(comment);
  for (std::string line; std::getline(lines, line);) y << "# " << line << "\n";
  y << "# Similarities map p -> scale * R(rotation) * p + translation; rotation = quaternion x y z w.\n"
    << "target: " << truth.target_agent << "\n"
    << "source: " << truth.source_agent << "\n"
    << "overlap: " << (truth.overlap ? "true" : "false") << "\n"
    << "S_target_source: " << sim3FlowYaml(truth.target_source) << "\n"
    << "world_to_target: " << sim3FlowYaml(truth.world_to_target) << "\n"
    << "world_to_source: " << sim3FlowYaml(truth.world_to_source) << "\n";
  if (!truth.world_poses.empty()) {
    y << "world_poses:  # camera -> world of every keyframe, by id [m]\n";
    for (const auto& [id, pose] : truth.world_poses) {
      const Eigen::Quaterniond q = pose.quaternion();
      const Eigen::Vector3d& t = pose.translation();
      y << "  " << id << ": {position: " << vec({t.x(), t.y(), t.z()})
        << ", orientation: " << vec({q.x(), q.y(), q.z(), q.w()}) << "}\n";
    }
  }
  y << extra_yaml;
  std::ofstream out(path);
  out << y.str();
  if (!out) throw InputError(path + ": cannot write file");
}

std::string yamlNumber(double v) {
  std::ostringstream s;
  s.precision(12);
  s << v;
  return s.str();
}

}  // namespace pcr_pro
