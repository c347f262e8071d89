#include "pcr_pro/io/bundle.h"

#include <yaml-cpp/yaml.h>

#include <cstdint>
#include <filesystem>
#include <fstream>
#include <iterator>
#include <map>
#include <opencv2/imgcodecs.hpp>
#include <opencv2/imgproc.hpp>
#include <utility>
#include <vector>

#include "io/yaml_block.h"
#include "io/yaml_fields.h"
#include "pcr_pro/io/cloud_io.h"
#include "pcr_pro/io/file_errors.h"
#include "pcr_pro/io/plausibility.h"
#include "pcr_pro/io/text_escape.h"

namespace pcr_pro {

// The camera block of a bundle (and of the simulator's configuration). Per-field ranges only:
// the rules that relate fields (focal length >= 1 px, principal point within one image size of
// the image, the pixel limit) are checked by checkIntrinsics() after binding.
template <>
const ParamSchema<PinholeCamera>& paramSchema<PinholeCamera>() {
  using O = PinholeCamera;
  using R = ParamRange;
  static const ParamSchema<O> schema{"camera", {
      {"fx", &O::fx, R::above(0), "px", "focal length along x"},
      {"fy", &O::fy, R::above(0), "px", "focal length along y"},
      {"cx", &O::cx, R::any(), "px", "principal point x (column of the optical axis)"},
      {"cy", &O::cy, R::any(), "px", "principal point y (row of the optical axis)"},
      {"width", &O::width, R::above(0), "px", "image width"},
      {"height", &O::height, R::above(0), "px", "image height"},
  }, ParamMessage::kNode};
  return schema;
}

namespace {

namespace fs = std::filesystem;

using yaml_detail::childKey;
using yaml_detail::elementKey;
using yaml_detail::FieldReader;
using yaml_detail::Fields;
using yaml_detail::oneLine;

YAML::Node loadYamlFile(const std::string& path) {
  std::error_code ec;
  if (!fs::exists(path, ec)) throw InputError(path + ": " + missingFileReason(ec, "file not found"));
  if (!fs::is_regular_file(path, ec)) throw InputError(path + ": not a regular file");
  std::ifstream in(path, std::ios::binary);
  if (!in) throw InputError(path + ": cannot open file (unreadable)");
  const std::string text((std::istreambuf_iterator<char>(in)), std::istreambuf_iterator<char>());
  return yaml_detail::parseYaml(text, path);
}

std::string matDescription(const cv::Mat& m) {
  const int depth = m.depth();
  const char* bits = depth == CV_8U || depth == CV_8S     ? "8-bit"
                     : depth == CV_16U || depth == CV_16S ? "16-bit"
                     : depth == CV_32F                    ? "32-bit float"
                     : depth == CV_64F                    ? "64-bit float"
                                                          : "32-bit";
  return std::string(bits) + " " + std::to_string(m.channels()) + "-channel";
}

void checkSize(int cols, int rows, const PinholeCamera& camera, const std::string& path, const std::string& field) {
  if (cols != camera.width || rows != camera.height) {
    throw InputError(path + ": image is " + std::to_string(cols) + "x" + std::to_string(rows) +
                     ", camera.width x camera.height is " + std::to_string(camera.width) + "x" +
                     std::to_string(camera.height) + " (" + field + ")");
  }
}

/// Reads an image file with the caller's reader (loadBundle()); errors name the file and the
/// bundle field.
cv::Mat readImageFile(const std::string& path, const std::string& field, const PinholeCamera& camera,
                      const ImageFileReader& read) {
  std::error_code ec;
  if (!fs::exists(path, ec)) throw InputError(path + ": " + missingFileReason(ec, "file not found") + " (" + field + ")");
  if (!fs::is_regular_file(path, ec)) throw InputError(path + ": not a regular file (" + field + ")");
  cv::Mat image;
  try {
    const cv::Size expected(camera.width, camera.height);
    image = read ? read(path, expected) : decodeImageFile(path, expected);
  } catch (const InputError& e) {
    throw InputError(std::string(e.what()) + " (" + field + ")");
  } catch (const cv::Exception& e) {
    throw InputError(oneLine(path + ": cannot read image: " + e.what(), 300) + " (" + field + ")");
  }
  if (image.empty()) throw InputError(path + ": cannot read image (" + field + ")");
  return image;
}

// In a JPEG's entropy-coded data a 0xff byte is followed only by 0x00 or a restart marker, so
// the end-of-image marker (ff d9) after the last start-of-scan (ff da) tells a complete file from
// one cut short (bytes after it are allowed: some writers pad).
bool jpegCutShort(const std::vector<unsigned char>& bytes) {
  // Start of the last "ff <second>" at or after `from`, or npos.
  const auto last = [&bytes](unsigned char second, std::size_t from) {
    for (std::size_t end = bytes.size(); end >= from + 2; --end) {
      if (bytes[end - 2] == 0xff && bytes[end - 1] == second) return end - 2;
    }
    return std::string::npos;
  };
  const std::size_t scan = last(0xda, 0);
  return scan == std::string::npos || last(0xd9, scan + 2) == std::string::npos;
}

cv::Mat loadGreyImage(const std::string& path, const std::string& field, const PinholeCamera& camera,
                      const ImageFileReader& read) {
  const cv::Mat raw = readImageFile(path, field, camera, read);
  if (raw.depth() != CV_8U || (raw.channels() != 1 && raw.channels() != 3 && raw.channels() != 4)) {
    throw InputError(path + ": must be an 8-bit grey or colour image, got " + matDescription(raw) + " (" + field + ")");
  }
  checkSize(raw.cols, raw.rows, camera, path, field);
  cv::Mat grey;
  if (raw.channels() == 1) {
    grey = raw;
  } else {
    cv::cvtColor(raw, grey, raw.channels() == 3 ? cv::COLOR_BGR2GRAY : cv::COLOR_BGRA2GRAY);
  }
  return grey;
}

cv::Mat loadDepthImage(const std::string& path, const std::string& field, const PinholeCamera& camera,
                       double depth_scale, const ImageFileReader& read) {
  const cv::Mat raw = readImageFile(path, field, camera, read);
  if (raw.type() != CV_16UC1) {
    throw InputError(path + ": depth image must be 16-bit single-channel, got " + matDescription(raw) + " (" + field +
                     ")");
  }
  checkSize(raw.cols, raw.rows, camera, path, field);
  cv::Mat depth(raw.rows, raw.cols, CV_32FC1);
  for (int r = 0; r < raw.rows; ++r) {
    const auto* in = raw.ptr<std::uint16_t>(r);
    auto* out = depth.ptr<float>(r);
    for (int c = 0; c < raw.cols; ++c) out[c] = static_cast<float>(static_cast<double>(in[c]) / depth_scale);
  }
  return depth;
}

/// What bundle.yaml says about one keyframe, before its files are read.
struct KeyframeSpec {
  long id = 0;
  std::string image;
  std::string depth;  // empty: none
  double depth_scale = 0.0;
  Sim3 pose;
};

Sim3 parseSim3(const FieldReader& reader, const YAML::Node& node, const std::string& field) {
  const Fields f = reader.fields(node, field, {"scale", "rotation", "translation"});
  const double scale = reader.positive(reader.require(f, "scale"), childKey(field, "scale"));
  const Eigen::Quaterniond q = reader.quaternion(reader.require(f, "rotation"), childKey(field, "rotation"));
  const Eigen::Vector3d t = reader.vector3(reader.require(f, "translation"), childKey(field, "translation"));
  return Sim3(scale, q, t);
}

// A focal length below one pixel or a principal point farther than one image size outside the
// image is no camera anyone calibrated: a unit or field mix-up (metres, normalised coordinates,
// cx and width swapped) that would otherwise give a merge without any error. These rules relate
// several fields, so they stay code beside the schema's per-field ranges.
void checkIntrinsics(const FieldReader& reader, const Fields& cam, const PinholeCamera& camera,
                     const InputLimits& limits) {
  if (const auto problem = implausibleIntrinsics(camera)) {
    reader.fail("camera." + problem->first, reader.require(cam, problem->first), problem->second);
  }
  const long long pixels = static_cast<long long>(camera.width) * camera.height;
  if (pixels > limits.max_image_pixels) {
    reader.fail("camera.width", cam.node,
                "camera.width x camera.height = " + std::to_string(pixels) +
                    " px, more than limits.max_image_pixels = " + std::to_string(limits.max_image_pixels));
  }
}

// The camera block binds through the camera's schema: every key required, no other key.
PinholeCamera parseCamera(const FieldReader& reader, const Fields& top, const InputLimits& limits) {
  const ParamSchema<PinholeCamera>& schema = paramSchema<PinholeCamera>();
  config_detail::Block block(reader, reader.require(top, schema.block), schema.block,
                             config_detail::Block::Keys::kRequired);
  std::vector<std::string> keys;
  for (const Param<PinholeCamera>& p : schema.params) keys.push_back(p.key);
  block.allowOnly(keys);
  PinholeCamera camera;
  config_detail::bindParams(schema, &block, &camera);
  checkIntrinsics(reader, block.fields(), camera, limits);
  return camera;
}

/// keyframes[i] of bundle.yaml (`field`); its id must not be in `first_index` (id -> index).
KeyframeSpec parseKeyframeSpec(const FieldReader& reader, const YAML::Node& node, const std::string& field,
                               std::size_t index, std::map<long long, std::size_t>* first_index) {
  const Fields kf = reader.fields(node, field, {"id", "image", "pose", "depth", "depth_scale"});
  KeyframeSpec spec;
  const YAML::Node& id_node = reader.require(kf, "id");
  const long long id = reader.integer(id_node, childKey(field, "id"));
  const auto seen = first_index->find(id);
  if (seen != first_index->end()) {
    reader.fail(childKey(field, "id"), id_node,
                "duplicate keyframe id " + std::to_string(id) + " (also keyframes[" + std::to_string(seen->second) +
                    "].id)");
  }
  first_index->emplace(id, index);
  spec.id = static_cast<long>(id);
  spec.image = reader.text(reader.require(kf, "image"), childKey(field, "image"));

  const std::string pose_field = childKey(field, "pose");
  const Fields pose = reader.fields(reader.require(kf, "pose"), pose_field, {"position", "orientation", "scale"});
  const Eigen::Vector3d position = reader.vector3(reader.require(pose, "position"), childKey(pose_field, "position"));
  const Eigen::Quaterniond q = reader.quaternion(reader.require(pose, "orientation"), childKey(pose_field, "orientation"));
  double scale = 1.0;
  if (const YAML::Node* s = pose.find("scale")) scale = reader.positive(*s, childKey(pose_field, "scale"));
  spec.pose = Sim3(scale, q, position);

  const YAML::Node* depth = kf.find("depth");
  const YAML::Node* depth_scale = kf.find("depth_scale");
  if (depth_scale != nullptr) spec.depth_scale = reader.positive(*depth_scale, childKey(field, "depth_scale"));
  if (depth != nullptr) {
    spec.depth = reader.text(*depth, childKey(field, "depth"));
    if (depth_scale == nullptr) reader.fail(childKey(field, "depth_scale"), kf.node, "required when depth is given");
  }
  return spec;
}

std::vector<KeyframeSpec> parseKeyframeSpecs(const FieldReader& reader, const Fields& top, const InputLimits& limits) {
  const YAML::Node& keyframes = reader.require(top, "keyframes");
  reader.list(keyframes, "keyframes", "keyframes");
  if (keyframes.size() == 0) reader.fail("keyframes", keyframes, "no keyframes (need at least one)");
  if (static_cast<std::int64_t>(keyframes.size()) > limits.max_keyframes) {
    reader.fail("keyframes", keyframes,
                std::to_string(keyframes.size()) + " keyframes, more than limits.max_keyframes = " +
                    std::to_string(limits.max_keyframes));
  }
  std::vector<KeyframeSpec> specs;
  std::map<long long, std::size_t> first_index;
  for (std::size_t i = 0; i < keyframes.size(); ++i) {
    specs.push_back(parseKeyframeSpec(reader, keyframes[i], elementKey("keyframes", i), i, &first_index));
  }
  return specs;
}

/// The keyframes' image and depth files, read once the whole YAML is known to be valid.
std::vector<MapKeyframe> readKeyframeFiles(const fs::path& base, const std::string& yaml_path,
                                           const std::vector<KeyframeSpec>& specs, const PinholeCamera& camera,
                                           const ImageFileReader& read) {
  std::vector<MapKeyframe> keyframes;
  keyframes.reserve(specs.size());
  for (std::size_t i = 0; i < specs.size(); ++i) {
    const KeyframeSpec& spec = specs[i];
    const std::string field = elementKey("keyframes", i);
    MapKeyframe kf;
    kf.id = spec.id;
    kf.pose = spec.pose;
    try {
      kf.image = loadGreyImage((base / spec.image).string(), childKey(field, "image"), camera, read);
      if (!spec.depth.empty()) {
        kf.depth = loadDepthImage((base / spec.depth).string(), childKey(field, "depth"), camera, spec.depth_scale, read);
      }
    } catch (const cv::Exception& e) {
      throw InputError(oneLine(yaml_path + ": " + field + ": image conversion failed: " + e.what(), 400));
    }
    keyframes.push_back(std::move(kf));
  }
  return keyframes;
}

AgentMap readBundle(const std::string& dir, const InputLimits& limits, std::vector<std::string>* warnings,
                    const ImageFileReader& read) {
  std::error_code ec;
  if (!fs::exists(dir, ec)) throw InputError(dir + ": " + missingFileReason(ec, "bundle directory not found"));
  if (!fs::is_directory(dir, ec))
    throw InputError(dir + ": not a directory (a bundle is a directory with bundle.yaml)");
  const fs::path base(dir);
  const std::string yaml_path = (base / "bundle.yaml").string();
  if (!fs::exists(yaml_path, ec))
    throw InputError(yaml_path + ": " + missingFileReason(ec, "file not found") + " (a bundle directory needs bundle.yaml)");
  const YAML::Node root = loadYamlFile(yaml_path);
  const FieldReader reader(yaml_path, warnings);

  AgentMap map;
  std::string cloud_file;
  std::vector<KeyframeSpec> specs;
  try {
    if (root.IsNull()) reader.fail("", root, "empty document (expected a map with cloud, camera, keyframes)");
    const Fields top = reader.fields(root, "", {"frame_id", "cloud", "camera", "keyframes"});
    if (const YAML::Node* frame = top.find("frame_id")) map.frame_id = reader.text(*frame, "frame_id");
    cloud_file = reader.text(reader.require(top, "cloud"), "cloud");
    map.camera = parseCamera(reader, top, limits);
    specs = parseKeyframeSpecs(reader, top, limits);
  } catch (const YAML::Exception& e) {
    // Safety net: yaml-cpp errors not caught by the checks above still name the file.
    throw InputError(oneLine(yaml_path + ": " + e.what(), 400));
  }

  // Files, after the whole YAML is known to be valid.
  const std::string cloud_path = (base / cloud_file).string();
  if (!fs::exists(cloud_path, ec)) throw InputError(cloud_path + ": " + missingFileReason(ec, "file not found") + " (cloud)");
  try {
    map.cloud = readCloud(cloud_path, limits);
  } catch (const InputError& e) {
    throw InputError(std::string(e.what()) + " (cloud)");
  }
  map.keyframes = readKeyframeFiles(base, yaml_path, specs, map.camera, read);
  return map;
}

BundleTruth readTruth(const std::string& path) {
  const YAML::Node root = loadYamlFile(path);
  const FieldReader reader(path);
  BundleTruth truth;
  try {
    const Fields top = reader.fields(root, "");
    if (const YAML::Node* n = top.find("target")) truth.target_agent = reader.text(*n, "target");
    if (const YAML::Node* n = top.find("source")) truth.source_agent = reader.text(*n, "source");
    if (const YAML::Node* n = top.find("overlap")) truth.overlap = reader.boolean(*n, "overlap");
    truth.target_source = parseSim3(reader, reader.require(top, "S_target_source"), "S_target_source");
    truth.world_to_target = parseSim3(reader, reader.require(top, "world_to_target"), "world_to_target");
    truth.world_to_source = parseSim3(reader, reader.require(top, "world_to_source"), "world_to_source");
    if (const YAML::Node* poses = top.find("world_poses")) {
      const Fields all = reader.fields(*poses, "world_poses");
      for (const yaml_detail::Entry& entry : all.entries) {
        const std::string field = childKey("world_poses", printable(entry.key));
        const long id = static_cast<long>(reader.integer(entry.key_node, field));
        const Fields pose = reader.fields(entry.value, field, {"position", "orientation"});
        const Eigen::Vector3d position = reader.vector3(reader.require(pose, "position"), childKey(field, "position"));
        const Eigen::Quaterniond q =
            reader.quaternion(reader.require(pose, "orientation"), childKey(field, "orientation"));
        truth.world_poses[id] = Sim3(1.0, q, position);
      }
    }
  } catch (const YAML::Exception& e) {
    throw InputError(oneLine(path + ": " + e.what(), 400));
  }
  return truth;
}

}  // namespace

cv::Mat decodeImageFile(const std::string& path, const cv::Size& /*expected_size*/) {
  std::ifstream in(path, std::ios::binary);
  if (!in) throw InputError(path + ": cannot open file (unreadable)");
  const std::vector<unsigned char> bytes((std::istreambuf_iterator<char>(in)), std::istreambuf_iterator<char>());
  // libjpeg decodes a JPEG cut short with a warning on stderr only: refuse it here instead.
  const bool jpeg = bytes.size() >= 3 && bytes[0] == 0xff && bytes[1] == 0xd8 && bytes[2] == 0xff;
  if (jpeg && jpegCutShort(bytes)) throw InputError(path + ": cannot read image: truncated JPEG");
  cv::Mat image = cv::imdecode(bytes, cv::IMREAD_UNCHANGED);
  if (image.empty()) throw InputError(path + ": cannot read image");
  return image;
}

AgentMap loadBundle(const std::string& dir, const InputLimits& limits, std::vector<std::string>* warnings,
                    const ImageFileReader& read_image) {
  try {
    return readBundle(dir, limits, warnings, read_image);
  } catch (const InputError& e) {
    // File names and YAML text end up in messages: keep them on one line.
    throw InputError(oneLine(e.what(), 1000));
  }
}

BundleTruth loadBundleTruth(const std::string& path) {
  try {
    return readTruth(path);
  } catch (const InputError& e) {
    throw InputError(oneLine(e.what(), 1000));
  }
}

}  // namespace pcr_pro
