// The real two-agent cases that the build makes from the real data (pcr_pro_make_real_cases, into
// BUILD/real_cases; see docs/FORMATS.md): every case is loaded and checked against the raw frames
// and poses of the real-data directory, read here independently of the builder. Skipped, with the
// reason, when the cases or the data are absent.
#include <gtest/gtest.h>
#include <yaml-cpp/yaml.h>

#include <algorithm>
#include <cmath>
#include <cstdint>
#include <cstdio>
#include <fstream>
#include <map>
#include <opencv2/imgcodecs.hpp>
#include <opencv2/imgproc.hpp>
#include <set>
#include <string>
#include <vector>

#include "common/data_dir.h"
#include "pcr_pro/io/bundle.h"
#include "pcr_pro/sim/semi_dense.h"

namespace pcr_pro {
namespace {

constexpr double kRadToDeg = 180.0 / M_PI;

// ---- the index and the raw data, read here ---------------------------------------------------

struct IndexedCase {
  std::string path, data_set;
  bool overlap = false, depth_images = false;
  long ref_target = 0, ref_source = 0;
};

std::vector<IndexedCase> readIndex() {
  std::vector<IndexedCase> out;
  const YAML::Node root = YAML::LoadFile(test::realCasePath("index.yaml"));
  for (const YAML::Node& n : root["cases"]) {
    IndexedCase c;
    c.path = n["path"].as<std::string>();
    c.data_set = n["data_set"].as<std::string>();
    c.overlap = n["overlap"].as<bool>();
    c.depth_images = n["depth_images"].as<bool>();
    c.ref_target = n["reference_pair"][0].as<long>();
    c.ref_source = n["reference_pair"][1].as<long>();
    out.push_back(c);
  }
  return out;
}

bool isSevenScenes(const std::string& data_set) { return data_set == "7scenes_redkitchen"; }

std::string sevenScenesStem(long id) {
  char name[64];
  std::snprintf(name, sizeof name, "7scenes_redkitchen/frames/frame-%06ld", id);
  return test::dataPath(name);
}

// camera -> world of a raw frame [m]: a 4x4 matrix file (7-Scenes; its rotation block, printed to
// about 8 digits, projected onto the nearest rotation) or line `id` of pose.txt (slambook2:
// tx ty tz qx qy qz qw).
Sim3 rawPose(const std::string& data_set, long id) {
  if (isSevenScenes(data_set)) {
    std::ifstream in(sevenScenesStem(id) + ".pose.txt");
    Eigen::Matrix4d m;
    for (int i = 0; i < 16; ++i) in >> m(i / 4, i % 4);
    return Sim3(1.0, projectToRotation(m.topLeftCorner<3, 3>()), m.topRightCorner<3, 1>());
  }
  std::ifstream in(test::dataPath("slambook2_ch5_rgbd/pose.txt"));
  double v[7] = {0, 0, 0, 0, 0, 0, 1};
  for (long line = 1; line <= id; ++line) {
    for (double& x : v) in >> x;
  }
  return Sim3(1.0, Eigen::Quaterniond(v[6], v[3], v[4], v[5]), Eigen::Vector3d(v[0], v[1], v[2]));
}

cv::Mat rawGrey(const std::string& data_set, long id) {
  const std::string path = isSevenScenes(data_set)
                               ? sevenScenesStem(id) + ".color.jpg"
                               : test::dataPath("slambook2_ch5_rgbd/color/" + std::to_string(id) + ".png");
  cv::Mat grey;
  cv::cvtColor(cv::imread(path, cv::IMREAD_COLOR), grey, cv::COLOR_BGR2GRAY);
  return grey;
}

cv::Mat rawDepthMm(const std::string& data_set, long id) {
  return cv::imread(isSevenScenes(data_set) ? sevenScenesStem(id) + ".depth.png"
                                            : test::dataPath("slambook2_ch5_rgbd/depth/" + std::to_string(id) + ".pgm"),
                    cv::IMREAD_UNCHANGED);
}

// Intrinsics of the camera that measured the raw 640x480 depth images: 7-Scenes'
// camera-intrinsics.txt (its depth camera; the colour camera is another one, which the data does
// not calibrate); slambook2's from its SOURCE.txt (joinMap.cpp; its depth is registered to colour,
// so this is its colour camera too).
PinholeCamera rawDepthCamera(const std::string& data_set) {
  PinholeCamera c;
  c.width = 640;
  c.height = 480;
  if (isSevenScenes(data_set)) {
    std::ifstream in(test::dataPath("7scenes_redkitchen/camera-intrinsics.txt"));
    double k[9];
    for (double& x : k) in >> x;
    c.fx = k[0];
    c.fy = k[4];
    c.cx = k[2];
    c.cy = k[5];
  } else {
    c.fx = 518.0;
    c.fy = 519.0;
    c.cx = 325.5;
    c.cy = 253.5;
  }
  return c;
}

// Raw depth [m] of a frame, 0 = none (7-Scenes: 65535 also means none).
cv::Mat rawDepthMetres(const std::string& data_set, long id) {
  const cv::Mat mm = rawDepthMm(data_set, id);
  cv::Mat metres;
  mm.convertTo(metres, CV_32F, 1.0 / 1000.0);
  metres.setTo(0.0f, mm == 65535);
  return metres;
}

// The raw depth seen through a colour camera (in the frame of the depth camera, the extrinsic
// between them ignored as the builder documents): for every colour pixel, the raw depth at the
// depth pixel nearest to where its ray meets the depth image. An inverse lookup, written here
// independently of the builder's forward z-buffer; used for cameras other than the bundle's.
cv::Mat lookUpDepth(const cv::Mat& raw, const PinholeCamera& depth_camera, const PinholeCamera& colour) {
  cv::Mat out(colour.height, colour.width, CV_32FC1, cv::Scalar(0.0f));
  for (int r = 0; r < colour.height; ++r) {
    for (int c = 0; c < colour.width; ++c) {
      const long u = std::lround(depth_camera.cx + depth_camera.fx * (c - colour.cx) / colour.fx);
      const long v = std::lround(depth_camera.cy + depth_camera.fy * (r - colour.cy) / colour.fy);
      if (u >= 0 && v >= 0 && u < raw.cols && v < raw.rows)
        out.at<float>(r, c) = raw.at<float>(static_cast<int>(v), static_cast<int>(u));
    }
  }
  return out;
}

Sim3 flowSim3(const YAML::Node& n) {
  const YAML::Node q = n["rotation"], t = n["translation"];
  return Sim3(n["scale"].as<double>(),
              Eigen::Quaterniond(q[3].as<double>(), q[0].as<double>(), q[1].as<double>(), q[2].as<double>()),
              Eigen::Vector3d(t[0].as<double>(), t[1].as<double>(), t[2].as<double>()));
}

struct LoadedCase {
  IndexedCase index;
  AgentMap target, source;
  BundleTruth truth;
  YAML::Node extra;  // the truth file's further keys
};

LoadedCase loadCase(const IndexedCase& c) {
  const std::string dir = test::realCasePath(c.path);
  LoadedCase out;
  out.index = c;
  out.truth = loadBundleTruth(dir + "/truth.yaml");
  out.target = loadBundle(dir + "/" + out.truth.target_agent);
  out.source = loadBundle(dir + "/" + out.truth.source_agent);
  out.extra = YAML::LoadFile(dir + "/truth.yaml");
  return out;
}

// Skips the test when the cases or the data they were made from are absent; else the index.
#define PCR_PRO_REAL_CASES(cases)                     \
  PCR_PRO_REQUIRE_REAL_CASE("index.yaml");            \
  PCR_PRO_REQUIRE_DATA("7scenes_redkitchen");         \
  PCR_PRO_REQUIRE_DATA("slambook2_ch5_rgbd");         \
  const std::vector<IndexedCase> cases = readIndex(); \
  ASSERT_FALSE(cases.empty())

// For each point in a keyframe's camera frame, whether it lands on a pixel whose measured depth
// agrees with its own within `tolerance` of the depth; *compared counts the points that landed
// on a pixel with depth.
std::vector<bool> seenByDepth(const Cloud& camera_points, const PinholeCamera& camera, const cv::Mat& depth,
                              double tolerance, int* compared) {
  std::vector<bool> seen(static_cast<std::size_t>(camera_points.cols()), false);
  for (Eigen::Index i = 0; i < camera_points.cols(); ++i) {
    double u = 0.0, v = 0.0;
    if (!camera.project(camera_points.col(i), &u, &v)) continue;
    const long c = std::lround(u), r = std::lround(v);
    if (c < 0 || r < 0 || c >= camera.width || r >= camera.height) continue;
    const double d = depth.at<float>(static_cast<int>(r), static_cast<int>(c));
    if (!(d > 0.0)) continue;
    ++*compared;
    seen[static_cast<std::size_t>(i)] = std::abs(camera_points(2, i) - d) <= tolerance * d;
  }
  return seen;
}

// Fraction of `map_points` (in the viewer's map frame) that some keyframe of `viewer` sees.
double fractionSeen(const Cloud& map_points, const AgentMap& viewer, double tolerance) {
  std::vector<bool> any(static_cast<std::size_t>(map_points.cols()), false);
  for (const MapKeyframe& kf : viewer.keyframes) {
    int compared = 0;
    const std::vector<bool> seen =
        seenByDepth(kf.pose.inverse().apply(map_points), viewer.camera, kf.depth, tolerance, &compared);
    for (std::size_t i = 0; i < any.size(); ++i) any[i] = any[i] || seen[i];
  }
  return map_points.cols() ? static_cast<double>(std::count(any.begin(), any.end(), true)) / map_points.cols() : 0.0;
}

// Depth agreement of a seen point: 5 %, above the semi-dense samples' noise (1 % at the reference
// gradient, up to 4 % on weak edges) and Kinect's at room range, below the gap between an
// occluder and what it hides. The same rule the builder uses.
constexpr double kDepthTolerance = 0.05;

// ---- the tests -------------------------------------------------------------------------------

std::string caseBase(const std::string& path) { return path.substr(0, path.rfind('/')); }

TEST(RealCases, IndexHoldsTheCasesTheIssueAsksFor) {
  PCR_PRO_REAL_CASES(cases);
  int overlapping = 0, apart = 0;
  std::set<std::string> with_depth, without_depth, slambook;
  for (const IndexedCase& c : cases) {
    if (!isSevenScenes(c.data_set)) {
      slambook.insert(c.path);
      continue;
    }
    (c.depth_images ? with_depth : without_depth).insert(caseBase(c.path));
    if (!c.depth_images) continue;
    // The camera angle of the reference pair, from the raw poses.
    const double angle =
        rotationDistance(rawPose(c.data_set, c.ref_target).rotation(), rawPose(c.data_set, c.ref_source).rotation()) *
        kRadToDeg;
    if (c.overlap && angle >= 20.0 && angle <= 76.0) ++overlapping;
    if (!c.overlap) ++apart;
  }
  EXPECT_GE(overlapping, 8);
  EXPECT_GE(apart, 2);
  EXPECT_EQ(with_depth, without_depth);  // every 7-Scenes case with and without depth images
  EXPECT_EQ(slambook, (std::set<std::string>{"slambook2/depth", "slambook2/nodepth", "slambook2/nooverlap",
                                             "slambook2/sharedworld"}));
}

// Where a keyframe's registered depth comes from: every depth pixel is one of the raw depths
// around the point where its colour ray meets the depth image (the builder projects each depth
// pixel to the nearest colour pixel, so the source is within about one depth pixel of that
// point); compared in the data's whole millimetres. Where the raw depth is valid all around that
// point, the colour pixel has a depth, as long as the colour camera's pixels are not finer than
// the depth camera's (else a forward projection leaves gaps between its samples).
void expectDepthRegisteredFromRaw(const cv::Mat& depth, const cv::Mat& raw_mm, const PinholeCamera& colour,
                                  const PinholeCamera& depth_camera) {
  const bool no_gaps = colour.fx <= depth_camera.fx && colour.fy <= depth_camera.fy;
  auto raw = [&](long u, long v) -> long {
    if (u < 0 || v < 0 || u >= raw_mm.cols || v >= raw_mm.rows) return 0;
    const long mm = raw_mm.at<std::uint16_t>(static_cast<int>(v), static_cast<int>(u));
    return mm == 65535 ? 0 : mm;
  };
  long foreign = 0, missing = 0, with_depth = 0;
  for (int r = 0; r < depth.rows; ++r) {
    for (int c = 0; c < depth.cols; ++c) {
      const long u = std::lround(depth_camera.cx + depth_camera.fx * (c - colour.cx) / colour.fx);
      const long v = std::lround(depth_camera.cy + depth_camera.fy * (r - colour.cy) / colour.fy);
      const long z_mm = std::lround(1000.0 * depth.at<float>(r, c));
      bool from_neighbour = false, all_valid = true;
      for (long dv = -1; dv <= 1; ++dv) {
        for (long du = -1; du <= 1; ++du) {
          from_neighbour = from_neighbour || (z_mm > 0 && raw(u + du, v + dv) == z_mm);
          all_valid = all_valid && raw(u + du, v + dv) > 0;
        }
      }
      with_depth += z_mm > 0 ? 1 : 0;
      foreign += (z_mm > 0 && !from_neighbour) ? 1 : 0;
      missing += (no_gaps && all_valid && z_mm == 0) ? 1 : 0;
    }
  }
  EXPECT_GT(with_depth, depth.rows * depth.cols / 4);  // Kinect depth covers most of a room view
  EXPECT_EQ(foreign, 0);
  EXPECT_EQ(missing, 0);
}

void expectAgentHoldsRawFrames(const AgentMap& map, const IndexedCase& c, const BundleTruth& truth) {
  const PinholeCamera depth_camera = rawDepthCamera(c.data_set);
  cv::Rect window(0, 0, 640, 480);
  if (isSevenScenes(c.data_set)) {
    // The keyframe camera is the colour camera, which the data does not calibrate (the builder
    // measured it; KeyframeCameraIsWhereTheColourImagesAgree checks it against the images). The
    // 7-Scenes cases use whole frames.
    EXPECT_EQ(map.camera.width, 640);
    EXPECT_EQ(map.camera.height, 480);
    EXPECT_DOUBLE_EQ(map.camera.fx, map.camera.fy);
  } else {
    // slambook2: one camera for colour and depth. A crop of the frames (slambook2/nooverlap)
    // shifts the principal point by its offset.
    EXPECT_DOUBLE_EQ(map.camera.fx, depth_camera.fx);
    EXPECT_DOUBLE_EQ(map.camera.fy, depth_camera.fy);
    const int x0 = static_cast<int>(std::lround(depth_camera.cx - map.camera.cx)),
              y0 = static_cast<int>(std::lround(depth_camera.cy - map.camera.cy));
    ASSERT_EQ(depth_camera.cx - map.camera.cx, x0);
    ASSERT_EQ(depth_camera.cy - map.camera.cy, y0);
    ASSERT_TRUE(x0 >= 0 && y0 >= 0 && x0 + map.camera.width <= depth_camera.width &&
                y0 + map.camera.height <= depth_camera.height);
    window = cv::Rect(x0, y0, map.camera.width, map.camera.height);
  }
  EXPECT_GT(map.cloud.cols(), 1000);
  EXPECT_TRUE(map.cloud.allFinite());
  ASSERT_FALSE(map.keyframes.empty());
  for (const MapKeyframe& kf : map.keyframes) {
    SCOPED_TRACE("keyframe " + std::to_string(kf.id));
    EXPECT_EQ(truth.world_poses.count(kf.id), 1u);
    const cv::Mat grey = rawGrey(c.data_set, kf.id);
    ASSERT_FALSE(grey.empty());
    EXPECT_LE(cv::norm(kf.image, grey(window), cv::NORM_INF), 1.0);
    EXPECT_EQ(kf.depth.empty(), !c.depth_images);
    if (!c.depth_images) continue;
    const cv::Mat mm = rawDepthMm(c.data_set, kf.id);
    ASSERT_EQ(mm.type(), CV_16UC1);
    if (!isSevenScenes(c.data_set)) {
      // Registered to colour already: the raw depth, unchanged.
      EXPECT_LE(cv::norm(kf.depth, rawDepthMetres(c.data_set, kf.id)(window), cv::NORM_INF), 1e-6);
    }
    expectDepthRegisteredFromRaw(kf.depth, mm, map.camera, depth_camera);
  }
}

TEST(RealCases, BundlesHoldTheRawFrames) {
  PCR_PRO_REAL_CASES(cases);
  for (const IndexedCase& c : cases) {
    SCOPED_TRACE(c.path);
    const LoadedCase lc = loadCase(c);
    EXPECT_EQ(lc.target.frame_id, lc.truth.target_agent + "/map");
    EXPECT_EQ(lc.source.frame_id, lc.truth.source_agent + "/map");
    EXPECT_EQ(lc.truth.overlap, c.overlap);
    if (isSevenScenes(c.data_set)) {
      EXPECT_EQ(lc.target.keyframes.size(), 5u);
      EXPECT_EQ(lc.source.keyframes.size(), 5u);
    }
    expectAgentHoldsRawFrames(lc.target, c, lc.truth);
    expectAgentHoldsRawFrames(lc.source, c, lc.truth);
  }
}

void expectSim3Near(const Sim3& a, const Sim3& b, double translation_tol, const std::string& what) {
  EXPECT_NEAR(a.scale() / b.scale(), 1.0, 1e-9) << what;
  EXPECT_LT(rotationDistance(a.rotation(), b.rotation()), 1e-8) << what;
  EXPECT_LT((a.translation() - b.translation()).norm(), translation_tol) << what;
}

// Every keyframe pose is its local world -> map similarity G (truth file) applied to the raw
// camera -> world pose: the drifted map agrees with the raw poses where the keyframe is.
void expectKeyframePosesFollowTheRawPoses(const LoadedCase& lc) {
  for (const auto& [map, agent] :
       {std::pair{&lc.target, lc.truth.target_agent}, std::pair{&lc.source, lc.truth.source_agent}}) {
    const YAML::Node truth_kfs = lc.extra["agents"][agent]["keyframes"];
    for (const MapKeyframe& kf : map->keyframes) {
      const Sim3 g = flowSim3(truth_kfs[kf.id]["G"]);
      expectSim3Near(kf.pose, g * rawPose(lc.index.data_set, kf.id), 1e-6 * std::max(1.0, g.scale()),
                     agent + " keyframe " + std::to_string(kf.id));
    }
  }
}

// Each cross-agent keyframe pair: angle and distance from the raw poses; the local similarity
// near the pair turns the bundles' keyframe poses into the raw relative pose exactly; the case's
// one S_target_source does so within the truth's stated accuracy.
void expectKeyframePairsFollowTheRawPoses(const LoadedCase& lc) {
  std::map<long, const MapKeyframe*> kfs;
  for (const AgentMap* map : {&lc.target, &lc.source}) {
    for (const MapKeyframe& kf : map->keyframes) kfs[kf.id] = &kf;
  }
  const YAML::Node acc = lc.extra["truth_accuracy"];
  const double rot_tol = acc["rotation_deg"].as<double>(), scale_tol = acc["scale_rel"].as<double>();
  int pairs = 0;
  for (const YAML::Node& p : lc.extra["keyframe_pairs"]) {
    const long a = p["target"].as<long>(), b = p["source"].as<long>();
    SCOPED_TRACE("pair " + std::to_string(a) + "-" + std::to_string(b));
    const Sim3 raw =
        rawPose(lc.index.data_set, a).inverse() * rawPose(lc.index.data_set, b);  // camera b -> camera a [m]
    EXPECT_NEAR(p["angle_deg"].as<double>(), raw.rotationAngle() * kRadToDeg, 1e-4);
    EXPECT_NEAR(p["distance_m"].as<double>(), raw.translation().norm(), 1e-6);
    const Sim3 local = kfs.at(a)->pose.inverse() * flowSim3(p["local"]) * kfs.at(b)->pose;
    expectSim3Near(local, raw, 1e-6, "local");
    ++pairs;
    if (!lc.truth.overlap || !p["covisible"].as<bool>()) continue;
    const Sim3 global = kfs.at(a)->pose.inverse() * lc.truth.target_source * kfs.at(b)->pose;
    EXPECT_LT(std::abs(global.scale() - 1.0), scale_tol);
    EXPECT_LT(rotationDistance(global.rotation(), raw.rotation()) * kRadToDeg, rot_tol);
  }
  EXPECT_EQ(pairs, static_cast<int>(lc.target.keyframes.size() * lc.source.keyframes.size()));
}

TEST(RealCases, TruthAgreesWithTheRawPoses) {
  PCR_PRO_REAL_CASES(cases);
  for (const IndexedCase& c : cases) {
    SCOPED_TRACE(c.path);
    const LoadedCase lc = loadCase(c);
    for (const auto& [id, pose] : lc.truth.world_poses) {
      const Sim3 raw = rawPose(c.data_set, id);
      EXPECT_LT((pose.translation() - raw.translation()).norm(), 1e-6) << id;
      EXPECT_LT(rotationDistance(pose.rotation(), raw.rotation()), 1e-6) << id;
    }
    const Sim3 composed = lc.truth.world_to_target * lc.truth.world_to_source.inverse();
    expectSim3Near(composed, lc.truth.target_source, 1e-8 * (1.0 + lc.truth.target_source.translation().norm()),
                   "S_target_source = world_to_target * world_to_source^-1");
    expectKeyframePosesFollowTheRawPoses(lc);
    expectKeyframePairsFollowTheRawPoses(lc);
  }
}

TEST(RealCases, OverlapFlagAgreesWithCovisibility) {
  PCR_PRO_REAL_CASES(cases);
  for (const IndexedCase& c : cases) {
    if (!c.depth_images) continue;  // the nodepth twin has the same maps and truth
    SCOPED_TRACE(c.path);
    const LoadedCase lc = loadCase(c);
    const Sim3& s = lc.truth.target_source;
    const double source_seen = fractionSeen(s.apply(lc.source.cloud), lc.target, kDepthTolerance);
    const double target_seen = fractionSeen(s.inverse().apply(lc.target.cloud), lc.source, kDepthTolerance);
    RecordProperty(c.path, std::to_string(source_seen) + " " + std::to_string(target_seen));
    if (lc.truth.overlap) {
      // The builder asks 10 % of each cloud to be seen by some frame of the other window;
      // its keyframes alone (5 of 13-17 frames) see at least half of that.
      EXPECT_GT(std::min(source_seen, target_seen), 0.05) << source_seen << " " << target_seen;
      // The check can fail: a transform 30 % off in scale does not make the maps agree.
      const Sim3 wrong = s * Sim3(1.3, Eigen::Matrix3d::Identity(), Eigen::Vector3d::Zero());
      EXPECT_LT(fractionSeen(wrong.apply(lc.source.cloud), lc.target, kDepthTolerance), 0.5 * source_seen);
    } else {
      EXPECT_LT(std::max(source_seen, target_seen), 0.005) << source_seen << " " << target_seen;
    }
  }
}

// Per keyframe of `viewer`: the median relative depth error of `cloud_owner`'s cloud there, and
// the keyframe's median measured depth [m].
struct Reprojection {
  double median_error = 1.0, median_depth = 0.0;
};

std::vector<Reprojection> reproject(const AgentMap& cloud_owner, const AgentMap& viewer) {
  std::vector<Reprojection> out;
  for (const MapKeyframe& kf : viewer.keyframes) {
    const Cloud in_camera = kf.pose.inverse().apply(cloud_owner.cloud);
    std::vector<double> rel, depth;
    for (int r = 0; r < kf.depth.rows; ++r) {
      for (int c = 0; c < kf.depth.cols; ++c) {
        if (kf.depth.at<float>(r, c) > 0.0f) depth.push_back(kf.depth.at<float>(r, c));
      }
    }
    for (Eigen::Index i = 0; i < in_camera.cols(); ++i) {
      double u = 0.0, v = 0.0;
      if (!viewer.camera.project(in_camera.col(i), &u, &v)) continue;
      const long c = std::lround(u), r = std::lround(v);
      if (c < 0 || r < 0 || c >= viewer.camera.width || r >= viewer.camera.height) continue;
      const double d = kf.depth.at<float>(static_cast<int>(r), static_cast<int>(c));
      if (d > 0.0) rel.push_back(std::abs(in_camera(2, i) - d) / d);
    }
    Reprojection p;
    if (!rel.empty()) {
      std::nth_element(rel.begin(), rel.begin() + static_cast<long>(rel.size() / 2), rel.end());
      p.median_error = rel[rel.size() / 2];
    }
    if (!depth.empty()) {
      std::nth_element(depth.begin(), depth.begin() + static_cast<long>(depth.size() / 2), depth.end());
      p.median_depth = depth[depth.size() / 2];
    }
    out.push_back(p);
  }
  return out;
}

TEST(RealCases, MapCloudsReprojectIntoTheirKeyframes) {
  PCR_PRO_REAL_CASES(cases);
  for (const IndexedCase& c : cases) {
    if (!c.depth_images) continue;
    SCOPED_TRACE(c.path);
    const LoadedCase lc = loadCase(c);
    const double pose_m = lc.extra["truth_accuracy"]["stated_pose"]["translation_m"].as<double>();
    for (const auto& [map, agent] :
         {std::pair{&lc.target, lc.truth.target_agent}, std::pair{&lc.source, lc.truth.source_agent}}) {
      // A point mapped from frame k sits in keyframe j's view with: the scale drift between k and
      // j (at most the agent's whole drift), its semi-dense noise (1 % of the depth at the
      // reference gradient; the median point is about there), and the disagreement of the data's
      // poses of k and j (the stated pose accuracy, relative to the depth seen). The median error
      // stays below the drift, twice the noise and that pose term.
      const double drift = std::abs(lc.extra["agents"][agent]["scale_drift"].as<double>());
      for (const Reprojection& p : reproject(*map, *map)) {
        ASSERT_GT(p.median_depth, 0.0);
        EXPECT_LT(p.median_error, drift + 2.0 * SemiDenseOptions().idepth_noise + pose_m / p.median_depth) << agent;
      }
    }
    // The check can fail: the target's cloud in the source's keyframes (another map frame).
    for (const Reprojection& p : reproject(lc.target, lc.source)) EXPECT_GT(p.median_error, 0.1);
  }
}

// ---- the keyframe camera against the colour images ------------------------------------------

// Grey levels of `grey` at (u, v), bilinear; false outside.
bool bilinear(const cv::Mat& grey, double u, double v, double* out) {
  const int u0 = static_cast<int>(std::floor(u)), v0 = static_cast<int>(std::floor(v));
  if (u0 < 0 || v0 < 0 || u0 + 1 >= grey.cols || v0 + 1 >= grey.rows) return false;
  const double a = u - u0, b = v - v0;
  *out = (1 - a) * (1 - b) * grey.at<std::uint8_t>(v0, u0) + a * (1 - b) * grey.at<std::uint8_t>(v0, u0 + 1) +
         (1 - a) * b * grey.at<std::uint8_t>(v0 + 1, u0) + a * b * grey.at<std::uint8_t>(v0 + 1, u0 + 1);
  return true;
}

// A pixel takes part when its grey-level gradient is at least this [grey levels / px]: where the
// image is flat, any landing point agrees. The semi-dense sampling's own threshold order.
constexpr double kMinWarpGradient = 10.0;

// For every pixel of `from` with a gradient and a depth: put it into the world with its depth,
// camera and true pose, project it into `to` with the same camera and to's true pose, and collect
// |grey difference| there.
void collectWarpDifferences(const cv::Mat& from_grey, const cv::Mat& from_depth, const cv::Mat& to_grey,
                            const PinholeCamera& camera, const Sim3& to_from, std::vector<float>* out) {
  cv::Mat gx, gy;
  cv::Sobel(from_grey, gx, CV_32F, 1, 0, 3, 1.0 / 8.0);  // grey levels / px
  cv::Sobel(from_grey, gy, CV_32F, 0, 1, 3, 1.0 / 8.0);
  for (int r = 1; r + 1 < from_grey.rows; ++r) {
    for (int c = 1; c + 1 < from_grey.cols; ++c) {
      const double z = from_depth.at<float>(r, c);
      if (!(z > 0.0) || std::hypot(gx.at<float>(r, c), gy.at<float>(r, c)) < kMinWarpGradient) continue;
      const Eigen::Vector3d p(z * (c - camera.cx) / camera.fx, z * (r - camera.cy) / camera.fy, z);
      double u = 0.0, v = 0.0, grey = 0.0;
      if (!camera.project(to_from.apply(p), &u, &v) || !bilinear(to_grey, u, v, &grey)) continue;
      out->push_back(static_cast<float>(std::abs(grey - from_grey.at<std::uint8_t>(r, c))));
    }
  }
}

double median(std::vector<float> v) {
  if (v.empty()) return 0.0;
  std::nth_element(v.begin(), v.begin() + static_cast<long>(v.size() / 2), v.end());
  return v[v.size() / 2];
}

// The colour camera's focal is not in the 7-Scenes data; the builder measured it on the frames.
// Here the bundles are held to it: a keyframe's gradient pixels, put into the world with the
// bundle's registered depth and camera and projected into another keyframe with the true poses,
// land where the colour images agree (small grey difference), and less so with the camera's focal
// 5 % shorter or longer or with the depth camera's own intrinsics (the cases' old camera), each
// with the raw depth seen through that camera. Pooled over the keyframe pairs that see each other
// (consecutive keyframes of an agent and the co-visible cross-agent pairs of every overlapping
// case). Why 5 % must show: the builder's measurement pins the focal down to about 2 %; a focal 5 %
// off misplaces a pixel at half the image's width by 16 px in the registration alone, against the
// 1-3 px by which the data's poses misplace it.
TEST(RealCases, KeyframeCameraIsWhereTheColourImagesAgree) {
  PCR_PRO_REAL_CASES(cases);
  constexpr double kFocalStep = 0.05;
  std::vector<float> bundle, shorter, longer, depth_camera;
  int pairs = 0;
  for (const IndexedCase& c : cases) {
    if (!c.depth_images || !c.overlap || !isSevenScenes(c.data_set)) continue;
    const LoadedCase lc = loadCase(c);
    const PinholeCamera& camera = lc.target.camera;
    ASSERT_EQ(lc.source.camera.fx, camera.fx);
    std::map<long, const MapKeyframe*> kfs;
    std::vector<std::pair<long, long>> seeing;  // (from, to)
    for (const AgentMap* map : {&lc.target, &lc.source}) {
      for (std::size_t k = 0; k < map->keyframes.size(); ++k) {
        kfs[map->keyframes[k].id] = &map->keyframes[k];
        if (k > 0) seeing.emplace_back(map->keyframes[k - 1].id, map->keyframes[k].id);
      }
    }
    for (const YAML::Node& p : lc.extra["keyframe_pairs"]) {
      if (p["covisible"].as<bool>()) seeing.emplace_back(p["target"].as<long>(), p["source"].as<long>());
    }
    for (const auto& [from, to] : seeing) {
      const Sim3 to_from = rawPose(c.data_set, to).inverse() * rawPose(c.data_set, from);
      const cv::Mat &from_grey = kfs.at(from)->image, &to_grey = kfs.at(to)->image;
      collectWarpDifferences(from_grey, kfs.at(from)->depth, to_grey, camera, to_from, &bundle);
      const cv::Mat raw = rawDepthMetres(c.data_set, from);
      const PinholeCamera raw_camera = rawDepthCamera(c.data_set);
      for (auto [factor, out] : {std::pair{1.0 - kFocalStep, &shorter}, std::pair{1.0 + kFocalStep, &longer}}) {
        PinholeCamera other = camera;
        other.fx *= factor;
        other.fy *= factor;
        collectWarpDifferences(from_grey, lookUpDepth(raw, raw_camera, other), to_grey, other, to_from, out);
      }
      collectWarpDifferences(from_grey, raw, to_grey, raw_camera, to_from, &depth_camera);
      ++pairs;
    }
  }
  ASSERT_GT(pairs, 50);
  const double at_bundle = median(bundle);
  RecordProperty("median_grey_difference", std::to_string(at_bundle) + " (bundle) " + std::to_string(median(shorter)) +
                                               " (-5 %) " + std::to_string(median(longer)) + " (+5 %) " +
                                               std::to_string(median(depth_camera)) + " (depth camera)");
  EXPECT_LT(at_bundle, median(shorter));
  EXPECT_LT(at_bundle, median(longer));
  EXPECT_LT(at_bundle, median(depth_camera));
}

TEST(RealCases, ScalesAndDriftAreAsDeclared) {
  PCR_PRO_REAL_CASES(cases);
  for (const IndexedCase& c : cases) {
    if (!c.depth_images || !isSevenScenes(c.data_set)) continue;
    SCOPED_TRACE(c.path);
    const LoadedCase lc = loadCase(c);
    for (const auto& [map, agent] :
         {std::pair{&lc.target, lc.truth.target_agent}, std::pair{&lc.source, lc.truth.source_agent}}) {
      const YAML::Node a = lc.extra["agents"][agent];
      const double first = a["scale_first"].as<double>(), last = a["scale_last"].as<double>();
      EXPECT_GE(first, 0.1);
      EXPECT_LE(first, 10.0);
      const double drift = last / first - 1.0;
      EXPECT_NEAR(a["scale_drift"].as<double>(), drift, 1e-3);
      EXPECT_GE(std::abs(drift), 0.01 - 1e-6);
      EXPECT_LE(std::abs(drift), 0.03 + 1e-6);
      // The keyframe scales move monotonically from the first towards the last (path order).
      for (std::size_t k = 1; k < map->keyframes.size(); ++k) {
        const double step = map->keyframes[k].pose.scale() - map->keyframes[k - 1].pose.scale();
        EXPECT_GE(step * drift, 0.0) << agent << " keyframe " << map->keyframes[k].id;
      }
      EXPECT_NEAR(map->keyframes.front().pose.scale(), first, 1e-7 * first);  // the first keyframe is the first frame
    }
  }
}

}  // namespace
}  // namespace pcr_pro
