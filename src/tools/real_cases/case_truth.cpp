#include "real_cases/case_truth.h"

#include <algorithm>
#include <cmath>
#include <sstream>
#include <tuple>

#include "pcr_pro/io/bundle_writer.h"
#include "pcr_pro/geometry/median.h"
#include "pcr_pro/registration/icp.h"  // umeyama

namespace pcr_pro {
namespace real_cases {
namespace {

constexpr double kRadToDeg = 180.0 / M_PI;

std::string num(double v, int precision = 6) {
  std::ostringstream s;
  s.precision(precision);
  s << v;
  return s.str();
}

// The frames of one agent, ready for visibility tests.
class Viewer {
 public:
  Viewer(const BuiltAgent& agent, const TruthOptions& options) : agent_(agent), options_(options) {
    for (const auto& [id, pose] : agent.camera_to_world) {
      ids_.push_back(id);
      world_to_camera_.push_back(pose.inverse());
    }
  }

  /// @return whether frame index f (of ids()) sees world point p
  bool sees(std::size_t f, const Eigen::Vector3d& p) const {
    const PinholeCamera& cam = agent_.map.camera;
    const Eigen::Vector3d q = world_to_camera_[f].apply(p);
    double u = 0.0, v = 0.0;
    if (!cam.project(q, &u, &v)) return false;
    const long c = std::lround(u), r = std::lround(v);
    const int b = options_.border_px;
    if (c < b || r < b || c >= cam.width - b || r >= cam.height - b) return false;
    const float d = agent_.depth.at(ids_[f]).at<float>(static_cast<int>(r), static_cast<int>(c));
    return d > 0.0f && std::abs(d - q.z()) <= options_.depth_tolerance * q.z();
  }

  /// @return the frame with the nearest camera centre among those that see p, or -1
  long nearestSeeing(const Eigen::Vector3d& p) const {
    long best = -1;
    double best_distance = 0.0;
    for (std::size_t f = 0; f < ids_.size(); ++f) {
      if (!sees(f, p)) continue;
      const double d = (agent_.camera_to_world.at(ids_[f]).translation() - p).norm();
      if (best < 0 || d < best_distance) {
        best = ids_[f];
        best_distance = d;
      }
    }
    return best;
  }

  std::size_t index(long id) const {
    return static_cast<std::size_t>(std::find(ids_.begin(), ids_.end(), id) - ids_.begin());
  }

 private:
  const BuiltAgent& agent_;
  const TruthOptions& options_;
  std::vector<long> ids_;
  std::vector<Sim3> world_to_camera_;
};

// World points of frame id's measured depth on a grid [m].
Cloud depthGrid(const BuiltAgent& agent, long id, int step) {
  const cv::Mat& depth = agent.depth.at(id);
  const PinholeCamera& cam = agent.map.camera;
  const Sim3& pose = agent.camera_to_world.at(id);
  std::vector<Eigen::Vector3d> points;
  for (int r = step / 2; r < depth.rows; r += step) {
    for (int c = step / 2; c < depth.cols; c += step) {
      const double z = depth.at<float>(r, c);
      if (z > 0.0)
        points.push_back(pose.apply(Eigen::Vector3d(z * (c - cam.cx) / cam.fx, z * (r - cam.cy) / cam.fy, z)));
    }
  }
  Cloud out(3, static_cast<Eigen::Index>(points.size()));
  for (std::size_t i = 0; i < points.size(); ++i) out.col(static_cast<Eigen::Index>(i)) = points[i];
  return out;
}

double fractionSeen(const Cloud& world, const Viewer& viewer, std::size_t frame) {
  if (world.cols() == 0) return 0.0;
  long seen = 0;
  for (Eigen::Index i = 0; i < world.cols(); ++i) seen += viewer.sees(frame, world.col(i)) ? 1 : 0;
  return static_cast<double>(seen) / static_cast<double>(world.cols());
}

// Point pairs of the overlap: world point, its target-map and its source-map coordinates.
struct OverlapPairs {
  std::vector<Eigen::Vector3d> world, in_target, in_source;
  double target_fraction = 0.0, source_fraction = 0.0;  // of each cloud seen by the other agent
};

// Adds the points of `own` seen by `other`; own_is_target says which map coordinates are whose.
double addSeen(const BuiltAgent& own, const BuiltAgent& other, const Viewer& other_view, bool own_is_target,
               OverlapPairs* pairs) {
  long seen = 0;
  for (Eigen::Index i = 0; i < own.world_points.cols(); ++i) {
    const Eigen::Vector3d x = own.world_points.col(i);
    const long frame = other_view.nearestSeeing(x);
    if (frame < 0) continue;
    ++seen;
    const Eigen::Vector3d own_map = own.map.cloud.col(i), other_map = other.world_to_map.at(frame).apply(x);
    pairs->world.push_back(x);
    pairs->in_target.push_back(own_is_target ? own_map : other_map);
    pairs->in_source.push_back(own_is_target ? other_map : own_map);
  }
  return own.world_points.cols() ? static_cast<double>(seen) / static_cast<double>(own.world_points.cols()) : 0.0;
}

Cloud toCloud(const std::vector<Eigen::Vector3d>& v) {
  Cloud c(3, static_cast<Eigen::Index>(v.size()));
  for (std::size_t i = 0; i < v.size(); ++i) c.col(static_cast<Eigen::Index>(i)) = v[i];
  return c;
}

// Diagonal of the box between the 5th and 95th percentiles of each coordinate.
double robustDiagonal(const std::vector<Eigen::Vector3d>& points) {
  if (points.size() < 2) return 0.0;
  Eigen::Vector3d lo, hi;
  for (int axis = 0; axis < 3; ++axis) {
    std::vector<double> v;
    for (const Eigen::Vector3d& p : points) v.push_back(p(axis));
    std::sort(v.begin(), v.end());
    lo(axis) = v[v.size() / 20];
    hi(axis) = v[v.size() - 1 - v.size() / 20];
  }
  return (hi - lo).norm();
}

Sim3 middleFrameG(const BuiltAgent& agent) {
  auto it = agent.world_to_map.begin();
  std::advance(it, static_cast<long>(agent.world_to_map.size() / 2));
  return it->second;
}

// Depth check of the reference pair: each frame's depth pixels, put into the world by its true
// pose and projected into the other frame, against the depth measured there.
void depthCheck(const BuiltAgent& target, const BuiltAgent& source, long ref_target, long ref_source,
                const TruthOptions& options, TruthAccuracy* accuracy) {
  std::vector<double> rel, metres;
  for (const auto& [own, own_id, other, other_id] :
       {std::tuple{&target, ref_target, &source, ref_source}, std::tuple{&source, ref_source, &target, ref_target}}) {
    const Cloud world = depthGrid(*own, own_id, options.grid_step_px);
    const Sim3 to_camera = other->camera_to_world.at(other_id).inverse();
    const cv::Mat& depth = other->depth.at(other_id);
    const PinholeCamera& cam = other->map.camera;
    for (Eigen::Index i = 0; i < world.cols(); ++i) {
      const Eigen::Vector3d q = to_camera.apply(Eigen::Vector3d(world.col(i)));
      double u = 0.0, v = 0.0;
      if (!cam.project(q, &u, &v)) continue;
      const long c = std::lround(u), r = std::lround(v);
      if (c < 0 || r < 0 || c >= cam.width || r >= cam.height) continue;
      const double d = depth.at<float>(static_cast<int>(r), static_cast<int>(c));
      if (d > 0.0 && std::abs(d - q.z()) <= options.depth_tolerance * q.z()) {
        rel.push_back(std::abs(d - q.z()) / q.z());
        metres.push_back(std::abs(d - q.z()));
      }
    }
  }
  // A median of fewer pixels than this says little about a 640x480 pair.
  constexpr std::size_t kMinPixels = 100;
  if (rel.size() < kMinPixels) return;
  accuracy->measured = true;
  accuracy->measured_depth_rel = upperMedian(&rel);
  accuracy->measured_depth_m = upperMedian(&metres);
}

void keyframePairs(const BuiltAgent& target, const BuiltAgent& source, const Viewer& target_view,
                   const Viewer& source_view, const TruthOptions& options, CaseTruth* out) {
  for (const MapKeyframe& a : target.map.keyframes) {
    const Cloud a_grid = depthGrid(target, a.id, options.grid_step_px);
    for (const MapKeyframe& b : source.map.keyframes) {
      KeyframePairTruth p;
      p.target_id = a.id;
      p.source_id = b.id;
      const Sim3& pa = target.camera_to_world.at(a.id);
      const Sim3& pb = source.camera_to_world.at(b.id);
      p.angle_deg = rotationDistance(pa.rotation(), pb.rotation()) * kRadToDeg;
      p.distance_m = (pa.translation() - pb.translation()).norm();
      p.target_seen_by_source = fractionSeen(a_grid, source_view, source_view.index(b.id));
      p.source_seen_by_target =
          fractionSeen(depthGrid(source, b.id, options.grid_step_px), target_view, target_view.index(a.id));
      p.covisible = std::min(p.target_seen_by_source, p.source_seen_by_target) >= options.min_pair_covisibility;
      p.local = target.world_to_map.at(a.id) * source.world_to_map.at(b.id).inverse();
      out->keyframe_pairs.push_back(p);
    }
  }
}

void overlapTruth(const OverlapPairs& pairs, const SequenceFacts& facts, CaseTruth* out) {
  const Cloud world = toCloud(pairs.world), in_target = toCloud(pairs.in_target), in_source = toCloud(pairs.in_source);
  out->truth.world_to_target = pcr_pro::umeyama(world, in_target, true);
  out->truth.world_to_source = pcr_pro::umeyama(world, in_source, true);
  out->truth.target_source = out->truth.world_to_target * out->truth.world_to_source.inverse();
  out->overlap_points = static_cast<long>(pairs.world.size());
  double sum2 = 0.0;
  for (Eigen::Index i = 0; i < world.cols(); ++i) {
    sum2 += (out->truth.target_source.apply(Eigen::Vector3d(in_source.col(i))) - in_target.col(i)).squaredNorm();
  }
  TruthAccuracy& acc = out->accuracy;
  acc.fit_rms = std::sqrt(sum2 / static_cast<double>(std::max<Eigen::Index>(1, world.cols())));
  const double target_scale = out->truth.world_to_target.scale();
  const double extent_m = robustDiagonal(pairs.world);
  acc.extent = extent_m * target_scale;
  const double s = out->truth.target_source.scale();
  for (const KeyframePairTruth& p : out->keyframe_pairs) {
    if (p.covisible) acc.scale_spread = std::max(acc.scale_spread, std::abs(p.local.scale() / s - 1.0));
  }
  const double pose_m = std::max(acc.stated_translation_m, acc.measured ? acc.measured_depth_m : 0.0);
  acc.rotation_deg = acc.stated_rotation_deg;
  acc.translation = target_scale * (pose_m + facts.depth_colour_offset_m) + acc.fit_rms;
  acc.scale_rel = acc.scale_spread + (extent_m > 0.0 ? pose_m / extent_m : 0.0);
}

}  // namespace

std::vector<long> nearestSeeingFrames(const Cloud& world, const BuiltAgent& viewer, const TruthOptions& options) {
  const Viewer view(viewer, options);
  std::vector<long> out(static_cast<std::size_t>(world.cols()));
  for (Eigen::Index i = 0; i < world.cols(); ++i) out[static_cast<std::size_t>(i)] = view.nearestSeeing(world.col(i));
  return out;
}

void validate(const TruthOptions& o) {
  auto fail = [](const std::string& key, const std::string& what) {
    throw InputError("truth." + key + ": must be " + what);
  };
  if (!(o.depth_tolerance > 0.0 && o.depth_tolerance < 1.0)) fail("depth_tolerance", "in (0, 1)");
  if (o.border_px < 0) fail("border_px", ">= 0");
  if (!(o.min_overlap > 0.0 && o.min_overlap < 1.0)) fail("min_overlap", "in (0, 1)");
  if (!(o.max_non_overlap >= 0.0 && o.max_non_overlap < o.min_overlap)) fail("max_non_overlap", "in [0, min_overlap)");
  if (!(o.min_pair_covisibility > 0.0 && o.min_pair_covisibility < 1.0)) fail("min_pair_covisibility", "in (0, 1)");
  if (o.grid_step_px < 1) fail("grid_step_px", ">= 1");
}

CaseTruth computeTruth(const BuiltAgent& target, const BuiltAgent& source, long reference_target, long reference_source,
                       const RgbdSequence& sequence, bool expect_overlap, const TruthOptions& options) {
  validate(options);
  const SequenceFacts& facts = sequence.facts();
  const Viewer target_view(target, options), source_view(source, options);
  CaseTruth out;
  out.truth.target_agent = target.map.frame_id.substr(0, target.map.frame_id.find('/'));
  out.truth.source_agent = source.map.frame_id.substr(0, source.map.frame_id.find('/'));
  OverlapPairs pairs;
  out.target_seen_by_source = addSeen(target, source, source_view, true, &pairs);
  out.source_seen_by_target = addSeen(source, target, target_view, false, &pairs);
  const double low = std::min(out.target_seen_by_source, out.source_seen_by_target);
  const double high = std::max(out.target_seen_by_source, out.source_seen_by_target);
  const std::string fractions = num(out.target_seen_by_source, 3) + " / " + num(out.source_seen_by_target, 3);
  if (expect_overlap && low < options.min_overlap) {
    throw InputError("case meant to overlap sees too little of the other map: " + fractions);
  }
  if (!expect_overlap && high > options.max_non_overlap) {
    throw InputError("case meant not to overlap sees part of the other map: " + fractions);
  }
  out.truth.overlap = expect_overlap;
  for (const BuiltAgent* agent : {&target, &source}) {
    for (const MapKeyframe& kf : agent->map.keyframes) out.truth.world_poses[kf.id] = agent->camera_to_world.at(kf.id);
  }
  keyframePairs(target, source, target_view, source_view, options, &out);

  TruthAccuracy& acc = out.accuracy;
  acc.stated_rotation_deg = facts.pose_rotation_deg;
  acc.stated_translation_m = facts.pose_translation_m;
  acc.depth_colour_offset_m = facts.depth_colour_offset_m;
  if (!expect_overlap) {
    out.truth.world_to_target = middleFrameG(target);
    out.truth.world_to_source = middleFrameG(source);
    out.truth.target_source = out.truth.world_to_target * out.truth.world_to_source.inverse();
    acc.rotation_deg = acc.stated_rotation_deg;
    acc.translation = out.truth.world_to_target.scale() * (acc.stated_translation_m + acc.depth_colour_offset_m);
    return out;
  }
  depthCheck(target, source, reference_target, reference_source, options, &acc);
  overlapTruth(pairs, facts, &out);
  return out;
}

std::string truthExtraYaml(const CaseTruth& truth, const BuiltAgent& target, const BuiltAgent& source,
                           const SequenceFacts& facts) {
  std::ostringstream y;
  y << "data_set: " << facts.data_set << "\n"
    << "data_note: \"" << facts.note << "\"\n"
    << "overlap_fractions: {target_seen_by_source: " << num(truth.target_seen_by_source, 4)
    << ", source_seen_by_target: " << num(truth.source_seen_by_target, 4) << ", point_pairs: " << truth.overlap_points
    << "}\n";
  y << "agents:\n";
  for (const BuiltAgent* agent : {&target, &source}) {
    const std::string name = agent->map.frame_id.substr(0, agent->map.frame_id.find('/'));
    const double first = agent->world_to_map.begin()->second.scale(),
                 last = agent->world_to_map.rbegin()->second.scale();
    y << "  " << name << ":\n"
      << "    frames: [" << agent->world_to_map.begin()->first << ", " << agent->world_to_map.rbegin()->first
      << "]  # first and last frame of the window; every frame's points are in the map cloud\n"
      << "    frame_count: " << agent->world_to_map.size() << "\n"
      << "    path_length_m: " << num(agent->path_length_m, 4) << "\n"
      << "    scale_first: " << num(first, 8) << "  # map units per metre at the first frame\n"
      << "    scale_last: " << num(last, 8) << "\n"
      << "    scale_drift: " << num(last / first - 1.0, 4) << "\n"
      << "    keyframes:  # true camera -> world [m] is in world_poses; G = world -> map near the keyframe\n";
    for (const MapKeyframe& kf : agent->map.keyframes) {
      y << "      " << kf.id << ": {G: " << sim3FlowYaml(agent->world_to_map.at(kf.id)) << "}\n";
    }
  }
  y << "keyframe_pairs:  # every cross-agent keyframe pair; local = G_target * G_source^-1 near the pair\n";
  for (const KeyframePairTruth& p : truth.keyframe_pairs) {
    y << "  - {target: " << p.target_id << ", source: " << p.source_id << ", angle_deg: " << num(p.angle_deg, 8)
      << ", distance_m: " << num(p.distance_m, 8) << ", target_seen_by_source: " << num(p.target_seen_by_source, 3)
      << ", source_seen_by_target: " << num(p.source_seen_by_target, 3)
      << ", covisible: " << (p.covisible ? "true" : "false") << ", local: " << sim3FlowYaml(p.local) << "}\n";
  }
  const TruthAccuracy& a = truth.accuracy;
  y << "truth_accuracy:  # how far the truth itself can be from the real answer (target units unless stated)\n"
    << "  stated_pose: {rotation_deg: " << num(a.stated_rotation_deg)
    << ", translation_m: " << num(a.stated_translation_m) << "}\n"
    << "  depth_colour_offset_m: " << num(a.depth_colour_offset_m)
    << "  # baseline between the depth and colour cameras, ignored when the depth was registered to colour\n";
  if (a.measured) {
    y << "  depth_check: {median_relative: " << num(a.measured_depth_rel, 4)
      << ", median_m: " << num(a.measured_depth_m, 4) << "}  # reference pair, through the true poses\n";
  } else {
    y << "  depth_check: null\n";
  }
  y << "  scale_spread: " << num(a.scale_spread, 4) << "\n"
    << "  fit_rms: " << num(a.fit_rms, 6) << "\n"
    << "  extent: " << num(a.extent, 6) << "\n"
    << "  rotation_deg: " << num(a.rotation_deg, 4) << "\n"
    << "  translation: " << num(a.translation, 6) << "\n"
    << "  scale_rel: " << num(a.scale_rel, 4) << "\n";
  return y.str();
}

}  // namespace real_cases
}  // namespace pcr_pro
