// pcr_pro/pcl.h: the README's example ("C++ API for PCL users") compiled and run on the generated
// demo world and checked against its truth; conversions of PCL point types; the helpers' errors.
#include <gtest/gtest.h>
#include <pcl/point_cloud.h>
#include <pcl/point_types.h>

#include <cmath>
#include <fstream>
#include <functional>
#include <iostream>
#include <limits>
#include <sstream>
#include <string>
#include <vector>

#include "common/sim_worlds.h"
#include "pcr_pro/io/bundle.h"
#include "pcr_pro/io/truth_comparison.h"
#include "pcr_pro/pcl.h"

namespace pcr_pro {
namespace {

// One agent of a bundle as a PCL user holds it: a coloured PCL cloud, BGR images, depth images,
// camera -> map poses.
struct PclAgent {
  pcl::PointCloud<pcl::PointXYZRGB> cloud;
  PinholeCamera camera;
  std::vector<cv::Mat> images, depths;
  std::vector<Sim3> poses;
};

PclAgent pclAgent(const AgentMap& map) {
  PclAgent a;
  a.cloud = *toPcl<pcl::PointXYZRGB>(map.cloud);
  a.camera = map.camera;
  for (const MapKeyframe& kf : map.keyframes) {
    cv::Mat bgr;
    cv::cvtColor(kf.image, bgr, cv::COLOR_GRAY2BGR);
    a.images.push_back(bgr);
    a.depths.push_back(kf.depth);
    a.poses.push_back(kf.pose);
  }
  return a;
}

// The README's example, line for line between the markers (ReadmeExampleIsThisCode checks it).
MergeResult runReadmeExample(const PclAgent& agent_a, const PclAgent& agent_b) {
  const auto& [cloud_a, camera_a, images_a, depths_a, poses_a] = agent_a;
  const auto& [cloud_b, camera_b, images_b, depths_b, poses_b] = agent_b;
  // README example begin
  const pcr_pro::AgentMap a = pcr_pro::agentFromPcl(cloud_a, camera_a, images_a, depths_a, poses_a);
  const pcr_pro::AgentMap b = pcr_pro::agentFromPcl(cloud_b, camera_b, images_b, depths_b, poses_b);
  const pcr_pro::MergeResult merged = pcr_pro::mergeAgents(b, a);  // b's map into a's frame: S_a_b
  if (merged.report.status == pcr_pro::Status::kOk) std::cout << merged.report.transform->matrix() << "\n";
  // README example end
  return merged;
}

// The lines between two markers of a text, each without its leading and trailing blanks.
std::vector<std::string> linesBetween(const std::string& path, const std::string& begin, const std::string& end) {
  std::ifstream in(path);
  EXPECT_TRUE(in.good()) << path;
  std::vector<std::string> lines;
  bool inside = false;
  for (std::string line; std::getline(in, line);) {
    const auto first = line.find_first_not_of(" \t");
    const std::string trimmed =
        first == std::string::npos ? std::string() : line.substr(first, line.find_last_not_of(" \t") - first + 1);
    if (inside && trimmed == end) return lines;
    if (inside) lines.push_back(trimmed);
    if (trimmed == begin) inside = true;
  }
  ADD_FAILURE() << "no block between '" << begin << "' and '" << end << "' in " << path;
  return {};
}

TEST(PclApi, ReadmeExampleIsThisCode) {
  // The README's block: after its "#include <pcr_pro/pcl.h>" line and the comment lines that
  // describe the inputs, up to the closing fence, must be the code runReadmeExample() runs.
  std::vector<std::string> readme = linesBetween(PCR_PRO_SOURCE_DIR "/README.md", "#include <pcr_pro/pcl.h>", "```");
  std::vector<std::string> code;
  for (const std::string& line : readme) {
    if (!line.empty() && line.rfind("//", 0) != 0) code.push_back(line);
  }
  const std::vector<std::string> here = linesBetween(PCR_PRO_SOURCE_DIR "/test/pcl/test_pcl_api.cpp", "// README example begin", "// README example end");
  ASSERT_FALSE(here.empty());
  EXPECT_EQ(code, here);
}

TEST(PclApi, ReadmeExampleMergesTheDemoWorldToItsTruth) {
  const std::string demo = test::simPath("demo");
  const BundleTruth truth = loadBundleTruth(demo + "/truth.yaml");
  const MergeResult merged = runReadmeExample(pclAgent(loadBundle(demo + "/agent_a")), pclAgent(loadBundle(demo + "/agent_b")));
  ASSERT_EQ(merged.report.status, Status::kOk) << merged.report.message;
  ASSERT_TRUE(merged.report.transform && merged.report.covariance);
  // The tolerance of the world itself (sim_worlds.h: twice the spread of the local truths); the
  // API loses only the clouds' float rounding (1e-7 relative), far below it.
  const TruthErrors e = compareWithTruth(*merged.report.transform, truth.target_source, std::nullopt, std::nullopt);
  const test::PairTolerance tolerance = test::pairTolerance(demo + "/truth.yaml");
  std::printf("readme example: rotation %.3f deg (< %.3f), translation %.4f (< %.4f), scale %.3f %% (< %.3f)\n",
              e.rotation_deg, tolerance.rotation_deg, e.translation, tolerance.translation, e.scale_percent,
              tolerance.scale_percent);
  EXPECT_TRUE(test::within(e, tolerance));
}

// Every point type the API names, through toPcl() and back: float rounding only, as many points.
template <typename PointT>
void expectRoundTrip(const Cloud& cloud) {
  const typename pcl::PointCloud<PointT>::Ptr p = toPcl<PointT>(cloud);
  ASSERT_EQ(p->size(), static_cast<std::size_t>(cloud.cols()));
  EXPECT_EQ(p->height, 1u);
  const Cloud back = fromPcl(*p);
  ASSERT_EQ(back.cols(), cloud.cols());
  // float keeps 24 bits: each coordinate within half a float ulp, bounded by eps * |value|.
  const Eigen::ArrayXXd bound = std::numeric_limits<float>::epsilon() * cloud.array().abs();
  EXPECT_TRUE(((back - cloud).array().abs() <= bound).all());
}

TEST(PclApi, PointTypesRoundTrip) {
  const AgentMap map = loadBundle(test::simPath("demo/agent_b"));
  ASSERT_GT(map.cloud.cols(), 0);
  expectRoundTrip<pcl::PointXYZ>(map.cloud);
  expectRoundTrip<pcl::PointXYZI>(map.cloud);
  expectRoundTrip<pcl::PointXYZRGB>(map.cloud);
}

TEST(PclApi, NonFinitePointsAreDroppedOrRefused) {
  pcl::PointCloud<pcl::PointXYZI> organised(3, 2);  // an organised cloud with holes, as a depth camera gives
  for (std::size_t i = 0; i < organised.size(); ++i) organised[i].x = organised[i].y = organised[i].z = float(i + 1);
  organised[1].x = std::numeric_limits<float>::quiet_NaN();
  organised[4].z = std::numeric_limits<float>::infinity();
  const Cloud c = fromPcl(organised);
  ASSERT_EQ(c.cols(), 4);
  EXPECT_EQ(c(0, 1), 3.0);  // points 0, 2, 3, 5 in order
  Cloud bad = c;
  bad(1, 2) = std::numeric_limits<double>::quiet_NaN();
  EXPECT_THROW(toPcl(bad), InputError);
  bad(1, 2) = 1e39;  // beyond float
  EXPECT_THROW(toPcl(bad), InputError);
}

TEST(PclApi, KeyframeFromImages) {
  PinholeCamera camera;
  camera.fx = camera.fy = 50.0;
  camera.cx = 15.5, camera.cy = 11.5;
  camera.width = 32, camera.height = 24;
  cv::Mat bgr(24, 32, CV_8UC3, cv::Scalar(10, 20, 30));
  cv::Mat mm(24, 32, CV_16UC1, cv::Scalar(1500));
  mm.at<std::uint16_t>(3, 4) = 0;
  const Sim3 pose(2.0, Eigen::Matrix3d::Identity(), Eigen::Vector3d(1, 2, 3));
  const MapKeyframe kf = keyframeFromImages(7, bgr, mm, camera, pose);
  EXPECT_EQ(kf.id, 7);
  ASSERT_EQ(kf.image.type(), CV_8UC1);
  cv::Mat grey;
  cv::cvtColor(bgr, grey, cv::COLOR_BGR2GRAY);
  EXPECT_EQ(cv::countNonZero(kf.image != grey), 0);
  ASSERT_EQ(kf.depth.type(), CV_32FC1);
  EXPECT_FLOAT_EQ(kf.depth.at<float>(0, 0), 1.5f);  // REP 118: millimetres
  EXPECT_EQ(kf.depth.at<float>(3, 4), 0.0f);        // unknown stays unknown
  EXPECT_DOUBLE_EQ(kf.pose.scale(), 2.0);

  cv::Mat metres(24, 32, CV_32FC1, cv::Scalar(2.0f));
  metres.at<float>(1, 1) = std::numeric_limits<float>::quiet_NaN();
  metres.at<float>(1, 2) = -1.0f;
  const MapKeyframe kf2 = keyframeFromImages(8, grey, metres, camera, pose);
  EXPECT_EQ(kf2.depth.at<float>(1, 1), 0.0f);
  EXPECT_EQ(kf2.depth.at<float>(1, 2), 0.0f);
  EXPECT_EQ(kf2.depth.at<float>(2, 2), 2.0f);
  EXPECT_TRUE(keyframeFromImages(9, grey, cv::Mat(), camera, pose).depth.empty());

  const auto expectError = [&](const std::function<void()>& f, const std::string& part) {
    try {
      f();
      ADD_FAILURE() << "no error for " << part;
    } catch (const InputError& e) {
      EXPECT_NE(std::string(e.what()).find(part), std::string::npos) << e.what();
    }
  };
  expectError([&] { keyframeFromImages(1, grey(cv::Rect(0, 0, 16, 24)), cv::Mat(), camera, pose); }, "image: size");
  expectError([&] { keyframeFromImages(1, cv::Mat(24, 32, CV_16UC1), cv::Mat(), camera, pose); }, "image: type");
  expectError([&] { keyframeFromImages(1, grey, metres(cv::Rect(0, 0, 8, 8)), camera, pose); }, "depth: size");
  expectError([&] { keyframeFromImages(1, grey, cv::Mat(24, 32, CV_64FC1), camera, pose); }, "depth: type");
  PinholeCamera no_focal = camera;
  no_focal.fx = 0.0;
  expectError([&] { keyframeFromImages(1, grey, cv::Mat(), no_focal, pose); }, "camera");
  expectError([&] { agentFromPcl(pcl::PointCloud<pcl::PointXYZ>(), camera, {grey, grey}, {}, {pose}); }, "2 images");
  expectError([&] { agentFromPcl(pcl::PointCloud<pcl::PointXYZ>(), camera, {grey, bgr(cv::Rect(0, 0, 4, 4))}, {},
                                 {pose, pose}); },
              "keyframe 1: keyframeFromImages: image: size");
}

}  // namespace
}  // namespace pcr_pro
