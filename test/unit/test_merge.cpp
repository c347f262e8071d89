// End-to-end merges. On the project's generated demo world (BUILD/sim/demo, exact truth; always
// there): scale ratios from 0.1 to 10, given keyframes, the vote preselection, refusal of a pair
// that does not overlap, bad maps, and the pcr_pro_merge command line. On the real slambook2
// two-agent cases that the build makes from the real data (BUILD/real_cases/slambook2,
// pcr_pro_make_real_cases; skipped with the reason when absent): the same accuracy at scale
// ratios from 0.1 to 10 and the shared-world clouds.
#include <gtest/gtest.h>

#include <Eigen/Cholesky>
#include <algorithm>
#include <cstdio>

#include <sys/wait.h>

#include <filesystem>
#include <fstream>
#include <vector>

#include <yaml-cpp/yaml.h>

#include "common/sim_worlds.h"
#include "common/cli_run.h"
#include "pcr_pro/geometry/similarity_fit.h"
#include "pcr_pro/io/bundle.h"
#include "pcr_pro/merge/merge_pipeline.h"
#include "pcr_pro/registration/filters.h"
#include "test_helpers.h"

namespace pcr_pro {
namespace {

// Tolerances the approximate poses of the data allow (slambook2 poses are good to about 1 deg /
// a few cm, the truth files' truth_accuracy; the two agents' maps inherit that disagreement):
// rotation, relative scale, and translation in target units (the target agent is in metres).
constexpr double kRotationTolDeg = 1.0;
constexpr double kScaleTol = 0.015;
constexpr double kTranslationTol = 0.12;

// Expresses an agent's map in units `factor` times larger: S' = diag(factor) ∘ S.
AgentMap rescaled(const AgentMap& map, double factor) {
  AgentMap out = map;
  out.cloud *= factor;
  for (MapKeyframe& kf : out.keyframes) {
    kf.pose = Sim3(factor, Eigen::Matrix3d::Identity(), Eigen::Vector3d::Zero()) * kf.pose;
  }
  return out;
}

using test::Errors;
using test::errors;

class MergeScaleRatios : public ::testing::TestWithParam<std::tuple<std::string, double>> {};

TEST_P(MergeScaleRatios, RecoversTheKnownSimilarity) {
  const std::string variant = std::get<0>(GetParam());
  const double ratio = std::get<1>(GetParam());  // wanted scale of S_target_source
  PCR_PRO_REQUIRE_REAL_CASE("slambook2/" + variant);
  const std::string dir = test::realCasePath("slambook2/" + variant);
  const BundleTruth truth = loadBundleTruth(dir + "/truth.yaml");
  const AgentMap target = loadBundle(dir + "/agent_a");
  // Rescale the source map so that S_target_source has the wanted scale.
  const double factor = truth.target_source.scale() / ratio;
  const AgentMap source = rescaled(loadBundle(dir + "/agent_b"), factor);
  const Sim3 expected = truth.target_source * Sim3(1.0 / factor, Eigen::Matrix3d::Identity(), Eigen::Vector3d::Zero());
  ASSERT_NEAR(expected.scale(), ratio, 1e-12);

  const MergeResult r = mergeMaps(source, target, MergeRequest(), MergeOptions());
  ASSERT_EQ(r.report.status, Status::kOk) << r.report.message;
  ASSERT_TRUE(r.report.transform && r.report.covariance && r.report.information);
  const Errors e = errors(*r.report.transform, expected);
  EXPECT_LT(e.rotation_deg, kRotationTolDeg);
  EXPECT_LT(e.scale_rel, kScaleTol);
  EXPECT_LT(e.translation, kTranslationTol);
  // The Kalman scale alone is already close; ICP refines it.
  EXPECT_LT(std::abs(r.diagnostics.kalman_scale / ratio - 1.0), 0.05);
  EXPECT_TRUE(r.report.scale_difference_detected.value_or(false) || std::abs(std::log(ratio)) < std::log(1.2));
  EXPECT_TRUE(r.report.covariance->allFinite());
  EXPECT_GT(r.report.covariance->diagonal().minCoeff(), 0.0);
}

INSTANTIATE_TEST_SUITE_P(RealBundles, MergeScaleRatios,
                         ::testing::Combine(::testing::Values("depth", "nodepth"),
                                            ::testing::Values(0.1, 0.4, 1.0, 2.5, 10.0)),
                         [](const auto& info) {
                           return std::get<0>(info.param) + "_ratio_" +
                                  std::to_string(static_cast<int>(std::get<1>(info.param) * 10)) + "_tenths";
                         });

// --- the generated demo world (exact truth) ----------------------------------------------------

// The demo pair (agent_b into agent_a) and its tolerance (test/common/sim_worlds.h: twice the spread
// of the keyframe pairs' local truths around the global one, which the drift makes; 0.74 deg,
// 0.028 target units = 2.8 cm in the 7 m room and 1.2 % for config/sim_demo.yaml, against 1 deg,
// 12 cm and 1.5 % on the real data, whose truth is itself only good to about 1 deg and a few cm).
std::string simDemo() { return test::simPath("demo"); }
test::PairTolerance simTolerance() { return test::pairTolerance(simDemo() + "/truth.yaml"); }

void expectWithin(const TruthErrors& e, const test::PairTolerance& t, const std::string& what) {
  std::printf("%s: rotation %.3f deg (< %.3f), translation %.4f (< %.4f), scale %.3f %% (< %.3f)\n", what.c_str(),
              e.rotation_deg, t.rotation_deg, e.translation, t.translation, e.scale_percent, t.scale_percent);
  EXPECT_LT(e.rotation_deg, t.rotation_deg) << what;
  EXPECT_LT(e.translation, t.translation) << what;
  EXPECT_LT(std::abs(e.scale_percent), t.scale_percent) << what;
}

class SimMergeScaleRatios : public ::testing::TestWithParam<double> {};

// The source map rescaled so that S_target_source has the wanted scale: the same tolerance holds,
// as the errors are measured in the target's units and do not depend on the source frame.
TEST_P(SimMergeScaleRatios, RecoversTheExactTruth) {
  const double ratio = GetParam();
  const BundleTruth truth = loadBundleTruth(simDemo() + "/truth.yaml");
  const double factor = truth.target_source.scale() / ratio;
  const AgentMap source = rescaled(loadBundle(simDemo() + "/agent_b"), factor);
  const Sim3 expected = truth.target_source * Sim3(1.0 / factor, Eigen::Matrix3d::Identity(), Eigen::Vector3d::Zero());
  const MergeResult r = mergeMaps(source, loadBundle(simDemo() + "/agent_a"), MergeRequest(), MergeOptions());
  ASSERT_EQ(r.report.status, Status::kOk) << r.report.message;
  ASSERT_TRUE(r.report.transform && r.report.covariance && r.report.information);
  expectWithin(compareWithTruth(*r.report.transform, expected, std::nullopt, std::nullopt), simTolerance(),
               "ratio " + std::to_string(ratio));
  EXPECT_TRUE(r.report.scale_difference_detected.value_or(false) || std::abs(std::log(ratio)) < std::log(1.2));
  EXPECT_TRUE(r.report.covariance->allFinite());
  EXPECT_GT(r.report.covariance->diagonal().minCoeff(), 0.0);
}

INSTANTIATE_TEST_SUITE_P(GeneratedWorld, SimMergeScaleRatios, ::testing::Values(0.1, 1.0, 10.0),
                         [](const auto& info) { return "ratio_" + std::to_string(static_cast<int>(info.param * 10)) + "_tenths"; });

TEST(Merge, GivenKeyframesAreUsed) {
  // Source keyframe 1000 and target keyframe 2 see the same surface (keyframe_pairs of the truth).
  const std::string dir = simDemo();
  MergeRequest req;
  req.source_keyframe = 1000;
  req.target_keyframe = 2;
  const MergeResult r = mergeMaps(loadBundle(dir + "/agent_b"), loadBundle(dir + "/agent_a"), req, MergeOptions());
  ASSERT_EQ(r.report.status, Status::kOk) << r.report.message;
  EXPECT_EQ(r.report.source_keyframe.value_or(-1), 1000);
  EXPECT_EQ(r.report.target_keyframe.value_or(-1), 2);
  EXPECT_EQ(r.diagnostics.candidate_pairs, 1);
  // The edge between the two keyframes: pose_target^-1 * S_target_source * pose_source.
  ASSERT_TRUE(r.report.keyframe_edge);
  EXPECT_EQ(r.report.keyframe_edge->source_keyframe, 1000);
  EXPECT_EQ(r.report.keyframe_edge->target_keyframe, 2);
  const AgentMap s = loadBundle(dir + "/agent_b"), t = loadBundle(dir + "/agent_a");
  Sim3 ps, pt;
  for (const MapKeyframe& kf : s.keyframes) ps = kf.id == 1000 ? kf.pose : ps;
  for (const MapKeyframe& kf : t.keyframes) pt = kf.id == 2 ? kf.pose : pt;
  const Sim3 edge = pt.inverse() * *r.report.transform * ps;
  EXPECT_LT((r.report.keyframe_edge->transform.matrix() - edge.matrix()).cwiseAbs().maxCoeff(), 1e-9 * edge.matrix().norm());
  expectWithin(compareWithTruth(*r.report.transform, loadBundleTruth(dir + "/truth.yaml").target_source, std::nullopt,
                                std::nullopt),
               simTolerance(), "given keyframes");
}

TEST(Merge, SharedWorldCloudsAreRegisteredToTheirExactTruth) {
  // Both clouds sample one world cloud (see docs/FORMATS.md, real cases): the truth is exact for
  // them, so their registration must be far tighter than the real bundles' tolerances (the
  // refinement: 0.02°, 6 mm, 0.04 %; 0.03-0.24 % of the extent and 0.03 % scale with 30 % of the
  // points). The reported estimate combines it with the keyframe estimate, the gates' prior, and
  // that rests on which keyframe pairs pass their own check. The best pair (source 5 / target 4,
  // 150 inliers) must pass it: its relative pose's rotation lies 0.26° from its depth matches',
  // which their per-match noise alone does not cover (squared Mahalanobis distance 22.1 > 16.3),
  // and a pixel's worth of keypoint offset in each image does (keypointOffsetCovariance() in
  // similarity_initializer.cpp). Without that term the other pairs' keyframe estimate was 0.53°,
  // 9 cm, 0.49 % off and the reported one 0.18°; with it, 0.02°.
  PCR_PRO_REQUIRE_REAL_CASE("slambook2/sharedworld");
  const std::string dir = test::realCasePath("slambook2/sharedworld");
  const AgentMap target = loadBundle(dir + "/agent_a"), source = loadBundle(dir + "/agent_b");
  const Sim3 truth = loadBundleTruth(dir + "/truth.yaml").target_source;
  const MergeResult r = mergeMaps(source, target, MergeRequest(), MergeOptions());
  ASSERT_EQ(r.report.status, Status::kOk) << r.report.message;
  ASSERT_TRUE(r.report.transform && r.report.covariance);
  const Errors e = errors(*r.report.transform, truth);
  const Errors refined = errors(r.diagnostics.refined, truth);
  const Errors guess = errors(r.diagnostics.initial, truth);
  std::printf("shared world: reported %.3f deg, %.4f, %.3f %%; refined %.3f deg, %.4f, %.3f %%; keyframe %.3f deg, %.4f, "
              "%.3f %% (%s)\n",
              e.rotation_deg, e.translation, 100 * e.scale_rel, refined.rotation_deg, refined.translation,
              100 * refined.scale_rel, guess.rotation_deg, guess.translation, 100 * guess.scale_rel,
              r.report.message.c_str());
  EXPECT_LT(refined.rotation_deg, 0.15);
  EXPECT_LT(refined.scale_rel, 0.002);
  EXPECT_LT(refined.translation, 0.02);
  const auto best = std::max_element(r.report.keyframe_pairs.begin(), r.report.keyframe_pairs.end(),
                                     [](const KeyframePairReport& a, const KeyframePairReport& b) {
                                       return a.inliers < b.inliers;
                                     });
  ASSERT_NE(best, r.report.keyframe_pairs.end());
  EXPECT_TRUE(best->used) << best->note;
  // The reported estimate: as tight as the refinement's bound, nearer than the keyframe guess,
  // and inside its covariance (6-DoF, chi-square 95 % bound).
  EXPECT_LT(e.rotation_deg, 0.15);
  EXPECT_LT(e.scale_rel, 0.015);
  EXPECT_LT(e.translation, 0.5 * guess.translation);
  const Eigen::Matrix<double, 6, 1> d = similarityDifference(*r.report.transform, truth).head<6>();
  EXPECT_LT(d.dot(r.report.covariance->ldlt().solve(d)), 12.59);
}

// The slambook2 maps without depth images, their clouds thinned to 30 % and 10 % of the points (as
// `make bench`'s robustness sweep does): the keyframe depth then comes from sparser clouds and the
// keyframe estimate is 2.0 % and 2.8 % off in scale, while the refinement is within 0.7 deg and
// 0.3 % and agrees with it within the gate. It used to be set aside because it moved the matches
// farther than the envelope of the two keyframe pairs' own estimates (an envelope of two, and of
// pairs pooled jointly, says nothing: merge_gates.cpp), and the merge reported the keyframe scale.
TEST(Merge, SparseCloudsWithoutDepthImagesKeepTheirRefinement) {
  PCR_PRO_REQUIRE_REAL_CASE("slambook2/nodepth");
  const std::string dir = test::realCasePath("slambook2/nodepth");
  const BundleTruth truth = loadBundleTruth(dir + "/truth.yaml");
  const AgentMap full_target = loadBundle(dir + "/" + truth.target_agent);
  const AgentMap full_source = loadBundle(dir + "/" + truth.source_agent);
  for (const double keep : {0.3, 0.1}) {
    AgentMap target = full_target, source = full_source;
    RandomSamplingOptions thin;
    thin.keep_ratio = keep;
    thin.seed = 101;
    target.cloud = randomSamplingFilter(full_target.cloud, thin);
    thin.seed = 202;
    source.cloud = randomSamplingFilter(full_source.cloud, thin);
    const MergeResult r = mergeMaps(source, target, MergeRequest(), MergeOptions());
    const std::string what = "keep " + std::to_string(keep) + ": " + r.report.message;
    ASSERT_EQ(r.report.status, Status::kOk) << what;
    EXPECT_TRUE(r.report.refinement_kept.value_or(false)) << what;
    const Errors e = errors(*r.report.transform, truth.target_source);
    EXPECT_LT(e.rotation_deg, kRotationTolDeg) << what;
    EXPECT_LT(e.scale_rel, kScaleTol) << what;
    // Where the two put the source map (its centroid), not the translation at the target's origin,
    // which a rotation error within the tolerance moves by its lever arm (10 m here).
    const Eigen::Vector3d centre = source.cloud.rowwise().mean();
    EXPECT_LT((r.report.transform->apply(centre) - truth.target_source.apply(centre)).norm(), kTranslationTol) << what;
  }
}

TEST(Merge, VotePreselectionKeepsTheBestPair) {
  // 3 x 3 keyframes = 9 pairs (fewer than merge.max_candidate_pairs, 10: all are matched); matching
  // only the 2 with most descriptor votes must still find the pair that the full search picks.
  const std::string dir = simDemo();
  const AgentMap target = loadBundle(dir + "/agent_a"), source = loadBundle(dir + "/agent_b");
  const int pairs = static_cast<int>(target.keyframes.size() * source.keyframes.size());
  ASSERT_GT(pairs, 2);
  ASSERT_LE(pairs, MergeOptions().merge.max_candidate_pairs);
  const MergeResult all = mergeMaps(source, target, MergeRequest(), MergeOptions());
  MergeOptions two;
  two.merge.max_candidate_pairs = 2;
  two.merge.local_keyframes = 0;  // the preselection alone, without the best pair's neighbourhood
  const MergeResult few = mergeMaps(source, target, MergeRequest(), two);
  ASSERT_EQ(all.report.status, Status::kOk) << all.report.message;
  ASSERT_EQ(few.report.status, Status::kOk) << few.report.message;
  EXPECT_EQ(all.diagnostics.candidate_pairs, pairs);
  EXPECT_EQ(few.diagnostics.candidate_pairs, 2);
  EXPECT_EQ(few.diagnostics.keyframe_pairs, pairs);
  // The best pair (most relative-pose inliers: first of the verified pairs) is the same. (The edge's
  // anchor need not be: it is the used pair closest to the pooled estimate, which depends on the
  // pairs pooled.)
  ASSERT_FALSE(all.report.keyframe_pairs.empty());
  ASSERT_FALSE(few.report.keyframe_pairs.empty());
  EXPECT_EQ(few.report.keyframe_pairs.front().source_keyframe, all.report.keyframe_pairs.front().source_keyframe);
  EXPECT_EQ(few.report.keyframe_pairs.front().target_keyframe, all.report.keyframe_pairs.front().target_keyframe);
  EXPECT_EQ(few.report.keyframe_pairs.front().inliers, all.report.keyframe_pairs.front().inliers);
  // With the neighbourhood (merge.local_keyframes 3), every pair within 3 keyframes of the best
  // verified one is matched as well: with 3 keyframes per map, all of them.
  two.merge.local_keyframes = 3;
  EXPECT_EQ(mergeMaps(source, target, MergeRequest(), two).diagnostics.candidate_pairs, pairs);
}

TEST(Merge, NonOverlappingMapsAreRefused) {
  // agent_c looks at the other side of the room (truth: overlap false): no merge, and why.
  const std::string dir = simDemo();
  ASSERT_FALSE(loadBundleTruth(dir + "/truth_agent_a_agent_c.yaml").overlap);
  const MergeResult r = mergeMaps(loadBundle(dir + "/agent_c"), loadBundle(dir + "/agent_a"), MergeRequest(), MergeOptions());
  EXPECT_NE(r.report.status, Status::kOk);
  EXPECT_FALSE(r.report.transform);
  EXPECT_FALSE(r.report.message.empty());
}

TEST(Merge, UnknownKeyframeAndBadMapsGiveInvalidInput) {
  const std::string dir = simDemo();
  const AgentMap a = loadBundle(dir + "/agent_a"), b = loadBundle(dir + "/agent_b");
  MergeRequest req;
  req.source_keyframe = 99;
  EXPECT_EQ(mergeMaps(b, a, req, MergeOptions()).report.status, Status::kInvalidInput);
  AgentMap empty = b;
  empty.cloud.resize(3, 0);
  EXPECT_EQ(mergeMaps(empty, a, MergeRequest(), MergeOptions()).report.status, Status::kInvalidInput);
  AgentMap no_kf = b;
  no_kf.keyframes.clear();
  EXPECT_EQ(mergeMaps(no_kf, a, MergeRequest(), MergeOptions()).report.status, Status::kInvalidInput);
}

// Error rule (pcr_pro.h): what the maps hold is a status (above, and a cloud the filters empty);
// only invalid options, the caller's own choice, throw.
TEST(Merge, InvalidOptionsThrowAndAMapTheFiltersEmptyIsAStatus) {
  const std::string dir = simDemo();
  const AgentMap a = loadBundle(dir + "/agent_a"), b = loadBundle(dir + "/agent_b");
  MergeOptions invalid;
  invalid.merge.min_overlap = 2.0;
  EXPECT_THROW(MergePipeline{invalid}, InputError);
  EXPECT_THROW(mergeMaps(b, a, MergeRequest(), invalid), InputError);

  // Each point kept with probability 1e-9: the chain empties the map clouds (checked first).
  MergeOptions sparse;
  FilterStep step;
  step.type = FilterStep::Type::kRandomSampling;
  step.random_sampling.keep_ratio = 1e-9;
  sparse.registration.filters.steps.push_back(step);
  ASSERT_EQ(applyFilterChain(b.cloud, sparse.registration.filters).cols(), 0);
  MergeResult r;
  ASSERT_NO_THROW(r = mergeMaps(b, a, MergeRequest(), sparse));
  EXPECT_EQ(r.report.status, Status::kInvalidInput) << r.report.message;
  EXPECT_FALSE(r.report.transform);
  AgentMap empty = b;
  empty.cloud.resize(3, 0);
  ASSERT_NO_THROW(r = mergeMaps(empty, a, MergeRequest(), MergeOptions()));
  EXPECT_NE(r.report.message.find("empty cloud"), std::string::npos) << r.report.message;
}

TEST(Merge, ShippedConfigLoadsWithStructDefaults) {
  const MergeOptions shipped = loadMergeConfig(std::string(PCR_PRO_CONFIG_DIR) + "/merge.yaml");
  const MergeOptions d;
  EXPECT_EQ(shipped.matching.image_scale, d.matching.image_scale);
  EXPECT_EQ(shipped.matching.nfeatures, d.matching.nfeatures);
  EXPECT_EQ(shipped.matching.ratio_test, d.matching.ratio_test);
  EXPECT_EQ(shipped.matching.min_matches, d.matching.min_matches);
  EXPECT_EQ(shipped.relative_pose.algorithm, d.relative_pose.algorithm);
  EXPECT_EQ(shipped.relative_pose.pixel_error, d.relative_pose.pixel_error);
  EXPECT_EQ(shipped.relative_pose.min_inliers, d.relative_pose.min_inliers);
  EXPECT_EQ(shipped.keyframe_depth.neighborhood_radius_px, d.keyframe_depth.neighborhood_radius_px);
  EXPECT_EQ(shipped.keyframe_depth.spatial_sigma_px, d.keyframe_depth.spatial_sigma_px);
  EXPECT_EQ(shipped.keyframe_depth.max_relative_stddev, d.keyframe_depth.max_relative_stddev);
  EXPECT_EQ(shipped.merge.local_keyframes, d.merge.local_keyframes);
  EXPECT_EQ(shipped.scale_estimation.gating_chi2, d.scale_estimation.gating_chi2);
  EXPECT_EQ(shipped.merge.min_overlap, d.merge.min_overlap);
  EXPECT_EQ(shipped.merge.refine_scale, d.merge.refine_scale);
  EXPECT_EQ(shipped.merge.max_candidate_pairs, d.merge.max_candidate_pairs);
  EXPECT_EQ(shipped.registration.icp.trim_ratio, d.registration.icp.trim_ratio);
  EXPECT_THROW(parseMergeConfig("relative_pose: {algorithm: FOO}\n", "x.yaml"), InputError);
  EXPECT_THROW(parseMergeConfig("matching: {ratio_test: 2}\n", "x.yaml"), InputError);
  EXPECT_THROW(parseMergeConfig("merge: {min_overlap: -1}\n", "x.yaml"), InputError);
  EXPECT_THROW(parseMergeConfig("merge: {max_candidate_pairs: -1}\n", "x.yaml"), InputError);
  EXPECT_THROW(parseMergeConfig("merge: {local_keyframes: -1}\n", "x.yaml"), InputError);
  EXPECT_THROW(parseMergeConfig("keyframe_depth: {max_relative_stddev: 1.5}\n", "x.yaml"), InputError);
  EXPECT_THROW(parseMergeConfig("keyframe_depth: {spatial_sigma_px: 0}\n", "x.yaml"), InputError);
}

// A key that moved (merge.register_noisier_as_target, now the ICP's) is refused with where it
// lives now, the file and the line; the new key is read; the same name elsewhere is only unknown.
TEST(Merge, AMovedConfigKeyNamesItsNewPlace) {
  std::string message;
  try {
    parseMergeConfig("merge:\n  min_overlap: 0.3\n  register_noisier_as_target: false\n", "old.yaml");
  } catch (const InputError& e) {
    message = e.what();
  }
  for (const char* part : {"old.yaml", "merge.register_noisier_as_target: unknown key",
                           "now icp.sampling.register_noisier_as_target", "(line 3)"}) {
    EXPECT_NE(message.find(part), std::string::npos) << "'" << message << "' lacks '" << part << "'";
  }
  EXPECT_EQ(message.find('\n'), std::string::npos) << "one line";
  EXPECT_TRUE(MergeOptions().registration.icp.register_noisier_as_target);
  EXPECT_FALSE(parseMergeConfig("icp:\n  sampling:\n    register_noisier_as_target: false\n", "new.yaml")
                   .registration.icp.register_noisier_as_target);
  message.clear();
  try {
    parseMergeConfig("icp:\n  register_noisier_as_target: false\n", "x.yaml");
  } catch (const InputError& e) {
    message = e.what();
  }
  EXPECT_NE(message.find("icp.register_noisier_as_target: unknown key (allowed:"), std::string::npos) << message;
}

// --- the pcr_pro_merge command line

using test::CliRun;

CliRun runMerge(const std::string& args) { return test::runCli(PCR_PRO_MERGE_BIN, args, "pcr_pro_merge_cli"); }

TEST(MergeCli, MergesWritesOutputsAndRefuses) {
  namespace fs = std::filesystem;
  const std::string dir = simDemo();
  const fs::path out = fs::temp_directory_path() / ("pcr_pro_merge_out_" + std::to_string(::getpid()));
  fs::remove_all(out);
  const CliRun ok = runMerge("--source " + dir + "/agent_b --target " + dir + "/agent_a --output " + out.string() +
                             " --truth " + dir + "/truth.yaml");
  ASSERT_EQ(ok.status, 0) << ok.err << ok.out;
  for (const char* key : {"status: OK", "source_keyframe:", "target_keyframe:", "scale:", "rotation:", "translation:",
                          "covariance:", "information:", "scale_stddev:", "fitness_rmse:", "correspondences:",
                          "scale_difference_detected:", "timings_ms: {features:", "errors_vs_truth:"}) {
    EXPECT_NE(ok.out.find(key), std::string::npos) << key;
  }
  std::ifstream written(out / "result.yaml");
  EXPECT_EQ(std::string(std::istreambuf_iterator<char>(written), {}), ok.out);
  EXPECT_TRUE(fs::exists(out / "fused.pcd"));
  // --truth: the printed errors are the merge's against the truth file, within the world's tolerance.
  const YAML::Node result = YAML::Load(ok.out);
  const YAML::Node errors = result["errors_vs_truth"];
  ASSERT_TRUE(errors.IsMap()) << ok.out;
  const auto q = result["rotation"].as<std::vector<double>>();
  const auto t = result["translation"].as<std::vector<double>>();
  const Sim3 printed(result["scale"].as<double>(), Eigen::Quaterniond(q[3], q[0], q[1], q[2]).normalized(),
                     Eigen::Vector3d(t[0], t[1], t[2]));
  const TruthErrors e = compareWithTruth(printed, loadBundleTruth(dir + "/truth.yaml").target_source, std::nullopt,
                                         std::nullopt);
  EXPECT_NEAR(errors["rotation_deg"].as<double>(), e.rotation_deg, 1e-3 * e.rotation_deg + 1e-6);
  EXPECT_NEAR(errors["translation"].as<double>(), e.translation, 1e-3 * e.translation + 1e-9);
  EXPECT_NEAR(errors["scale_percent"].as<double>(), e.scale_percent, 1e-3 * std::abs(e.scale_percent) + 1e-6);
  EXPECT_TRUE(errors["reported_sigma"].IsMap() && errors["pose_chi2"].IsScalar()) << ok.out;
  expectWithin(e, simTolerance(), "pcr_pro_merge");
  // Against a wrong truth (agent_c's pair) the same merge is far off: the errors are measured, not copied.
  const CliRun wrong = runMerge("--source " + dir + "/agent_b --target " + dir + "/agent_a --truth " + dir +
                                "/truth_agent_a_agent_c.yaml");
  ASSERT_EQ(wrong.status, 0) << wrong.err;
  EXPECT_GT(YAML::Load(wrong.out)["errors_vs_truth"]["rotation_deg"].as<double>(), 10 * simTolerance().rotation_deg);

  const CliRun refused = runMerge("--source " + dir + "/agent_c --target " + dir + "/agent_a --truth " + dir +
                                  "/truth_agent_a_agent_c.yaml");
  EXPECT_EQ(refused.status, 1);
  EXPECT_NE(refused.out.find("message:"), std::string::npos);
  EXPECT_EQ(refused.out.find("status: OK"), std::string::npos);
  EXPECT_EQ(refused.out.find("errors_vs_truth"), std::string::npos) << "no errors without a merge";
  fs::remove_all(out);
}

TEST(MergeCli, BadInputExitsTwoNamingTheFile) {
  const std::string dir = simDemo();
  const CliRun missing = runMerge("--source /nonexistent/bundle --target " + dir + "/agent_a");
  EXPECT_EQ(missing.status, 2);
  EXPECT_NE(missing.err.find("/nonexistent/bundle"), std::string::npos) << missing.err;
  EXPECT_EQ(std::count(missing.err.begin(), missing.err.end(), '\n'), 1);
  const CliRun bad_id = runMerge("--source " + dir + "/agent_b --target " + dir + "/agent_a --source-keyframe 42");
  EXPECT_EQ(bad_id.status, 2);
  EXPECT_NE(bad_id.err.find("42"), std::string::npos);
  EXPECT_EQ(runMerge("--source " + dir + "/agent_b").status, 2);
  EXPECT_EQ(runMerge("--source " + dir + "/agent_b --target " + dir + "/agent_a --source-keyframe x").status, 2);
  // A bad truth file ends the run before the merge, naming the file.
  const CliRun bad_truth = runMerge("--source " + dir + "/agent_b --target " + dir + "/agent_a --truth " + dir +
                                    "/agent_a/bundle.yaml");
  EXPECT_EQ(bad_truth.status, 2);
  EXPECT_NE(bad_truth.err.find(dir + "/agent_a/bundle.yaml"), std::string::npos) << bad_truth.err;
  EXPECT_TRUE(bad_truth.out.empty()) << bad_truth.out;
}

}  // namespace
}  // namespace pcr_pro
