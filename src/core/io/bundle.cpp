#include "pcr_pro/io/bundle.h"

#include <yaml-cpp/yaml.h>

#include <algorithm>
#include <cctype>
#include <climits>
#include <cmath>
#include <cstdint>
#include <cstdio>
#include <filesystem>
#include <fstream>
#include <initializer_list>
#include <iterator>
#include <map>
#include <opencv2/imgcodecs.hpp>
#include <opencv2/imgproc.hpp>
#include <sstream>
#include <utility>
#include <vector>

#include "pcr_pro/io/cloud_io.h"
#include "pcr_pro/io/file_errors.h"
#include "pcr_pro/io/plausibility.h"
#include "pcr_pro/io/text_escape.h"

namespace pcr_pro {
namespace {

namespace fs = std::filesystem;

// Keeps a message on one line and bounded, whatever the file holds.
std::string oneLine(const std::string& text, std::size_t max_length = 200) {
  std::string out;
  for (char c : text) {
    if (out.size() >= max_length) {
      out += "...";
      break;
    }
    out += (static_cast<unsigned char>(c) < 0x20 || c == 0x7f) ? ' ' : c;
  }
  return out;
}

std::string describe(const YAML::Node& node) {
  switch (node.Type()) {
    case YAML::NodeType::Null:
      return "null";
    case YAML::NodeType::Scalar:
      return "'" + printable(node.Scalar(), 60) + "'";
    case YAML::NodeType::Sequence:
      return "a list";
    case YAML::NodeType::Map:
      return "a map";
    case YAML::NodeType::Undefined:
      break;
  }
  return "nothing";
}

std::string numberText(double value) {
  std::ostringstream ss;
  ss << value;
  return ss.str();
}

std::string child(const std::string& parent, const std::string& key) {
  return parent.empty() ? key : parent + "." + key;
}

std::string element(const std::string& parent, std::size_t index) { return parent + "[" + std::to_string(index) + "]"; }

bool isQuoted(const YAML::Node& node) {
  // yaml-cpp tags quoted scalars "!" and explicit strings with the core str tag.
  return node.Tag() == "!" || node.Tag() == "tag:yaml.org,2002:str";
}

/// The entries of one YAML map, checked for duplicate and unknown keys.
struct Fields {
  std::string path;  // field path of the map itself ("" for the document root)
  YAML::Node node;
  std::vector<std::pair<std::string, YAML::Node>> entries;

  const YAML::Node* find(const std::string& key) const {
    for (const auto& entry : entries) {
      if (entry.first == key) return &entry.second;
    }
    return nullptr;
  }
};

/// Validating accessors that turn every defect into an InputError naming file and field.
class FieldReader {
 public:
  explicit FieldReader(std::string file, std::vector<std::string>* warnings = nullptr)
      : file_(std::move(file)), warnings_(warnings) {}

  const std::string& file() const { return file_; }

  [[noreturn]] void fail(const std::string& field, const YAML::Node& at, const std::string& problem) const {
    std::string message = file_ + ": ";
    if (!field.empty()) message += field + ": ";
    message += problem;
    throw InputError(oneLine(message + lineOf(at), 400));
  }

  /// A warning "<file>: <text> (line N)" for the caller, when it asked for warnings.
  void warn(const YAML::Node& at, const std::string& text) const {
    if (warnings_ && !text.empty()) warnings_->push_back(oneLine(file_ + ": " + text + lineOf(at), 400));
  }

  /**
   * Checks that `node` is a map with plain, unique keys; with `allowed` non-empty, every key must
   * be one of them.
   */
  Fields fields(const YAML::Node& node, const std::string& field, std::initializer_list<const char*> allowed) const {
    if (!node.IsMap()) {
      fail(field, node, std::string(field.empty() ? "top level" : "value") + " must be a map, got " + describe(node));
    }
    Fields out;
    out.path = field;
    out.node = node;
    for (auto it = node.begin(); it != node.end(); ++it) {
      if (!it->first.IsScalar()) fail(field, it->first, "keys must be plain strings, got " + describe(it->first));
      const std::string key = it->first.Scalar();
      if (out.find(key) != nullptr) fail(child(field, key), it->first, "duplicate key");
      if (allowed.size() > 0) {
        bool known = false;
        std::string list;
        for (const char* name : allowed) {
          known = known || key == name;
          list += (list.empty() ? "" : ", ") + std::string(name);
        }
        if (!known) fail(child(field, key), it->first, "unknown key (allowed: " + list + ")");
      }
      out.entries.emplace_back(key, it->second);
    }
    return out;
  }

  const YAML::Node& require(const Fields& map, const std::string& key) const {
    const YAML::Node* value = map.find(key);
    if (value == nullptr) fail(child(map.path, key), map.node, "missing (required key)");
    return *value;
  }

  double number(const YAML::Node& node, const std::string& field) const {
    if (!node.IsScalar()) fail(field, node, "must be a number, got " + describe(node));
    if (isQuoted(node)) fail(field, node, "must be a number, got the string " + describe(node));
    double value = 0.0;
    if (!YAML::convert<double>::decode(node, value)) fail(field, node, "must be a number, got " + describe(node));
    if (!std::isfinite(value)) fail(field, node, "must be finite, got " + describe(node));
    return value;
  }

  double positive(const YAML::Node& node, const std::string& field) const {
    const double value = number(node, field);
    if (!(value > 0.0)) fail(field, node, "must be > 0, got " + numberText(value));
    return value;
  }

  long long integer(const YAML::Node& node, const std::string& field) const {
    if (!node.IsScalar()) fail(field, node, "must be an integer, got " + describe(node));
    if (isQuoted(node)) fail(field, node, "must be an integer, got the string " + describe(node));
    long long value = 0;
    if (!YAML::convert<long long>::decode(node, value)) {
      fail(field, node, "must be an integer, got " + describe(node));
    }
    return value;
  }

  int positiveInt(const YAML::Node& node, const std::string& field) const {
    const long long value = integer(node, field);
    if (value <= 0) fail(field, node, "must be > 0, got " + std::to_string(value));
    if (value > INT_MAX) fail(field, node, "is too large (" + std::to_string(value) + ")");
    return static_cast<int>(value);
  }

  std::string text(const YAML::Node& node, const std::string& field) const {
    if (!node.IsScalar()) fail(field, node, "must be a string, got " + describe(node));
    if (node.Scalar().empty()) fail(field, node, "must not be empty");
    return node.Scalar();
  }

  bool boolean(const YAML::Node& node, const std::string& field) const {
    bool value = false;
    if (!node.IsScalar() || !YAML::convert<bool>::decode(node, value)) {
      fail(field, node, "must be true or false, got " + describe(node));
    }
    return value;
  }

  std::vector<double> numbers(const YAML::Node& node, const std::string& field, std::size_t size) const {
    const std::string expected = "must be a list of " + std::to_string(size) + " numbers";
    if (!node.IsSequence()) fail(field, node, expected + ", got " + describe(node));
    if (node.size() != size) fail(field, node, expected + ", got " + std::to_string(node.size()));
    std::vector<double> values;
    for (std::size_t i = 0; i < size; ++i) values.push_back(number(node[i], element(field, i)));
    return values;
  }

  Eigen::Quaterniond quaternion(const YAML::Node& node, const std::string& field) const {
    const std::vector<double> v = numbers(node, field, 4);
    Eigen::Quaterniond q(v[3], v[0], v[1], v[2]);  // stored as x y z w
    if (!(q.norm() >= 1e-12)) fail(field, node, "zero quaternion (norm < 1e-12)");
    warn(node, quaternionNormWarning(q.norm(), field));
    q.normalize();
    return q;
  }

  Eigen::Vector3d vector3(const YAML::Node& node, const std::string& field) const {
    const std::vector<double> v = numbers(node, field, 3);
    return Eigen::Vector3d(v[0], v[1], v[2]);
  }

 private:
  static std::string lineOf(const YAML::Node& at) {
    const YAML::Mark mark = at.Mark();
    return mark.line >= 0 ? " (line " + std::to_string(mark.line + 1) + ")" : std::string();
  }

  std::string file_;
  std::vector<std::string>* warnings_ = nullptr;
};

YAML::Node loadYamlFile(const std::string& path) {
  std::error_code ec;
  if (!fs::exists(path, ec)) throw InputError(path + ": " + missingFileReason(ec, "file not found"));
  if (!fs::is_regular_file(path, ec)) throw InputError(path + ": not a regular file");
  try {
    return YAML::LoadFile(path);
  } catch (const YAML::ParserException& e) {
    throw InputError(oneLine(path + ": YAML syntax error at line " + std::to_string(e.mark.line + 1) + ", column " +
                                 std::to_string(e.mark.column + 1) + ": " + e.msg,
                             400));
  } catch (const YAML::BadFile&) {
    throw InputError(path + ": cannot open file (unreadable)");
  } catch (const YAML::Exception& e) {
    throw InputError(oneLine(path + ": cannot parse YAML: " + e.what(), 400));
  }
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
  const double scale = reader.positive(reader.require(f, "scale"), child(field, "scale"));
  const Eigen::Quaterniond q = reader.quaternion(reader.require(f, "rotation"), child(field, "rotation"));
  const Eigen::Vector3d t = reader.vector3(reader.require(f, "translation"), child(field, "translation"));
  return Sim3(scale, q, t);
}

// A focal length below one pixel or a principal point farther than one image size outside the
// image is no camera anyone calibrated: a unit or field mix-up (metres, normalised coordinates,
// cx and width swapped) that would otherwise give a merge without any error.
void checkIntrinsics(const FieldReader& reader, const Fields& cam, const PinholeCamera& camera) {
  if (const auto problem = implausibleIntrinsics(camera)) {
    reader.fail("camera." + problem->first, reader.require(cam, problem->first), problem->second);
  }
}

PinholeCamera parseCamera(const FieldReader& reader, const Fields& top, const InputLimits& limits) {
  const Fields cam = reader.fields(reader.require(top, "camera"), "camera", {"fx", "fy", "cx", "cy", "width", "height"});
  PinholeCamera camera;
  camera.fx = reader.positive(reader.require(cam, "fx"), "camera.fx");
  camera.fy = reader.positive(reader.require(cam, "fy"), "camera.fy");
  camera.cx = reader.number(reader.require(cam, "cx"), "camera.cx");
  camera.cy = reader.number(reader.require(cam, "cy"), "camera.cy");
  camera.width = reader.positiveInt(reader.require(cam, "width"), "camera.width");
  camera.height = reader.positiveInt(reader.require(cam, "height"), "camera.height");
  checkIntrinsics(reader, cam, camera);
  const long long pixels = static_cast<long long>(camera.width) * camera.height;
  if (pixels > limits.max_image_pixels) {
    reader.fail("camera.width", cam.node,
                "camera.width x camera.height = " + std::to_string(pixels) +
                    " px, more than limits.max_image_pixels = " + std::to_string(limits.max_image_pixels));
  }
  return camera;
}

/// keyframes[i] of bundle.yaml (`field`); its id must not be in `first_index` (id -> index).
KeyframeSpec parseKeyframeSpec(const FieldReader& reader, const YAML::Node& node, const std::string& field,
                               std::size_t index, std::map<long long, std::size_t>* first_index) {
  const Fields kf = reader.fields(node, field, {"id", "image", "pose", "depth", "depth_scale"});
  KeyframeSpec spec;
  const YAML::Node& id_node = reader.require(kf, "id");
  const long long id = reader.integer(id_node, child(field, "id"));
  const auto seen = first_index->find(id);
  if (seen != first_index->end()) {
    reader.fail(child(field, "id"), id_node,
                "duplicate keyframe id " + std::to_string(id) + " (also keyframes[" + std::to_string(seen->second) +
                    "].id)");
  }
  first_index->emplace(id, index);
  spec.id = static_cast<long>(id);
  spec.image = reader.text(reader.require(kf, "image"), child(field, "image"));

  const std::string pose_field = child(field, "pose");
  const Fields pose = reader.fields(reader.require(kf, "pose"), pose_field, {"position", "orientation", "scale"});
  const Eigen::Vector3d position = reader.vector3(reader.require(pose, "position"), child(pose_field, "position"));
  const Eigen::Quaterniond q = reader.quaternion(reader.require(pose, "orientation"), child(pose_field, "orientation"));
  double scale = 1.0;
  if (const YAML::Node* s = pose.find("scale")) scale = reader.positive(*s, child(pose_field, "scale"));
  spec.pose = Sim3(scale, q, position);

  const YAML::Node* depth = kf.find("depth");
  const YAML::Node* depth_scale = kf.find("depth_scale");
  if (depth_scale != nullptr) spec.depth_scale = reader.positive(*depth_scale, child(field, "depth_scale"));
  if (depth != nullptr) {
    spec.depth = reader.text(*depth, child(field, "depth"));
    if (depth_scale == nullptr) reader.fail(child(field, "depth_scale"), kf.node, "required when depth is given");
  }
  return spec;
}

std::vector<KeyframeSpec> parseKeyframeSpecs(const FieldReader& reader, const Fields& top, const InputLimits& limits) {
  const YAML::Node& keyframes = reader.require(top, "keyframes");
  if (!keyframes.IsSequence()) {
    reader.fail("keyframes", keyframes, "must be a list of keyframes, got " + describe(keyframes));
  }
  if (keyframes.size() == 0) reader.fail("keyframes", keyframes, "no keyframes (need at least one)");
  if (static_cast<std::int64_t>(keyframes.size()) > limits.max_keyframes) {
    reader.fail("keyframes", keyframes,
                std::to_string(keyframes.size()) + " keyframes, more than limits.max_keyframes = " +
                    std::to_string(limits.max_keyframes));
  }
  std::vector<KeyframeSpec> specs;
  std::map<long long, std::size_t> first_index;
  for (std::size_t i = 0; i < keyframes.size(); ++i) {
    specs.push_back(parseKeyframeSpec(reader, keyframes[i], element("keyframes", i), i, &first_index));
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
    const std::string field = element("keyframes", i);
    MapKeyframe kf;
    kf.id = spec.id;
    kf.pose = spec.pose;
    try {
      kf.image = loadGreyImage((base / spec.image).string(), child(field, "image"), camera, read);
      if (!spec.depth.empty()) {
        kf.depth = loadDepthImage((base / spec.depth).string(), child(field, "depth"), camera, spec.depth_scale, read);
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
    const Fields top = reader.fields(root, "", {});
    if (const YAML::Node* n = top.find("target")) truth.target_agent = reader.text(*n, "target");
    if (const YAML::Node* n = top.find("source")) truth.source_agent = reader.text(*n, "source");
    if (const YAML::Node* n = top.find("overlap")) truth.overlap = reader.boolean(*n, "overlap");
    truth.target_source = parseSim3(reader, reader.require(top, "S_target_source"), "S_target_source");
    truth.world_to_target = parseSim3(reader, reader.require(top, "world_to_target"), "world_to_target");
    truth.world_to_source = parseSim3(reader, reader.require(top, "world_to_source"), "world_to_source");
    if (const YAML::Node* poses = top.find("world_poses")) {
      const Fields all = reader.fields(*poses, "world_poses", {});
      for (const auto& entry : all.entries) {
        const std::string field = child("world_poses", entry.first);
        const long id = static_cast<long>(reader.integer(YAML::Node(entry.first), field));
        const Fields pose = reader.fields(entry.second, field, {"position", "orientation"});
        const Eigen::Vector3d position = reader.vector3(reader.require(pose, "position"), child(field, "position"));
        const Eigen::Quaterniond q =
            reader.quaternion(reader.require(pose, "orientation"), child(field, "orientation"));
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
