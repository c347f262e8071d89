/**
 * @file simulator.h
 * @brief The synthetic multi-agent world: N monocular-SLAM agents move through a textured room
 * (world.h) on camera paths; each gets rendered keyframes (render.h), an LSD-SLAM-like
 * semi-dense map (semi_dense.h) in its own frame and scale, with the map errors real monocular
 * maps have (scale drift and bending that integrate along the path, per-keyframe pose noise,
 * inverse-depth noise and outliers, partial overlap), LSD-SLAM's per-keyframe data and graph
 * snapshots that later correct part of the drift; and the exact truth of every pair of agents.
 * Deterministic from a seed. simulate() returns everything in memory; writeSimulation() writes
 * map bundles and truth files (the ROS bags are written by the pcr_pro_simulate tool).
 *
 * Frames: world = metres, z up (world.h). Agent i's map frame is world_to_map(i) applied to the
 * world: LSD-SLAM's convention, the first keyframe's camera frame, scaled by the agent's scale
 * (map units per metre). Keyframe poses are camera -> map similarities whose scale carries the
 * map scale (and its drift); camera units are metres.
 */
#pragma once

#include <opencv2/core.hpp>

#include <cstdint>
#include <optional>
#include <string>
#include <utility>
#include <vector>

#include "pcr_pro/geometry/map_types.h"
#include "pcr_pro/geometry/sim3.h"
#include "pcr_pro/io/lsd_keyframe.h"
#include "pcr_pro/sim/render.h"
#include "pcr_pro/sim/semi_dense.h"
#include "pcr_pro/sim/world.h"

namespace pcr_pro {

/// Camera paths (YAML block `trajectory`). Every agent looks from inside the room at the walls:
/// the looked-at point P(phi) is where the horizontal ray from the room centre at azimuth phi
/// meets the walls (at target_height); the camera stands `distance` back from P along that ray
/// turned by the agent's view angle about the vertical, so two agents with view angles a and b
/// see the same wall point from directions about |a - b| apart. phi sweeps the agent's azimuth
/// range; height, yaw and roll wobble smoothly (random phases from the seed).
struct TrajectoryOptions {
  double azimuth_span_deg = 80.0;  ///< azimuth range an agent sweeps [deg], in [1, 360]
  double distance = 2.2;           ///< camera to looked-at wall point [m], in [0.5, 20]
  double camera_height = 1.5;      ///< [m], > 0, below the ceiling
  double target_height = 1.1;      ///< height of the looked-at point [m], in [0, room height]
  double height_wobble = 0.12;     ///< amplitude of the camera height variation [m], >= 0
  double yaw_wobble_deg = 6.0;     ///< amplitude of the yaw variation [deg], in [0, 45]
  double pitch_wobble_deg = 4.0;   ///< amplitude of the pitch variation [deg], in [0, 45]
  double roll_wobble_deg = 3.0;    ///< amplitude of the roll variation [deg], in [0, 45]
  /// A new keyframe when the camera has moved this far since the last one [m], > 0 ...
  double keyframe_distance = 0.3;
  /// ... or turned this much [deg], > 0.
  double keyframe_angle_deg = 12.0;
  int max_keyframes = 60;  ///< keyframes per agent at most [-], in [2, 1000]
  /// Smallest distance of a camera from walls, ceiling, floor and boxes [m], >= 0. Where the
  /// path would come closer, the camera moves towards the looked-at point until it is free
  /// (no closer than 0.3 m to it; a path that cannot be made free is an error).
  double clearance = 0.3;
};

/// How the agents are placed when their own options leave it open (YAML block `layout`).
struct LayoutOptions {
  /// Overlap of agent_b with agent_a [-], in [0, 1]: the fraction of the surface agent_b maps
  /// (its map points, true positions) that agent_a also observes. agent_b's azimuth range is
  /// placed (bisection over low-resolution renders) to reach it as closely as the geometry
  /// allows; the measured value is in the truth.
  double overlap = 0.5;
  /// View-angle difference of agent_b to agent_a about the vertical [deg], in [0, 120]
  /// (agent_a gets -half, agent_b +half; real cases: 20-76 deg).
  double view_angle_difference_deg = 30.0;
  /// Azimuth where agent_a starts [deg]. Agent 2 (agent_c) starts 180 deg further, so it does
  /// not overlap agent_a with the default span; agents 3+ start (1 - overlap) * span after
  /// the previous one.
  double first_azimuth_deg = 20.0;
};

/// Map errors (YAML block `drift`; agents may override scale_drift and bend_deg).
struct DriftOptions {
  /// Relative change of the map scale from the first to the last keyframe [-], in [-0.5, 0.5]:
  /// it builds up step by step in proportion to the motion (m = translation + 0.5 m/rad *
  /// rotation), as odometry drift does.
  double scale_drift = 0.0;
  /// Rotation drift about the vertical from the first to the last keyframe [deg], in
  /// [-45, 45] (the map bends), built up like scale_drift.
  double bend_deg = 0.0;
  /// Per-keyframe pose noise that does not build up (jitter of each keyframe's estimate):
  /// rotation [deg], translation [m, camera units], relative scale [-]; each >= 0.
  double pose_noise_rotation_deg = 0.0;
  double pose_noise_translation = 0.0;
  double pose_noise_scale = 0.0;
  /// Fraction of the drift (and noise) a final LSD graph update removes, as a loop closure does
  /// [-], in [0, 1]: the map poses move this far from the tracked ones towards the drift-free
  /// ones. 0 = no correction.
  double loop_closure = 0.0;
};

/// What the agents' maps hold (YAML block `map`).
struct MapOutputOptions {
  SemiDenseOptions semi_dense;  ///< LSD-like sampling of every keyframe (block `map.semi_dense`)
  /// Fraction of each keyframe's semi-dense points that go into the map cloud, at random [-],
  /// in (0, 1] (the LSD keyframes keep all of them).
  double cloud_fraction = 0.1;
  /// Depth images of the bundle / pcr_pro keyframes: "dense" (the rendered depth, exact, like an
  /// RGB-D camera), "semi_dense" (the noisy semi-dense depth) or "none".
  std::string depth_images = "dense";
};

/// One agent's own settings (YAML list `per_agent`); unset values come from the layout.
struct AgentOptions {
  std::string name;                          ///< default agent_a, agent_b, ... (bundle dir name)
  std::optional<double> scale;               ///< map units per metre, in [1e-3, 1e3]
  std::optional<double> azimuth_start_deg;   ///< [deg]
  std::optional<double> azimuth_span_deg;    ///< [deg], in [1, 360]
  std::optional<double> view_angle_deg;      ///< [deg], in [-60, 60]
  std::optional<double> scale_drift;         ///< overrides drift.scale_drift
  std::optional<double> bend_deg;            ///< overrides drift.bend_deg
  /// Overrides map.semi_dense.idepth_noise for this agent's keyframes [-], >= 0: two agents
  /// whose maps are not equally noisy (another camera, farther walls, weaker texture), as real
  /// pairs of maps seldom are.
  std::optional<double> idepth_noise;
  /// This agent's camera (YAML block `camera` of its entry, keys not given taken from the top-level
  /// `camera`): robots of a team seldom carry the same one. Unset: SimulatorOptions::camera.
  std::optional<PinholeCamera> camera;
};

/// Everything simulate() needs. Defaults: 2 agents, 50 % overlap, 30 deg view-angle
/// difference, no drift.
struct SimulatorOptions {
  std::uint64_t seed = 1;
  int agents = 2;                   ///< number of agents [-], in [1, 26]
  std::vector<AgentOptions> per_agent;  ///< per-agent settings, agent i = entry i (at most `agents` entries)
  /// Camera of every agent that does not set its own (AgentOptions::camera): 640x480, 525 px focal
  /// length (a 62 deg horizontal field of view).
  PinholeCamera camera{525.0, 525.0, 319.5, 239.5, 640, 480};
  WorldOptions world;
  RenderOptions render;
  TrajectoryOptions trajectory;
  LayoutOptions layout;
  DriftOptions drift;
  MapOutputOptions map;
  /// Pairs whose overlap (see LayoutOptions::overlap) is below this count as not overlapping
  /// in the truth [-], in [0, 1].
  double min_overlap = 0.05;
};

/// @throw InputError naming the option, e.g. "layout.overlap: must be in [0, 1], got 2"
void validate(const SimulatorOptions& options);

/**
 * @brief Parses a simulator configuration (every block and key optional; see
 * config/simulator.yaml).
 * @throw InputError "<origin>: <key>: <what>" on bad YAML, unknown keys, wrong types or ranges
 */
SimulatorOptions parseSimulatorConfig(const std::string& text, const std::string& origin);
/// As parseSimulatorConfig() from a file. @throw InputError naming the file
SimulatorOptions loadSimulatorConfig(const std::string& path);
/// @return the options as YAML that parseSimulatorConfig() reads back to equal options
std::string simulatorConfigYaml(const SimulatorOptions& options);

/// One keyframe of an agent, with its truth.
struct SimKeyframe {
  long id = 0;          ///< unique over all agents: 1000 * agent index + keyframe index
  cv::Mat image;        ///< CV_8UC1 rendered grey image
  cv::Mat depth;        ///< CV_32FC1 rendered depth at each pixel centre, exact [m]; 0 = none
  SemiDenseKeyframe semi_dense;  ///< the LSD-like depth [m]
  Sim3 true_pose;       ///< camera -> world, rigid [m]
  Sim3 tracked_pose;    ///< camera -> map as tracked: drift and pose noise [map units]
  Sim3 map_pose;        ///< camera -> map after the last graph update (the bundle's pose)
  /// LSD-SLAM normalisation: the keyframe's inverse depths are multiplied by this so that their
  /// mean is 1, and its camToWorld is pose * Sim3(lsd_scale) [m]
  double lsd_scale = 1.0;
  double motion = 0.0;  ///< path motion from the first keyframe (m = translation + 0.5 m/rad * rotation) [m]
};

/// One agent's output.
struct SimAgent {
  std::string name;
  Sim3 world_to_map;   ///< world -> map at the path start (drift-free) [map units / m]
  double scale_drift = 0.0, bend_deg = 0.0;  ///< the drift this agent got
  double idepth_noise = 0.0;  ///< the semi-dense inverse-depth noise of its keyframes [-]
  double azimuth_start_deg = 0.0, azimuth_span_deg = 0.0, view_angle_deg = 0.0;
  std::vector<SimKeyframe> keyframes;
  /// The map as bundles hold it: frame "<name>/map", the cloud mapped by the map poses, the
  /// camera, keyframes with image, depth (MapOutputOptions::depth_images) and map pose.
  AgentMap map;
  Cloud cloud_world;               ///< true world position of every map cloud point [m]
  std::vector<int> cloud_keyframe; ///< index into keyframes of the keyframe of each point
  std::vector<bool> cloud_outlier; ///< whether each point's depth is an outlier
  /// LSD-SLAM graph snapshots (keyframeGraphMsg poses, camToWorld with the LSD normalisation):
  /// one after each keyframe with the tracked poses of the keyframes so far, then a last one
  /// with every keyframe's map pose (the loop closure).
  std::vector<std::vector<std::pair<long, Sim3>>> graph_snapshots;
};

/**
 * @brief The LSD-SLAM keyframe (keyframeMsg) of a simulated keyframe: every semi-dense pixel's
 * inverse depth and variance times lsd_scale (mean inverse depth 1), the grey image, camToWorld
 * = tracked pose * Sim3(lsd_scale).
 * @param[in] keyframe simulated keyframe
 * @param[in] camera the agents' camera
 * @param[in] time LSD-SLAM's frame time [s]
 */
LsdKeyframe toLsdKeyframe(const SimKeyframe& keyframe, const PinholeCamera& camera, double time);

/// A keyframe pair of two agents that see the same surface.
struct SimKeyframePair {
  long target_id = 0, source_id = 0;
  double covisible = 0.0;       ///< fraction of the source keyframe's map points the target keyframe sees [-]
  double view_angle_deg = 0.0;  ///< angle between the two optical axes [deg]
  /// S_target_source local to this pair: target map pose * target true pose⁻¹ * source true
  /// pose * source map pose⁻¹ (exact for points seen by both keyframes)
  Sim3 target_source;
};

/// Truth of an ordered pair of agents (target, source).
struct SimPairTruth {
  int target = 0, source = 0;   ///< agent indices
  double overlap_fraction = 0.0; ///< fraction of the source's map points the target observes [-]
  bool overlap = false;          ///< overlap_fraction >= SimulatorOptions::min_overlap
  /// Least-squares similarity (Umeyama) from the source map to the target map over the
  /// co-visible points of both maps: each of the source's points that a target keyframe sees,
  /// its source-map position (true camera point mapped by its own keyframe's map pose) against
  /// its target-map position (the same world point mapped through the target keyframe that sees
  /// it nearest its image centre), and each of the target's points that a source keyframe sees,
  /// the same way round. Pair (t, s) and pair (s, t) thus fit the same points, and their truths
  /// are inverses of each other (to the second order of the fit's residual). Without drift and
  /// pose noise it equals `start` (and is exact for the clouds); with drift it is what a merge
  /// of the overlap should find. Equals `start` when there is no co-visible point.
  Sim3 target_source;
  double rms = 0.0;   ///< residual of that fit [target units]: how far the maps are from one similarity
  int points = 0;     ///< co-visible points of the fit (of both maps)
  Sim3 start;         ///< world_to_map(target) * world_to_map(source)⁻¹ (drift-free frames)
  std::vector<SimKeyframePair> keyframe_pairs;  ///< pairs whose covisible >= min_overlap
};

/// Wall-clock times [ms].
struct SimTimings {
  double world = 0.0;      ///< scene and textures
  double layout = 0.0;     ///< placing the agents (overlap bisection)
  double render = 0.0;     ///< all keyframes
  int rendered = 0;        ///< keyframes rendered
  double maps = 0.0;       ///< semi-dense sampling, clouds, LSD data
  double truth = 0.0;      ///< pair truth
  double total = 0.0;
};

/// Everything simulate() makes.
struct Simulation {
  SimulatorOptions options;  ///< the options used
  World world;
  std::vector<SimAgent> agents;
  std::vector<SimPairTruth> pairs;  ///< every ordered pair (target != source)
  SimTimings timings;
  /// @return the truth of (target, source). @throw InputError when the indices are not a pair
  const SimPairTruth& pair(int target, int source) const;
};

/**
 * @brief Runs the simulator.
 * @param[in] options configuration (validated here)
 * @return world, agents and truth
 * @throw InputError on invalid options, or when a camera path cannot be kept inside the room
 */
Simulation simulate(const SimulatorOptions& options);

/**
 * @brief Writes DIR/<agent>/ (one map bundle per agent, loadBundle()), DIR/truth.yaml
 * (agent_a target, agent_b source, loadBundleTruth(); plus every agent's per-keyframe truth
 * and a summary of every pair), DIR/truth_<target>_<source>.yaml for every ordered pair
 * (loadBundleTruth()) and DIR/simulation.yaml (the options, parseSimulatorConfig()).
 * @param[in] dir output directory (created)
 * @param[in] simulation simulate()'s result
 * @param[in] depth_images false: write no depth images whatever map.depth_images says (the same
 *   world without depth; simulation.yaml then says depth_images: none, which reproduces it)
 * @throw InputError naming the file that cannot be written
 */
void writeSimulation(const std::string& dir, const Simulation& simulation, bool depth_images = true);

}  // namespace pcr_pro
