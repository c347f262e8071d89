// Message conversions (round trips on the generated demo world's keyframes), LSD-SLAM decoding and
// filters, the agent store and parameter validation. Plain gtest: no ROS master needed.
#include <gtest/gtest.h>
#include <ros/message_traits.h>

#include <cmath>
#include <cstring>
#include <functional>
#include <limits>

#include <pcl_conversions/pcl_conversions.h>

#include "common/option_checks.h"
#include "common/sim_worlds.h"
#include "pcr_pro/io/bundle.h"
#include "pcr_pro/merge/agent_store.h"
#include "pcr_pro/pcl.h"
#include "pcr_pro/ros/msg_conversion.h"
#include "pcr_pro/ros/node_options.h"

namespace pcr_pro {
namespace ros_bridge {
namespace {

Sim3 someSim3() {
  return Sim3(0.4, Eigen::Quaterniond(Eigen::AngleAxisd(2.0, Eigen::Vector3d(-0.5, 0.8, 0.6).normalized())),
              Eigen::Vector3d(2.5, -1.2, 3.0));
}

void expectSim3Near(const Sim3& a, const Sim3& b, double tol) {
  EXPECT_NEAR(a.scale(), b.scale(), tol * b.scale());
  EXPECT_LT(rotationDistance(a.rotation(), b.rotation()), tol);
  EXPECT_LT((a.translation() - b.translation()).norm(), tol * (1.0 + b.translation().norm()));
}

// agent_b of the generated demo world: 640x480 keyframes with dense depth, a semi-dense map cloud.
AgentMap generatedAgent() { return loadBundle(test::simPath("demo/agent_b")); }

// --- LSD-SLAM message types -------------------------------------------------------------------

TEST(LsdSlamMessages, TypeNamesAndMd5SumsAreLsdSlams) {
  // The MD5 sums of an unmodified LSD-SLAM (lsd_slam_viewer package).
  EXPECT_STREQ(ros::message_traits::DataType<lsd_slam_viewer::keyframeMsg>::value(), "lsd_slam_viewer/keyframeMsg");
  EXPECT_STREQ(ros::message_traits::MD5Sum<lsd_slam_viewer::keyframeMsg>::value(), "42d4108dbb7d0e5d166eb68dd4054826");
  EXPECT_STREQ(ros::message_traits::DataType<lsd_slam_viewer::keyframeGraphMsg>::value(),
               "lsd_slam_viewer/keyframeGraphMsg");
  EXPECT_STREQ(ros::message_traits::MD5Sum<lsd_slam_viewer::keyframeGraphMsg>::value(),
               "d23a8a86773b54db7399debf884d0c9e");
}

TEST(LsdSlamMessages, Sim3LayoutIsSophus) {
  const Sim3 s = someSim3();
  const std::array<float, 7> v = sim3ToLsd(s);
  const Eigen::Quaterniond q = s.quaternion().normalized();
  EXPECT_NEAR(v[0], 0.4 * q.x(), 1e-6);
  EXPECT_NEAR(v[3], 0.4 * q.w(), 1e-6);
  EXPECT_NEAR(v[4], 2.5, 1e-6);
  EXPECT_NEAR(v[6], 3.0, 1e-6);
  EXPECT_NEAR(std::sqrt(v[0] * v[0] + v[1] * v[1] + v[2] * v[2] + v[3] * v[3]), 0.4, 1e-6);  // scale = |q|
  expectSim3Near(sim3FromLsd(v.data()), s, 1e-6);
  const float zero[7] = {0, 0, 0, 0, 1, 2, 3};
  EXPECT_THROW(sim3FromLsd(zero), InputError);
  const float nan[7] = {0, 0, 0, NAN, 1, 2, 3};
  EXPECT_THROW(sim3FromLsd(nan), InputError);
}

LsdKeyframe syntheticLsdKeyframe(int w = 40, int h = 30) {
  LsdKeyframe kf;
  kf.id = 7;
  kf.time = 12.5;
  kf.camera = {50.0, 52.0, 20.0, 15.0, w, h};
  kf.cam_to_world = someSim3();
  kf.idepth = cv::Mat(h, w, CV_32FC1, cv::Scalar(0.5f));  // depth 2
  kf.idepth_var = cv::Mat(h, w, CV_32FC1, cv::Scalar(1e-5f));
  kf.image.create(h, w, CV_8UC1);
  for (int r = 0; r < h; ++r)
    for (int c = 0; c < w; ++c) kf.image.at<std::uint8_t>(r, c) = static_cast<std::uint8_t>((r * 7 + c * 3) % 256);
  return kf;
}

TEST(LsdSlamMessages, KeyframeRoundTrip) {
  const LsdKeyframe kf = syntheticLsdKeyframe();
  const lsd_slam_viewer::keyframeMsg msg = lsdKeyframeToMsg(kf);
  EXPECT_EQ(msg.pointcloud.size(), 40u * 30u * 12u);
  EXPECT_TRUE(msg.isKeyframe);
  // Record layout: float idepth, float idepth_var, uchar color[4].
  float idepth;
  std::memcpy(&idepth, &msg.pointcloud[12 * (3 * 40 + 5)], 4);
  EXPECT_FLOAT_EQ(idepth, 0.5f);
  EXPECT_EQ(msg.pointcloud[12 * (3 * 40 + 5) + 8], kf.image.at<std::uint8_t>(3, 5));
  const LsdKeyframe back = lsdKeyframeFromMsg(msg);
  EXPECT_EQ(back.id, 7);
  EXPECT_DOUBLE_EQ(back.time, 12.5);
  EXPECT_DOUBLE_EQ(back.camera.fx, 50.0);
  EXPECT_EQ(back.camera.width, 40);
  EXPECT_EQ(cv::norm(back.image, kf.image, cv::NORM_INF), 0.0);
  EXPECT_EQ(cv::norm(back.idepth, kf.idepth, cv::NORM_INF), 0.0);
  EXPECT_EQ(cv::norm(back.idepth_var, kf.idepth_var, cv::NORM_INF), 0.0);
  expectSim3Near(back.cam_to_world, kf.cam_to_world, 1e-6);
}

TEST(LsdSlamMessages, BadKeyframesAreRejected) {
  const lsd_slam_viewer::keyframeMsg good = lsdKeyframeToMsg(syntheticLsdKeyframe());
  auto bad = good;
  bad.pointcloud.pop_back();
  EXPECT_THROW(lsdKeyframeFromMsg(bad), InputError);
  bad = good;
  bad.pointcloud.clear();
  EXPECT_THROW(lsdKeyframeFromMsg(bad), InputError);
  bad = good;
  bad.fx = 0.0f;
  EXPECT_THROW(lsdKeyframeFromMsg(bad), InputError);
  bad = good;
  bad.width = 0;
  EXPECT_THROW(lsdKeyframeFromMsg(bad), InputError);
  bad = good;
  std::fill(bad.camToWorld.begin(), bad.camToWorld.begin() + 4, 0.0f);
  EXPECT_THROW(lsdKeyframeFromMsg(bad), InputError);
}

TEST(LsdSlamMessages, GraphRoundTripAndCountChecks) {
  LsdGraph g;
  g.poses = {{3, someSim3()}, {5, Sim3()}};
  g.constraints = {{3, 5, 0.25f}};
  const lsd_slam_viewer::keyframeGraphMsg msg = lsdGraphToMsg(g);
  EXPECT_EQ(msg.numFrames, 2u);
  EXPECT_EQ(msg.frameData.size(), 64u);
  EXPECT_EQ(msg.constraintsData.size(), 12u);
  const LsdGraph back = lsdGraphFromMsg(msg);
  ASSERT_EQ(back.poses.size(), 2u);
  EXPECT_EQ(back.poses[0].first, 3);
  expectSim3Near(back.poses[0].second, someSim3(), 1e-6);
  ASSERT_EQ(back.constraints.size(), 1u);
  EXPECT_EQ(back.constraints[0].to, 5);
  EXPECT_FLOAT_EQ(back.constraints[0].error, 0.25f);
  auto bad = msg;
  bad.numFrames = 3;
  EXPECT_THROW(lsdGraphFromMsg(bad), InputError);
  bad = msg;
  bad.numConstraints = 0;
  EXPECT_THROW(lsdGraphFromMsg(bad), InputError);
  bad = msg;
  std::memset(&bad.frameData[4], 0, 16);  // zero quaternion of the first pose
  EXPECT_THROW(lsdGraphFromMsg(bad), InputError);
  // two poses of one keyframe id: refused, naming the entry and the id
  LsdGraph twice;
  twice.poses = {{3, someSim3()}, {5, Sim3()}, {3, Sim3()}};
  try {
    lsdGraphFromMsg(lsdGraphToMsg(twice));
    ADD_FAILURE() << "a duplicate keyframe id was accepted";
  } catch (const InputError& e) {
    EXPECT_EQ(std::string(e.what()), "frameData[2]: duplicate keyframe id 3 (also frameData[0])");
  }
}

// --- LSD viewer filters -----------------------------------------------------------------------

TEST(LsdFilters, ViewerSemantics) {
  LsdKeyframe kf = syntheticLsdKeyframe();
  LsdFilterOptions o;  // viewer defaults: 1e-3, 1e-1, 7, 1
  const LsdPoints all = extractPoints(kf, o);
  EXPECT_EQ(all.camera_points.cols(), 38 * 28);  // the one-pixel border is skipped
  // A kept point back-projects through K at depth 1 / idepth.
  EXPECT_NEAR(all.depth.at<float>(15, 20), 2.0f, 1e-6);
  EXPECT_EQ(all.depth.at<float>(0, 0), 0.0f);

  // scaled threshold: var * depth^4 = 1e-5 * 16 = 1.6e-4
  o.scaled_depth_var_th = 1e-4;
  EXPECT_EQ(extractPoints(kf, o).camera_points.cols(), 0);
  o = LsdFilterOptions();
  // absolute threshold adds scale^2 = 0.16: 1.6e-4 * 0.16 = 2.56e-5
  o.abs_depth_var_th = 2e-5;
  EXPECT_EQ(extractPoints(kf, o).camera_points.cols(), 0);
  o.abs_depth_var_th = 3e-5;
  EXPECT_EQ(extractPoints(kf, o).camera_points.cols(), 38 * 28);

  // near support: an isolated pixel has support 1 (itself) and goes with min_near_support > 1.
  o = LsdFilterOptions();
  kf.idepth.setTo(0.0f);
  kf.idepth.at<float>(10, 10) = 0.5f;
  EXPECT_EQ(extractPoints(kf, o).camera_points.cols(), 0);
  o.min_near_support = 1;
  EXPECT_EQ(extractPoints(kf, o).camera_points.cols(), 1);
  // a neighbour with a very different inverse depth does not support it
  o.min_near_support = 2;
  kf.idepth.at<float>(10, 11) = 0.9f;
  EXPECT_EQ(extractPoints(kf, o).camera_points.cols(), 0);
  kf.idepth.at<float>(10, 11) = 0.501f;  // (0.001)^2 < 2 * 1e-5
  EXPECT_EQ(extractPoints(kf, o).camera_points.cols(), 2);

  // sparsify keeps about one in k, deterministically
  kf = syntheticLsdKeyframe(200, 100);
  o = LsdFilterOptions();
  o.sparsify_factor = 4;
  const Eigen::Index n = extractPoints(kf, o).camera_points.cols();
  EXPECT_NEAR(static_cast<double>(n) / (198 * 98), 0.25, 0.03);
  EXPECT_EQ(extractPoints(kf, o).camera_points.cols(), n);
}

TEST(LsdFilters, OptionsAreValidated) {
  test::expectEachRefused<LsdFilterOptions>({
      {[](LsdFilterOptions* o) { o->min_near_support = 10; }, "lsd.min_near_support"},
      {[](LsdFilterOptions* o) { o->sparsify_factor = 0; }, "lsd.sparsify_factor"},
      {[](LsdFilterOptions* o) { o->scaled_depth_var_th = 0.0; }, "lsd.scaled_depth_var_th"},
  });
}

// --- pcr_pro messages -------------------------------------------------------------------------

TEST(Conversions, KeyframeRoundTripOnGeneratedFrames) {
  const AgentMap agent = generatedAgent();
  for (bool mm : {false, true}) {
    const MapKeyframe& kf = agent.keyframes.front();
    const pcr_pro::Keyframe msg = keyframeToMsg(kf, agent.camera, agent.frame_id, ros::Time(5.0), mm);
    EXPECT_EQ(msg.header.frame_id, "agent_b/map");
    EXPECT_EQ(msg.depth.encoding, mm ? "16UC1" : "32FC1");
    const DecodedKeyframe back = keyframeFromMsg(msg);
    EXPECT_EQ(back.keyframe.id, kf.id);
    EXPECT_EQ(back.frame_id, "agent_b/map");
    EXPECT_EQ(cv::norm(back.keyframe.image, kf.image, cv::NORM_INF), 0.0);
    ASSERT_FALSE(back.keyframe.depth.empty());
    // 16UC1 rounds to the millimetre: half a millimetre, plus float32 steps at a few metres (~5e-7 m).
    EXPECT_LE(cv::norm(back.keyframe.depth, kf.depth, cv::NORM_INF), mm ? 0.0005 + 1e-6 : 0.0);
    EXPECT_DOUBLE_EQ(back.camera.fx, agent.camera.fx);
    EXPECT_DOUBLE_EQ(back.camera.cy, agent.camera.cy);
    EXPECT_EQ(back.camera.width, agent.camera.width);
    expectSim3Near(back.keyframe.pose, kf.pose, 1e-12);
  }
}

TEST(Conversions, ColourImagesBecomeGrey) {
  cv::Mat grey(4, 6, CV_8UC1, cv::Scalar(100));
  sensor_msgs::Image msg = greyImageToMsg(grey);
  msg.encoding = "rgb8";
  msg.step = 18;
  msg.data.assign(18 * 4, 100);
  const cv::Mat back = greyImageFromMsg(msg);
  EXPECT_EQ(back.type(), CV_8UC1);
  EXPECT_EQ(back.at<std::uint8_t>(2, 3), 100);
}

TEST(Conversions, BadKeyframesAreRejected) {
  const AgentMap agent = generatedAgent();
  const pcr_pro::Keyframe good = keyframeToMsg(agent.keyframes.front(), agent.camera, "", ros::Time(), false);
  auto bad = good;
  bad.camera_info.P[0] = 0.0;  // zero intrinsics
  EXPECT_THROW(keyframeFromMsg(bad), InputError);
  // implausible intrinsics (plausibility.h): one-line errors naming the matrix and the entry
  const auto message = [](const pcr_pro::Keyframe& m) {
    try {
      keyframeFromMsg(m);
    } catch (const InputError& e) {
      return std::string(e.what());
    }
    return std::string("accepted");
  };
  bad = good;
  bad.camera_info.P[5] = 0.5;  // fy below one pixel
  EXPECT_EQ(message(bad).rfind("camera_info.P: fy: a focal length below one pixel", 0), 0u) << message(bad);
  bad = good;
  bad.camera_info.P[2] = 3.0 * good.camera_info.width;  // cx beyond twice the width
  EXPECT_EQ(message(bad).rfind("camera_info.P: cx: principal point far outside the image", 0), 0u) << message(bad);
  bad = good;
  bad.camera_info.P[2] = 1.9 * good.camera_info.width;  // odd but within the bound: accepted
  EXPECT_EQ(message(bad), "accepted");
  bad = good;
  bad.camera_info.width = 320;  // image size vs camera_info
  EXPECT_THROW(keyframeFromMsg(bad), InputError);
  bad = good;
  std::fill(bad.camera_info.P.begin(), bad.camera_info.P.end(), 0.0);
  bad.camera_info.D[0] = 0.1;  // no P (rectified intrinsics) and a distorted image
  EXPECT_THROW(keyframeFromMsg(bad), InputError);
  bad = good;
  bad.image.encoding = "yuv422";
  EXPECT_THROW(keyframeFromMsg(bad), InputError);
  bad = good;
  bad.image.data.resize(100);
  EXPECT_THROW(keyframeFromMsg(bad), InputError);
  bad = good;
  bad.scale = 0.0;
  EXPECT_THROW(keyframeFromMsg(bad), InputError);
  bad = good;
  bad.pose.orientation.w = bad.pose.orientation.x = bad.pose.orientation.y = bad.pose.orientation.z = 0.0;
  EXPECT_THROW(keyframeFromMsg(bad), InputError);
  bad = good;
  bad.depth.width = 320;
  bad.depth.step = 1280;
  bad.depth.data.resize(1280 * 480);
  EXPECT_THROW(keyframeFromMsg(bad), InputError);  // depth size != image size
  try {
    bad = good;
    std::fill(bad.camera_info.P.begin(), bad.camera_info.P.end(), 0.0);
    bad.camera_info.K[4] = -1.0;
    keyframeFromMsg(bad);
    FAIL();
  } catch (const InputError& e) {
    EXPECT_NE(std::string(e.what()).find("camera_info.K"), std::string::npos) << e.what();
  }
}

// ROS camera conventions (issue 14): a rectified image (image_rect) takes its intrinsics from P,
// whatever K (the raw camera's) and D (its distortion) say; without P (all zero) K is used and D
// must be zero.
TEST(Conversions, RectifiedImagesTakeTheirIntrinsicsFromP) {
  const AgentMap agent = generatedAgent();
  const PinholeCamera& truth = agent.camera;
  pcr_pro::Keyframe msg = keyframeToMsg(agent.keyframes.front(), truth, "", ros::Time(), false);
  // As a driver + image_proc publish it: K, D of the raw (distorted) camera, P of the rectified one.
  msg.camera_info.K = {truth.fx * 1.07, 0.0, truth.cx + 9.0, 0.0, truth.fy * 1.05, truth.cy - 6.0, 0.0, 0.0, 1.0};
  msg.camera_info.D = {-0.28, 0.07, 0.001, -0.0005, 0.0};
  msg.camera_info.R = {0.999, 0.01, 0.0, -0.01, 0.999, 0.0, 0.0, 0.0, 1.0};
  msg.camera_info.P[3] = -0.12 * truth.fx;  // a stereo pair's right camera: Tx = -fx * baseline
  const PinholeCamera c = keyframeFromMsg(msg).camera;
  EXPECT_EQ(c.fx, truth.fx);
  EXPECT_EQ(c.fy, truth.fy);
  EXPECT_EQ(c.cx, truth.cx);
  EXPECT_EQ(c.cy, truth.cy);
  // Without P, K is the image's intrinsics (and D must be zero).
  std::fill(msg.camera_info.P.begin(), msg.camera_info.P.end(), 0.0);
  msg.camera_info.D.assign(5, 0.0);
  const PinholeCamera k = keyframeFromMsg(msg).camera;
  EXPECT_DOUBLE_EQ(k.fx, truth.fx * 1.07);
  EXPECT_DOUBLE_EQ(k.cy, truth.cy - 6.0);
  msg.camera_info.D.clear();  // an empty D is no distortion too
  EXPECT_NO_THROW(keyframeFromMsg(msg));
  // Our own messages carry P = [K | 0] and round-trip.
  const sensor_msgs::CameraInfo ours = cameraToMsg(truth);
  EXPECT_EQ(ours.P[0], truth.fx);
  EXPECT_EQ(ours.P[6], truth.cy);
  const PinholeCamera back = cameraFromMsg(ours);
  EXPECT_EQ(back.fx, truth.fx);
  EXPECT_EQ(back.cx, truth.cx);
}

// Binning and a region of interest (REP 104): camera_info's K, P, width and height are the full
// sensor's, roi is a window of it in full-resolution pixels and the image is that window at
// 1 / binning of its size. The image's intrinsics are then (f / b, (c - offset) / b), as
// image_geometry takes them; sent so, a keyframe converts to the camera it was taken with.
TEST(Conversions, BinnedAndWindowedImagesTakeTheirIntrinsicsFromTheWindow) {
  const AgentMap agent = generatedAgent();
  const PinholeCamera& truth = agent.camera;
  const auto sent = [&](int binning, int x_offset, int y_offset, int margin_x, int margin_y) {
    pcr_pro::Keyframe msg = keyframeToMsg(agent.keyframes.front(), truth, "", ros::Time(), false);
    sensor_msgs::CameraInfo& ci = msg.camera_info;
    const int b = std::max(1, binning);  // 0 means 1
    const double fx = b * truth.fx, fy = b * truth.fy;
    const double cx = b * truth.cx + x_offset, cy = b * truth.cy + y_offset;
    ci.K = {fx, 0.0, cx, 0.0, fy, cy, 0.0, 0.0, 1.0};
    ci.P = {fx, 0.0, cx, 0.0, 0.0, fy, cy, 0.0, 0.0, 0.0, 1.0, 0.0};
    ci.binning_x = ci.binning_y = static_cast<std::uint32_t>(binning);
    ci.width = static_cast<std::uint32_t>(b * truth.width + x_offset + margin_x);
    ci.height = static_cast<std::uint32_t>(b * truth.height + y_offset + margin_y);
    if (x_offset || y_offset || margin_x || margin_y) {
      ci.roi.x_offset = static_cast<std::uint32_t>(x_offset);
      ci.roi.y_offset = static_cast<std::uint32_t>(y_offset);
      ci.roi.width = static_cast<std::uint32_t>(b * truth.width);
      ci.roi.height = static_cast<std::uint32_t>(b * truth.height);
    }
    return msg;
  };
  const auto expectTruth = [&](const pcr_pro::Keyframe& msg, const char* what) {
    const PinholeCamera c = keyframeFromMsg(msg).camera;
    EXPECT_DOUBLE_EQ(c.fx, truth.fx) << what;
    EXPECT_DOUBLE_EQ(c.fy, truth.fy) << what;
    EXPECT_DOUBLE_EQ(c.cx, truth.cx) << what;
    EXPECT_DOUBLE_EQ(c.cy, truth.cy) << what;
    EXPECT_EQ(c.width, truth.width) << what;
    EXPECT_EQ(c.height, truth.height) << what;
  };
  expectTruth(sent(2, 0, 0, 0, 0), "binning 2");
  expectTruth(sent(1, 40, 20, 60, 40), "a window");
  expectTruth(sent(2, 80, 40, 120, 80), "a window at binning 2");
  expectTruth(sent(0, 0, 0, 0, 0), "binning 0 (= 1)");
  // Without P (the raw image, D zero) the window is taken from K alike.
  pcr_pro::Keyframe raw = sent(2, 80, 40, 120, 80);
  std::fill(raw.camera_info.P.begin(), raw.camera_info.P.end(), 0.0);
  expectTruth(raw, "a window of the raw image at binning 2");
  // A keyframe image that is not the window's binned size is refused, naming the sizes.
  pcr_pro::Keyframe wrong = sent(2, 0, 0, 0, 0);
  wrong.camera_info.binning_x = wrong.camera_info.binning_y = 4;
  try {
    keyframeFromMsg(wrong);
    ADD_FAILURE() << "an image of twice the binned size was accepted";
  } catch (const InputError& e) {
    EXPECT_NE(std::string(e.what()).find("camera_info size"), std::string::npos) << e.what();
  }
}

TEST(Conversions, CloudRoundTripAndValidation) {
  const AgentMap agent = generatedAgent();
  const sensor_msgs::PointCloud2 msg = cloudToMsg(agent.cloud, "agent_b/map", ros::Time(1.0));
  EXPECT_EQ(msg.width * msg.height, static_cast<std::uint32_t>(agent.cloud.cols()));
  const Cloud back = cloudFromMsg(msg);
  ASSERT_EQ(back.cols(), agent.cloud.cols());
  EXPECT_LT((back - agent.cloud).cwiseAbs().maxCoeff(), 1e-5 * (1.0 + agent.cloud.cwiseAbs().maxCoeff()));

  auto bad = msg;
  bad.data.pop_back();  // width * height * point_step != data.size()
  EXPECT_THROW(cloudFromMsg(bad), InputError);
  bad = msg;
  bad.row_step += 1;
  EXPECT_THROW(cloudFromMsg(bad), InputError);
  bad = msg;
  bad.fields[2].name = "intensity";
  EXPECT_THROW(cloudFromMsg(bad), InputError);
  bad = msg;
  bad.fields[1].datatype = sensor_msgs::PointField::UINT16;
  EXPECT_THROW(cloudFromMsg(bad), InputError);
  bad = msg;
  bad.fields[2].offset = 10;  // 10 + 4 > point_step 12
  EXPECT_THROW(cloudFromMsg(bad), InputError);
  // Non-finite points are dropped.
  bad = msg;
  const float nan = NAN;
  std::memcpy(&bad.data[0], &nan, 4);
  EXPECT_EQ(cloudFromMsg(bad).cols(), agent.cloud.cols() - 1);
}

// The error text of a conversion, or "accepted".
template <typename F>
std::string errorOf(F&& f) {
  try {
    f();
  } catch (const InputError& e) {
    return e.what();
  }
  return "accepted";
}

TEST(Conversions, DuplicatedOrMultiCountCoordinateFieldsAreRejected) {
  const Cloud c = generatedAgent().cloud.leftCols(50);
  const sensor_msgs::PointCloud2 msg = cloudToMsg(c, "agent_b/map", ros::Time(1.0));
  // A second "x" after the first (here at y's offset): which one holds would be undefined.
  auto bad = msg;
  sensor_msgs::PointField second_x = bad.fields[0];
  second_x.offset = 4;
  bad.fields.push_back(second_x);
  EXPECT_EQ(errorOf([&] { cloudFromMsg(bad); }),
            "cloud: field x (fields[3]) is a duplicate: 'x' appears twice");
  // The duplicate first: still refused, naming the later one.
  bad = msg;
  bad.fields.insert(bad.fields.begin(), msg.fields[2]);
  EXPECT_EQ(errorOf([&] { cloudFromMsg(bad); }),
            "cloud: field z (fields[3]) is a duplicate: 'z' appears twice");
  for (std::uint32_t count : {0u, 3u}) {
    bad = msg;
    bad.fields[1].count = count;
    EXPECT_EQ(errorOf([&] { cloudFromMsg(bad); }),
              "cloud: field y (fields[1]) has count " + std::to_string(count) + ": a coordinate must have count 1");
  }
  // Other fields may repeat or have any count: they are not read.
  auto extra = msg;
  sensor_msgs::PointField rgb;
  rgb.name = "rgb";
  rgb.offset = 0;
  rgb.datatype = sensor_msgs::PointField::FLOAT32;
  rgb.count = 4;
  extra.fields.push_back(rgb);
  extra.fields.push_back(rgb);
  EXPECT_EQ(cloudFromMsg(extra).cols(), c.cols());
}

TEST(Conversions, PublishedCloudRoundTripsThroughOursAndPcl) {
  const Cloud c = generatedAgent().cloud;
  const ros::Time stamp(1234.000000789);  // below PCL's microsecond stamps: must be kept exactly
  const sensor_msgs::PointCloud2 msg = cloudToPclMsg(c, "agent_a/map", stamp);
  EXPECT_EQ(msg.header.frame_id, "agent_a/map");
  EXPECT_EQ(msg.header.stamp, stamp);
  EXPECT_EQ(msg.width * msg.height, static_cast<std::uint32_t>(c.cols()));
  EXPECT_EQ(msg.point_step, sizeof(pcl::PointXYZ));
  // float keeps 24 bits: each coordinate within eps * |value| of the double.
  const Eigen::ArrayXXd bound = std::numeric_limits<float>::epsilon() * c.array().abs();
  const Cloud ours = cloudFromMsg(msg);
  ASSERT_EQ(ours.cols(), c.cols());
  EXPECT_TRUE(((ours - c).array().abs() <= bound).all());
  pcl::PointCloud<pcl::PointXYZ> theirs;
  pcl::fromROSMsg(msg, theirs);
  ASSERT_EQ(fromPcl(theirs).cols(), c.cols());
  EXPECT_EQ(fromPcl(theirs), ours);  // the same floats
  // The bags' writer and this one carry the same points.
  EXPECT_EQ(cloudFromMsg(cloudToMsg(c, "agent_a/map", stamp)), ours);
}

TEST(Conversions, ImageSizeGuardIs64Bit) {
  // step * height = 65536 * 65537 = 2^32 + 65536 wraps to 65536 in 32 bits, where cv_bridge makes
  // its check: 65536 bytes would pass it. The guard in front of cv_bridge computes it in 64 bits.
  sensor_msgs::Image msg;
  msg.encoding = "mono8";
  msg.width = 10;
  msg.height = 65537;
  msg.step = 65536;
  msg.data.resize(static_cast<std::uint32_t>(msg.step * msg.height));  // the 32-bit product: 65536
  ASSERT_EQ(msg.data.size(), 65536u);
  EXPECT_EQ(errorOf([&] { greyImageFromMsg(msg); }), "image: data size 65536 != step * height = 4295032832");
}

TEST(Conversions, ImagesThroughCvBridge) {
  // A padded row (step > width) and 16-bit depth under both of its names.
  sensor_msgs::Image grey;
  grey.encoding = "mono8";
  grey.width = 3, grey.height = 2, grey.step = 5;
  grey.data = {1, 2, 3, 0, 0, 4, 5, 6, 0, 0};
  const cv::Mat g = greyImageFromMsg(grey);
  ASSERT_EQ(g.size(), cv::Size(3, 2));
  EXPECT_EQ(g.at<std::uint8_t>(1, 2), 6);
  cv::Mat metres(2, 3, CV_32FC1, cv::Scalar(1.25f));
  metres.at<float>(0, 1) = NAN;
  metres.at<float>(1, 0) = -2.0f;
  metres.at<float>(1, 1) = INFINITY;
  const cv::Mat d = depthFromMsg(depthToMsg(metres));
  EXPECT_EQ(d.at<float>(0, 0), 1.25f);
  EXPECT_EQ(d.at<float>(0, 1), 0.0f);  // unknown depths are 0
  EXPECT_EQ(d.at<float>(1, 0), 0.0f);
  EXPECT_EQ(d.at<float>(1, 1), 0.0f);
  sensor_msgs::Image mm = depthToMsgMillimetres(metres);
  EXPECT_EQ(mm.encoding, "16UC1");
  for (const char* encoding : {"16UC1", "mono16"}) {
    mm.encoding = encoding;
    const cv::Mat back = depthFromMsg(mm);
    EXPECT_EQ(back.at<float>(0, 0), 1.25f) << encoding;
    EXPECT_EQ(back.at<float>(0, 1), 0.0f) << encoding;
  }
}

TEST(Conversions, EdgeRoundTrip) {
  RegistrationReport r;
  r.status = Status::kOk;
  r.transform = someSim3();
  Matrix6d cov = Matrix6d::Identity() * 1e-4;
  cov(0, 3) = cov(3, 0) = 2e-5;
  r.covariance = cov;
  r.information = cov.inverse();
  r.scale_stddev = 0.002;
  r.fitness_rmse = 0.013;
  r.correspondences = 5120;
  r.source_keyframe = 3;
  r.target_keyframe = 2;
  const EdgeNames names{"agent_b", "agent_a", "agent_b/map", "agent_a/map"};
  const pcr_pro::MapEdge msg = edgeToMsg(r, names, ros::Time(3.0));
  EXPECT_EQ(msg.header.frame_id, "agent_a/map");
  EXPECT_EQ(msg.pose.covariance[3], 2e-5);  // row-major (x, y, z, rx, ry, rz)
  EXPECT_EQ(msg.pose.covariance[18], 2e-5);
  EXPECT_DOUBLE_EQ(msg.scale, 0.4);
  const EdgeData back = edgeFromMsg(msg);
  expectSim3Near(back.target_source, *r.transform, 1e-12);
  EXPECT_EQ(back.covariance, cov);
  EXPECT_LT((back.information - cov.inverse()).norm(), 1e-6);
  EXPECT_EQ(back.scale_stddev, 0.002);
  EXPECT_EQ(back.fitness_rmse, 0.013);
  EXPECT_EQ(back.correspondences, 5120);
  EXPECT_EQ(back.source_keyframe, 3);
  EXPECT_EQ(back.target_keyframe, 2);
  EXPECT_EQ(back.names.source_frame, "agent_b/map");
  EXPECT_EQ(back.names.target_agent, "agent_a");
  RegistrationReport failed;
  failed.status = Status::kNotEnoughMatches;
  EXPECT_THROW(edgeToMsg(failed, names, ros::Time()), InputError);

  const geometry_msgs::TransformStamped t = rigidTransformToMsg(*r.transform, "agent_a/map", "agent_b/map", ros::Time());
  EXPECT_EQ(t.header.frame_id, "agent_a/map");
  EXPECT_EQ(t.child_frame_id, "agent_b/map");
  EXPECT_DOUBLE_EQ(t.transform.translation.y, -1.2);
  const Eigen::Quaterniond q(t.transform.rotation.w, t.transform.rotation.x, t.transform.rotation.y,
                             t.transform.rotation.z);
  EXPECT_LT(rotationDistance(q.toRotationMatrix(), r.transform->rotation()), 1e-9);
}

// --- agent store ------------------------------------------------------------------------------

TEST(AgentStore, ResentKeyframeIdReplaces) {
  const AgentMap agent = generatedAgent();
  AgentStore store("agent_b/map");
  EXPECT_FALSE(store.setKeyframe(agent.keyframes[0], agent.camera));
  EXPECT_FALSE(store.setKeyframe(agent.keyframes[1], agent.camera));
  MapKeyframe moved = agent.keyframes[0];
  moved.pose = Sim3(1.0, Eigen::Matrix3d::Identity(), Eigen::Vector3d(1, 2, 3)) * moved.pose;
  EXPECT_TRUE(store.setKeyframe(moved, agent.camera));
  EXPECT_EQ(store.keyframeCount(), 2u);
  Sim3 pose;
  ASSERT_TRUE(store.keyframePose(moved.id, &pose));
  EXPECT_LT((pose.translation() - moved.pose.translation()).norm(), 1e-12);
  PinholeCamera other = agent.camera;
  other.fx += 1.0;
  EXPECT_THROW(store.setKeyframe(agent.keyframes[0], other), InputError);
  store.setCloud(agent.cloud);
  const AgentMap map = store.toAgentMap(LsdFilterOptions());
  EXPECT_EQ(map.frame_id, "agent_b/map");
  EXPECT_EQ(map.keyframes.size(), 2u);
  EXPECT_EQ(map.cloud.cols(), agent.cloud.cols());
}

TEST(AgentStore, GraphUpdatesMoveLsdKeyframesAndTheirPoints) {
  AgentStore store("agent_a/map");
  LsdKeyframe kf = syntheticLsdKeyframe();
  store.setLsdKeyframe(kf);
  const AgentMap before = store.toAgentMap(LsdFilterOptions());
  ASSERT_EQ(before.keyframes.size(), 1u);
  ASSERT_GT(before.cloud.cols(), 0);
  const Sim3 g(2.0, Eigen::Quaterniond(Eigen::AngleAxisd(0.3, Eigen::Vector3d::UnitZ())), Eigen::Vector3d(1, 0, 0));
  EXPECT_EQ(store.updateLsdPoses({{kf.id, g * kf.cam_to_world}, {999, Sim3()}}), 1);
  const AgentMap after = store.toAgentMap(LsdFilterOptions());
  ASSERT_EQ(after.cloud.cols(), before.cloud.cols());
  EXPECT_LT((after.cloud - g.apply(before.cloud)).cwiseAbs().maxCoeff(), 1e-9);
  expectSim3Near(after.keyframes[0].pose, g * kf.cam_to_world, 1e-9);
  // the keyframe depth is the depth of the kept points
  EXPECT_NEAR(after.keyframes[0].depth.at<float>(15, 20), 2.0f, 1e-6);
}

// --- parameters -------------------------------------------------------------------------------

TEST(NodeOptions, DefaultsAreValidAndBadValuesNameTheKey) {
  NodeOptions o;
  EXPECT_NO_THROW(validate(o));
  EXPECT_EQ(o.agents.size(), 2u);
  EXPECT_EQ(o.agents[1].frame_id, "agent_b/map");
  const auto expectKey = [](const NodeOptions& bad, const std::string& key) {
    try {
      validate(bad);
      ADD_FAILURE() << "no error for " << key;
    } catch (const InputError& e) {
      EXPECT_NE(std::string(e.what()).find(key), std::string::npos) << e.what();
    }
  };
  // Each change of the defaults and the key its error must name.
  const std::vector<std::pair<std::function<void(NodeOptions&)>, std::string>> cases = {
      {[](NodeOptions& b) { b.agents.pop_back(); }, "~agents"},
      {[](NodeOptions& b) { b.agents[1].name = "/agent_b"; }, "~agents"},
      {[](NodeOptions& b) { b.agents[1].name = "agent_a"; }, "~agents"},
      {[](NodeOptions& b) { b.agents[0].frame_id = "/map"; }, "~agent_a/frame_id"},
      {[](NodeOptions& b) { b.agents[1].frame_id = "agent_a/map"; }, "~agent_b/frame_id"},
      {[](NodeOptions& b) { b.queue_size = 0; }, "~queue_size"},
      {[](NodeOptions& b) { b.lsd.min_near_support = 12; }, "~lsd.min_near_support"},
      {[](NodeOptions& b) { b.merge.matching.ratio_test = 2.0; }, "~"},
  };
  for (const auto& [change, key] : cases) {
    NodeOptions bad = o;
    change(bad);
    expectKey(bad, key);
  }
}

// A quaternion far from unit norm is used normalised with a warning, also where no node runs and
// ros::Time is not initialised (rosbag API tools, these tests): the fuzzer found that the
// throttled warning read ros::Time::now() and threw there.
TEST(Poses, FarFromUnitQuaternionWarnsWithoutARosClock) {
  ASSERT_FALSE(ros::Time::isValid());
  geometry_msgs::Pose pose;
  pose.orientation.w = 2.0;  // norm 2
  pose.position.x = 1.0;
  Sim3 s;
  ASSERT_NO_THROW(s = sim3FromPose(pose, 1.5));
  EXPECT_LT((s.rotation() - Eigen::Matrix3d::Identity()).cwiseAbs().maxCoeff(), 1e-12);
  EXPECT_DOUBLE_EQ(s.scale(), 1.5);
  ASSERT_NO_THROW(sim3FromPose(pose, 1.5));  // and again, within the throttle period
}

}  // namespace
}  // namespace ros_bridge
}  // namespace pcr_pro
