#include "pcr_pro/sim/simulator.h"

#include <algorithm>
#include <chrono>
#include <cmath>
#include <sstream>

#include "pcr_pro/registration/icp.h"
#include "sim/sim_random.h"
#include "sim/trajectory.h"

namespace pcr_pro {
namespace {

using Clock = std::chrono::steady_clock;
using sim_detail::AgentPath;
using sim_detail::PathKeyframes;
using sim_detail::subSeed;

double msSince(Clock::time_point t) { return std::chrono::duration<double, std::milli>(Clock::now() - t).count(); }

// Seed streams (sim_detail::subSeed(options.seed, stream)); one per purpose and keyframe id.
enum Stream : std::uint64_t {
  kWorldStream = 1,
  kPathStream = 100,
  kScaleStream = 200,
  kRenderStream = 100000,
  kSemiDenseStream = 200000,
  kCloudStream = 300000,
  kPoseNoiseStream = 400000,
};

constexpr long kIdsPerAgent = 1000;

std::string agentName(int i) { return std::string("agent_") + static_cast<char>('a' + i); }

// The agent's settings with the layout's defaults filled in (azimuth of agent_b: see layout()).
struct ResolvedAgent {
  std::string name;
  double scale = 1.0;
  AgentPath path;
  double scale_drift = 0.0, bend_deg = 0.0;
  double idepth_noise = 0.0;
  PinholeCamera camera;
  bool azimuth_given = false;
};

std::vector<ResolvedAgent> resolveAgents(const SimulatorOptions& o) {
  std::vector<ResolvedAgent> out;
  const LayoutOptions& l = o.layout;
  const double span = o.trajectory.azimuth_span_deg;
  for (int i = 0; i < o.agents; ++i) {
    const AgentOptions a = i < static_cast<int>(o.per_agent.size()) ? o.per_agent[static_cast<std::size_t>(i)] : AgentOptions();
    ResolvedAgent r;
    r.name = a.name.empty() ? agentName(i) : a.name;
    // Default scales: agent_a 1, agent_b 0.4 (the pair's scale ratio 2.5), agent_c 3, then
    // log-uniform in [0.1, 10].
    std::mt19937_64 rng(subSeed(o.seed, kScaleStream + static_cast<std::uint64_t>(i)));
    const double default_scale = i == 0 ? 1.0 : i == 1 ? 0.4 : i == 2 ? 3.0 : sim_detail::logUniform(rng, 0.1, 10.0);
    r.scale = a.scale.value_or(default_scale);
    r.path.azimuth_span_deg = a.azimuth_span_deg.value_or(span);
    double start = l.first_azimuth_deg;
    if (i == 2) start += 180.0;
    if (i >= 3) start += 180.0 + (i - 2) * (1.0 - l.overlap) * span;
    r.azimuth_given = a.azimuth_start_deg.has_value() || i != 1;
    r.path.azimuth_start_deg = a.azimuth_start_deg.value_or(start);
    const double half = 0.5 * l.view_angle_difference_deg;
    r.path.view_angle_deg = a.view_angle_deg.value_or(i % 2 ? half : -half);
    r.path.seed = subSeed(o.seed, kPathStream + static_cast<std::uint64_t>(i));
    r.scale_drift = a.scale_drift.value_or(o.drift.scale_drift);
    r.bend_deg = a.bend_deg.value_or(o.drift.bend_deg);
    r.idepth_noise = a.idepth_noise.value_or(o.map.semi_dense.idepth_noise);
    r.camera = a.camera.value_or(o.camera);
    out.push_back(r);
  }
  return out;
}

// A low-resolution camera (1/8 of the size) for the layout's overlap estimate.
PinholeCamera lowResolution(const PinholeCamera& c) {
  constexpr double f = 1.0 / 8.0;
  PinholeCamera low = c;
  low.width = std::max(8, static_cast<int>(c.width * f));
  low.height = std::max(8, static_cast<int>(c.height * f));
  low.fx = c.fx * f, low.fy = c.fy * f;
  low.cx = (c.cx + 0.5) * f - 0.5, low.cy = (c.cy + 0.5) * f - 0.5;
  return low;
}

// Whether camera `pose` with depth image `depth` sees world point x: in the image, in front, and
// the rendered depth there within `tolerance` (relative) of x's depth (not occluded).
bool sees(const PinholeCamera& cam, const Sim3& pose, const cv::Mat& depth, const Eigen::Vector3d& x, double tolerance,
          double* centre_distance = nullptr) {
  const Eigen::Vector3d p = pose.rotation().transpose() * (x - pose.translation());
  double u = 0.0, v = 0.0;
  if (!cam.project(p, &u, &v)) return false;
  const int c = static_cast<int>(std::lround(u)), r = static_cast<int>(std::lround(v));
  if (c < 0 || r < 0 || c >= cam.width || r >= cam.height) return false;
  const float d = depth.at<float>(r, c);
  if (!(d > 0.0f) || std::abs(d - p.z()) > tolerance * p.z()) return false;
  if (centre_distance) *centre_distance = std::hypot(u - cam.cx, v - cam.cy);
  return true;
}

// Fraction of the surface seen by `source` poses that `target` poses see too (every pixel of
// low-resolution depth renders; `low` the source's low-resolution camera, `target_low` the
// target's, in which target_depth was rendered).
double lowResolutionOverlap(const World& world, const PinholeCamera& low, const PinholeCamera& target_low,
                            const std::vector<cv::Mat>& target_depth, const std::vector<Sim3>& target_poses,
                            const std::vector<Sim3>& source_poses) {
  RenderOptions ro;
  ro.supersampling = 1;
  ro.image_noise = 0.0;
  long seen = 0, total = 0;
  for (const Sim3& pose : source_poses) {
    const cv::Mat depth = render(world, low, pose, ro, 0).depth;
    for (int r = 0; r < low.height; ++r) {
      for (int c = 0; c < low.width; ++c) {
        const float z = depth.at<float>(r, c);
        if (!(z > 0.0f)) continue;
        const Eigen::Vector3d x = pose.apply(Eigen::Vector3d(z * (c - low.cx) / low.fx, z * (r - low.cy) / low.fy, z));
        ++total;
        for (std::size_t j = 0; j < target_poses.size(); ++j) {
          if (sees(target_low, target_poses[j], target_depth[j], x, 0.05)) {
            ++seen;
            break;
          }
        }
      }
    }
  }
  return total > 0 ? static_cast<double>(seen) / static_cast<double>(total) : 0.0;
}

// Places agent_b's azimuth range so that its overlap with agent_a is layout.overlap (the
// overlap falls as b's start moves away from a's: bisection over the offset).
void layoutSecondAgent(const World& world, const SimulatorOptions& o, std::vector<ResolvedAgent>* agents) {
  if (agents->size() < 2 || (*agents)[1].azimuth_given) return;
  ResolvedAgent& b = (*agents)[1];
  const ResolvedAgent& a = (*agents)[0];
  const PinholeCamera low_a = lowResolution(a.camera), low_b = lowResolution(b.camera);
  RenderOptions ro;
  ro.supersampling = 1;
  ro.image_noise = 0.0;
  const PathKeyframes pa = sim_detail::keyframePath(world, o.trajectory, a.path, "per_agent[0]");
  std::vector<cv::Mat> depth_a;
  for (const Sim3& p : pa.poses) depth_a.push_back(render(world, low_a, p, ro, 0).depth);
  auto overlapAt = [&](double offset) {
    AgentPath path = b.path;
    path.azimuth_start_deg = a.path.azimuth_start_deg + offset;
    const PathKeyframes pb = sim_detail::keyframePath(world, o.trajectory, path, "per_agent[1]");
    return lowResolutionOverlap(world, low_b, low_a, depth_a, pa.poses, pb.poses);
  };
  double lo = 0.0, hi = a.path.azimuth_span_deg + 120.0;
  if (overlapAt(lo) <= o.layout.overlap) {
    hi = lo;  // the largest overlap this geometry gives
  } else {
    for (int k = 0; k < 10; ++k) {  // 200 deg / 2^10: 0.2 deg
      const double mid = 0.5 * (lo + hi);
      (overlapAt(mid) > o.layout.overlap ? lo : hi) = mid;
    }
  }
  b.path.azimuth_start_deg = a.path.azimuth_start_deg + 0.5 * (lo + hi);
}

// Adds keyframe k's share of the map cloud (cloud_fraction of its semi-dense points, mapped by
// its map pose) to the agent.
void addCloudPoints(const SimulatorOptions& o, int k, std::vector<Eigen::Vector3d>* map_points, SimAgent* agent) {
  const SimKeyframe& kf = agent->keyframes[static_cast<std::size_t>(k)];
  const PinholeCamera& cam = agent->map.camera;
  std::mt19937_64 rng(subSeed(o.seed, kCloudStream + static_cast<std::uint64_t>(kf.id)));
  std::vector<Eigen::Vector3d> world;
  Eigen::Index i = 0;  // index into semi_dense.points: kept pixels in row-major order
  for (int r = 0; r < kf.semi_dense.idepth.rows; ++r) {
    for (int c = 0; c < kf.semi_dense.idepth.cols; ++c) {
      if (!(kf.semi_dense.idepth.at<float>(r, c) > 0.0f)) continue;
      const Eigen::Vector3d p = kf.semi_dense.points.col(i++);
      if (sim_detail::uniform01(rng) >= o.map.cloud_fraction) continue;
      const double z = kf.depth.at<float>(r, c);
      map_points->push_back(kf.map_pose.apply(p));
      world.push_back(kf.true_pose.apply(Eigen::Vector3d(z * (c - cam.cx) / cam.fx, z * (r - cam.cy) / cam.fy, z)));
      agent->cloud_keyframe.push_back(k);
      agent->cloud_outlier.push_back(kf.semi_dense.outlier.at<std::uint8_t>(r, c) != 0);
    }
  }
  const Eigen::Index n0 = agent->cloud_world.cols();
  agent->cloud_world.conservativeResize(3, n0 + static_cast<Eigen::Index>(world.size()));
  for (std::size_t j = 0; j < world.size(); ++j) agent->cloud_world.col(n0 + static_cast<Eigen::Index>(j)) = world[j];
}

// Renders and samples every keyframe of one agent, builds its map and LSD data.
SimAgent makeAgent(const World& world, const SimulatorOptions& o, const ResolvedAgent& r, int index,
                   SimTimings* timings) {
  SimAgent agent;
  agent.name = r.name;
  agent.scale_drift = r.scale_drift;
  agent.bend_deg = r.bend_deg;
  agent.idepth_noise = r.idepth_noise;
  SemiDenseOptions semi_dense = o.map.semi_dense;
  semi_dense.idepth_noise = r.idepth_noise;
  agent.azimuth_start_deg = r.path.azimuth_start_deg;
  agent.azimuth_span_deg = r.path.azimuth_span_deg;
  agent.view_angle_deg = r.path.view_angle_deg;
  const PathKeyframes path =
      sim_detail::keyframePath(world, o.trajectory, r.path, "per_agent[" + std::to_string(index) + "]");
  // LSD-SLAM's map frame: the first keyframe's camera frame, scaled to map units.
  agent.world_to_map = Sim3(r.scale, Eigen::Matrix3d::Identity(), Eigen::Vector3d::Zero()) * path.poses[0].inverse();
  const sim_detail::DriftedPoses poses =
      sim_detail::driftPoses(path, agent.world_to_map, r.scale_drift, r.bend_deg, o.drift,
                             subSeed(o.seed, kPoseNoiseStream + static_cast<std::uint64_t>(index)));
  agent.map.frame_id = r.name + "/map";
  agent.map.camera = r.camera;
  agent.cloud_world = Cloud(3, 0);
  std::vector<Eigen::Vector3d> map_points;
  for (std::size_t k = 0; k < path.poses.size(); ++k) {
    SimKeyframe kf;
    kf.id = kIdsPerAgent * index + static_cast<long>(k);
    kf.true_pose = path.poses[k];
    kf.tracked_pose = poses.tracked[k];
    kf.map_pose = poses.map[k];
    kf.motion = path.motion[k];
    auto t = Clock::now();
    RenderedView view = render(world, r.camera, kf.true_pose, o.render, subSeed(o.seed, kRenderStream + kf.id));
    timings->render += msSince(t);
    ++timings->rendered;
    t = Clock::now();
    kf.image = view.image;
    kf.depth = view.depth;
    kf.semi_dense =
        sampleSemiDense(kf.image, kf.depth, r.camera, semi_dense, subSeed(o.seed, kSemiDenseStream + kf.id));
    // LSD normalises the mean of its (estimated) inverse depth to 1.
    const cv::Scalar mean = cv::mean(kf.semi_dense.idepth, kf.semi_dense.idepth > 0.0f);
    kf.lsd_scale = mean[0] > 0.0 ? 1.0 / mean[0] : 1.0;
    agent.keyframes.push_back(kf);
    addCloudPoints(o, static_cast<int>(k), &map_points, &agent);
    MapKeyframe mk;
    mk.id = kf.id;
    mk.image = kf.image;
    mk.pose = kf.map_pose;
    if (o.map.depth_images == "dense") mk.depth = kf.depth;
    if (o.map.depth_images == "semi_dense") mk.depth = kf.semi_dense.depth;
    agent.map.keyframes.push_back(mk);
    timings->maps += msSince(t);
  }
  agent.map.cloud = Cloud(3, static_cast<Eigen::Index>(map_points.size()));
  for (std::size_t i = 0; i < map_points.size(); ++i) agent.map.cloud.col(static_cast<Eigen::Index>(i)) = map_points[i];
  // LSD graph snapshots: the tracked poses after each keyframe, then the loop closure.
  const auto camToWorld = [](const SimKeyframe& kf, const Sim3& pose) {
    return pose * Sim3(kf.lsd_scale, Eigen::Matrix3d::Identity(), Eigen::Vector3d::Zero());
  };
  for (std::size_t k = 0; k < agent.keyframes.size(); ++k) {
    std::vector<std::pair<long, Sim3>> snapshot;
    for (std::size_t j = 0; j <= k; ++j) {
      snapshot.emplace_back(agent.keyframes[j].id, camToWorld(agent.keyframes[j], agent.keyframes[j].tracked_pose));
    }
    agent.graph_snapshots.push_back(snapshot);
  }
  std::vector<std::pair<long, Sim3>> closed;
  for (const SimKeyframe& kf : agent.keyframes) closed.emplace_back(kf.id, camToWorld(kf, kf.map_pose));
  agent.graph_snapshots.push_back(closed);
  return agent;
}

// The points of `owner` that `observer` sees: for each, its position in the owner's map (true
// camera point mapped by its own keyframe's map pose) and in the observer's map (the same world
// point mapped through the observer keyframe that sees it nearest its image centre), appended to
// owner_map / observer_map; seen[k][j] counts owner keyframe k's points seen by observer keyframe j.
void coVisiblePoints(const SimAgent& observer, const SimAgent& owner,
                     std::vector<Eigen::Vector3d>* owner_map, std::vector<Eigen::Vector3d>* observer_map,
                     std::vector<std::vector<long>>* seen, std::vector<long>* per_owner_keyframe) {
  const std::size_t nt = observer.keyframes.size(), ns = owner.keyframes.size();
  seen->assign(ns, std::vector<long>(nt, 0));
  per_owner_keyframe->assign(ns, 0);
  const Eigen::Index n = owner.cloud_world.cols();
  for (Eigen::Index i = 0; i < n; ++i) {
    const Eigen::Vector3d x = owner.cloud_world.col(i);
    const auto k = static_cast<std::size_t>(owner.cloud_keyframe[static_cast<std::size_t>(i)]);
    ++(*per_owner_keyframe)[k];
    double best = 1e300;
    std::size_t best_j = nt;
    for (std::size_t j = 0; j < nt; ++j) {
      const SimKeyframe& kt = observer.keyframes[j];
      double d = 0.0;
      // 2 %: far below the depth step between a box face and the wall behind it.
      if (!sees(observer.map.camera, kt.true_pose, kt.depth, x, 0.02, &d)) continue;
      ++(*seen)[k][j];
      if (d < best) best = d, best_j = j;
    }
    if (best_j == nt) continue;
    const SimKeyframe& ks = owner.keyframes[k];
    const SimKeyframe& kt = observer.keyframes[best_j];
    owner_map->push_back(ks.map_pose.apply(ks.true_pose.inverse().apply(x)));
    observer_map->push_back(kt.map_pose.apply(kt.true_pose.inverse().apply(x)));
  }
}

// Truth of one ordered pair. The similarity is fitted over the co-visible points of both maps
// (the source's points the target sees and the target's points the source sees), so that the
// truth of (target, source) is the inverse of the truth of (source, target). Over one side's
// points alone it is not on drifting maps: on the bench's worlds with 2.5-5 % scale drift the
// fits over the source's and over the target's points were up to 1.7 deg apart.
SimPairTruth pairTruth(const SimulatorOptions& o, const SimAgent& target, const SimAgent& source, int ti, int si) {
  SimPairTruth t;
  t.target = ti;
  t.source = si;
  t.start = target.world_to_map * source.world_to_map.inverse();
  const std::size_t nt = target.keyframes.size(), ns = source.keyframes.size();
  std::vector<std::vector<long>> counts, reverse_counts;
  std::vector<long> per_source_keyframe, per_target_keyframe;
  std::vector<Eigen::Vector3d> src, dst;
  coVisiblePoints(target, source, &src, &dst, &counts, &per_source_keyframe);
  const std::size_t source_points = src.size();
  coVisiblePoints(source, target, &dst, &src, &reverse_counts, &per_target_keyframe);
  const Eigen::Index n = source.cloud_world.cols();
  t.points = static_cast<int>(src.size());
  t.overlap_fraction = n > 0 ? static_cast<double>(source_points) / static_cast<double>(n) : 0.0;
  t.overlap = t.overlap_fraction >= o.min_overlap;
  t.target_source = t.start;
  if (src.size() >= 3) {
    Cloud a(3, static_cast<Eigen::Index>(src.size())), b(3, static_cast<Eigen::Index>(dst.size()));
    for (std::size_t i = 0; i < src.size(); ++i) {
      a.col(static_cast<Eigen::Index>(i)) = src[i];
      b.col(static_cast<Eigen::Index>(i)) = dst[i];
    }
    t.target_source = umeyama(a, b, true);
    t.rms = std::sqrt((t.target_source.apply(a) - b).colwise().squaredNorm().mean());
  }
  for (std::size_t k = 0; k < ns; ++k) {
    for (std::size_t j = 0; j < nt; ++j) {
      if (per_source_keyframe[k] == 0) continue;
      const double covisible = static_cast<double>(counts[k][j]) / static_cast<double>(per_source_keyframe[k]);
      if (covisible < o.min_overlap) continue;
      const SimKeyframe& ks = source.keyframes[k];
      const SimKeyframe& kt = target.keyframes[j];
      SimKeyframePair p;
      p.target_id = kt.id;
      p.source_id = ks.id;
      p.covisible = covisible;
      p.view_angle_deg = std::acos(std::clamp(kt.true_pose.rotation().col(2).dot(ks.true_pose.rotation().col(2)), -1.0, 1.0)) *
                         180.0 / M_PI;
      p.target_source = kt.map_pose * kt.true_pose.inverse() * ks.true_pose * ks.map_pose.inverse();
      t.keyframe_pairs.push_back(p);
    }
  }
  return t;
}

}  // namespace

LsdKeyframe toLsdKeyframe(const SimKeyframe& kf, const PinholeCamera& camera, double time) {
  LsdKeyframe lsd;
  lsd.id = kf.id;
  lsd.time = time;
  lsd.camera = camera;
  lsd.cam_to_world = kf.tracked_pose * Sim3(kf.lsd_scale, Eigen::Matrix3d::Identity(), Eigen::Vector3d::Zero());
  lsd.image = kf.image;
  kf.semi_dense.idepth.convertTo(lsd.idepth, CV_32FC1, kf.lsd_scale);
  kf.semi_dense.idepth_var.convertTo(lsd.idepth_var, CV_32FC1, kf.lsd_scale * kf.lsd_scale);
  return lsd;
}

const SimPairTruth& Simulation::pair(int target, int source) const {
  for (const SimPairTruth& p : pairs) {
    if (p.target == target && p.source == source) return p;
  }
  throw InputError("simulation: no pair target " + std::to_string(target) + " / source " + std::to_string(source));
}

Simulation simulate(const SimulatorOptions& options) {
  validate(options);
  const auto t_total = Clock::now();
  Simulation sim;
  sim.options = options;
  auto t = Clock::now();
  sim.world = makeRoomWorld(options.world, subSeed(options.seed, kWorldStream));
  sim.timings.world = msSince(t);
  t = Clock::now();
  std::vector<ResolvedAgent> agents = resolveAgents(options);
  layoutSecondAgent(sim.world, options, &agents);
  sim.timings.layout = msSince(t);
  for (std::size_t i = 0; i < agents.size(); ++i) {
    sim.agents.push_back(makeAgent(sim.world, options, agents[i], static_cast<int>(i), &sim.timings));
  }
  t = Clock::now();
  for (std::size_t ti = 0; ti < sim.agents.size(); ++ti) {
    for (std::size_t si = 0; si < sim.agents.size(); ++si) {
      if (ti == si) continue;
      sim.pairs.push_back(
          pairTruth(options, sim.agents[ti], sim.agents[si], static_cast<int>(ti), static_cast<int>(si)));
    }
  }
  sim.timings.truth = msSince(t);
  sim.timings.total = msSince(t_total);
  return sim;
}

}  // namespace pcr_pro
