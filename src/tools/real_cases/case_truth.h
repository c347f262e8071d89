// The truth of a real two-agent case: whether the maps overlap, S_target_source where they do,
// the keyframe pairs that see the same surfaces with their camera angle and distance, and how
// accurate that truth itself is (the data's poses, the depth/colour offset, the agents' drift).
#pragma once

#include <string>
#include <vector>

#include "pcr_pro/io/bundle.h"
#include "real_cases/agent_builder.h"

namespace pcr_pro {
namespace real_cases {

/// Options of the truth computation.
struct TruthOptions {
  /// A world point is seen by a frame when it projects inside the frame's image, in front of the
  /// camera, and its depth there agrees with the frame's measured depth within this fraction of the
  /// depth [-], in (0, 1). 5 %: above the semi-dense samples' depth noise (1 % at the reference
  /// gradient, at most 4 % on weak edges) and Kinect's noise at room range (1-2 %), below the depth
  /// gap between an occluder and what it hides (tens of cm at 1-3 m).
  double depth_tolerance = 0.05;
  /// Pixels this close to the image border do not count as seen [px], >= 0 (the NYU frames of
  /// slambook2 have a white border of about 8 px; 0 elsewhere).
  int border_px = 0;
  /// The maps overlap when at least this fraction of each agent's cloud is seen by a frame of the
  /// other agent [-], in (0, 1).
  double min_overlap = 0.10;
  /// The maps do not overlap when at most this fraction of either cloud is seen by the other
  /// agent's frames [-], in [0, min_overlap). A case between the two is refused as ambiguous.
  double max_non_overlap = 0.005;
  /// A keyframe pair is co-visible when at least this fraction of each keyframe's depth pixels is
  /// seen by the other keyframe [-], in (0, 1).
  double min_pair_covisibility = 0.10;
  /// Sampling step of the depth grids used for keyframe pairs and the depth check [px], >= 1.
  int grid_step_px = 4;
};

/// @throw InputError naming the option
void validate(const TruthOptions& options);

/// A cross-agent keyframe pair.
struct KeyframePairTruth {
  long target_id = 0, source_id = 0;
  double angle_deg = 0.0;              ///< angle between the two cameras' orientations [deg]
  double distance_m = 0.0;             ///< distance between the camera centres [m]
  double target_seen_by_source = 0.0;  ///< fraction of the target keyframe's depth pixels the source keyframe sees
  double source_seen_by_target = 0.0;  ///< and the other way round
  bool covisible = false;              ///< both fractions >= min_pair_covisibility
  Sim3 local;                          ///< G_target(keyframe) * G_source(keyframe)^-1: S_target_source near this pair
};

/// How accurate the truth is, in the units of the target map unless stated.
struct TruthAccuracy {
  double stated_rotation_deg = 0.0;  ///< the data set's stated pose accuracy
  double stated_translation_m = 0.0;
  double depth_colour_offset_m = 0.0;
  /// Depth check of the reference keyframe pair: the median disagreement between where one frame's
  /// depth pixels land in the other frame (through the truth's poses) and the depth measured
  /// there, over the pixels both see. Pose errors of the data show in it, together with the depth
  /// noise; it runs when enough pixels are co-visible.
  bool measured = false;
  double measured_depth_rel = 0.0;  ///< median |Δz| / z [-]
  double measured_depth_m = 0.0;    ///< median |Δz| [m]
  double scale_spread = 0.0;        ///< max |local scale / S scale - 1| over co-visible keyframe pairs
  double fit_rms = 0.0;             ///< RMS residual of S_target_source over the overlap [target units]
  double extent = 0.0;              ///< size of the overlap (5-95 % box diagonal) [target units]
  double rotation_deg = 0.0;        ///< total: the stated rotation accuracy
  double translation = 0.0;         ///< total [target units]
  double scale_rel = 0.0;           ///< total [-]
};

/// The truth of a case.
struct CaseTruth {
  BundleTruth truth;                   ///< what loadBundleTruth() reads
  double target_seen_by_source = 0.0;  ///< fraction of the target cloud seen by a source frame
  double source_seen_by_target = 0.0;  ///< fraction of the source cloud seen by a target frame
  long overlap_points = 0;             ///< point pairs the least-squares S_target_source was fitted to
  std::vector<KeyframePairTruth> keyframe_pairs;
  TruthAccuracy accuracy;
};

/**
 * @brief For each world point, the frame of `viewer` with the nearest camera among those that see
 * it (TruthOptions::depth_tolerance, border_px), or -1 when none does.
 * @param[in] world points in the world frame [m]
 * @param[in] viewer the agent whose frames look
 * @param[in] options visibility options
 */
std::vector<long> nearestSeeingFrames(const Cloud& world, const BuiltAgent& viewer, const TruthOptions& options);

/**
 * @brief Computes the truth of a case from its two built agents.
 *
 * Overlap: see TruthOptions. Where the maps overlap, each agent's map restricted to the overlap
 * is fitted by one similarity of the world (least squares over the world points that both
 * agents see, each point mapped by the local G_k of the frame of that agent with the nearest
 * camera that sees it): world_to_target, world_to_source, and S_target_source = world_to_target *
 * world_to_source^-1. Without drift this is exact. Where they do not overlap, world_to_X = G of
 * the middle frame of the agent's window.
 *
 * @param[in] target the target agent
 * @param[in] source the source agent
 * @param[in] reference_target, reference_source the keyframe pair the case was chosen around (the
 *   depth check runs on it)
 * @param[in] sequence the frames (for the facts of the data set)
 * @param[in] expect_overlap what the case is meant to be
 * @param[in] options the options
 * @throw InputError when the overlap contradicts expect_overlap or is ambiguous (the case is
 *   ill-chosen), or on invalid options
 */
CaseTruth computeTruth(const BuiltAgent& target, const BuiltAgent& source, long reference_target, long reference_source,
                       const RgbdSequence& sequence, bool expect_overlap, const TruthOptions& options);

/// @return the YAML keys of truth.yaml beyond those loadBundleTruth() reads (see docs/FORMATS.md)
std::string truthExtraYaml(const CaseTruth& truth, const BuiltAgent& target, const BuiltAgent& source,
                           const SequenceFacts& facts);

}  // namespace real_cases
}  // namespace pcr_pro
