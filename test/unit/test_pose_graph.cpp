// Pose-graph export (io/pose_graph.h): g2o Sim(3) exp / log, the merge's edge and its information,
// the g2o text read back, the TUM trajectory.
#include <gtest/gtest.h>

#include <Eigen/Eigenvalues>
#include <Eigen/LU>
#include <unsupported/Eigen/MatrixFunctions>

#include <cmath>
#include <random>
#include <sstream>

#include "pcr_pro/geometry/similarity_fit.h"
#include "pcr_pro/io/pose_graph.h"
#include "pcr_pro/merge/merge_pipeline.h"
#include "pcr_pro/sim/simulator.h"
#include "test_helpers.h"

namespace pcr_pro {
namespace {

// The algebra element of (ω, υ, σ) as a 4x4 matrix [σI + [ω]×, υ; 0 0]: its matrix exponential
// is the group element [e^σ R, W υ; 0 1] whatever closed form g2oSim3Exp() uses.
Eigen::Matrix4d algebraMatrix(const G2oTangent& v) {
  Eigen::Matrix4d m = Eigen::Matrix4d::Zero();
  m.topLeftCorner<3, 3>() = v(6) * Eigen::Matrix3d::Identity() + skew(v.head<3>());
  m.block<3, 1>(0, 3) = v.segment<3>(3);
  return m;
}

double sim3Distance(const Sim3& a, const Sim3& b) { return (a.matrix() - b.matrix()).cwiseAbs().maxCoeff(); }

Sim3 randomSim3(std::mt19937_64* rng, double max_log_scale) {
  std::uniform_real_distribution<double> u(-1.0, 1.0);
  const Eigen::Vector3d w(u(*rng), u(*rng), u(*rng));
  return Sim3(std::exp(max_log_scale * u(*rng)), expSO3(2.5 * w.normalized() * std::abs(u(*rng))),
              Eigen::Vector3d(3 * u(*rng), 3 * u(*rng), 3 * u(*rng)));
}

TEST(PoseGraph, ExpMatchesTheMatrixExponentialAndLogInvertsIt) {
  std::mt19937_64 rng(7);
  std::uniform_real_distribution<double> u(-1.0, 1.0);
  for (int k = 0; k < 200; ++k) {
    G2oTangent v;
    // rotations up to 3 rad, scales e^±2, and tiny ones (the series branches near 0)
    const double mag = (k % 4 == 0) ? 1e-5 : 1.0;
    for (int i = 0; i < 3; ++i) v(i) = mag * 1.7 * u(rng);
    for (int i = 3; i < 6; ++i) v(i) = 2.0 * u(rng);
    v(6) = mag * 2.0 * u(rng);
    const Sim3 expected = Sim3::fromMatrix(algebraMatrix(v).exp());
    const Sim3 got = g2oSim3Exp(v);
    // double rounding of the 4x4 exponential of entries up to ~e^2 * 6: 1e-11 relative is ample
    EXPECT_LT(sim3Distance(got, expected), 1e-9) << v.transpose();
    EXPECT_LT((g2oSim3Log(got) - v).cwiseAbs().maxCoeff(), 1e-9) << v.transpose();
  }
}

struct TwoMaps {
  AgentMap target, source;
  MergeEdge edge;
};

// Two small trajectories and a merge edge with a full (correlated) covariance.
TwoMaps twoMaps() {
  std::mt19937_64 rng(11);
  TwoMaps m;
  for (AgentMap* map : {&m.target, &m.source}) {
    map->camera.fx = 500;
    map->camera.fy = 505;
    map->camera.cx = 320;
    map->camera.cy = 240;
    map->camera.width = 640;
    map->camera.height = 480;
    for (long id : {4L, 1L, 9L}) {
      MapKeyframe kf;
      kf.id = id + (map == &m.source ? 100 : 0);
      kf.pose = randomSim3(&rng, 0.3);
      map->keyframes.push_back(kf);
    }
  }
  m.edge.target_from_source = randomSim3(&rng, 0.8);
  Eigen::Matrix<double, 7, 7> a = Eigen::Matrix<double, 7, 7>::Random();
  const Eigen::Matrix<double, 7, 1> sd = (Eigen::Matrix<double, 7, 1>() << 0.02, 0.03, 0.01, 0.004, 0.002, 0.003, 0.01).finished();
  m.edge.covariance = sd.asDiagonal() * (a * a.transpose() / 7.0 + Matrix7d::Identity()) * sd.asDiagonal();
  m.edge.target_keyframe = 9;
  m.edge.source_keyframe = 101;
  return m;
}

const MapKeyframe& keyframe(const AgentMap& map, long id) {
  for (const MapKeyframe& kf : map.keyframes) {
    if (kf.id == id) return kf;
  }
  throw std::runtime_error("no keyframe");
}

TEST(PoseGraph, VerticesAndTheEdgeMeasurement) {
  const TwoMaps m = twoMaps();
  const PoseGraph g = mergePoseGraph(m.target, "agent a", m.source, "agent_b", m.edge);
  ASSERT_EQ(g.vertices.size(), 6u);
  ASSERT_EQ(g.edges.size(), 1u);
  // target first, ids sorted, each camera -> target map
  const long ids[6] = {1, 4, 9, 101, 104, 109};
  for (int i = 0; i < 6; ++i) {
    const PoseGraphVertex& v = g.vertices[static_cast<std::size_t>(i)];
    EXPECT_EQ(v.id, i);
    EXPECT_EQ(v.keyframe, ids[i]);
    EXPECT_EQ(v.agent, i < 3 ? "agent_a" : "agent_b");
    const Sim3 expected = i < 3 ? keyframe(m.target, ids[i]).pose
                                : m.edge.target_from_source * keyframe(m.source, ids[i]).pose;
    EXPECT_LT(sim3Distance(v.camera_to_world, expected), 1e-12);
  }
  const PoseGraphEdge& e = g.edges[0];
  EXPECT_EQ(e.from, 2);  // target keyframe 9
  EXPECT_EQ(e.to, 3);    // source keyframe 101
  // C = S_j S_i⁻¹ with S = world -> camera: the source anchor camera <- the target anchor camera,
  // i.e. the inverse of KeyframeEdge::transform = P_t⁻¹ S_ts P_s.
  const Sim3 keyframe_edge =
      keyframe(m.target, 9).pose.inverse() * m.edge.target_from_source * keyframe(m.source, 101).pose;
  EXPECT_LT(sim3Distance(e.measurement, keyframe_edge.inverse()), 1e-12);
  // g2o's edge error log(C S_i S_j⁻¹) vanishes at the exported vertices.
  const Sim3 si = g.vertices[2].camera_to_world.inverse(), sj = g.vertices[3].camera_to_world.inverse();
  EXPECT_LT(g2oSim3Log(e.measurement * si * sj.inverse()).norm(), 1e-12);
  EXPECT_EQ(g.fixed, std::vector<int>{0});
}

// The information, checked against an independent computation: the Jacobian of g2o's edge error
// log(C(δ) Ĉ⁻¹) with respect to the merge's perturbation δ (S_ts = exp(δ) Ŝ_ts, applyDelta())
// by central differences, no adjoint and no reordering involved. cov_g2o = J cov Jᵀ.
TEST(PoseGraph, InformationIsTheInverseOfTheCarriedCovariance) {
  const TwoMaps m = twoMaps();
  const PoseGraph g = mergePoseGraph(m.target, "a", m.source, "b", m.edge);
  const Sim3& pt = keyframe(m.target, 9).pose;
  const Sim3& ps = keyframe(m.source, 101).pose;
  const Sim3 c_hat = (m.edge.target_from_source * ps).inverse() * pt;
  Matrix7d jacobian;
  const double h = 1e-6;  // central differences: error O(h²) ~ 1e-12, rounding ~1e-16 / h = 1e-10
  for (int k = 0; k < 7; ++k) {
    Eigen::Matrix<double, 7, 1> d = Eigen::Matrix<double, 7, 1>::Zero();
    d(k) = h;
    const Sim3 cp = (applyDelta(d, m.edge.target_from_source) * ps).inverse() * pt;
    const Sim3 cm = (applyDelta(-d, m.edge.target_from_source) * ps).inverse() * pt;
    jacobian.col(k) = (g2oSim3Log(cp * c_hat.inverse()) - g2oSim3Log(cm * c_hat.inverse())) / (2 * h);
  }
  const Matrix7d expected_cov = jacobian * m.edge.covariance * jacobian.transpose();
  const Matrix7d cov = g.edges[0].information.inverse();
  // relative to the covariance's own size: finite-difference error ~1e-9 of the Jacobian entries
  EXPECT_LT((cov - expected_cov).cwiseAbs().maxCoeff(), 1e-6 * expected_cov.cwiseAbs().maxCoeff())
      << "got\n" << cov << "\nexpected\n" << expected_cov;
  // the expected value distinguishes a missing reorder (pcr_pro's order differs from g2o's)
  const Matrix7d ad = similarityAdjoint((m.edge.target_from_source * ps).inverse());
  const Matrix7d unordered = ad * m.edge.covariance * ad.transpose();
  EXPECT_GT((unordered - expected_cov).cwiseAbs().maxCoeff(), 0.1 * expected_cov.cwiseAbs().maxCoeff());
}

TEST(PoseGraph, G2oTextReadsBack) {
  const TwoMaps m = twoMaps();
  const PoseGraph g = mergePoseGraph(m.target, "alpha", m.source, "beta", m.edge);
  const std::string text = toG2o(g);
  // the documented line shapes: 1 + 7 + 4 numbers per vertex, 2 + 7 + 28 per edge
  std::istringstream lines(text);
  std::string line;
  int vertex_lines = 0, edge_lines = 0;
  while (std::getline(lines, line)) {
    std::istringstream in(line);
    std::string tag, tok;
    in >> tag;
    int n = 0;
    while (in >> tok) ++n;
    if (tag == "VERTEX_SIM3:EXPMAP") {
      EXPECT_EQ(n, 12) << line;
      ++vertex_lines;
    }
    if (tag == "EDGE_SIM3:EXPMAP") {
      EXPECT_EQ(n, 37) << line;
      ++edge_lines;
    }
  }
  EXPECT_EQ(vertex_lines, 6);
  EXPECT_EQ(edge_lines, 1);

  const PoseGraph r = parseG2o(text, "graph.g2o");
  ASSERT_EQ(r.vertices.size(), g.vertices.size());
  for (std::size_t i = 0; i < r.vertices.size(); ++i) {
    EXPECT_EQ(r.vertices[i].id, g.vertices[i].id);
    EXPECT_EQ(r.vertices[i].agent, g.vertices[i].agent);
    EXPECT_EQ(r.vertices[i].keyframe, g.vertices[i].keyframe);
    EXPECT_LT(sim3Distance(r.vertices[i].camera_to_world, g.vertices[i].camera_to_world), 1e-12);
    EXPECT_DOUBLE_EQ(r.vertices[i].fy, 505.0);
    EXPECT_DOUBLE_EQ(r.vertices[i].cx, 320.0);
  }
  ASSERT_EQ(r.edges.size(), 1u);
  EXPECT_EQ(r.edges[0].from, g.edges[0].from);
  EXPECT_EQ(r.edges[0].to, g.edges[0].to);
  EXPECT_LT(sim3Distance(r.edges[0].measurement, g.edges[0].measurement), 1e-12);
  EXPECT_LT((r.edges[0].information - g.edges[0].information).cwiseAbs().maxCoeff(),
            1e-14 * g.edges[0].information.cwiseAbs().maxCoeff());
  EXPECT_EQ(r.fixed, g.fixed);
}

TEST(PoseGraph, BadG2oTextIsAOneLineErrorWithTheLine) {
  auto message = [](const std::string& text) {
    try {
      parseG2o(text, "g.g2o");
    } catch (const InputError& e) {
      return std::string(e.what());
    }
    return std::string("no error");
  };
  EXPECT_EQ(message("VERTEX_SE3:QUAT 0 0 0 0 0 0 0 1\n").rfind("g.g2o: line 1: unknown tag", 0), 0u);
  EXPECT_NE(message("VERTEX_SIM3:EXPMAP 0 0 0 0 0 0 0 0 1 1 0\n").find("line 1: missing cy"), std::string::npos);
  EXPECT_NE(message("VERTEX_SIM3:EXPMAP 0 0 0 0 0 0 0 nan 1 1 0 0\n").find("not a finite number"), std::string::npos);
  EXPECT_NE(message("# x\nFIX 3\n").find("line 2: FIX names an undefined vertex 3"), std::string::npos);
  EXPECT_NE(message("VERTEX_SIM3:EXPMAP 0 0 0 0 0 0 0 0 1 1 0 0\nVERTEX_SIM3:EXPMAP 0 0 0 0 0 0 0 0 1 1 0 0\n")
                .find("line 2: vertex 0 defined twice"),
            std::string::npos);
  const std::string escaped = message("\x01\xff\n");
  EXPECT_NE(escaped.find("\\x01\\xff"), std::string::npos) << escaped;
}

TEST(PoseGraph, RefusesWhatIsNotASuccessfulMerge) {
  TwoMaps m = twoMaps();
  m.edge.source_keyframe = 5;  // not in the source map
  EXPECT_THROW(mergePoseGraph(m.target, "a", m.source, "b", m.edge), InputError);
  m = twoMaps();
  m.edge.covariance.setZero();
  EXPECT_THROW(mergePoseGraph(m.target, "a", m.source, "b", m.edge), InputError);
  m = twoMaps();
  EXPECT_THROW(mergePoseGraph(m.target, "a", m.source, "a", m.edge), InputError);
}

TEST(PoseGraph, TumHasEveryKeyframeInTheTargetFrame) {
  const TwoMaps m = twoMaps();
  const PoseGraph g = mergePoseGraph(m.target, "a", m.source, "b", m.edge);
  std::istringstream lines(toTum(g));
  std::string line;
  std::size_t n = 0;
  while (std::getline(lines, line)) {
    if (line.empty() || line[0] == '#') continue;
    std::istringstream in(line);
    double stamp, tx, ty, tz, qx, qy, qz, qw;
    ASSERT_TRUE(in >> stamp >> tx >> ty >> tz >> qx >> qy >> qz >> qw) << line;
    ASSERT_LT(n, g.vertices.size());
    const Sim3& p = g.vertices[n].camera_to_world;
    EXPECT_EQ(stamp, static_cast<double>(g.vertices[n].keyframe));
    EXPECT_LT((Eigen::Vector3d(tx, ty, tz) - p.translation()).norm(), 1e-8 * (1 + p.translation().norm()));
    const Eigen::Quaterniond q(qw, qx, qy, qz);
    EXPECT_NEAR(q.norm(), 1.0, 1e-8);
    EXPECT_LT((q.toRotationMatrix() - p.rotation()).cwiseAbs().maxCoeff(), 1e-8);
    ++n;
  }
  EXPECT_EQ(n, g.vertices.size());
}

// A real merge of a simulated world (two agents overlapping about half, as test_merge_stages):
// the exported edge against the merge's own keyframe edge (report.keyframe_edge, computed by the
// pipeline from the same covariance through the target anchor's frame instead of the source's).
TEST(PoseGraph, RealMergeOfASimulatedWorld) {
  const Simulation sim = simulate(test::mergeTestWorld(11, 2, 0.5));
  const AgentMap& a = sim.agents[0].map;
  const AgentMap& b = sim.agents[1].map;
  const MergeResult result = mergeMaps(b, a, MergeRequest(), MergeOptions());
  ASSERT_EQ(result.report.status, Status::kOk) << result.report.message;
  const std::optional<MergeEdge> edge = poseGraphEdge(result);
  ASSERT_TRUE(edge);
  const KeyframeEdge& kf = *result.report.keyframe_edge;
  const PoseGraph g = parseG2o(toG2o(mergePoseGraph(a, "agent_a", b, "agent_b", *edge)), "merge.g2o");
  ASSERT_EQ(g.vertices.size(), a.keyframes.size() + b.keyframes.size());
  ASSERT_EQ(g.edges.size(), 1u);
  const PoseGraphEdge& e = g.edges[0];
  EXPECT_EQ(g.vertices[static_cast<std::size_t>(e.from)].agent, "agent_a");
  EXPECT_EQ(g.vertices[static_cast<std::size_t>(e.from)].keyframe, kf.target_keyframe);
  EXPECT_EQ(g.vertices[static_cast<std::size_t>(e.to)].agent, "agent_b");
  EXPECT_EQ(g.vertices[static_cast<std::size_t>(e.to)].keyframe, kf.source_keyframe);
  // C = S_j S_i⁻¹ is the inverse of the keyframe edge P_t⁻¹ S_ts P_s (units of the target map:
  // 1e-9 of the translation's size is far above the 17 written digits' rounding)
  const Sim3 c = kf.transform.inverse();
  EXPECT_LT(sim3Distance(e.measurement, c), 1e-9 * (1.0 + c.translation().norm()));
  // keyframe_edge.covariance: left perturbation ε of T = P_t⁻¹ S_ts P_s; C = T⁻¹ = exp(-Ad(C) ε) C,
  // then g2o's order (ω, υ, σ) from pcr_pro's (υ, ω, σ) by an explicit permutation.
  Matrix7d perm = Matrix7d::Zero();
  for (int i = 0; i < 3; ++i) {
    perm(i, 3 + i) = 1.0;  // g2o ω_i = pcr_pro r_i
    perm(3 + i, i) = 1.0;  // g2o υ_i = pcr_pro t_i
  }
  perm(6, 6) = 1.0;
  const Matrix7d ad = similarityAdjoint(c);
  const Matrix7d expected = perm * ad * kf.covariance * ad.transpose() * perm.transpose();
  const Matrix7d cov = e.information.inverse();
  EXPECT_LT((cov - expected).cwiseAbs().maxCoeff(), 1e-6 * expected.cwiseAbs().maxCoeff())
      << "got\n" << cov << "\nexpected\n" << expected;
  // every fused keyframe in the target map frame: the source's through S_target_source
  for (const PoseGraphVertex& v : g.vertices) {
    const AgentMap& map = v.agent == "agent_a" ? a : b;
    const Sim3 to_target = v.agent == "agent_a" ? Sim3() : *result.report.transform;
    for (const MapKeyframe& k : map.keyframes) {
      if (k.id != v.keyframe) continue;
      const Sim3 expected_pose = to_target * k.pose;
      EXPECT_LT(sim3Distance(v.camera_to_world, expected_pose), 1e-9 * (1.0 + expected_pose.translation().norm()));
    }
  }
}

}  // namespace
}  // namespace pcr_pro
