// Hardening of the ROS layer (issue 6), no ROS master: every class of bad message the node can
// receive is refused by its conversion with an InputError naming the field (never another
// exception, a crash or a silent success); the agent store keeps within its limits (keyframes:
// the one received longest ago is dropped; clouds: voxelised to the cap) and keeps its data when
// a message is refused; the limits are validated as node parameters.
#include <gtest/gtest.h>

#include <cmath>
#include <cstring>
#include <functional>
#include <limits>
#include <random>
#include <set>
#include <typeinfo>

#include "common/sim_worlds.h"
#include "pcr_pro/io/bundle.h"
#include "pcr_pro/merge/agent_store.h"
#include "pcr_pro/ros/msg_conversion.h"
#include "pcr_pro/ros/node_options.h"

namespace pcr_pro {
namespace ros_bridge {
namespace {

// Runs `f`, which must throw an InputError whose message contains every one of `words`.
template <typename F>
void expectRejected(F f, std::initializer_list<const char*> words, const std::string& what) {
  try {
    f();
    ADD_FAILURE() << what << ": accepted";
  } catch (const InputError& e) {
    const std::string m = e.what();
    EXPECT_EQ(m.find('\n'), std::string::npos) << what << ": " << m;
    for (const char* w : words) EXPECT_NE(m.find(w), std::string::npos) << what << ": '" << w << "' not in: " << m;
  } catch (const std::exception& e) {
    ADD_FAILURE() << what << ": not an InputError but " << typeid(e).name() << ": " << e.what();
  }
}

// agent_b of the generated demo world (keyframes with dense depth, a semi-dense map cloud).
const AgentMap& generatedAgent() {
  static const AgentMap agent = loadBundle(test::simPath("demo/agent_b"));
  return agent;
}

Sim3 someSim3() {
  return Sim3(0.4, Eigen::Quaterniond(Eigen::AngleAxisd(2.0, Eigen::Vector3d(-0.5, 0.8, 0.6).normalized())),
              Eigen::Vector3d(2.5, -1.2, 3.0));
}

LsdKeyframe lsdKeyframe(long id, int w = 40, int h = 30) {
  LsdKeyframe kf;
  kf.id = id;
  kf.camera = {50.0, 52.0, w / 2.0, h / 2.0, w, h};
  kf.cam_to_world = someSim3();
  kf.idepth = cv::Mat(h, w, CV_32FC1, cv::Scalar(0.5f));
  kf.idepth_var = cv::Mat(h, w, CV_32FC1, cv::Scalar(1e-5f));
  kf.image = cv::Mat(h, w, CV_8UC1, cv::Scalar(100));
  return kf;
}

// --- PointCloud2 ------------------------------------------------------------------------------

TEST(BadClouds, EveryInconsistencyIsRefusedNamingTheField) {
  const sensor_msgs::PointCloud2 good = cloudToMsg(generatedAgent().cloud, "agent_b/map", ros::Time(1.0));
  auto bad = good;
  bad.data.push_back(0);
  expectRejected([&] { cloudFromMsg(bad); }, {"cloud", "data size"}, "one byte too many");
  bad = good;
  bad.width += 1;
  expectRejected([&] { cloudFromMsg(bad); }, {"cloud", "width * height * point_step"}, "width too large");
  bad = good;
  bad.point_step = 16;
  expectRejected([&] { cloudFromMsg(bad); }, {"cloud", "data size"}, "point_step vs data");
  // width * height * point_step = 2^31 * 2^31 * 4 = 2^64 wraps to 0 in 64 bits: must not pass as 0 bytes.
  bad = good;
  bad.width = 1u << 31;
  bad.height = 1u << 31;
  bad.point_step = 4;
  bad.row_step = 0;
  bad.data.clear();
  expectRejected([&] { cloudFromMsg(bad); }, {"cloud", "data size"}, "64-bit overflow of the size product");
  bad = good;
  bad.row_step -= 12;
  expectRejected([&] { cloudFromMsg(bad); }, {"cloud", "row_step"}, "row_step");
  bad = good;
  bad.fields.erase(bad.fields.begin());
  expectRejected([&] { cloudFromMsg(bad); }, {"cloud", "no field 'x'"}, "missing field x");
  bad = good;
  bad.fields[1].datatype = sensor_msgs::PointField::INT32;
  expectRejected([&] { cloudFromMsg(bad); }, {"cloud", "field y", "FLOAT32"}, "integer field");
  bad = good;
  bad.fields[2].datatype = sensor_msgs::PointField::FLOAT64;  // 8 + 8 > point_step 12
  expectRejected([&] { cloudFromMsg(bad); }, {"cloud", "field z", "point_step"}, "field beyond point_step");
  bad = good;
  bad.fields[0].offset = 0xFFFFFFF0u;
  expectRejected([&] { cloudFromMsg(bad); }, {"cloud", "field x", "point_step"}, "huge offset");
  bad = good;
  bad.is_bigendian = true;
  expectRejected([&] { cloudFromMsg(bad); }, {"cloud", "big-endian"}, "big-endian");
}

TEST(BadClouds, NonFinitePointsAreDroppedAndCounted) {
  Cloud c(3, 6);
  const double inf = std::numeric_limits<double>::infinity(), nan = std::numeric_limits<double>::quiet_NaN();
  c << 1, nan, 3, inf, 5, 6,  //
      1, 2, 3, 4, -inf, 6,    //
      1, 2, nan, 4, 5, 6;
  const Cloud back = cloudFromMsg(cloudToMsg(c, "m", ros::Time()));
  ASSERT_EQ(back.cols(), 2);  // columns 0 and 5
  EXPECT_TRUE(back.allFinite());
  EXPECT_EQ(back(0, 1), 6.0);
  Cloud all_bad(3, 2);
  all_bad << nan, inf, 0, 0, 0, 0;
  EXPECT_EQ(cloudFromMsg(cloudToMsg(all_bad, "m", ros::Time())).cols(), 0);  // the node refuses it
}

// --- images and CameraInfo --------------------------------------------------------------------

TEST(BadKeyframes, ImagesCamerasAndPosesAreRefusedNamingTheField) {
  const AgentMap& agent = generatedAgent();
  const pcr_pro::Keyframe good = keyframeToMsg(agent.keyframes.front(), agent.camera, "", ros::Time(), false);
  ASSERT_NO_THROW(keyframeFromMsg(good));
  const auto rejected = [&](const std::function<void(pcr_pro::Keyframe&)>& mutate,
                            std::initializer_list<const char*> words, const std::string& what) {
    pcr_pro::Keyframe bad = good;
    mutate(bad);
    expectRejected([&] { keyframeFromMsg(bad); }, words, what);
  };
  // images
  rejected([](auto& m) { m.image.encoding = "yuv422"; }, {"image", "unsupported encoding 'yuv422'"}, "encoding");
  rejected([](auto& m) { m.image.encoding = "16UC1"; }, {"image", "unsupported encoding"}, "depth encoding as image");
  rejected([](auto& m) { m.image.step = m.image.width - 1; }, {"image", "step"}, "step < width");
  rejected([](auto& m) { m.image.data.pop_back(); }, {"image", "data size"}, "short data");
  rejected([](auto& m) { m.image.height = 0; }, {"image", "empty"}, "zero height");
  rejected([](auto& m) { m.image.width = 200000; }, {"image", "100000"}, "huge width");
  rejected([](auto& m) { m.camera_info.width = 320; }, {"image", "camera_info size"}, "image size vs camera_info");
  rejected([](auto& m) { m.camera_info.height = 481; }, {"image", "camera_info size"}, "image size vs camera_info");
  // depth images
  rejected([](auto& m) { m.depth.encoding = "rgb8"; }, {"depth", "unsupported encoding"}, "depth encoding");
  rejected([](auto& m) { m.depth.is_bigendian = 1; }, {"depth", "big-endian"}, "big-endian depth");
  rejected([](auto& m) { m.depth.data.resize(10); }, {"depth", "data size"}, "short depth");
  rejected(
      [](auto& m) {
        m.depth.width = 320;
        m.depth.step = 1280;
        m.depth.data.resize(1280 * 480);
      },
      {"depth", "!= image size"}, "depth size vs image size");
  // camera_info
  // (the intrinsics of a rectified image are in P; K and D describe the raw camera)
  rejected([](auto& m) { m.camera_info.P[0] = 0.0; }, {"camera_info.P", "focal"}, "zero fx");
  rejected([](auto& m) { m.camera_info.P[5] = 0.0; }, {"camera_info.P", "focal"}, "zero fy");
  rejected([](auto& m) { m.camera_info.P[0] = NAN; }, {"camera_info.P", "finite"}, "NaN fx");
  rejected([](auto& m) { m.camera_info.P[2] = INFINITY; }, {"camera_info.P", "finite"}, "infinite cx");
  rejected([](auto& m) { m.camera_info.P[1] = 0.5; }, {"camera_info.P", "skew"}, "skew in P");
  rejected([](auto& m) { m.camera_info.P[10] = 2.0; }, {"camera_info.P", "last row"}, "P[10] != 1");
  const auto without_p = [](pcr_pro::Keyframe& m) { std::fill(m.camera_info.P.begin(), m.camera_info.P.end(), 0.0); };
  rejected([&](auto& m) { without_p(m); std::fill(m.camera_info.K.begin(), m.camera_info.K.end(), 0.0); },
           {"camera_info.K", "focal"}, "all-zero K and P");
  rejected([&](auto& m) { without_p(m); m.camera_info.K[0] = NAN; }, {"camera_info.K", "finite"}, "NaN fx in K");
  rejected([&](auto& m) { without_p(m); m.camera_info.K[1] = 0.5; }, {"camera_info.K", "skew"}, "skew in K");
  rejected([&](auto& m) { without_p(m); m.camera_info.K[8] = 0.0; }, {"camera_info.K", "last row"}, "K[8] != 1");
  rejected([&](auto& m) { without_p(m); m.camera_info.D = {0.0, 0.1}; }, {"camera_info.D", "P is all zero"},
           "distortion without P");
  rejected([](auto& m) { m.camera_info.width = 0; }, {"camera_info", "size"}, "zero camera size");
  // (binning and a window of the sensor are taken as REP 104 says: test_msg_conversion)
  rejected([](auto& m) { m.camera_info.binning_x = 2; }, {"camera_info size"}, "binning with the full-size image");
  rejected([](auto& m) { m.camera_info.binning_y = 100000; }, {"camera_info.binning", "larger than"}, "binning");
  rejected([](auto& m) { m.camera_info.roi.x_offset = 400; m.camera_info.roi.width = 320; m.camera_info.roi.height = 240; },
           {"camera_info.roi", "not a window"}, "roi beyond the image");
  rejected([](auto& m) { m.camera_info.roi.width = 320; m.camera_info.roi.height = 240; m.camera_info.D = {0.1}; },
           {"camera_info.roi", "rectification moves pixels"}, "roi of a rectified distorted image");
  // poses
  rejected([](auto& m) { m.pose.orientation = geometry_msgs::Quaternion(); }, {"pose.orientation"}, "zero quaternion");
  rejected([](auto& m) { m.pose.orientation.w = NAN; }, {"pose.orientation"}, "NaN quaternion");
  rejected([](auto& m) { m.pose.position.y = INFINITY; }, {"pose.position", "finite"}, "infinite position");
  rejected([](auto& m) { m.pose.position.x = 1e12; }, {"pose.position", "degenerate"}, "position at 1e12");
  rejected([](auto& m) { m.scale = 0.0; }, {"scale"}, "zero scale");
  rejected([](auto& m) { m.scale = -2.0; }, {"scale"}, "negative scale");
  rejected([](auto& m) { m.scale = 1e-12; }, {"scale", "degenerate"}, "vanishing scale");
  rejected([](auto& m) { m.scale = 1e12; }, {"scale", "degenerate"}, "huge scale");
}

TEST(BadKeyframes, TextFromTheMessageIsQuotedOnOneLine) {
  // Found by fuzz_ros_keyframe: an encoding with a newline made the warning two lines.
  const AgentMap& agent = generatedAgent();
  pcr_pro::Keyframe bad = keyframeToMsg(agent.keyframes.front(), agent.camera, "", ros::Time(), false);
  bad.image.encoding = std::string("rg\nb8\x1b[31m") + std::string(100, 'x');
  expectRejected([&] { keyframeFromMsg(bad); }, {"image", "unsupported encoding 'rg\\x0ab8\\x1b[31mxxx", "...'"},
                 "control characters in the encoding");
  bad.depth.encoding = std::string("\0\xff", 2);
  bad.image.encoding = "mono8";
  expectRejected([&] { keyframeFromMsg(bad); }, {"depth", "'\\x00\\xff'"}, "control characters in the depth encoding");
  EXPECT_EQ(printable("agent_a/map"), "agent_a/map");
  EXPECT_EQ(printable("a\tb", 64), "a\\x09b");
  EXPECT_EQ(printable("abcdef", 3), "abc...");
}

TEST(BadKeyframes, AcceptedEncodingsAndDepthValuesDecodeSafely) {
  // Every accepted encoding gives a grey image of the message's size; NaN/Inf/negative depth is "unknown" (0).
  for (const std::string enc : {"mono8", "rgb8", "bgr8", "rgba8", "bgra8"}) {
    const int channels = enc == "mono8" ? 1 : enc.size() == 4 ? 3 : 4;
    sensor_msgs::Image m;
    m.encoding = enc;
    m.width = 5;
    m.height = 3;
    m.step = 5 * channels + 3;  // padded rows
    m.data.assign(m.step * m.height, 7);
    const cv::Mat grey = greyImageFromMsg(m);
    EXPECT_EQ(grey.type(), CV_8UC1) << enc;
    EXPECT_EQ(grey.cols, 5) << enc;
    EXPECT_EQ(grey.rows, 3) << enc;
  }
  cv::Mat_<float> d(2, 3);
  d << 1.0f, NAN, INFINITY, -1.0f, 0.0f, 2.5f;
  const cv::Mat back = depthFromMsg(depthToMsg(d));
  EXPECT_EQ(back.at<float>(0, 0), 1.0f);
  EXPECT_EQ(back.at<float>(0, 1), 0.0f);
  EXPECT_EQ(back.at<float>(0, 2), 0.0f);
  EXPECT_EQ(back.at<float>(1, 0), 0.0f);
  EXPECT_EQ(back.at<float>(1, 2), 2.5f);
}

// --- LSD-SLAM ---------------------------------------------------------------------------------

TEST(BadLsdMessages, KeyframesOfTheWrongSizeOrWithADegenerateSim3AreRefused) {
  const lsd_slam_viewer::keyframeMsg good = lsdKeyframeToMsg(lsdKeyframe(7));
  ASSERT_NO_THROW(lsdKeyframeFromMsg(good));
  const auto rejected = [&](const std::function<void(lsd_slam_viewer::keyframeMsg&)>& mutate,
                            std::initializer_list<const char*> words, const std::string& what) {
    lsd_slam_viewer::keyframeMsg bad = good;
    mutate(bad);
    expectRejected([&] { lsdKeyframeFromMsg(bad); }, words, what);
  };
  rejected([](auto& m) { m.pointcloud.pop_back(); }, {"pointcloud", "width * height * 12"}, "one byte short");
  rejected([](auto& m) { m.pointcloud.resize(m.pointcloud.size() + 12); }, {"pointcloud"}, "one record too many");
  rejected([](auto& m) { m.pointcloud.resize(40 * 30 * 8); }, {"pointcloud"}, "8-byte records");
  rejected([](auto& m) { m.pointcloud.clear(); }, {"pointcloud", "without depth"}, "empty pointcloud");
  rejected([](auto& m) { m.height = 31; }, {"pointcloud"}, "height vs bytes");
  rejected([](auto& m) { m.width = 0; }, {"width/height"}, "zero width");
  rejected([](auto& m) { m.width = 1u << 31; }, {"width/height"}, "huge width");
  rejected([](auto& m) { m.fx = 0.0f; }, {"fx/fy/cx/cy"}, "zero fx");
  rejected([](auto& m) { m.fy = -3.0f; }, {"fx/fy/cx/cy"}, "negative fy");
  rejected([](auto& m) { m.cx = NAN; }, {"fx/fy/cx/cy"}, "NaN cx");
  rejected([](auto& m) { m.cy = INFINITY; }, {"fx/fy/cx/cy"}, "infinite cy");
  rejected([](auto& m) { std::fill(m.camToWorld.begin(), m.camToWorld.begin() + 4, 0.0f); },
           {"camToWorld", "degenerate"}, "zero quaternion part");
  rejected([](auto& m) { m.camToWorld[1] = NAN; }, {"camToWorld", "not finite"}, "NaN");
  rejected([](auto& m) { m.camToWorld[5] = -INFINITY; }, {"camToWorld", "not finite"}, "Inf translation");
  rejected(
      [](auto& m) {
        for (int i = 0; i < 4; ++i) m.camToWorld[i] *= 1e-11f;
      },
      {"camToWorld", "scale"}, "scale 4e-12");
  rejected(
      [](auto& m) {
        for (int i = 0; i < 4; ++i) m.camToWorld[i] *= 1e11f;
      },
      {"camToWorld", "scale"}, "scale 4e10");
  rejected([](auto& m) { m.camToWorld[6] = 3e12f; }, {"camToWorld", "degenerate"}, "translation 3e12");
}

TEST(BadLsdMessages, ExtremeDepthsNeverGiveNonFinitePoints) {
  LsdKeyframe kf = lsdKeyframe(3);
  kf.idepth.setTo(std::numeric_limits<float>::denorm_min());  // depth 7e44: depth^4 overflows
  kf.idepth_var.setTo(0.0f);                                  // 0 * inf = NaN must not pass the filters
  LsdFilterOptions o;
  o.min_near_support = 0;
  const LsdPoints p = extractPoints(kf, o);
  EXPECT_TRUE(p.camera_points.allFinite());
  EXPECT_EQ(p.camera_points.cols(), 0);
  kf.idepth.setTo(std::numeric_limits<float>::max());  // depth 3e-39 > 0
  kf.camera.fx = kf.camera.fy = std::numeric_limits<float>::denorm_min();
  const LsdPoints q = extractPoints(kf, o);
  EXPECT_TRUE(q.camera_points.allFinite());
}

TEST(BadLsdMessages, GraphsWithInconsistentCountsOrDegeneratePosesAreRefused) {
  LsdGraph g;
  g.poses = {{3, someSim3()}, {5, Sim3()}, {9, someSim3()}};
  g.constraints = {{3, 5, 0.25f}, {5, 9, 0.5f}};
  const lsd_slam_viewer::keyframeGraphMsg good = lsdGraphToMsg(g);
  ASSERT_NO_THROW(lsdGraphFromMsg(good));
  const auto rejected = [&](const std::function<void(lsd_slam_viewer::keyframeGraphMsg&)>& mutate,
                            std::initializer_list<const char*> words, const std::string& what) {
    lsd_slam_viewer::keyframeGraphMsg bad = good;
    mutate(bad);
    expectRejected([&] { lsdGraphFromMsg(bad); }, words, what);
  };
  rejected([](auto& m) { m.numFrames = 4; }, {"frameData", "numFrames * 32"}, "more frames than data");
  rejected([](auto& m) { m.numFrames = 2; }, {"frameData", "numFrames * 32"}, "fewer frames than data");
  rejected([](auto& m) { m.numFrames = 0xFFFFFFFFu; }, {"frameData"}, "numFrames 2^32 - 1");
  rejected([](auto& m) { m.frameData.pop_back(); }, {"frameData"}, "truncated frameData");
  rejected([](auto& m) { m.numConstraints = 3; }, {"constraintsData", "numConstraints * 12"}, "constraint count");
  rejected([](auto& m) { m.constraintsData.push_back(1); }, {"constraintsData"}, "constraint bytes");
  rejected([](auto& m) { std::memset(&m.frameData[32 + 4], 0, 16); }, {"frameData[1]", "keyframe 5", "degenerate"},
           "zero quaternion of the second pose");
  rejected(
      [](auto& m) {
        const float nan = NAN;
        std::memcpy(&m.frameData[64 + 4 + 4 * 4], &nan, 4);
      },
      {"frameData[2]", "keyframe 9", "not finite"}, "NaN translation of the third pose");
}

// --- the agent store: limits, and data kept when a message is refused --------------------------

TEST(StoreLimits, AreValidatedAndNamedAsNodeParameters) {
  EXPECT_NO_THROW(validate(StoreLimits()));
  StoreLimits l;
  l.max_keyframes = 0;
  expectRejected([&] { validate(l); }, {"max_keyframes_per_agent", ">= 1", "got 0"}, "zero keyframes");
  l = StoreLimits();
  l.max_cloud_points = 999;
  expectRejected([&] { validate(l); }, {"max_cloud_points_per_agent", "got 999"}, "tiny cloud cap");
  expectRejected([&] { AgentStore("m", l); }, {"max_cloud_points_per_agent"}, "store with a bad limit");
  NodeOptions o;
  EXPECT_EQ(o.limits.max_keyframes, StoreLimits().max_keyframes);
  o.limits.max_keyframes = -1;
  expectRejected([&] { validate(o); }, {"~max_keyframes_per_agent"}, "node option");
  o = NodeOptions();
  o.limits.max_cloud_points = 300'000'000;
  expectRejected([&] { validate(o); }, {"~max_cloud_points_per_agent"}, "node option");
}

TEST(StoreLimits, KeyframesBeyondTheCapDropTheOneReceivedLongestAgo) {
  const AgentMap& agent = generatedAgent();
  StoreLimits limits;
  limits.max_keyframes = 3;
  AgentStore store("agent_b/map", limits);
  MapKeyframe kf = agent.keyframes.front();
  std::vector<long> dropped;
  for (long id : {10, 11, 12}) {
    kf.id = id;
    store.setKeyframe(kf, agent.camera, &dropped);
  }
  EXPECT_TRUE(dropped.empty());
  kf.id = 13;
  store.setKeyframe(kf, agent.camera, &dropped);
  EXPECT_EQ(dropped, std::vector<long>{10});
  EXPECT_EQ(store.keyframeIds(), (std::vector<long>{11, 12, 13}));
  // A re-sent id counts as received anew: 11 is now newer than 12.
  kf.id = 11;
  dropped.clear();
  EXPECT_TRUE(store.setKeyframe(kf, agent.camera, &dropped));
  EXPECT_TRUE(dropped.empty());
  kf.id = 14;
  store.setKeyframe(kf, agent.camera, &dropped);
  EXPECT_EQ(dropped, std::vector<long>{12});
  EXPECT_EQ(store.keyframeIds(), (std::vector<long>{11, 13, 14}));
  // A long stream stays at the cap.
  for (long id = 100; id < 400; ++id) {
    kf.id = id;
    store.setKeyframe(kf, agent.camera);
    ASSERT_LE(store.keyframeCount(), 3u);
  }
  EXPECT_EQ(store.keyframeIds(), (std::vector<long>{397, 398, 399}));
  Sim3 pose;
  EXPECT_FALSE(store.keyframePose(396, &pose));
  EXPECT_TRUE(store.keyframePose(399, &pose));
}

TEST(StoreLimits, LsdKeyframesAreCappedTooAndGraphUpdatesIgnoreDroppedIds) {
  StoreLimits limits;
  limits.max_keyframes = 2;
  AgentStore store("agent_a/map", limits);
  std::vector<long> dropped;
  for (long id : {1, 2, 3}) store.setLsdKeyframe(lsdKeyframe(id), &dropped);
  EXPECT_EQ(dropped, std::vector<long>{1});
  EXPECT_EQ(store.keyframeIds(), (std::vector<long>{2, 3}));
  EXPECT_EQ(store.updateLsdPoses({{1, Sim3()}, {2, Sim3()}}), 1);
  EXPECT_EQ(store.toAgentMap(LsdFilterOptions()).keyframes.size(), 2u);
}

TEST(StoreLimits, ARefusedKeyframeLeavesTheStoreAsItWas) {
  const AgentMap& agent = generatedAgent();
  StoreLimits limits;
  limits.max_keyframes = 2;
  AgentStore store("agent_b/map", limits);
  store.setKeyframe(agent.keyframes[0], agent.camera);
  store.setKeyframe(agent.keyframes[1], agent.camera);
  store.setCloud(agent.cloud);
  const std::vector<long> ids = store.keyframeIds();
  PinholeCamera other = agent.camera;
  other.width = 320;
  MapKeyframe kf = agent.keyframes[0];
  kf.id = 99;
  std::vector<long> dropped;
  EXPECT_THROW(store.setKeyframe(kf, other, &dropped), InputError);
  EXPECT_TRUE(dropped.empty());  // nothing dropped for a refused keyframe
  EXPECT_EQ(store.keyframeIds(), ids);
  EXPECT_EQ(store.cloudPoints(), static_cast<std::size_t>(agent.cloud.cols()));
}

// Points of a filled cube, a plane and a line: the cap must fit them and stay close to the cap.
Cloud syntheticCloud(int dims, int n, unsigned seed) {
  std::mt19937 rng(seed);
  std::uniform_real_distribution<double> u(0.0, 4.0);
  Cloud c(3, n);
  for (int i = 0; i < n; ++i) {
    c.col(i) = Eigen::Vector3d(u(rng), dims >= 2 ? u(rng) : 0.0, dims >= 3 ? u(rng) : 0.0);
  }
  return c;
}

TEST(StoreLimits, CloudsAboveTheCapAreVoxelisedCloseToTheCap) {
  for (int dims : {3, 2, 1}) {
    const Cloud c = syntheticCloud(dims, 60000, 7 + dims);
    CloudCap cap;
    const Cloud out = capCloud(c, 10000, &cap);
    EXPECT_LE(out.cols(), 10000) << dims << "-d";
    EXPECT_GE(out.cols(), 5000) << dims << "-d: voxelised much further than needed";
    EXPECT_TRUE(out.allFinite());
    EXPECT_EQ(cap.input_points, 60000);
    EXPECT_EQ(cap.kept_points, out.cols());
    EXPECT_GT(cap.leaf, 0.0) << dims << "-d";
    EXPECT_FALSE(cap.subsampled);
    // voxel centroids stay inside the cloud's bounding box
    EXPECT_TRUE(((out.rowwise().minCoeff() - c.rowwise().minCoeff()).array() >= -1e-12).all());
    EXPECT_TRUE(((out.rowwise().maxCoeff() - c.rowwise().maxCoeff()).array() <= 1e-12).all());
  }
  // Within the cap: unchanged.
  const Cloud small = syntheticCloud(3, 500, 1);
  CloudCap cap;
  const Cloud same = capCloud(small, 500, &cap);
  EXPECT_EQ(same, small);
  EXPECT_FALSE(cap.capped());
  EXPECT_EQ(cap.leaf, 0.0);
  // Extents a voxel grid cannot index (found by fuzz_ros_cloud: denormal, and beyond a double):
  // a uniform subsample, never an undefined conversion in the grid.
  for (const double span : {1e-310, 1e-300, 1e308}) {
    Cloud odd = syntheticCloud(3, 3000, 2) * (span / 4.0);  // coordinates in [0, span]
    if (span > 1.0) {
      odd.row(0).array() -= 0.85 * span;  // x in [-0.85e308, 0.15e308], and one point at 1.7e308:
      odd(0, 0) = 1.7e308;                // max - min overflows to inf
    }
    const Cloud out = capCloud(odd, 1000, &cap);
    EXPECT_EQ(out.cols(), 1000) << span;
    EXPECT_TRUE(cap.subsampled) << span;
    EXPECT_TRUE(out.allFinite()) << span;
  }
  // All points at one place: no extent to size a voxel grid by; a uniform subsample is kept.
  const Cloud one = capCloud(Cloud::Ones(3, 5000), 1000, &cap);
  EXPECT_EQ(one.cols(), 1000);
  EXPECT_TRUE(cap.subsampled);
}

TEST(StoreLimits, TheMapCloudStreamedDenserIsVoxelisedInTheStore) {
  // The generated agent's map cloud three times, jittered by 1e-3 map units (2.5 mm at agent_b's
  // 0.4 units per metre): the store keeps at most the cap.
  const Cloud& map = generatedAgent().cloud;
  Cloud dense(3, 3 * map.cols());
  std::mt19937 rng(3);
  std::normal_distribution<double> jitter(0.0, 1e-3);
  for (int k = 0; k < 3; ++k) {
    for (Eigen::Index i = 0; i < map.cols(); ++i) {
      dense.col(k * map.cols() + i) = map.col(i) + Eigen::Vector3d(jitter(rng), jitter(rng), jitter(rng));
    }
  }
  StoreLimits limits;
  limits.max_cloud_points = static_cast<int>(map.cols() / 2);
  AgentStore store("agent_b/map", limits);
  const CloudCap cap = store.setCloud(dense);
  EXPECT_TRUE(cap.capped());
  EXPECT_LE(store.cloudPoints(), static_cast<std::size_t>(limits.max_cloud_points));
  EXPECT_GE(store.cloudPoints(), static_cast<std::size_t>(limits.max_cloud_points / 2));
  std::printf("map cloud x3 (%ld points) -> %zu points, leaf %.4g, cap %d\n", static_cast<long>(dense.cols()),
              store.cloudPoints(), cap.leaf, limits.max_cloud_points);
}

TEST(StoreLimits, TheLsdMapCloudIsVoxelisedToTheCap) {
  StoreLimits limits;
  limits.max_cloud_points = 1000;
  AgentStore store("agent_a/map", limits);
  store.setLsdKeyframe(lsdKeyframe(1, 200, 100));
  LsdKeyframe second = lsdKeyframe(2, 200, 100);
  second.cam_to_world = Sim3(0.4, Eigen::Matrix3d::Identity(), Eigen::Vector3d(1, 0, 0)) * second.cam_to_world;
  store.setLsdKeyframe(second);
  CloudCap cap;
  const AgentMap map = store.toAgentMap(LsdFilterOptions(), &cap);
  EXPECT_EQ(cap.input_points, 2 * 198 * 98);
  EXPECT_LE(map.cloud.cols(), 1000);
  EXPECT_GE(map.cloud.cols(), 500);
  EXPECT_EQ(cap.kept_points, map.cloud.cols());
  EXPECT_EQ(map.keyframes.size(), 2u);
  // the keyframe depth is untouched by the cloud cap
  EXPECT_GT(cv::countNonZero(map.keyframes[0].depth), 198 * 98 - 1);
}

}  // namespace
}  // namespace ros_bridge
}  // namespace pcr_pro
