// Bad input at the command line (issue 6): pcr_pro_merge and pcr_pro_icp over a table of defective
// bundles, clouds and configurations. Every case must end with exit status 2 and exactly one line on
// stderr naming the file and the field at fault: never a crash, a signal or a hang.
//
// The bundles are copies of a base bundle made from the generated demo world's agent_a (its cloud,
// keyframe and depth images, camera and poses; BUILD/sim/demo, test/common/sim_worlds.h) with a
// bundle.yaml written by this test, each copy mutated in one way.

#include <gtest/gtest.h>
#include <sys/wait.h>
#include <unistd.h>

#include <algorithm>
#include <cstdint>
#include <cstdlib>
#include <filesystem>
#include <fstream>
#include <functional>
#include <iterator>
#include <limits>
#include <opencv2/core.hpp>
#include <opencv2/imgcodecs.hpp>
#include <ostream>
#include <sstream>
#include <string>
#include <vector>

#include "common/sim_worlds.h"
#include "pcr_pro/io/bundle.h"
#include "pcr_pro/io/plausibility.h"
#include "pcr_pro/merge/merge_pipeline.h"

namespace pcr_pro {
namespace {

namespace fs = std::filesystem;

// Two valid bundles of the generated demo world (partners of the defective ones).
const std::string kAgentA = test::simPath("demo/agent_a");
const std::string kAgentB = test::simPath("demo/agent_b");
// A run longer than this is a hang (the slowest valid merge of the generated bundles takes seconds).
constexpr int kTimeoutSeconds = 120;

struct ToolRun {
  int exit_status = -1;  // exit status; -1 when the process did not exit normally
  int signal = 0;        // the signal that ended it (timeout's 124 counts as a hang)
  bool timed_out = false;
  std::string out, err;
};

fs::path scratch() {
  static const fs::path dir = [] {
    const fs::path d = fs::temp_directory_path() / ("pcr_pro_bad_input_" + std::to_string(::getpid()));
    fs::remove_all(d);
    fs::create_directories(d);
    return d;
  }();
  return dir;
}

// Removes the scratch directory when the test program ends.
struct ScratchCleanup {
  ~ScratchCleanup() {
    std::error_code ec;
    fs::remove_all(fs::temp_directory_path() / ("pcr_pro_bad_input_" + std::to_string(::getpid())), ec);
  }
} scratch_cleanup;

std::string readText(const fs::path& p) {
  std::ifstream in(p, std::ios::binary);
  return std::string((std::istreambuf_iterator<char>(in)), std::istreambuf_iterator<char>());
}

void writeBytes(const fs::path& p, const std::string& bytes) {
  std::ofstream out(p, std::ios::binary | std::ios::trunc);
  out << bytes;
}

// Runs a tool under `timeout` (coreutils), which kills it after kTimeoutSeconds.
ToolRun runTool(const std::string& binary, const std::string& args) {
  const std::string out = (scratch() / "stdout.txt").string(), err = (scratch() / "stderr.txt").string();
  const std::string cmd = "timeout -s KILL " + std::to_string(kTimeoutSeconds) + " " + binary + " " + args +
                          " </dev/null >" + out + " 2>" + err;
  const int raw = std::system(cmd.c_str());
  ToolRun r;
  if (WIFEXITED(raw)) {
    const int code = WEXITSTATUS(raw);
    // The shell and timeout report a child killed by signal N as 128 + N.
    if (code > 128) {
      r.signal = code - 128;
      r.timed_out = r.signal == SIGKILL;
    } else {
      r.exit_status = code;
    }
  } else if (WIFSIGNALED(raw)) {
    r.signal = WTERMSIG(raw);
  }
  r.out = readText(out);
  r.err = readText(err);
  return r;
}

// A valid cloud for the partner side of the cloud and configuration cases, written once: 3 x 400
// points on three orthogonal planes (a well-conditioned ICP input) as CSV with a header.
std::string goodCloud() {
  static const std::string path = [] {
    std::ostringstream csv;
    csv << "x,y,z\n";
    for (int plane = 0; plane < 3; ++plane) {
      for (int i = 0; i < 20; ++i) {
        for (int j = 0; j < 20; ++j) {
          double p[3] = {0.0, 0.0, 0.0};
          p[(plane + 1) % 3] = 0.1 * i;
          p[(plane + 2) % 3] = 0.1 * j;
          csv << p[0] << "," << p[1] << "," << p[2] << "\n";
        }
      }
    }
    const fs::path file = scratch() / "good_cloud.csv";
    writeBytes(file, csv.str());
    return file.string();
  }();
  return path;
}

/// Asserts the contract of bad input: exit 2, one line on stderr, naming `file` and each of `mentions`.
void expectBadInput(const ToolRun& r, const std::string& file, const std::vector<std::string>& mentions) {
  EXPECT_FALSE(r.timed_out) << "hang (killed after " << kTimeoutSeconds << " s)";
  EXPECT_EQ(r.signal, 0) << "ended by signal " << r.signal << "; stderr: " << r.err;
  EXPECT_EQ(r.exit_status, 2) << "stderr: " << r.err << "\nstdout: " << r.out;
  ASSERT_FALSE(r.err.empty());
  EXPECT_EQ(std::count(r.err.begin(), r.err.end(), '\n'), 1) << "not one line: " << r.err;
  EXPECT_EQ(r.err.back(), '\n') << r.err;
  // printable ASCII only: no control character, and bytes from files escaped as \xNN (valid UTF-8)
  const bool printable = std::all_of(r.err.begin(), r.err.end() - 1, [](char c) {
    return static_cast<unsigned char>(c) >= 0x20 && static_cast<unsigned char>(c) < 0x7f;
  });
  EXPECT_TRUE(printable) << "control characters or non-ASCII bytes in the message: " << r.err;
  EXPECT_NE(r.err.find(file), std::string::npos) << "does not name " << file << ": " << r.err;
  for (const std::string& m : mentions) EXPECT_NE(r.err.find(m), std::string::npos) << "lacks '" << m << "': " << r.err;
  EXPECT_TRUE(r.out.empty()) << "stdout: " << r.out;
}

// ---- PCD / CSV builders -----------------------------------------------------------------------

std::string pcdHeader(const std::string& fields, const std::string& size, const std::string& type,
                      const std::string& count, const std::string& points, const std::string& data) {
  return "# .PCD v0.7\nVERSION 0.7\nFIELDS " + fields + "\nSIZE " + size + "\nTYPE " + type + "\nCOUNT " + count +
         "\nWIDTH " + points + "\nHEIGHT 1\nVIEWPOINT 0 0 0 1 0 0 0\nPOINTS " + points + "\nDATA " + data + "\n";
}

std::string xyzHeader(const std::string& points, const std::string& data) {
  return pcdHeader("x y z", "4 4 4", "F F F", "1 1 1", points, data);
}

std::string floats(const std::vector<float>& v) {
  return std::string(reinterpret_cast<const char*>(v.data()), sizeof(float) * v.size());
}

std::string bytesOf(const std::vector<std::uint32_t>& words) {
  return std::string(reinterpret_cast<const char*>(words.data()), sizeof(std::uint32_t) * words.size());
}

std::string garbage(std::size_t n, unsigned seed) {
  std::string s(n, '\0');
  unsigned x = seed;
  for (char& c : s) {
    x = x * 1103515245u + 12345u;
    c = static_cast<char>(x >> 16);
  }
  return s;
}

// ---- the base bundle -------------------------------------------------------------------------

// The generated agent_a with a bundle.yaml in a layout of this test's own (keyframe ids 1, 2, 4;
// one number format), so that every defect below is one text substitution that is known to apply:
// the strings the defects replace are kept here.
struct BaseBundle {
  fs::path dir;
  std::string yaml;
  std::string camera;                 // the whole camera block
  std::string fx, fy, cx, width, height;  // "fx: 525", ... as written
  std::string p1, q1;                 // the first keyframe's position and orientation lists
  std::string scale1;                 // "      scale: <s>\n    depth: keyframes/1_depth.png"
  std::string depth_scale1;           // "depth_scale: <d>" of the first keyframe
};

std::string num(double v) {
  std::ostringstream os;
  os.precision(12);
  os << v;
  return os.str();
}

std::string list(std::initializer_list<double> values) {
  std::string out = "[";
  for (double v : values) out += (out.size() > 1 ? ", " : "") + num(v);
  return out + "]";
}

const BaseBundle& base() {
  static const BaseBundle b = [] {
    BaseBundle out;
    out.dir = scratch() / "base";
    fs::create_directories(out.dir / "keyframes");
    const AgentMap map = loadBundle(kAgentA);
    if (map.keyframes.size() < 3) throw std::runtime_error("test bug: the generated agent_a has fewer than 3 keyframes");
    fs::copy_file(kAgentA + "/map.pcd", out.dir / "map.pcd");
    const PinholeCamera& c = map.camera;
    out.fx = "fx: " + num(c.fx);
    out.fy = "fy: " + num(c.fy);
    out.cx = "cx: " + num(c.cx);
    out.width = "width: " + std::to_string(c.width);
    out.height = "height: " + std::to_string(c.height);
    out.camera = "camera:\n  " + out.fx + "\n  " + out.fy + "\n  " + out.cx + "\n  cy: " + num(c.cy) + "\n  " +
                 out.width + "\n  " + out.height + "\n";
    std::string keyframes = "keyframes:\n";
    const long ids[3] = {1, 2, 4};
    for (int k = 0; k < 3; ++k) {
      // The generated keyframes in the order 1, 2, 0: the first one listed has a pose other than identity.
      const MapKeyframe& kf = map.keyframes[static_cast<std::size_t>((k + 1) % 3)];
      const std::string id = std::to_string(ids[k]);
      const std::string image = "keyframes/" + id + ".png", depth = "keyframes/" + id + "_depth.png";
      cv::imwrite((out.dir / image).string(), kf.image);
      const double depth_scale = 1000.0 * (k + 1);  // 16-bit depth in steps of 1, 0.5, 0.33 mm
      cv::Mat depth16;
      kf.depth.convertTo(depth16, CV_16UC1, depth_scale);
      cv::imwrite((out.dir / depth).string(), depth16);
      const Eigen::Quaterniond q = kf.pose.quaternion();
      const Eigen::Vector3d& t = kf.pose.translation();
      const std::string position = list({t.x(), t.y(), t.z()}), orientation = list({q.x(), q.y(), q.z(), q.w()});
      const std::string scale_depth = "      scale: " + num(kf.pose.scale()) + "\n    depth: " + depth;
      if (k == 0) {
        out.p1 = position;
        out.q1 = orientation;
        out.scale1 = scale_depth;
        out.depth_scale1 = "depth_scale: " + num(depth_scale);
      }
      keyframes += "  - id: " + id + "\n    image: " + image + "\n    pose:\n      position: " + position +
                   "\n      orientation: " + orientation + "\n" + scale_depth + "\n    depth_scale: " +
                   num(depth_scale) + "\n";
    }
    out.yaml = "frame_id: agent_a/map\ncloud: map.pcd\n" + out.camera + keyframes;
    writeBytes(out.dir / "bundle.yaml", out.yaml);
    return out;
  }();
  return b;
}

// The base bundle itself is valid: each defect below is the only thing wrong with its copy.
TEST(BaseBundle, LoadsAndKeepsTheGeneratedKeyframes) {
  const AgentMap map = loadBundle(base().dir.string());
  ASSERT_EQ(map.keyframes.size(), 3u);
  EXPECT_EQ(map.keyframes[0].id, 1);
  EXPECT_EQ(map.keyframes[2].id, 4);
  EXPECT_EQ(map.cloud.cols(), loadBundle(kAgentA).cloud.cols());
  EXPECT_FALSE(map.keyframes[0].depth.empty());
  for (const std::string& text : {base().camera, base().p1, base().q1, base().scale1, base().depth_scale1}) {
    EXPECT_EQ(base().yaml.find(text), base().yaml.rfind(text)) << "not unique in bundle.yaml: " << text;
  }
}

// ---- pcr_pro_merge over mutated copies of the base bundle --------------------------------------

struct BundleDefect {
  std::string name;
  std::string from, to;                             // replace `from` by `to` in bundle.yaml (once), if from != ""
  std::function<void(const fs::path&)> edit_files;  // further edits of the copy (may be empty)
  std::string file;                   // the file the error must name: relative to the copy, or absolute ("/dev/zero")
  std::vector<std::string> mentions;  // the field (and what) the error must name
  std::string config;                 // optional --config text
};

void PrintTo(const BundleDefect& d, std::ostream* os) { *os << d.name; }

std::function<void(const fs::path&)> writeFile(const std::string& rel, const std::string& bytes) {
  return [rel, bytes](const fs::path& d) { writeBytes(d / rel, bytes); };
}

std::function<void(const fs::path&)> truncateFile(const std::string& rel, double fraction) {
  return [rel, fraction](const fs::path& d) {
    const std::string bytes = readText(d / rel);
    writeBytes(d / rel, bytes.substr(0, static_cast<std::size_t>(fraction * static_cast<double>(bytes.size()))));
  };
}

// Keeps the file up to and including the first `marker`.
std::function<void(const fs::path&)> truncateAfter(const std::string& rel, const std::string& marker) {
  return [rel, marker](const fs::path& d) {
    const std::string bytes = readText(d / rel);
    writeBytes(d / rel, bytes.substr(0, bytes.find(marker) + marker.size()));
  };
}

std::function<void(const fs::path&)> removeFile(const std::string& rel) {
  return [rel](const fs::path& d) { fs::remove_all(d / rel); };
}

std::function<void(const fs::path&)> writeImage(const std::string& rel, const cv::Mat& image) {
  return [rel, image](const fs::path& d) {
    fs::remove(d / rel);
    cv::imwrite((d / rel).string(), image);
  };
}

std::function<void(const fs::path&)> flipByte(const std::string& rel, std::size_t at) {
  return [rel, at](const fs::path& d) {
    std::string bytes = readText(d / rel);
    bytes[at] = static_cast<char>(bytes[at] ^ 0x5a);
    writeBytes(d / rel, bytes);
  };
}

// A JPEG of the right size written under the PNG's name, cut in the middle of its scan data.
std::function<void(const fs::path&)> truncatedJpeg(const std::string& rel) {
  return [rel](const fs::path& d) {
    cv::Mat grey(480, 640, CV_8UC1);
    cv::randu(grey, 0, 255);
    std::vector<unsigned char> jpeg;
    cv::imencode(".jpg", grey, jpeg);
    writeBytes(d / rel, std::string(jpeg.begin(), jpeg.begin() + static_cast<std::ptrdiff_t>(jpeg.size() / 2)));
  };
}

std::vector<BundleDefect> bundleDefects() {
  const BaseBundle& b = base();
  const std::string y = "bundle.yaml";
  const std::string img = "keyframes/1.png", dep = "keyframes/1_depth.png";
  const std::string& camera = b.camera;
  const std::size_t cy_at = camera.find("cy: ");
  const std::string cy_line = camera.substr(cy_at, camera.find('\n', cy_at) - cy_at);
  const std::string& q1 = b.q1;
  const std::string& p1 = b.p1;
  const std::string& kf_scale = b.scale1;
  const std::string before_keyframes = b.yaml.substr(0, b.yaml.find("keyframes:"));
  const cv::Mat small_grey(240, 320, CV_8UC1, cv::Scalar(7));
  const cv::Mat grey16(480, 640, CV_16UC1, cv::Scalar(7));
  const cv::Mat grey8(480, 640, CV_8UC1, cv::Scalar(7));
  return {
      // bundle.yaml itself
      {"YamlMissing", "", "", removeFile(y), y, {"not found"}, ""},
      {"YamlIsDirectory",
       "",
       "",
       [y](const fs::path& d) {
         fs::remove(d / y);
         fs::create_directory(d / y);
       },
       y,
       {"not a regular file"},
       ""},
      {"YamlEmpty", "", "", writeFile(y, ""), y, {"empty document"}, ""},
      {"YamlGarbage", "", "", writeFile(y, garbage(700, 3)), y, {}, ""},
      {"YamlBinaryZeros", "", "", writeFile(y, std::string(300, '\0')), y, {}, ""},
      {"YamlTruncated", "", "", truncateAfter(y, "  - id: 4\n"), y, {"keyframes[2].image: missing"}, ""},
      {"YamlTruncatedMidKey", "", "", truncateAfter(y, "    depth_sc"), y, {"keyframes[0].depth_sc: unknown key"}, ""},
      {"YamlTruncatedMidList",
       "",
       "",
       truncateAfter(y, "position: " + p1.substr(0, p1.find(',') + 4)),
       y,
       {"YAML syntax error"},
       ""},
      {"YamlTopLevelList", "", "", writeFile(y, "- cloud\n- camera\n"), y, {"top level must be a map"}, ""},
      {"YamlSyntaxError", "  " + b.fx + "\n", "  fx: [" + b.fx.substr(4) + "\n", nullptr, y, {"YAML syntax error"}, ""},
      {"YamlDeepNesting", "", "", writeFile(y, "cloud: " + std::string(100000, '[') + "\n"), y, {}, ""},
      {"YamlUnknownKey", "frame_id:", "frameid:", nullptr, y, {"frameid: unknown key"}, ""},
      {"YamlDuplicateKey", "  " + b.fx + "\n", "  " + b.fx + "\n  fx: 1.0\n", nullptr, y, {"camera.fx: duplicate key"}, ""},
      // camera
      {"FxZero", b.fx, "fx: 0", nullptr, y, {"camera.fx", "> 0"}, ""},
      {"FxNegative", b.fx, "fx: -" + b.fx.substr(4), nullptr, y, {"camera.fx", "> 0"}, ""},
      {"FyZero", b.fy, "fy: 0.0", nullptr, y, {"camera.fy", "> 0"}, ""},
      {"FxNan", b.fx, "fx: .nan", nullptr, y, {"camera.fx", "finite"}, ""},
      {"FxString", b.fx, "fx: \"" + b.fx.substr(4) + "\"", nullptr, y, {"camera.fx", "string"}, ""},
      {"CxWord", b.cx, "cx: left", nullptr, y, {"camera.cx", "number"}, ""},
      {"WidthZero", b.width, "width: 0", nullptr, y, {"camera.width", "> 0"}, ""},
      {"HeightNegative", b.height, "height: -480", nullptr, y, {"camera.height", "> 0"}, ""},
      {"WidthFraction", b.width, "width: 640.5", nullptr, y, {"camera.width", "integer"}, ""},
      {"WidthHuge", b.width, "width: 99999999999", nullptr, y, {"camera.width", "too large"}, ""},
      {"CameraList", camera, "camera: [525, 525, 319.5, 239.5, 640, 480]\n", nullptr, y, {"camera", "map"}, ""},
      {"CameraMissing", camera, "", nullptr, y, {"camera: missing"}, ""},
      // keyframes
      {"NoKeyframes", "", "", writeFile(y, before_keyframes + "keyframes: []\n"), y, {"keyframes", "no keyframes"}, ""},
      {"KeyframesMissing", "", "", writeFile(y, before_keyframes), y, {"keyframes: missing"}, ""},
      {"KeyframesMap", "", "", writeFile(y, before_keyframes + "keyframes: {id: 1}\n"), y, {"keyframes", "list"}, ""},
      {"IdWord", "- id: 1", "- id: one", nullptr, y, {"keyframes[0].id", "integer"}, ""},
      {"IdHuge", "- id: 1", "- id: 123456789012345678901234567890", nullptr, y, {"keyframes[0].id", "integer"}, ""},
      {"DuplicateId", "- id: 2", "- id: 1", nullptr, y, {"keyframes[1].id", "duplicate"}, ""},
      {"ZeroQuaternion", q1, "[0, 0, 0, 0]", nullptr, y, {"keyframes[0].pose.orientation", "zero quaternion"}, ""},
      // intrinsics no calibration gives (a unit mix-up): one pixel and one image size are the bounds
      {"FocalBelowOnePixel", b.fx, "fx: 0.518", nullptr, y, {"camera.fx", "below one pixel"}, ""},
      {"PrincipalPointFarOutside", cy_line, "cy: 2530.5", nullptr, y,
       {"camera.cy", "principal point far outside", "[-" + b.height.substr(8) + ", " + std::to_string(2 * std::stoi(b.height.substr(8))) + "]"}, ""},
      // a non-UTF-8 byte and an escape sequence in a YAML value are quoted escaped
      {"YamlValueBytesEscaped", b.fy, "fy: \"\\xff\\x1b[31m\"", nullptr, y, {"camera.fy", "\\x1b[31m"}, ""},
      {"QuaternionTooShort", q1, "[0, 0, 1]", nullptr, y, {"keyframes[0].pose.orientation", "4 numbers"}, ""},
      {"QuaternionInf", q1, "[0, 0, 0, .inf]", nullptr, y, {"keyframes[0].pose.orientation[3]", "finite"}, ""},
      {"PositionWord", p1, "[0.2, up, 0.8]", nullptr, y, {"keyframes[0].pose.position[1]", "number"}, ""},
      {"PositionMap", p1, "{x: 0.2}", nullptr, y, {"keyframes[0].pose.position", "list"}, ""},
      {"ScaleZero",
       kf_scale,
       "      scale: 0\n    depth: keyframes/1_depth.png",
       nullptr,
       y,
       {"keyframes[0].pose.scale", "> 0"},
       ""},
      {"ScaleNegative",
       kf_scale,
       "      scale: -1.0\n    depth: keyframes/1_depth.png",
       nullptr,
       y,
       {"keyframes[0].pose.scale", "> 0"},
       ""},
      {"ScaleWord",
       kf_scale,
       "      scale: big\n    depth: keyframes/1_depth.png",
       nullptr,
       y,
       {"keyframes[0].pose.scale", "number"},
       ""},
      {"DepthScaleMissing", "    " + b.depth_scale1 + "\n", "", nullptr, y, {"keyframes[0].depth_scale", "required"}, ""},
      {"DepthScaleZero", b.depth_scale1, "depth_scale: 0", nullptr, y, {"keyframes[0].depth_scale", "> 0"}, ""},
      {"DepthScaleList",
       b.depth_scale1,
       "depth_scale: [1000]",
       nullptr,
       y,
       {"keyframes[0].depth_scale", "number"},
       ""},
      {"ImageEmptyPath", "image: keyframes/1.png", "image: ''", nullptr, y, {"keyframes[0].image", "empty"}, ""},
      // the map cloud
      {"CloudMissing", "", "", removeFile("map.pcd"), "map.pcd", {"not found", "(cloud)"}, ""},
      {"CloudEmptyFile", "", "", writeFile("map.pcd", ""), "map.pcd", {"empty", "(cloud)"}, ""},
      {"CloudTruncated", "", "", truncateFile("map.pcd", 0.5), "map.pcd", {"truncated", "(cloud)"}, ""},
      {"CloudHeaderOnly", "", "", truncateAfter("map.pcd", "DATA binary\n"), "map.pcd", {"(cloud)"}, ""},
      {"CloudGarbage", "", "", writeFile("map.pcd", garbage(5000, 5)), "map.pcd", {"(cloud)"}, ""},
      {"CloudNoPoints", "", "", writeFile("map.pcd", xyzHeader("0", "binary")), "map.pcd", {"empty", "(cloud)"}, ""},
      {"CloudAllNan",
       "",
       "",
       writeFile("map.pcd", xyzHeader("2", "binary") + floats({NAN, 0, 0, 1, INFINITY, 2})),
       "map.pcd",
       {"NaN", "(cloud)"},
       ""},
      {"CloudHeaderLies",
       "",
       "",
       writeFile("map.pcd", xyzHeader("150000000", "binary") + floats({1, 2, 3})),
       "map.pcd",
       {"POINTS", "(cloud)"},
       ""},
      {"CloudNoXyz",
       "",
       "",
       writeFile("map.pcd", pcdHeader("a b c", "4 4 4", "F F F", "1 1 1", "1", "ascii") + "1 2 3\n"),
       "map.pcd",
       {"x y z", "(cloud)"},
       ""},
      {"CloudIsDirectory", "cloud: map.pcd", "cloud: keyframes", nullptr, "keyframes", {"(cloud)"}, ""},
      {"CloudIsDevice",
       "cloud: map.pcd",
       "cloud: /dev/zero",
       nullptr,
       "/dev/zero",
       {"not a regular file", "(cloud)"},
       ""},
      {"CloudWrongType", "cloud: map.pcd", "cloud: [map.pcd]", nullptr, y, {"cloud", "string"}, ""},
      // keyframe images
      {"ImageMissing", "", "", removeFile(img), img, {"not found", "(keyframes[0].image)"}, ""},
      {"ImageEmptyFile", "", "", writeFile(img, ""), img, {"(keyframes[0].image)"}, ""},
      {"ImageGarbage",
       "",
       "",
       writeFile(img, garbage(4000, 7)),
       img,
       {"cannot read image", "(keyframes[0].image)"},
       ""},
      {"ImageTruncated", "", "", truncateFile(img, 0.5), img, {"truncated PNG", "(keyframes[0].image)"}, ""},
      {"ImageBadCrc", "", "", flipByte(img, 100), img, {"CRC", "(keyframes[0].image)"}, ""},
      {"ImageTruncatedJpeg", "", "", truncatedJpeg(img), img, {"(keyframes[0].image)"}, ""},
      {"ImageWrongSize", "", "", writeImage(img, small_grey), img, {"320x240", "(keyframes[0].image)"}, ""},
      {"Image16Bit", "", "", writeImage(img, grey16), img, {"8-bit", "(keyframes[0].image)"}, ""},
      {"ImageIsDirectory",
       "image: keyframes/1.png",
       "image: keyframes",
       nullptr,
       "keyframes",
       {"not a regular file", "(keyframes[0].image)"},
       ""},
      {"ImageIsDevice",
       "image: keyframes/1.png",
       "image: /dev/zero",
       nullptr,
       "/dev/zero",
       {"not a regular file", "(keyframes[0].image)"},
       ""},
      {"DepthMissing", "", "", removeFile(dep), dep, {"not found", "(keyframes[0].depth)"}, ""},
      {"DepthTruncated", "", "", truncateFile(dep, 0.3), dep, {"(keyframes[0].depth)"}, ""},
      {"DepthGarbage", "", "", writeFile(dep, garbage(3000, 11)), dep, {"(keyframes[0].depth)"}, ""},
      {"Depth8Bit", "", "", writeImage(dep, grey8), dep, {"16-bit", "(keyframes[0].depth)"}, ""},
      {"DepthWrongSize",
       "",
       "",
       writeImage(dep, cv::Mat(240, 320, CV_16UC1, cv::Scalar(1))),
       dep,
       {"320x240", "(keyframes[0].depth)"},
       ""},
      // resource bounds (config limits)
      {"TooManyCloudPoints",
       "",
       "",
       nullptr,
       "map.pcd",
       {"limits.max_cloud_points", "(cloud)"},
       "limits: {max_cloud_points: 1000}\n"},
      {"TooManyKeyframes", "", "", nullptr, y, {"keyframes", "limits.max_keyframes"}, "limits: {max_keyframes: 2}\n"},
      {"CameraTooLarge",
       "",
       "",
       nullptr,
       y,
       {"camera.width", "limits.max_image_pixels"},
       "limits: {max_image_pixels: 100000}\n"},
  };
}

class MergeBadBundle : public ::testing::TestWithParam<BundleDefect> {};

TEST_P(MergeBadBundle, ExitsTwoWithOneLineNamingFileAndField) {
  const BundleDefect& d = GetParam();
  const fs::path copy = scratch() / d.name;
  fs::remove_all(copy);
  fs::copy(base().dir, copy, fs::copy_options::recursive);
  if (!d.from.empty()) {
    std::string text = readText(copy / "bundle.yaml");
    const std::size_t at = text.find(d.from);
    ASSERT_NE(at, std::string::npos) << "test bug: '" << d.from << "' is not in the base bundle.yaml";
    text.replace(at, d.from.size(), d.to);
    writeBytes(copy / "bundle.yaml", text);
  }
  if (d.edit_files) d.edit_files(copy);
  std::string args = "--source " + copy.string() + " --target " + kAgentB;
  if (!d.config.empty()) {
    const fs::path config = scratch() / (d.name + ".yaml");
    writeBytes(config, d.config);
    args += " --config " + config.string();
  }
  const std::string file = d.file.front() == '/' ? d.file : (copy / d.file).string();
  expectBadInput(runTool(PCR_PRO_MERGE_BIN, args), file, d.mentions);
  // The same defect on the target side is reported the same way.
  if (d.name == "ZeroQuaternion" || d.name == "CloudTruncated" || d.name == "ImageTruncated") {
    std::string swapped = "--source " + kAgentB + " --target " + copy.string();
    expectBadInput(runTool(PCR_PRO_MERGE_BIN, swapped), file, d.mentions);
  }
  fs::remove_all(copy);
}

// A quaternion far from unit norm is used normalised, with a warning naming the field and line.
TEST(QuaternionNorm, FarFromUnitIsAWarning) {
  EXPECT_EQ(quaternionNormWarning(1.0 + 0.9 * kQuaternionNormTolerance, "q"), "");
  EXPECT_EQ(quaternionNormWarning(1.0 - 0.9 * kQuaternionNormTolerance, "q"), "");
  EXPECT_EQ(quaternionNormWarning(1.5, "a.orientation"), "a.orientation: quaternion norm 1.5 is not 1 (|norm - 1| > 0.001); normalised");
  EXPECT_NE(quaternionNormWarning(1.0 - 2 * kQuaternionNormTolerance, "q"), "");
  const fs::path copy = scratch() / "quaternion_norm";
  fs::remove_all(copy);
  fs::copy(base().dir, copy, fs::copy_options::recursive);
  // The base bundle's first keyframe's orientation, and the same quaternion doubled.
  const std::string q1 = base().q1;
  const Eigen::Quaterniond q = loadBundle(base().dir.string()).keyframes[0].pose.quaternion();
  const std::string q1_doubled = list({2 * q.x(), 2 * q.y(), 2 * q.z(), 2 * q.w()});
  std::string text = readText(copy / "bundle.yaml");
  ASSERT_NE(text.find(q1), std::string::npos);
  std::vector<std::string> warnings;
  const AgentMap plain = loadBundle(copy.string(), InputLimits(), &warnings);
  EXPECT_TRUE(warnings.empty()) << warnings.front();
  text.replace(text.find(q1), q1.size(), q1_doubled);
  writeBytes(copy / "bundle.yaml", text);
  const AgentMap doubled = loadBundle(copy.string(), InputLimits(), &warnings);
  ASSERT_EQ(warnings.size(), 1u);
  EXPECT_EQ(warnings[0].rfind((copy / "bundle.yaml").string() + ": keyframes[0].pose.orientation: quaternion norm 2", 0), 0u)
      << warnings[0];
  EXPECT_NE(warnings[0].find("(line "), std::string::npos) << warnings[0];
  // used normalised: the same rotation
  EXPECT_LT((doubled.keyframes[0].pose.rotation() - plain.keyframes[0].pose.rotation()).cwiseAbs().maxCoeff(), 1e-9);
  fs::remove_all(copy);
}

// A symlink loop (ELOOP) is reported as one, not as a missing file: a cloud, a bundle directory,
// and a bundle's bundle.yaml and image.
TEST(SymlinkLoop, IsReportedAsOne) {
  const fs::path dir = scratch() / "symlink_loop";
  fs::remove_all(dir);
  fs::create_directories(dir);
  fs::create_symlink(dir / "b.pcd", dir / "a.pcd");
  fs::create_symlink(dir / "a.pcd", dir / "b.pcd");
  const std::string loop = (dir / "a.pcd").string();
  expectBadInput(runTool(PCR_PRO_ICP_BIN, "--source " + loop + " --target " + goodCloud()), loop, {"symlink loop"});
  fs::create_symlink(dir / "bundle_b", dir / "bundle_a");
  fs::create_symlink(dir / "bundle_a", dir / "bundle_b");
  const std::string bundle = (dir / "bundle_a").string();
  expectBadInput(runTool(PCR_PRO_MERGE_BIN, "--source " + bundle + " --target " + kAgentA), bundle, {"symlink loop"});
  const fs::path copy = dir / "copy";
  fs::copy(base().dir, copy, fs::copy_options::recursive);  // its first keyframe is id 1
  fs::remove(copy / "keyframes/1.png");
  fs::create_symlink(copy / "keyframes/1.png", copy / "keyframes/1.png");  // points at itself
  const std::string image = (copy / "keyframes/1.png").string();
  expectBadInput(runTool(PCR_PRO_MERGE_BIN, "--source " + copy.string() + " --target " + kAgentB), image,
                 {"symlink loop", "(keyframes[0].image)"});
  fs::remove_all(dir);
}

INSTANTIATE_TEST_SUITE_P(Defects, MergeBadBundle, ::testing::ValuesIn(bundleDefects()),
                         [](const ::testing::TestParamInfo<BundleDefect>& info) { return info.param.name; });

// ---- pcr_pro_icp over defective clouds ------------------------------------------------------

struct CloudDefect {
  std::string name;
  std::string file_name;  // written into the scratch directory; "" = `path` as is
  std::string bytes;
  std::vector<std::string> mentions;
  std::string config;  // optional --config text
  std::string path;    // used when file_name is empty (a device, a directory, a missing file)
};

void PrintTo(const CloudDefect& d, std::ostream* os) { *os << d.name; }

std::vector<CloudDefect> cloudDefects() {
  const std::string three = floats({1, 2, 3, 4, 5, 6, 7, 8, 9});
  std::string many_rows = "x,y,z\n";
  for (int i = 0; i < 50; ++i) many_rows += std::to_string(i) + ",1,2\n";
  return {
      {"Missing", "", "", {"cannot open"}, "", "/nonexistent/cloud.pcd"},
      {"Directory", "", "", {"not a regular file"}, "", "/tmp"},
      {"Device", "", "", {"not a regular file"}, "", "/dev/zero"},
      {"EmptyPcd", "empty.pcd", "", {"empty"}, "", ""},
      {"EmptyCsv", "empty.csv", "", {"empty"}, "", ""},
      {"GarbagePcd", "garbage.pcd", garbage(2000, 13), {"PCD"}, "", ""},
      {"GarbageCsv", "garbage.csv", garbage(2000, 17), {"line"}, "", ""},
      // bytes from the file are quoted escaped (\xNN): no control character, valid UTF-8
      {"HeaderBytesEscaped", "bytes.pcd", "VERSION 0.7\nFIELDS x y z\n\x01\xfe\x1b[31m\n", {"unexpected header line", "\\x01\\xfe\\x1b[31m"}, "", ""},
      {"CsvBytesEscaped", "bytes.csv", "x,y,z\n1,2,\xff\x07\n", {"non-number", "\\xff\\x07"}, "", ""},
      {"NoDataLine", "nodata.pcd", "FIELDS x y z\nSIZE 4 4 4\n", {"DATA"}, "", ""},
      {"NoXyz", "noxyz.pcd", pcdHeader("a b c", "4 4 4", "F F F", "1 1 1", "3", "binary") + three, {"x y z"}, "", ""},
      {"BadSize",
       "badsize.pcd",
       pcdHeader("x y z", "4 3 4", "F F F", "1 1 1", "1", "binary") + three,
       {"SIZE"},
       "",
       ""},
      {"BadType",
       "badtype.pcd",
       pcdHeader("x y z", "4 4 4", "F Q F", "1 1 1", "1", "binary") + three,
       {"TYPE"},
       "",
       ""},
      {"ZeroCount",
       "zerocount.pcd",
       pcdHeader("x y z", "4 4 4", "F F F", "1 0 1", "1", "binary") + three,
       {"COUNT"},
       "",
       ""},
      {"NegativeWidth",
       "negwidth.pcd",
       pcdHeader("x y z", "4 4 4", "F F F", "1 1 1", "-3", "binary") + three,
       {"WIDTH"},
       "",
       ""},
      {"FieldsDisagree",
       "disagree.pcd",
       pcdHeader("x y z", "4 4", "F F F", "1 1 1", "1", "binary") + three,
       {"FIELDS/SIZE/TYPE/COUNT"},
       "",
       ""},
      {"UnknownData", "unknown.pcd", xyzHeader("3", "lzma") + three, {"DATA", "lzma"}, "", ""},
      {"TruncatedBinary", "trunc.pcd", xyzHeader("1000", "binary") + three, {"truncated"}, "", ""},
      {"TruncatedAscii", "trunc_ascii.pcd", xyzHeader("3", "ascii") + "1 2 3\n4 5\n", {"row 2"}, "", ""},
      {"AsciiWord", "word.pcd", xyzHeader("1", "ascii") + "1 two 3\n", {"row 1", "two"}, "", ""},
      {"HeaderLies", "lies.pcd", xyzHeader("5000000", "binary") + three, {"truncated"}, "", ""},
      {"HeaderBeyondLimit",
       "beyond.pcd",
       xyzHeader("199999999", "binary") + three,
       {"POINTS", "limits.max_cloud_points"},
       "",
       ""},
      {"CountTooLarge", "countbig.pcd", xyzHeader("99999999999", "binary") + three, {"WIDTH", "too large"}, "", ""},
      {"AllNanPcd",
       "nan.pcd",
       xyzHeader("3", "binary") + floats({NAN, 1, 2, 3, NAN, 4, INFINITY, 1, 1}),
       {"NaN"},
       "",
       ""},
      {"AllNanCsv", "nan.csv", "x,y,z\nnan,1,2\n1,inf,2\n", {"NaN"}, "", ""},
      {"CompressedNoSizes", "c0.pcd", xyzHeader("3", "binary_compressed") + "abc", {"compressed"}, "", ""},
      {"CompressedSizeLies",
       "c1.pcd",
       xyzHeader("3", "binary_compressed") + bytesOf({4, 99}) + "abcd",
       {"compressed", "disagrees"},
       "",
       ""},
      {"CompressedTruncated",
       "c2.pcd",
       xyzHeader("3", "binary_compressed") + bytesOf({400, 36}) + "abcd",
       {"compressed", "truncated"},
       "",
       ""},
      {"CompressedCorrupt",
       "c3.pcd",
       xyzHeader("3", "binary_compressed") + bytesOf({4, 36}) + std::string(4, '\xff'),
       {"compressed", "corrupt"},
       "",
       ""},
      {"CompressedBomb",
       "c4.pcd",
       xyzHeader("5000000", "binary_compressed") + bytesOf({4, 60000000}) + "abcd",
       {"compressed", "corrupt"},
       "",
       ""},
      {"CsvShortLine", "short.csv", "1,2,3\n4,5\n", {"line 2"}, "", ""},
      {"CsvWord", "word.csv", "1,2,3\n4,five,6\n", {"line 2", "five"}, "", ""},
      {"CsvHeaderWithoutZ", "noz.csv", "x,y,w\n1,2,3\n", {"header", "x, y, z"}, "", ""},
      {"CsvTooManyPoints",
       "many.csv",
       many_rows,
       {"limits.max_cloud_points", "line"},
       "limits: {max_cloud_points: 20}\n",
       ""},
      {"PcdTooManyPoints",
       "many.pcd",
       xyzHeader("3", "binary") + three,
       {"limits.max_cloud_points", "POINTS"},
       "limits: {max_cloud_points: 2}\n",
       ""},
  };
}

class IcpBadCloud : public ::testing::TestWithParam<CloudDefect> {};

TEST_P(IcpBadCloud, ExitsTwoWithOneLineNamingFileAndField) {
  const CloudDefect& d = GetParam();
  std::string path = d.path;
  if (!d.file_name.empty()) {
    const fs::path dir = scratch() / ("icp_" + d.name);
    fs::create_directories(dir);
    path = (dir / d.file_name).string();
    writeBytes(path, d.bytes);
  }
  std::string config;
  std::string partner = goodCloud();
  if (!d.config.empty()) {
    config = " --config " + (scratch() / (d.name + ".yaml")).string();
    writeBytes(scratch() / (d.name + ".yaml"), d.config);
    partner = (scratch() / "one_point.csv").string();  // within any limit
    writeBytes(partner, "1,2,3\n");
  }
  expectBadInput(runTool(PCR_PRO_ICP_BIN, "--source " + path + " --target " + partner + config), path, d.mentions);
  expectBadInput(runTool(PCR_PRO_ICP_BIN, "--source " + partner + " --target " + path + config), path, d.mentions);
}

INSTANTIATE_TEST_SUITE_P(Defects, IcpBadCloud, ::testing::ValuesIn(cloudDefects()),
                         [](const ::testing::TestParamInfo<CloudDefect>& info) { return info.param.name; });

// ---- configuration files (both tools) -------------------------------------------------------

struct ConfigDefect {
  std::string name;
  std::string text;  // written to a file; empty: `path` is used
  std::vector<std::string> mentions;
  std::string path;
};

void PrintTo(const ConfigDefect& d, std::ostream* os) { *os << d.name; }

class BadConfig : public ::testing::TestWithParam<ConfigDefect> {};

TEST_P(BadConfig, BothToolsExitTwoNamingFileAndKey) {
  const ConfigDefect& d = GetParam();
  std::string path = d.path;
  if (path.empty()) {
    path = (scratch() / ("config_" + d.name + ".yaml")).string();
    writeBytes(path, d.text);
  }
  expectBadInput(runTool(PCR_PRO_MERGE_BIN, "--source " + kAgentB + " --target " + kAgentA + " --config " + path), path,
                 d.mentions);
  expectBadInput(runTool(PCR_PRO_ICP_BIN, "--source " + goodCloud() + " --target " + goodCloud() + " --config " + path), path,
                 d.mentions);
}

INSTANTIATE_TEST_SUITE_P(
    Defects, BadConfig,
    ::testing::Values(
        ConfigDefect{"Missing", "", {"cannot open"}, "/nonexistent/merge.yaml"},
        ConfigDefect{"Device", "", {"not a regular file"}, "/dev/zero"},
        ConfigDefect{"Directory", "", {"not a regular file"}, "/tmp"},
        ConfigDefect{"Garbage", garbage(500, 19), {}, ""},
        ConfigDefect{"TopLevelList", "- a\n- b\n", {"top level"}, ""},
        ConfigDefect{"UnknownKey", "limits: {max_points: 3}\n", {"limits.max_points", "unknown"}, ""},
        ConfigDefect{"DuplicateKey", "icp:\n  stop:\n    max_iterations: 5\n    max_iterations: 90\n",
                     {"icp.stop.max_iterations", "duplicate key (lines 3 and 4)"}, ""},
        ConfigDefect{"LimitZero", "limits: {max_cloud_points: 0}\n", {"limits.max_cloud_points"}, ""},
        ConfigDefect{"LimitTooLarge", "limits: {max_cloud_points: 300000000}\n", {"limits.max_cloud_points"}, ""},
        ConfigDefect{"LimitWrongType", "limits: {max_keyframes: many}\n", {"limits.max_keyframes", "must be an integer, got 'many'"}, ""},
        ConfigDefect{
            "LimitFraction", "limits: {max_image_pixels: 1.5}\n", {"limits.max_image_pixels", "must be an integer, got '1.5'"}, ""},
        ConfigDefect{"LimitsNotAMap", "limits: 5\n", {"limits", "map"}, ""},
        ConfigDefect{"StageWrongType", "icp: {stop: {max_iterations: [1]}}\n", {"icp.stop.max_iterations"}, ""},
        ConfigDefect{"FilterNotAMap", "filters: [voxel_grid]\n", {"filters[0]"}, ""}),
    [](const ::testing::TestParamInfo<ConfigDefect>& info) { return info.param.name; });

// ---- the limits block -----------------------------------------------------------------------

TEST(InputLimits, ShippedConfigCarriesTheStructDefaults) {
  const MergeOptions shipped = loadMergeConfig(std::string(PCR_PRO_CONFIG_DIR) + "/merge.yaml");
  const InputLimits defaults;
  EXPECT_EQ(shipped.limits.max_cloud_points, defaults.max_cloud_points);
  EXPECT_EQ(shipped.limits.max_keyframes, defaults.max_keyframes);
  EXPECT_EQ(shipped.limits.max_image_pixels, defaults.max_image_pixels);
  EXPECT_NO_THROW(validate(defaults));
}

TEST(InputLimits, BundleWithinTheLimitsStillMerges) {
  // The limits set exactly to the generated bundles' sizes: nothing is refused.
  const AgentMap a = loadBundle(kAgentA), b = loadBundle(kAgentB);
  const fs::path config = scratch() / "exact_limits.yaml";
  writeBytes(config, "limits: {max_cloud_points: " + std::to_string(std::max(a.cloud.cols(), b.cloud.cols())) +
                         ", max_keyframes: " + std::to_string(std::max(a.keyframes.size(), b.keyframes.size())) +
                         ", max_image_pixels: " + std::to_string(a.camera.width * a.camera.height) + "}\n");
  const ToolRun r =
      runTool(PCR_PRO_MERGE_BIN, "--source " + kAgentB + " --target " + kAgentA + " --config " + config.string());
  EXPECT_EQ(r.signal, 0);
  EXPECT_EQ(r.exit_status, 0) << r.err;
  EXPECT_NE(r.out.find("status: OK"), std::string::npos) << r.out;
}

}  // namespace
}  // namespace pcr_pro
