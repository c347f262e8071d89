// Tests of the map bundle reader (pcr_pro/io/bundle.h) on synthetic bundles, good and deliberately
// broken. (The real two-agent cases are checked against their raw data in test_real_cases.cpp.)

#include <gtest/gtest.h>
#include <unistd.h>

#include <algorithm>
#include <cmath>
#include <cstdint>
#include <filesystem>
#include <fstream>
#include <functional>
#include <iterator>
#include <opencv2/core.hpp>
#include <opencv2/imgcodecs.hpp>
#include <ostream>
#include <set>
#include <sstream>
#include <string>
#include <vector>

#include "pcr_pro/io/bundle.h"
#include "pcr_pro/io/cloud_io.h"

namespace fs = std::filesystem;

namespace pcr_pro {
namespace {

// ---- synthetic bundles, good and broken -----------------------------------------------------

const char* const kBaseYaml = R"(frame_id: test/map
cloud: map.pcd
camera:
  fx: 100.0
  fy: 110.0
  cx: 4.0
  cy: 3.0
  width: 8
  height: 6
keyframes:
  - id: 7
    image: keyframes/7.png
    pose:
      position: [0.1, 0.2, 0.3]
      orientation: [0, 0, 0, 2]
      scale: 0.5
    depth: keyframes/7_depth.png
    depth_scale: 1000.0
  - id: 9
    image: keyframes/9.png
    pose:
      position: [1, 2, 3]
      orientation: [0, 0.6, 0, 0.8]
)";

/// A valid bundle in a fresh temporary directory, removed afterwards.
class TempBundle : public ::testing::Test {
 protected:
  void SetUp() override {
    static int counter = 0;
    dir_ = fs::temp_directory_path() /
           ("pcr_pro_test_bundle_" + std::to_string(::getpid()) + "_" + std::to_string(counter++));
    fs::remove_all(dir_);
    fs::create_directories(dir_ / "keyframes");
    Cloud cloud(3, 4);
    cloud << 0, 1, 0, 0, 0, 0, 1, 0, 1, 1, 1, 2;
    writePcd(path("map.pcd"), cloud);
    cv::Mat grey(6, 8, CV_8UC1);
    for (int r = 0; r < 6; ++r) {
      for (int c = 0; c < 8; ++c) grey.at<std::uint8_t>(r, c) = static_cast<std::uint8_t>(10 * r + c);
    }
    ASSERT_TRUE(cv::imwrite(path("keyframes/7.png"), grey));
    cv::Mat colour(6, 8, CV_8UC3, cv::Scalar(10, 20, 200));  // B G R
    ASSERT_TRUE(cv::imwrite(path("keyframes/9.png"), colour));
    cv::Mat depth(6, 8, CV_16UC1, cv::Scalar(1234));
    depth.at<std::uint16_t>(0, 0) = 0;
    depth.at<std::uint16_t>(5, 7) = 65535;
    ASSERT_TRUE(cv::imwrite(path("keyframes/7_depth.png"), depth));
    writeYaml(kBaseYaml);
  }
  void TearDown() override {
    std::error_code ec;
    fs::remove_all(dir_, ec);
  }

  std::string path(const std::string& relative) const { return (dir_ / relative).string(); }
  void writeYaml(const std::string& text) const { writeFile("bundle.yaml", text); }
  void writeFile(const std::string& relative, const std::string& bytes) const {
    std::ofstream out(path(relative), std::ios::binary | std::ios::trunc);
    out << bytes;
  }

  /// Loads the bundle, expecting an InputError; returns its message ("" when none was thrown).
  std::string loadError() const {
    try {
      loadBundle(dir_.string());
    } catch (const InputError& e) {
      return e.what();
    }
    ADD_FAILURE() << "loadBundle accepted a broken bundle";
    return "";
  }

  fs::path dir_;
};

TEST_F(TempBundle, ValidBundleLoads) {
  const AgentMap map = loadBundle(dir_.string());
  EXPECT_EQ(map.frame_id, "test/map");
  EXPECT_EQ(map.cloud.cols(), 4);
  EXPECT_DOUBLE_EQ(map.camera.fy, 110.0);
  ASSERT_EQ(map.keyframes.size(), 2u);
  const MapKeyframe& a = map.keyframes[0];
  const MapKeyframe& b = map.keyframes[1];
  EXPECT_EQ(a.id, 7);
  EXPECT_EQ(b.id, 9);
  EXPECT_DOUBLE_EQ(a.pose.scale(), 0.5);
  EXPECT_DOUBLE_EQ(b.pose.scale(), 1.0);                                       // default
  EXPECT_LT((a.pose.rotation() - Eigen::Matrix3d::Identity()).norm(), 1e-12);  // [0 0 0 2] normalised
  EXPECT_LT((a.pose.translation() - Eigen::Vector3d(0.1, 0.2, 0.3)).norm(), 1e-12);
  // [0 0.6 0 0.8]: rotation about y by 2*atan2(0.6, 0.8)
  EXPECT_NEAR(b.pose.rotationAngle(), 2.0 * std::atan2(0.6, 0.8), 1e-12);
  EXPECT_NEAR(b.pose.rotation()(0, 2), std::sin(2.0 * std::atan2(0.6, 0.8)), 1e-12);
  // p_map = scale * R * p_cam + position
  EXPECT_LT((a.pose.apply(Eigen::Vector3d(2, 0, 0)) - Eigen::Vector3d(1.1, 0.2, 0.3)).norm(), 1e-12);

  ASSERT_EQ(a.image.type(), CV_8UC1);
  EXPECT_EQ(a.image.at<std::uint8_t>(5, 7), 57);
  ASSERT_EQ(b.image.type(), CV_8UC1);  // colour converted: 0.299 R + 0.587 G + 0.114 B
  EXPECT_NEAR(b.image.at<std::uint8_t>(2, 3), 0.299 * 200 + 0.587 * 20 + 0.114 * 10, 1.0);
  ASSERT_EQ(a.depth.type(), CV_32FC1);
  EXPECT_FLOAT_EQ(a.depth.at<float>(1, 1), 1.234f);
  EXPECT_EQ(a.depth.at<float>(0, 0), 0.0f);
  EXPECT_FLOAT_EQ(a.depth.at<float>(5, 7), 65.535f);
  EXPECT_TRUE(b.depth.empty());
}

TEST_F(TempBundle, OptionalKeysTakeDefaults) {
  std::string text = kBaseYaml;
  text.erase(0, text.find('\n') + 1);  // drop frame_id
  writeYaml(text);
  EXPECT_EQ(loadBundle(dir_.string()).frame_id, "map");
}

TEST_F(TempBundle, MessagesStayOnOneLine) {
  std::string text = kBaseYaml;
  const std::string from = "image: keyframes/7.png";
  text.replace(text.find(from), from.size(), "image: \"keyframes/\\n7.png\"");  // a newline in the path
  writeYaml(text);
  const std::string message = loadError();
  EXPECT_EQ(message.find('\n'), std::string::npos) << message;
  EXPECT_NE(message.find("(keyframes[0].image)"), std::string::npos) << message;
}

// The core's own reader (decodeImageFile) keeps no process-wide state: it cannot see libjpeg's
// stderr warning, so it tells a JPEG cut short from its bytes. Its verdicts, and a complete JPEG
// (also with bytes after its end marker) still loading, on an image of the bundle's camera size.
TEST_F(TempBundle, CoreReaderRefusesImagesCutShort) {
  cv::Mat grey(6, 8, CV_8UC1);
  cv::randu(grey, 0, 255);
  std::vector<unsigned char> jpeg;
  ASSERT_TRUE(cv::imencode(".jpg", grey, jpeg));
  const std::string whole(jpeg.begin(), jpeg.end());
  writeFile("keyframes/7.png", whole + std::string(16, '\0'));
  EXPECT_EQ(loadBundle(dir_.string()).keyframes[0].image.size(), cv::Size(8, 6));
  writeFile("keyframes/7.png", whole.substr(0, whole.size() - 2));  // no end-of-image marker
  std::string message = loadError();
  EXPECT_NE(message.find("keyframes/7.png: cannot read image: truncated JPEG (keyframes[0].image)"), std::string::npos)
      << message;
  writeFile("keyframes/7.png", whole.substr(0, whole.size() / 2));
  message = loadError();
  EXPECT_NE(message.find("(keyframes[0].image)"), std::string::npos) << message;

  std::vector<unsigned char> png;
  ASSERT_TRUE(cv::imencode(".png", grey, png));
  writeFile("keyframes/7.png", std::string(png.begin(), png.begin() + static_cast<std::ptrdiff_t>(png.size() / 2)));
  message = loadError();
  EXPECT_NE(message.find("keyframes/7.png: cannot read image"), std::string::npos) << message;
  EXPECT_NE(message.find("(keyframes[0].image)"), std::string::npos) << message;
}

// The caller's reader reads every image and depth file, is told the camera's size, and its
// InputError gets the bundle field appended.
TEST_F(TempBundle, CallersImageReaderIsUsedForEveryFile) {
  std::vector<std::string> read;
  const ImageFileReader counting = [&read](const std::string& file, const cv::Size& expected) {
    EXPECT_EQ(expected, cv::Size(8, 6));
    read.push_back(fs::path(file).filename().string());
    return decodeImageFile(file, expected);
  };
  const AgentMap map = loadBundle(dir_.string(), InputLimits(), nullptr, counting);
  EXPECT_EQ(read, (std::vector<std::string>{"7.png", "7_depth.png", "9.png"}));
  EXPECT_EQ(map.keyframes.size(), 2u);
  const ImageFileReader refusing = [](const std::string& file, const cv::Size&) -> cv::Mat {
    throw InputError(file + ": refused by the reader");
  };
  try {
    loadBundle(dir_.string(), InputLimits(), nullptr, refusing);
    ADD_FAILURE() << "the reader's error was lost";
  } catch (const InputError& e) {
    EXPECT_NE(std::string(e.what()).find("7.png: refused by the reader (keyframes[0].image)"), std::string::npos)
        << e.what();
  }
}

TEST_F(TempBundle, MissingDirectory) {
  const std::string missing = (dir_ / "nope").string();
  try {
    loadBundle(missing);
    FAIL() << "no error";
  } catch (const InputError& e) {
    EXPECT_EQ(std::string(e.what()).rfind(missing + ": ", 0), 0u) << e.what();
    EXPECT_NE(std::string(e.what()).find("not found"), std::string::npos) << e.what();
  }
  const std::string file = path("map.pcd");  // a file, not a directory
  try {
    loadBundle(file);
    FAIL() << "no error";
  } catch (const InputError& e) {
    EXPECT_NE(std::string(e.what()).find("not a directory"), std::string::npos) << e.what();
  }
}

/// One broken bundle: a text edit of bundle.yaml and/or a file edit, and what the error must say.
struct Defect {
  std::string name;
  std::string from, to;                             // replace `from` in bundle.yaml (once); `from` empty: no edit
  std::function<void(const fs::path&)> edit_files;  // optional
  std::string file;                                 // the message must start with DIR/file + ": "
  std::vector<std::string> mentions;                // ... and contain each of these
};

void PrintTo(const Defect& d, std::ostream* os) { *os << d.name; }

void writeBytes(const fs::path& p, const std::string& bytes) {
  std::ofstream out(p, std::ios::binary | std::ios::trunc);
  out << bytes;
}

std::vector<Defect> defects() {
  const std::string y = "bundle.yaml";
  const std::string image = "keyframes/7.png";
  const std::string depth = "keyframes/7_depth.png";
  auto replaceAll = [](const std::string& text) {
    return [text](const fs::path& d) { writeBytes(d / "bundle.yaml", text); };
  };
  auto remove = [](const std::string& rel) { return [rel](const fs::path& d) { fs::remove(d / rel); }; };
  auto image_of = [](const std::string& rel, cv::Mat m) {
    return [rel, m](const fs::path& d) { cv::imwrite((d / rel).string(), m); };
  };
  const cv::Mat grey8(6, 8, CV_8UC1, cv::Scalar(5)), grey10(6, 10, CV_8UC1, cv::Scalar(5));
  const cv::Mat u16(6, 8, CV_16UC1, cv::Scalar(5)), u16c3(6, 8, CV_16UC3, cv::Scalar(5, 5, 5));
  const cv::Mat u16small(5, 8, CV_16UC1, cv::Scalar(5));
  auto truncated_png = [](const std::string& rel) {
    return [rel](const fs::path& d) {
      std::ifstream in(d / rel, std::ios::binary);
      std::string bytes((std::istreambuf_iterator<char>(in)), std::istreambuf_iterator<char>());
      in.close();
      writeBytes(d / rel, bytes.substr(0, 40));
    };
  };
  auto flip_byte = [](const std::string& rel, std::size_t at) {
    return [rel, at](const fs::path& d) {
      std::ifstream in(d / rel, std::ios::binary);
      std::string bytes((std::istreambuf_iterator<char>(in)), std::istreambuf_iterator<char>());
      in.close();
      bytes[at] = static_cast<char>(bytes[at] ^ 0x5a);
      writeBytes(d / rel, bytes);
    };
  };

  return {
      // files
      {"NoBundleYaml", "", "", remove("bundle.yaml"), y, {"not found"}},
      {"YamlSyntaxError", "  fx: 100.0\n", "  fx: [100.0\n", nullptr, y, {"YAML syntax error at line 5"}},
      {"YamlSyntaxErrorMapValue", "  cy: 3.0\n", "  cy: 3.0: 4.0\n", nullptr, y, {"YAML syntax error at line 7"}},
      {"YamlTabIndent", "  width: 8\n", "\twidth: 8\n", nullptr, y, {"YAML syntax error at line"}},
      {"EmptyDocument", "", "", replaceAll(""), y, {"empty document"}},
      {"TopLevelList", "", "", replaceAll("- cloud\n- camera\n"), y, {"top level must be a map"}},
      // missing required keys
      {"MissingCloud", "cloud: map.pcd\n", "", nullptr, y, {"cloud: missing"}},
      {"MissingCamera",
       "camera:\n  fx: 100.0\n  fy: 110.0\n  cx: 4.0\n  cy: 3.0\n  width: 8\n  height: 6\n",
       "",
       nullptr,
       y,
       {"camera: missing"}},
      {"MissingFx", "  fx: 100.0\n", "", nullptr, y, {"camera.fx: missing"}},
      {"MissingFy", "  fy: 110.0\n", "", nullptr, y, {"camera.fy: missing"}},
      {"MissingCx", "  cx: 4.0\n", "", nullptr, y, {"camera.cx: missing"}},
      {"MissingCy", "  cy: 3.0\n", "", nullptr, y, {"camera.cy: missing"}},
      {"MissingWidth", "  width: 8\n", "", nullptr, y, {"camera.width: missing"}},
      {"MissingHeight", "  height: 6\n", "", nullptr, y, {"camera.height: missing"}},
      {"KeyframesTypo", "keyframes:\n  - id: 7", "frames:\n  - id: 7", nullptr, y, {"frames: unknown key"}},
      {"MissingKeyframesKey",
       "",
       "",
       replaceAll(std::string(kBaseYaml).substr(0, std::string(kBaseYaml).find("keyframes:"))),
       y,
       {"keyframes: missing"}},
      {"MissingId", "  - id: 7\n    image", "  - image", nullptr, y, {"keyframes[0].id: missing"}},
      {"MissingImage", "    image: keyframes/9.png\n", "", nullptr, y, {"keyframes[1].image: missing"}},
      {"MissingPose",
       "    pose:\n      position: [1, 2, 3]\n      orientation: [0, 0.6, 0, 0.8]\n",
       "",
       nullptr,
       y,
       {"keyframes[1].pose: missing"}},
      {"MissingPosition", "      position: [0.1, 0.2, 0.3]\n", "", nullptr, y, {"keyframes[0].pose.position: missing"}},
      {"MissingOrientation",
       "      orientation: [0, 0.6, 0, 0.8]\n",
       "",
       nullptr,
       y,
       {"keyframes[1].pose.orientation: missing"}},
      // wrong types and shapes
      {"FxNotANumber", "fx: 100.0", "fx: abc", nullptr, y, {"camera.fx: must be a number", "'abc'"}},
      {"FxQuotedString", "fx: 100.0", "fx: \"100.0\"", nullptr, y, {"camera.fx: must be a number, got the string"}},
      {"FxList", "fx: 100.0", "fx: [100.0]", nullptr, y, {"camera.fx: must be a number, got a list"}},
      {"FxNull", "fx: 100.0", "fx:", nullptr, y, {"camera.fx: must be a number, got null"}},
      {"WidthNotInteger", "width: 8", "width: 8.5", nullptr, y, {"camera.width: must be an integer"}},
      {"HeightList", "height: 6", "height: [6]", nullptr, y, {"camera.height: must be an integer"}},
      {"CameraList",
       "camera:\n  fx: 100.0\n  fy: 110.0\n  cx: 4.0\n  cy: 3.0\n  width: 8\n  height: 6\n",
       "camera: [100, 110, 4, 3, 8, 6]\n",
       nullptr,
       y,
       {"camera: value must be a map"}},
      {"KeyframesMap",
       "",
       "",
       replaceAll(std::string(kBaseYaml).substr(0, std::string(kBaseYaml).find("keyframes:")) + "keyframes: {id: 7}\n"),
       y,
       {"keyframes: must be a list"}},
      {"KeyframeScalar",
       "keyframes:\n  - id: 7",
       "keyframes:\n  - 7\n  - id: 7",
       nullptr,
       y,
       {"keyframes[0]: value must be a map"}},
      {"IdNotInteger", "id: 7", "id: 7.5", nullptr, y, {"keyframes[0].id: must be an integer"}},
      {"IdString", "id: 7", "id: seven", nullptr, y, {"keyframes[0].id: must be an integer"}},
      {"ImageList",
       "image: keyframes/7.png",
       "image: [keyframes/7.png]",
       nullptr,
       y,
       {"keyframes[0].image: must be a string"}},
      {"ImageEmpty", "image: keyframes/7.png", "image: ''", nullptr, y, {"keyframes[0].image: must not be empty"}},
      {"PoseScalar",
       "    pose:\n      position: [1, 2, 3]\n      orientation: [0, 0.6, 0, 0.8]\n",
       "    pose: 3\n",
       nullptr,
       y,
       {"keyframes[1].pose: value must be a map"}},
      {"PositionTooShort",
       "[0.1, 0.2, 0.3]",
       "[0.1, 0.2]",
       nullptr,
       y,
       {"keyframes[0].pose.position: must be a list of 3 numbers, got 2"}},
      {"PositionScalar",
       "[0.1, 0.2, 0.3]",
       "0.1",
       nullptr,
       y,
       {"keyframes[0].pose.position: must be a list of 3 numbers"}},
      {"PositionElementString",
       "[0.1, 0.2, 0.3]",
       "[0.1, x, 0.3]",
       nullptr,
       y,
       {"keyframes[0].pose.position[1]: must be a number"}},
      {"OrientationTooLong",
       "[0, 0, 0, 2]",
       "[0, 0, 0, 2, 1]",
       nullptr,
       y,
       {"keyframes[0].pose.orientation: must be a list of 4 numbers, got 5"}},
      {"ScaleString", "scale: 0.5", "scale: big", nullptr, y, {"keyframes[0].pose.scale: must be a number"}},
      {"DepthScaleString",
       "depth_scale: 1000.0",
       "depth_scale: mm",
       nullptr,
       y,
       {"keyframes[0].depth_scale: must be a number"}},
      {"FrameIdList", "frame_id: test/map", "frame_id: [a]", nullptr, y, {"frame_id: must be a string"}},
      {"FrameIdEmpty", "frame_id: test/map", "frame_id: ''", nullptr, y, {"frame_id: must not be empty"}},
      {"CloudNull", "cloud: map.pcd", "cloud:", nullptr, y, {"cloud: must be a string, got null"}},
      // non-finite numbers
      {"FxNan", "fx: 100.0", "fx: .nan", nullptr, y, {"camera.fx: must be finite"}},
      {"CxInf", "cx: 4.0", "cx: .inf", nullptr, y, {"camera.cx: must be finite"}},
      {"PositionNan",
       "[0.1, 0.2, 0.3]",
       "[.NaN, 0.2, 0.3]",
       nullptr,
       y,
       {"keyframes[0].pose.position[0]: must be finite"}},
      {"OrientationInf",
       "[0, 0, 0, 2]",
       "[0, 0, 0, -.inf]",
       nullptr,
       y,
       {"keyframes[0].pose.orientation[3]: must be finite"}},
      {"ScaleInf", "scale: 0.5", "scale: .inf", nullptr, y, {"keyframes[0].pose.scale: must be finite"}},
      {"DepthScaleNan",
       "depth_scale: 1000.0",
       "depth_scale: .nan",
       nullptr,
       y,
       {"keyframes[0].depth_scale: must be finite"}},
      {"FxOverflow", "fx: 100.0", "fx: 1e999", nullptr, y, {"camera.fx: must be"}},
      // ranges
      {"FxZero", "fx: 100.0", "fx: 0", nullptr, y, {"camera.fx: must be > 0"}},
      {"FyNegative", "fy: 110.0", "fy: -110.0", nullptr, y, {"camera.fy: must be > 0"}},
      {"WidthZero", "width: 8", "width: 0", nullptr, y, {"camera.width: must be > 0"}},
      {"HeightNegative", "height: 6", "height: -6", nullptr, y, {"camera.height: must be > 0"}},
      {"WidthHuge", "width: 8", "width: 99999999999", nullptr, y, {"camera.width: is too large"}},
      {"ZeroQuaternion",
       "[0, 0, 0, 2]",
       "[0, 0, 0, 0]",
       nullptr,
       y,
       {"keyframes[0].pose.orientation: zero quaternion"}},
      {"TinyQuaternion",
       "[0, 0, 0, 2]",
       "[0, 0, 1e-13, 0]",
       nullptr,
       y,
       {"keyframes[0].pose.orientation: zero quaternion"}},
      {"ScaleZero", "scale: 0.5", "scale: 0", nullptr, y, {"keyframes[0].pose.scale: must be > 0"}},
      {"ScaleNegative", "scale: 0.5", "scale: -0.5", nullptr, y, {"keyframes[0].pose.scale: must be > 0"}},
      {"DuplicateIds", "id: 9", "id: 7", nullptr, y, {"keyframes[1].id: duplicate keyframe id 7", "keyframes[0].id"}},
      {"NoKeyframes",
       "",
       "",
       replaceAll(std::string(kBaseYaml).substr(0, std::string(kBaseYaml).find("keyframes:")) + "keyframes: []\n"),
       y,
       {"keyframes: no keyframes"}},
      {"DepthWithoutScale",
       "    depth_scale: 1000.0\n",
       "",
       nullptr,
       y,
       {"keyframes[0].depth_scale: required when depth is given"}},
      {"DepthScaleZero",
       "depth_scale: 1000.0",
       "depth_scale: 0",
       nullptr,
       y,
       {"keyframes[0].depth_scale: must be > 0"}},
      {"DepthScaleNegative",
       "depth_scale: 1000.0",
       "depth_scale: -1000",
       nullptr,
       y,
       {"keyframes[0].depth_scale: must be > 0"}},
      // unknown and duplicate keys
      {"UnknownRootKey", "cloud: map.pcd", "clouds: map.pcd", nullptr, y, {"clouds: unknown key"}},
      {"UnknownCameraKey", "  fx: 100.0", "  fz: 100.0", nullptr, y, {"camera.fz: unknown key", "allowed: fx"}},
      {"UnknownKeyframeKey",
       "image: keyframes/7.png",
       "imgae: keyframes/7.png",
       nullptr,
       y,
       {"keyframes[0].imgae: unknown key"}},
      {"UnknownPoseKey",
       "position: [1, 2, 3]",
       "postion: [1, 2, 3]",
       nullptr,
       y,
       {"keyframes[1].pose.postion: unknown key"}},
      {"DuplicateKey",
       "  fx: 100.0\n",
       "  fx: 100.0\n  fx: 101.0\n",
       nullptr,
       y,
       {"camera.fx: duplicate key (lines 4 and 5)"}},
      // image and depth files
      {"ImageMissing", "", "", remove(image), image, {"file not found", "(keyframes[0].image)"}},
      {"ImageCorrupt",
       "",
       "",
       [image](const fs::path& d) { writeBytes(d / image, "this is not an image"); },
       image,
       {"cannot read image", "(keyframes[0].image)"}},
      {"ImageTruncated", "", "", truncated_png(image), image, {"cannot read image", "(keyframes[0].image)"}},
      {"ImageIsDirectory",
       "image: keyframes/7.png",
       "image: keyframes",
       nullptr,
       "keyframes",
       {"not a regular file", "(keyframes[0].image)"}},
      {"ImageWrongSize", "", "", image_of(image, grey10), image, {"10x6", "8x6", "(keyframes[0].image)"}},
      {"Image16Bit", "", "", image_of(image, u16), image, {"8-bit grey or colour", "(keyframes[0].image)"}},
      {"SecondImageMissing", "", "", remove("keyframes/9.png"), "keyframes/9.png", {"(keyframes[1].image)"}},
      {"DepthMissing", "", "", remove(depth), depth, {"file not found", "(keyframes[0].depth)"}},
      {"DepthCorrupt",
       "",
       "",
       [depth](const fs::path& d) { writeBytes(d / depth, std::string(100, '\x7f')); },
       depth,
       {"cannot read image", "(keyframes[0].depth)"}},
      {"DepthTruncated", "", "", truncated_png(depth), depth, {"cannot read image", "(keyframes[0].depth)"}},
      // The core's reader leaves the CRC to libpng; the tools' reader names it (test_bad_input).
      {"DepthBadCrc", "", "", flip_byte(depth, 40), depth, {"cannot read image", "(keyframes[0].depth)"}},
      {"Depth8Bit", "", "", image_of(depth, grey8), depth, {"16-bit single-channel", "(keyframes[0].depth)"}},
      {"Depth16BitColour", "", "", image_of(depth, u16c3), depth, {"16-bit single-channel", "(keyframes[0].depth)"}},
      {"DepthWrongSize", "", "", image_of(depth, u16small), depth, {"8x5", "(keyframes[0].depth)"}},
      // the map cloud
      {"CloudMissing", "", "", remove("map.pcd"), "map.pcd", {"file not found", "(cloud)"}},
      {"CloudCorrupt",
       "",
       "",
       [](const fs::path& d) { writeBytes(d / "map.pcd", "VERSION 0.7\nFIELDS a b\n"); },
       "map.pcd",
       {"(cloud)"}},
      {"CloudEmpty", "", "", [](const fs::path& d) { writeBytes(d / "map.pcd", ""); }, "map.pcd", {"(cloud)"}},
  };
}

class BrokenBundle : public TempBundle, public ::testing::WithParamInterface<Defect> {};

TEST_P(BrokenBundle, ThrowsInputErrorNamingFileAndField) {
  const Defect& defect = GetParam();
  if (!defect.from.empty()) {
    std::string text = kBaseYaml;
    const std::size_t at = text.find(defect.from);
    ASSERT_NE(at, std::string::npos) << "test bug: '" << defect.from << "' not in the base bundle";
    text.replace(at, defect.from.size(), defect.to);
    writeYaml(text);
  }
  if (defect.edit_files) defect.edit_files(dir_);
  const std::string message = loadError();
  const std::string file = path(defect.file) + ": ";
  EXPECT_EQ(message.rfind(file, 0), 0u) << "message does not start with '" << file << "': " << message;
  for (const std::string& m : defect.mentions) {
    EXPECT_NE(message.find(m), std::string::npos) << "message lacks '" << m << "': " << message;
  }
  EXPECT_EQ(message.find('\n'), std::string::npos) << "message is not one line: " << message;
}

INSTANTIATE_TEST_SUITE_P(Defects, BrokenBundle, ::testing::ValuesIn(defects()),
                         [](const ::testing::TestParamInfo<Defect>& info) { return info.param.name; });

TEST(BundleTruthFile, RejectsBrokenTruth) {
  const fs::path dir = fs::temp_directory_path() / ("pcr_pro_test_truth_" + std::to_string(::getpid()));
  fs::create_directories(dir);
  const std::string file = (dir / "truth.yaml").string();
  writeBytes(file,
             "S_target_source: {scale: 0, rotation: [0, 0, 0, 1], translation: [0, 0, 0]}\n"
             "world_to_target: {scale: 1, rotation: [0, 0, 0, 1], translation: [0, 0, 0]}\n"
             "world_to_source: {scale: 1, rotation: [0, 0, 0, 1], translation: [0, 0, 0]}\n");
  try {
    loadBundleTruth(file);
    ADD_FAILURE() << "no error";
  } catch (const InputError& e) {
    EXPECT_NE(std::string(e.what()).find(file + ": S_target_source.scale: must be > 0"), std::string::npos) << e.what();
  }
  EXPECT_THROW(loadBundleTruth((dir / "missing.yaml").string()), InputError);
  fs::remove_all(dir);
}

}  // namespace
}  // namespace pcr_pro
