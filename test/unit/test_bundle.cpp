// Tests of the map bundle reader (pcr_pro/io/bundle.h) on the generated two-agent bundles of
// test/data/bundles (scripts/make_bundles.py) and on deliberately broken bundles.

#include <gtest/gtest.h>
#include <unistd.h>

#include <algorithm>
#include <cmath>
#include <cstdint>
#include <filesystem>
#include <fstream>
#include <functional>
#include <iterator>
#include <map>
#include <opencv2/core.hpp>
#include <opencv2/imgcodecs.hpp>
#include <opencv2/imgproc.hpp>
#include <ostream>
#include <set>
#include <sstream>
#include <string>
#include <unordered_map>
#include <vector>

#include "pcr_pro/io/bundle.h"
#include "pcr_pro/io/cloud_io.h"

namespace fs = std::filesystem;

namespace pcr_pro {
namespace {

const std::string kDataDir = PCR_PRO_TEST_DATA_DIR;

std::string bundleDir(const std::string& test_case, const std::string& agent) {
  return kDataDir + "/bundles/" + test_case + "/" + agent;
}

// camera -> world poses of the five source frames, read here from the original pose.txt
// (tx ty tz qx qy qz qw per line), independently of the generator.
std::map<long, Sim3> readPoseTxt() {
  std::ifstream in(kDataDir + "/slambook2_ch5_rgbd/pose.txt");
  std::map<long, Sim3> poses;
  double tx, ty, tz, qx, qy, qz, qw;
  long id = 1;
  while (in >> tx >> ty >> tz >> qx >> qy >> qz >> qw) {
    poses[id++] = Sim3(1.0, Eigen::Quaterniond(qw, qx, qy, qz), Eigen::Vector3d(tx, ty, tz));
  }
  return poses;
}

cv::Mat sourceGrey(long id) {
  const cv::Mat colour =
      cv::imread(kDataDir + "/slambook2_ch5_rgbd/color/" + std::to_string(id) + ".png", cv::IMREAD_COLOR);
  cv::Mat grey;
  if (!colour.empty()) cv::cvtColor(colour, grey, cv::COLOR_BGR2GRAY);
  return grey;
}

cv::Mat sourceDepthMm(long id) {
  return cv::imread(kDataDir + "/slambook2_ch5_rgbd/depth/" + std::to_string(id) + ".pgm", cv::IMREAD_UNCHANGED);
}

// ---- the generated bundles ------------------------------------------------------------------

struct Expected {
  std::string test_case, agent;
  std::vector<long> ids;
  double scale;
  int crop_x0, width;  // keyframes are the columns [crop_x0, crop_x0 + width) of the 640x480 frames
  bool depth;
};

const std::vector<Expected>& expectedBundles() {
  static const std::vector<Expected> all = {
      {"depth", "agent_a", {1, 2, 4}, 1.0, 0, 640, true},    {"depth", "agent_b", {3, 5}, 0.4, 0, 640, true},
      {"nodepth", "agent_a", {1, 2, 4}, 1.0, 0, 640, false}, {"nodepth", "agent_b", {3, 5}, 0.4, 0, 640, false},
      {"nooverlap", "agent_a", {1}, 1.0, 320, 320, true},    {"nooverlap", "agent_b", {4, 5}, 0.4, 0, 320, true},
  };
  return all;
}

void PrintTo(const Expected& e, std::ostream* os) { *os << e.test_case << "/" << e.agent; }

class GeneratedBundle : public ::testing::TestWithParam<Expected> {};

TEST_P(GeneratedBundle, CameraKeyframesAndPoses) {
  const Expected& e = GetParam();
  const AgentMap map = loadBundle(bundleDir(e.test_case, e.agent));
  EXPECT_EQ(map.frame_id, e.agent + "/map");
  EXPECT_DOUBLE_EQ(map.camera.fx, 518.0);
  EXPECT_DOUBLE_EQ(map.camera.fy, 519.0);
  EXPECT_DOUBLE_EQ(map.camera.cx, 325.5 - e.crop_x0);
  EXPECT_DOUBLE_EQ(map.camera.cy, 253.5);
  EXPECT_EQ(map.camera.width, e.width);
  EXPECT_EQ(map.camera.height, 480);
  EXPECT_GT(map.cloud.cols(), 5000);
  EXPECT_TRUE(map.cloud.allFinite());

  ASSERT_EQ(map.keyframes.size(), e.ids.size());
  for (std::size_t i = 0; i < e.ids.size(); ++i) {
    const MapKeyframe& kf = map.keyframes[i];
    EXPECT_EQ(kf.id, e.ids[i]);
    EXPECT_EQ(kf.image.type(), CV_8UC1);
    EXPECT_EQ(kf.image.cols, e.width);
    EXPECT_EQ(kf.image.rows, 480);
    EXPECT_NEAR(kf.pose.scale(), e.scale, 1e-12);
    EXPECT_NEAR((kf.pose.rotation().transpose() * kf.pose.rotation() - Eigen::Matrix3d::Identity()).norm(), 0.0, 1e-9);
    if (e.depth) {
      EXPECT_EQ(kf.depth.type(), CV_32FC1);
      EXPECT_EQ(kf.depth.size(), kf.image.size());
    } else {
      EXPECT_TRUE(kf.depth.empty());
    }
  }
}

TEST_P(GeneratedBundle, ImagesAndDepthAreTheSourceFrames) {
  const Expected& e = GetParam();
  const AgentMap map = loadBundle(bundleDir(e.test_case, e.agent));
  const cv::Rect window(e.crop_x0, 0, e.width, 480);
  for (const MapKeyframe& kf : map.keyframes) {
    SCOPED_TRACE("keyframe " + std::to_string(kf.id));
    const cv::Mat grey = sourceGrey(kf.id);
    ASSERT_FALSE(grey.empty());
    EXPECT_LE(cv::norm(kf.image, grey(window), cv::NORM_INF), 1.0);
    if (!e.depth) continue;
    const cv::Mat mm = sourceDepthMm(kf.id);
    ASSERT_EQ(mm.type(), CV_16UC1);
    cv::Mat expected;
    mm(window).convertTo(expected, CV_32F, 1.0 / 1000.0);
    EXPECT_LE(cv::norm(kf.depth, expected, cv::NORM_INF), 1e-6);
    EXPECT_EQ(cv::countNonZero(kf.depth), cv::countNonZero(mm(window)));
  }
}

TEST_P(GeneratedBundle, MapCloudReprojectsIntoEveryKeyframe) {
  const Expected& e = GetParam();
  const AgentMap map = loadBundle(bundleDir(e.test_case, e.agent));
  // Without depth images, compare with the depth of the same frames in the depth case.
  const AgentMap with_depth = e.depth ? map : loadBundle(bundleDir("depth", e.agent));
  ASSERT_EQ(with_depth.keyframes.size(), map.keyframes.size());
  for (std::size_t k = 0; k < map.keyframes.size(); ++k) {
    const MapKeyframe& kf = map.keyframes[k];
    const cv::Mat& depth = with_depth.keyframes[k].depth;
    SCOPED_TRACE("keyframe " + std::to_string(kf.id));
    ASSERT_FALSE(depth.empty());
    const Cloud in_camera = kf.pose.inverse().apply(map.cloud);  // camera units = metres
    int inside = 0;
    std::vector<double> relative_error;
    for (Eigen::Index i = 0; i < in_camera.cols(); ++i) {
      double u = 0.0, v = 0.0;
      if (!map.camera.project(in_camera.col(i), &u, &v)) continue;
      const int c = static_cast<int>(std::lround(u)), r = static_cast<int>(std::lround(v));
      if (c < 0 || r < 0 || c >= map.camera.width || r >= map.camera.height) continue;
      ++inside;
      const float d = depth.at<float>(r, c);
      if (d > 0.0f) relative_error.push_back(std::abs(in_camera(2, i) - d) / d);
    }
    const double inside_fraction = static_cast<double>(inside) / static_cast<double>(in_camera.cols());
    EXPECT_GT(inside_fraction, 0.5);
    ASSERT_GT(relative_error.size(), 1000u);
    std::nth_element(relative_error.begin(), relative_error.begin() + relative_error.size() / 2, relative_error.end());
    EXPECT_LT(relative_error[relative_error.size() / 2], 0.02);
    const auto close = std::count_if(relative_error.begin(), relative_error.end(), [](double x) { return x < 0.05; });
    EXPECT_GT(static_cast<double>(close) / static_cast<double>(relative_error.size()), 0.7);
  }
}

std::string bundleName(const ::testing::TestParamInfo<Expected>& info) {
  return info.param.test_case + "_" + info.param.agent;
}

INSTANTIATE_TEST_SUITE_P(Bundles, GeneratedBundle, ::testing::ValuesIn(expectedBundles()), bundleName);

TEST(GeneratedBundleData, KnownDepthPixelIsValueOverDepthScale) {
  // depth/1.pgm holds 2799 mm at row 240, column 320.
  const cv::Mat mm = sourceDepthMm(1);
  ASSERT_EQ(mm.at<std::uint16_t>(240, 320), 2799);
  const AgentMap full = loadBundle(bundleDir("depth", "agent_a"));
  ASSERT_EQ(full.keyframes.front().id, 1);
  EXPECT_FLOAT_EQ(full.keyframes.front().depth.at<float>(240, 320), 2.799f);
  const AgentMap half = loadBundle(bundleDir("nooverlap", "agent_a"));  // columns 320..639
  ASSERT_EQ(half.keyframes.front().id, 1);
  EXPECT_FLOAT_EQ(half.keyframes.front().depth.at<float>(240, 0), 2.799f);
  EXPECT_EQ(full.keyframes.front().depth.at<float>(0, 0), 0.0f);  // 0 = unknown stays 0
}

// A fraction of the points of `source` that lie within `radius` of a point of `target`.
double fractionNear(const Cloud& target, const Cloud& source, double radius) {
  struct KeyHash {
    std::size_t operator()(const Eigen::Vector3i& k) const {
      return (static_cast<std::size_t>(k.x()) * 73856093u) ^ (static_cast<std::size_t>(k.y()) * 19349663u) ^
             (static_cast<std::size_t>(k.z()) * 83492791u);
    }
  };
  std::unordered_multimap<Eigen::Vector3i, Eigen::Index, KeyHash> grid;
  auto key = [radius](const Eigen::Vector3d& p) { return Eigen::Vector3i((p / radius).array().floor().cast<int>()); };
  for (Eigen::Index i = 0; i < target.cols(); ++i) grid.emplace(key(target.col(i)), i);
  int near = 0;
  for (Eigen::Index i = 0; i < source.cols(); ++i) {
    const Eigen::Vector3i k = key(source.col(i));
    bool found = false;
    for (int dx = -1; dx <= 1 && !found; ++dx) {
      for (int dy = -1; dy <= 1 && !found; ++dy) {
        for (int dz = -1; dz <= 1 && !found; ++dz) {
          const auto range = grid.equal_range(k + Eigen::Vector3i(dx, dy, dz));
          for (auto it = range.first; it != range.second && !found; ++it) {
            found = (target.col(it->second) - source.col(i)).norm() <= radius;
          }
        }
      }
    }
    near += found ? 1 : 0;
  }
  return static_cast<double>(near) / static_cast<double>(source.cols());
}

class GeneratedTruth : public ::testing::TestWithParam<std::string> {};

TEST_P(GeneratedTruth, TransformAgreesWithPoseTxtAndKeyframes) {
  const std::string test_case = GetParam();
  const BundleTruth truth = loadBundleTruth(kDataDir + "/bundles/" + test_case + "/truth.yaml");
  const AgentMap a = loadBundle(bundleDir(test_case, truth.target_agent));
  const AgentMap b = loadBundle(bundleDir(test_case, truth.source_agent));
  EXPECT_EQ(truth.target_agent, "agent_a");
  EXPECT_EQ(truth.source_agent, "agent_b");
  EXPECT_EQ(truth.overlap, test_case != "nooverlap");
  EXPECT_NEAR(truth.target_source.scale(), 2.5, 1e-9);

  // S_target_source = G_a * G_b^-1
  const Sim3 composed = truth.world_to_target * truth.world_to_source.inverse();
  EXPECT_NEAR(composed.scale(), truth.target_source.scale(), 1e-9);
  EXPECT_LT(rotationDistance(composed.rotation(), truth.target_source.rotation()), 1e-9);
  EXPECT_LT((composed.translation() - truth.target_source.translation()).norm(), 1e-8);

  const std::map<long, Sim3> world = readPoseTxt();
  ASSERT_EQ(world.size(), 5u);
  for (const auto& entry : truth.world_poses) {
    ASSERT_EQ(world.count(entry.first), 1u);
    EXPECT_LT((entry.second.translation() - world.at(entry.first).translation()).norm(), 1e-9);
    EXPECT_LT(rotationDistance(entry.second.rotation(), world.at(entry.first).rotation()), 1e-9);
  }
  // Every keyframe of A sits where G_a puts the pose.txt camera; every keyframe of B, mapped by
  // S_target_source, lands there too (camera centre and orientation, in A's units = metres).
  auto check = [&](const MapKeyframe& kf, const Sim3& in_target) {
    SCOPED_TRACE("keyframe " + std::to_string(kf.id));
    const Sim3 expected = truth.world_to_target * world.at(kf.id);
    EXPECT_NEAR(in_target.scale(), expected.scale(), 1e-9);
    EXPECT_LT((in_target.translation() - expected.translation()).norm(), 1e-8);
    EXPECT_LT(rotationDistance(in_target.rotation(), expected.rotation()), 1e-8);
  };
  for (const MapKeyframe& kf : a.keyframes) check(kf, kf.pose);
  for (const MapKeyframe& kf : b.keyframes) check(kf, truth.target_source * kf.pose);

  // The clouds: under the true transform, B's map lies on A's map where the views overlap and
  // nowhere near it in the no-overlap case. A wrong transform (B's map taken as is) must not fit.
  const Cloud b_in_a = truth.target_source.apply(b.cloud);
  const double fraction = fractionNear(a.cloud, b_in_a, 0.05);
  if (truth.overlap) {
    EXPECT_GT(fraction, 0.4);
    EXPECT_LT(fractionNear(a.cloud, b.cloud, 0.05), 0.05);
  } else {
    EXPECT_LT(fraction, 0.01);
  }
}

INSTANTIATE_TEST_SUITE_P(Cases, GeneratedTruth, ::testing::Values("depth", "nodepth", "nooverlap"));

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
       {"camera.fx: duplicate key", "line 5"}},
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
      {"DepthBadCrc", "", "", flip_byte(depth, 40), depth, {"cannot read image", "CRC", "(keyframes[0].depth)"}},
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

// The checks above must be able to fail: a bundle whose pose is wrong does not reproject.
TEST(GeneratedBundleData, ReprojectionCheckDetectsAWrongPose) {
  const AgentMap a = loadBundle(bundleDir("depth", "agent_a"));
  const AgentMap b = loadBundle(bundleDir("depth", "agent_b"));
  // Agent A's cloud seen from agent B's pose of frame 3 (wrong map frame): the depth disagrees.
  const Cloud in_camera = b.keyframes.front().pose.inverse().apply(a.cloud);
  const cv::Mat& depth = b.keyframes.front().depth;
  int close = 0, compared = 0;
  for (Eigen::Index i = 0; i < in_camera.cols(); ++i) {
    double u = 0.0, v = 0.0;
    if (!a.camera.project(in_camera.col(i), &u, &v)) continue;
    const int c = static_cast<int>(std::lround(u)), r = static_cast<int>(std::lround(v));
    if (c < 0 || r < 0 || c >= a.camera.width || r >= a.camera.height || !(depth.at<float>(r, c) > 0.0f)) continue;
    ++compared;
    const float d = depth.at<float>(r, c);
    close += std::abs(in_camera(2, i) - d) / d < 0.05 ? 1 : 0;
  }
  EXPECT_LT(compared == 0 ? 0.0 : static_cast<double>(close) / compared, 0.3);
}

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
