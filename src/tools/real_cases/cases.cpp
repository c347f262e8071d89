#include "real_cases/cases.h"

#include <algorithm>
#include <cmath>
#include <cstdint>
#include <filesystem>
#include <random>
#include <sstream>
#include <tuple>

#include "pcr_pro/io/bundle_writer.h"

namespace pcr_pro {
namespace real_cases {
namespace {

namespace fs = std::filesystem;

// ---- 7-Scenes ---------------------------------------------------------------------------------
//
// Every case is two agents, each a window of consecutive frames (every 5th frame of the data set's
// 30 Hz sequence) around a reference frame; the reference frames are the case's keyframe pair.
// Overlapping pairs were chosen from the poses and depth of all 200 frames: for every frame pair
// at least 100 frames apart (so that the windows are disjoint: separate passes through the room)
// with a camera angle between 20 and 76 deg, the fraction of each frame's depth pixels that the
// other frame sees (depth-consistent projection); per band of angles and part of the path the
// pair seeing most of each other was taken, together with the pairs SOURCE.txt lists (250-945,
// 270-490, 460-900, 450-860, 480-840). Pairs that do not overlap: windows of which no frame sees
// more than 0.5 % of any frame of the other window (three such places exist on this path).
// computeTruth() checks both claims again on the built maps and refuses an ill-chosen case.
struct SevenScenesCase {
  long target_centre, source_centre;  // reference frames of agent_a (target) and agent_b (source)
  bool overlap;
};

const SevenScenesCase kSevenScenesCases[] = {
    {250, 945, true}, {270, 490, true}, {160, 675, true},  {295, 915, true},  {505, 950, true},
    {475, 945, true}, {185, 785, true}, {460, 900, true},  {320, 840, true},  {450, 860, true},
    {520, 830, true}, {480, 840, true}, {120, 420, false}, {120, 865, false}, {670, 860, false},
};

// Window half-widths in frames (of the every-5th sequence): 8 frames = 40 raw frames = 1.3 s at
// 30 Hz either side for overlapping cases; 6 for the apart cases, whose only disjoint views are
// that short. Keyframes: every half_window / 2 frames, 5 per agent, the reference frame included.
constexpr int kOverlapHalfWindow = 8;
constexpr int kApartHalfWindow = 6;

// Agent frames: scale log-uniform in [0.1, 10] (map units per metre, as independently initialised
// monocular maps have), uniform random orientation, translation up to 5 map units per axis.
// Scale drift 1-3 % along the window, either sign.
constexpr double kMinScale = 0.1, kMaxScale = 10.0, kMaxOffset = 5.0, kMinDrift = 0.01, kMaxDrift = 0.03;
constexpr std::uint64_t kSevenScenesSeed = 7;

// Semi-dense sampling: LSD-SLAM's own gradient threshold order and noise (SemiDenseOptions
// defaults); one gradient pixel in `subsample` keeps each agent's fused cloud near the size of a
// real LSD map of a few seconds (tens of thousands of points). The noise is milder than real
// LSD-SLAM's on these frames: against the registered 7-Scenes depth, the keyframes of
// lsd_slam_7scenes (frames 560-625, viewer filters) have a robust (MAD) relative depth error of
// 6-9 % once a per-keyframe affine map of inverse depth is fitted (their inverse depth carries an
// offset of 0.75-0.95 / m, which leaves 27-32 % before that fit), where these options give 2 %
// and 1.5 % beyond 30 %.
SemiDenseOptions semiDense(int subsample) {
  SemiDenseOptions o;
  o.subsample = subsample;
  return o;
}
constexpr int kSevenScenesSubsample = 12;
constexpr int kSlambookSubsample = 2;

// Portable draws (the standard distributions' algorithms are not fixed by the standard).
class Draws {
 public:
  explicit Draws(std::uint64_t seed) : rng_(seed) {}
  double uniform(double lo, double hi) { return lo + (hi - lo) * static_cast<double>(rng_() >> 11) * 0x1.0p-53; }
  double gaussian() {
    const double u1 = std::max(uniform(0.0, 1.0), 1e-300), u2 = uniform(0.0, 1.0);
    return std::sqrt(-2.0 * std::log(u1)) * std::cos(2.0 * M_PI * u2);
  }
  Sim3 frame() {
    const double scale = std::exp(uniform(std::log(kMinScale), std::log(kMaxScale)));
    const Eigen::Quaterniond q(gaussian(), gaussian(), gaussian(), gaussian());  // uniform on SO(3)
    const Eigen::Vector3d t(uniform(-kMaxOffset, kMaxOffset), uniform(-kMaxOffset, kMaxOffset),
                            uniform(-kMaxOffset, kMaxOffset));
    return Sim3(scale, q.normalized(), t);
  }
  double drift() { return (uniform(0.0, 1.0) < 0.5 ? -1.0 : 1.0) * uniform(kMinDrift, kMaxDrift); }

 private:
  std::mt19937_64 rng_;
};

AgentSpec windowAgent(const RgbdSequence& sequence, const std::string& name, long centre, int half_window) {
  AgentSpec spec;
  spec.name = name;
  const std::vector<long> ids = sequence.ids();
  const auto at = std::find(ids.begin(), ids.end(), centre);
  if (at == ids.end()) throw InputError(sequence.facts().data_set + ": no frame " + std::to_string(centre));
  const long c = at - ids.begin();
  if (c < half_window || c + half_window >= static_cast<long>(ids.size())) {
    throw InputError(sequence.facts().data_set + ": the window around frame " + std::to_string(centre) +
                     " leaves the sequence");
  }
  for (long k = c - half_window; k <= c + half_window; ++k) {
    spec.frames.push_back(ids[static_cast<std::size_t>(k)]);
    if ((k - c) % (half_window / 2) == 0) spec.keyframes.push_back(ids[static_cast<std::size_t>(k)]);
  }
  return spec;
}

CaseSummary summarise(const std::string& path, const SequenceFacts& facts, const BuiltAgent& target,
                      const BuiltAgent& source, const CaseTruth& truth, long ref_target, long ref_source) {
  CaseSummary s;
  s.path = path;
  s.data_set = facts.data_set;
  s.overlap = truth.truth.overlap;
  s.reference_target = ref_target;
  s.reference_source = ref_source;
  const Sim3 &a = target.camera_to_world.at(ref_target), &b = source.camera_to_world.at(ref_source);
  s.angle_deg = rotationDistance(a.rotation(), b.rotation()) * 180.0 / M_PI;
  s.distance_m = (a.translation() - b.translation()).norm();
  s.target_scale = target.world_to_map.begin()->second.scale();
  s.source_scale = source.world_to_map.begin()->second.scale();
  s.target_drift = target.world_to_map.rbegin()->second.scale() / s.target_scale - 1.0;
  s.source_drift = source.world_to_map.rbegin()->second.scale() / s.source_scale - 1.0;
  s.target_points = target.map.cloud.cols();
  s.source_points = source.map.cloud.cols();
  s.target_seen_by_source = truth.target_seen_by_source;
  s.source_seen_by_target = truth.source_seen_by_target;
  s.accuracy = truth.accuracy;
  return s;
}

// Writes DIR/{agent_a,agent_b,truth.yaml}.
void writeCase(const fs::path& output, const std::string& rel, const BuiltAgent& target, const BuiltAgent& source,
               const CaseTruth& truth, const SequenceFacts& facts, bool depth_images, const std::string& comment) {
  const fs::path dir = output / rel;
  BundleWriteOptions options;
  options.write_depth = depth_images;
  options.depth_scale = 1000.0;  // depth in millimetres, as the data's own 16-bit depth images
  options.comment = comment + (depth_images ? "" : " Without depth images: keyframe depth comes from the map cloud.");
  writeBundle((dir / truth.truth.target_agent).string(), target.map, options);
  writeBundle((dir / truth.truth.source_agent).string(), source.map, options);
  writeBundleTruth((dir / "truth.yaml").string(), truth.truth,
                   "Truth of the real two-agent case " + rel +
                       " (pcr_pro_make_real_cases, see "
                       "docs/FORMATS.md).\n" +
                       comment,
                   truthExtraYaml(truth, target, source, facts));
}

// Writes the case with and without depth images into DIR/depth and DIR/nodepth.
void writeBothVariants(const std::string& output, const std::string& rel, const BuiltAgent& target,
                       const BuiltAgent& source, const CaseTruth& truth, const SequenceFacts& facts, long ref_target,
                       long ref_source, const std::string& comment, std::vector<CaseSummary>* out) {
  for (bool depth : {true, false}) {
    const std::string path = rel + (depth ? "/depth" : "/nodepth");
    writeCase(output, path, target, source, truth, facts, depth, comment);
    out->push_back(summarise(path, facts, target, source, truth, ref_target, ref_source));
    out->back().depth_images = depth;
  }
}

// ---- slambook2 -------------------------------------------------------------------------------
//
// The five NYU frames give the small cases the project has always had: agent_a = frames 1, 2, 4,
// agent_b = frames 3, 5 (pairs 2-3, 3-4 and 4-5 overlap best), each frame a keyframe; no drift.
// World -> map: agent_a in metres, agent_b at 0.4 map units per metre with a 120 deg rotation
// and a large offset, so that S_target_source has scale 2.5.
Sim3 axisAngleFrame(double scale, const Eigen::Vector3d& axis, double degrees, const Eigen::Vector3d& t) {
  return Sim3(scale, Eigen::AngleAxisd(degrees * M_PI / 180.0, axis.normalized()).toRotationMatrix(), t);
}
const Sim3 kSlambookTarget = axisAngleFrame(1.0, {0.3, 1.0, -0.2}, 25.0, {0.4, -0.1, 0.7});
const Sim3 kSlambookSource = axisAngleFrame(0.4, {-0.5, 0.8, 0.6}, 120.0, {2.5, -1.2, 3.0});
constexpr std::uint64_t kSlambookSeed = 20240531;
// The NYU frames have a white border of about 8 px: nothing there counts as seen.
constexpr int kNyuBorderPx = 8;

BuiltAgent slambookAgent(RgbdSequence& sequence, const std::string& name, const std::vector<long>& frames,
                         const Sim3& world_to_map, const cv::Rect& crop, bool lsd_noise = true) {
  AgentSpec spec;
  spec.name = name;
  spec.frames = frames;
  spec.keyframes = frames;
  spec.world_to_map = world_to_map;
  spec.crop = crop;
  spec.semi_dense = semiDense(kSlambookSubsample);
  if (!lsd_noise) {
    spec.semi_dense.idepth_noise = 0.0;
    spec.semi_dense.outlier_fraction = 0.0;
  }
  spec.seed = mixSeed(kSlambookSeed, static_cast<std::uint64_t>(crop.x + 1000 * crop.width));
  return buildAgent(sequence, spec);
}

// Both agents' clouds drawn from one world cloud, the semi-dense points of all their frames: each
// point goes to an agent one of whose frames sees it, at random when both do. The clouds are then
// independent samples of the same surfaces, so S_target_source is exact for their geometry too
// (each agent's own cloud otherwise carries its own frames' pose errors). The points are the
// measured depth of the gradient pixels without the LSD-like noise and outliers, so that what a
// registration misses is its own error, not the data's.
void shareWorld(BuiltAgent* a, BuiltAgent* b, const TruthOptions& options) {
  Cloud world(3, a->world_points.cols() + b->world_points.cols());
  world << a->world_points, b->world_points;
  const std::vector<long> seen_a = nearestSeeingFrames(world, *a, options);
  const std::vector<long> seen_b = nearestSeeingFrames(world, *b, options);
  Draws coin(mixSeed(kSlambookSeed, 7));
  std::vector<Eigen::Index> to_a, to_b;
  for (Eigen::Index i = 0; i < world.cols(); ++i) {
    const std::size_t k = static_cast<std::size_t>(i);
    const bool pick_a = coin.uniform(0.0, 1.0) < 0.5;  // drawn for every point: a stream independent of the rest
    if (seen_a[k] >= 0 && (seen_b[k] < 0 || pick_a)) {
      to_a.push_back(i);
    } else if (seen_b[k] >= 0) {
      to_b.push_back(i);
    }
  }
  for (auto [agent, picked, seen] : {std::tuple{a, &to_a, &seen_a}, std::tuple{b, &to_b, &seen_b}}) {
    agent->world_points.resize(3, static_cast<Eigen::Index>(picked->size()));
    agent->map.cloud.resize(3, static_cast<Eigen::Index>(picked->size()));
    agent->point_frames.clear();
    for (std::size_t j = 0; j < picked->size(); ++j) {
      const Eigen::Index i = (*picked)[j];
      const long frame = (*seen)[static_cast<std::size_t>(i)];
      agent->world_points.col(static_cast<Eigen::Index>(j)) = world.col(i);
      agent->map.cloud.col(static_cast<Eigen::Index>(j)) =
          agent->world_to_map.at(frame).apply(Eigen::Vector3d(world.col(i)));
      agent->point_frames.push_back(frame);
    }
  }
}

// Computes the truth and writes one slambook2 case directory (with depth images unless told).
void writeSlambookCase(const std::string& output, const std::string& name, const BuiltAgent& target,
                       const BuiltAgent& source, long ref_target, long ref_source, bool overlap, bool depth,
                       const RgbdSequence& sequence, const std::string& comment, std::vector<CaseSummary>* out) {
  TruthOptions options;
  options.border_px = kNyuBorderPx;
  CaseTruth truth;
  try {
    truth = computeTruth(target, source, ref_target, ref_source, sequence, overlap, options);
  } catch (const InputError& e) {
    throw InputError("slambook2/" + name + ": " + e.what());
  }
  writeCase(output, "slambook2/" + name, target, source, truth, sequence.facts(), depth, comment);
  out->push_back(summarise("slambook2/" + name, sequence.facts(), target, source, truth, ref_target, ref_source));
  out->back().depth_images = depth;
}

}  // namespace

std::vector<CaseSummary> buildSlambook2Cases(RgbdSequence& sequence, const std::string& output) {
  std::vector<CaseSummary> out;
  const std::string frames = "slambook2 ch5 frames (NYU Depth V2) from the real-data directory: ";
  BuiltAgent a = slambookAgent(sequence, "agent_a", {1, 2, 4}, kSlambookTarget, cv::Rect());
  BuiltAgent b = slambookAgent(sequence, "agent_b", {3, 5}, kSlambookSource, cv::Rect());
  const std::string both = frames + "agent_a = 1, 2, 4; agent_b = 3, 5.";
  writeSlambookCase(output, "depth", a, b, 4, 5, true, true, sequence, both, &out);
  writeSlambookCase(output, "nodepth", a, b, 4, 5, true, false, sequence, both, &out);
  TruthOptions visibility;
  visibility.border_px = kNyuBorderPx;
  a = slambookAgent(sequence, "agent_a", {1, 2, 4}, kSlambookTarget, cv::Rect(), false);
  b = slambookAgent(sequence, "agent_b", {3, 5}, kSlambookSource, cv::Rect(), false);
  shareWorld(&a, &b, visibility);
  writeSlambookCase(output, "sharedworld", a, b, 4, 5, true, true, sequence,
                    both + " Both clouds sampled from one noise-free world cloud (exact truth for the clouds).", &out);
  // Disjoint views: the right half of frame 1 against the left halves of frames 4 and 5.
  const BuiltAgent right = slambookAgent(sequence, "agent_a", {1}, kSlambookTarget, cv::Rect(320, 0, 320, 480));
  const BuiltAgent left = slambookAgent(sequence, "agent_b", {4, 5}, kSlambookSource, cv::Rect(0, 0, 320, 480));
  writeSlambookCase(output, "nooverlap", right, left, 1, 4, false, true, sequence,
                    frames + "agent_a = frame 1, columns 320-639; agent_b = frames 4, 5, columns 0-319.", &out);
  return out;
}

std::vector<CaseSummary> buildSevenScenesCases(RgbdSequence& sequence, const std::string& output) {
  std::vector<CaseSummary> out;
  const TruthOptions truth_options;
  std::uint64_t index = 0;
  for (const SevenScenesCase& c : kSevenScenesCases) {
    Draws draws(mixSeed(kSevenScenesSeed, index++));
    const int half = c.overlap ? kOverlapHalfWindow : kApartHalfWindow;
    AgentSpec a = windowAgent(sequence, "agent_a", c.target_centre, half);
    AgentSpec b = windowAgent(sequence, "agent_b", c.source_centre, half);
    for (AgentSpec* spec : {&a, &b}) {
      spec->world_to_map = draws.frame();
      spec->scale_drift = draws.drift();
      spec->semi_dense = semiDense(kSevenScenesSubsample);
      spec->seed = mixSeed(kSevenScenesSeed, static_cast<std::uint64_t>(1000 * index + (spec == &a ? 0 : 1)));
    }
    const BuiltAgent target = buildAgent(sequence, a), source = buildAgent(sequence, b);
    const std::string name =
        (c.overlap ? "overlap_" : "apart_") + std::to_string(c.target_centre) + "_" + std::to_string(c.source_centre);
    CaseTruth truth;
    try {
      truth = computeTruth(target, source, c.target_centre, c.source_centre, sequence, c.overlap, truth_options);
    } catch (const InputError& e) {
      throw InputError("7scenes/" + name + ": " + e.what());
    }
    const std::string comment = "7-Scenes redkitchen frames " + std::to_string(a.frames.front()) + "-" +
                                std::to_string(a.frames.back()) + " (agent_a) and " + std::to_string(b.frames.front()) +
                                "-" + std::to_string(b.frames.back()) + " (agent_b), from the real-data directory.";
    writeBothVariants(output, "7scenes/" + name, target, source, truth, sequence.facts(), c.target_centre,
                      c.source_centre, comment, &out);
  }
  return out;
}

std::string indexYaml(const std::vector<CaseSummary>& cases, const std::string& data_dir) {
  std::ostringstream y;
  y.precision(6);
  y << "# Real two-agent cases built by pcr_pro_make_real_cases from " << data_dir << "\n"
    << "# (see docs/FORMATS.md). One entry per case directory (agent_a = target, agent_b = source).\n"
    << "cases:\n";
  for (const CaseSummary& c : cases) {
    y << "  - {path: " << c.path << ", data_set: " << c.data_set << ", overlap: " << (c.overlap ? "true" : "false")
      << ", depth_images: " << (c.depth_images ? "true" : "false") << ", reference_pair: [" << c.reference_target
      << ", " << c.reference_source << "], angle_deg: " << c.angle_deg << ", distance_m: " << c.distance_m
      << ", scales: [" << c.target_scale << ", " << c.source_scale << "], drifts: [" << c.target_drift << ", "
      << c.source_drift << "], points: [" << c.target_points << ", " << c.source_points << "], seen_by_other: ["
      << c.target_seen_by_source << ", " << c.source_seen_by_target
      << "], truth_accuracy: {rotation_deg: " << c.accuracy.rotation_deg << ", translation: " << c.accuracy.translation
      << ", extent: " << c.accuracy.extent << ", scale_rel: " << c.accuracy.scale_rel << "}}\n";
  }
  return y.str();
}

}  // namespace real_cases
}  // namespace pcr_pro
