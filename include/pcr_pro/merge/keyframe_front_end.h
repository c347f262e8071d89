/**
 * @file keyframe_front_end.h
 * @brief The merge's fast estimate, stage 1: SIFT once per keyframe (cached across merges),
 * the descriptor-vote preselection of keyframe pairs, FLANN matching and the OpenGV relative
 * pose of every candidate pair (votes, matches and poses cached across merges as well); then,
 * when the preselection left pairs out, every pair within
 * merge.local_keyframes of the best verified pair too (where the maps overlap best).
 */
#pragma once

#include <cstdint>
#include <map>
#include <memory>
#include <mutex>
#include <string>
#include <utility>
#include <vector>

#include "pcr_pro/frontend/feature_matching.h"
#include "pcr_pro/frontend/relative_pose.h"
#include "pcr_pro/geometry/map_types.h"
#include "pcr_pro/merge/merge_options.h"

namespace pcr_pro {

/**
 * @brief SIFT features per keyframe, kept across merges. An entry is keyed by (map key,
 * keyframe id) and remembers a fingerprint of the image it was computed from (buffer, size and a
 * sample of pixels) and of the SIFT options: a keyframe re-sent with new content, or other
 * options, is recomputed, never served stale. Thread-safe.
 */
class FeatureCache {
 public:
  /// @return the cached features of the keyframe, or null when absent or stale
  std::shared_ptr<const KeyframeFeatures> find(const std::string& map_key, const MapKeyframe& keyframe,
                                               const FeatureMatchingOptions& options) const;
  /// Stores the features of a keyframe (replacing an older entry).
  void store(const std::string& map_key, const MapKeyframe& keyframe, const FeatureMatchingOptions& options,
             std::shared_ptr<const KeyframeFeatures> features);
  /// Drops one keyframe's entry (e.g. when the keyframe is re-sent or leaves the map).
  void invalidate(const std::string& map_key, long keyframe_id);
  /// Drops every entry of one map.
  void invalidateMap(const std::string& map_key);
  void clear();
  /// @return number of entries
  std::size_t size() const;

 private:
  struct Entry {
    std::uint64_t fingerprint = 0;
    std::shared_ptr<const KeyframeFeatures> features;
  };
  mutable std::mutex mutex_;
  std::map<std::pair<std::string, long>, Entry> entries_;
};

/// A keyframe pair matched in full, with its relative pose (verified when pose.status is kOk).
struct CandidatePair {
  const MapKeyframe* source = nullptr;
  const MapKeyframe* target = nullptr;
  int votes = -1;          ///< descriptor votes of the preselection (-1: no preselection)
  FeatureMatches matches;  ///< a = target keyframe, b = source keyframe
  RelativePoseResult pose;
  bool cached = false;     ///< matches and pose came from the PairCache (computed by an earlier merge)
};

/**
 * @brief What the front end computed from keyframe images alone, kept across merges: the matches
 * and relative pose of each keyframe pair matched in full, and the preselection's vote index over
 * the last target keyframes with the votes of each source keyframe against it (a source map that
 * grows then costs one row of votes per new keyframe; new target keyframes need a new index, and
 * every row again). None depends on keyframe poses, depth or map clouds, which change as the maps
 * grow. Entries are keyed by the keyframes' features and hold them weakly: a keyframe re-sent with
 * other content, or invalidated in the FeatureCache, gets new features, so every entry made from
 * its old ones misses (and is dropped at the next run). A pair entry also keeps both cameras and
 * misses when either changed. Matching and RANSAC are seeded per pair and the votes' descriptor
 * index by the options, so a hit gives exactly what recomputing would. Thread-safe.
 */
class PairCache {
 public:
  /// Matches and relative pose of one pair.
  struct PairResult {
    FeatureMatches matches;
    RelativePoseResult pose;
  };
  using Features = std::shared_ptr<const KeyframeFeatures>;

  /// Pair entries kept at most; past it the least recently used is dropped. A merge matches at
  /// most merge.max_candidate_pairs + (2 merge.local_keyframes + 1)² pairs (59 by default), so
  /// this holds the pairs of 17 such merges or more. An entry takes about 50 bytes per match
  /// (two pixels, two indices, a distance, an inlier index): 25 kB for 500 matches, so the cache
  /// stays within about 25 MB however long a node runs.
  static constexpr std::size_t kMaxPairs = 1024;

  /// @return the pair's cached result, or null when absent or made from other features or cameras
  std::shared_ptr<const PairResult> find(const Features& target, const Features& source,
                                         const PinholeCamera& target_camera, const PinholeCamera& source_camera);
  void store(const Features& target, const Features& source, const PinholeCamera& target_camera,
             const PinholeCamera& source_camera, std::shared_ptr<const PairResult> result);
  /// @return the vote index last stored for exactly these target features (same order), or null
  std::shared_ptr<const KeyframeVoteIndex> findVoteIndex(const std::vector<Features>& targets) const;
  /// Keeps `index` for these target features; the rows of votes of the index before are dropped.
  void storeVoteIndex(const std::vector<Features>& targets, std::shared_ptr<const KeyframeVoteIndex> index);
  /// @return the votes of this source keyframe stored against `index`, or null when absent, made
  ///   from other features or against another index
  std::shared_ptr<const std::vector<int>> findVoteRow(const std::shared_ptr<const KeyframeVoteIndex>& index,
                                                      const Features& source) const;
  /// Keeps a source keyframe's votes against `index` (ignored when `index` is no longer the one kept).
  void storeVoteRow(const std::shared_ptr<const KeyframeVoteIndex>& index, const Features& source,
                    std::shared_ptr<const std::vector<int>> row);
  /// Drops the entries whose features are gone.
  void prune();
  void clear();
  /// @return number of pair entries
  std::size_t size() const;

 private:
  struct Slot {
    std::weak_ptr<const KeyframeFeatures> target, source;
    PinholeCamera target_camera, source_camera;
    std::shared_ptr<const PairResult> result;
    std::uint64_t used = 0;  ///< clock_ at the last find() or store()
  };
  // The vote index of one set of target keyframes and the rows of votes computed against it,
  // one per source keyframe's features.
  struct VoteRow {
    std::weak_ptr<const KeyframeFeatures> source;
    std::shared_ptr<const std::vector<int>> votes;
  };
  struct VoteSlot {
    std::vector<std::weak_ptr<const KeyframeFeatures>> targets;
    std::shared_ptr<const KeyframeVoteIndex> index;
    std::map<const KeyframeFeatures*, VoteRow> rows;
  };
  mutable std::mutex mutex_;
  std::map<std::pair<const KeyframeFeatures*, const KeyframeFeatures*>, Slot> slots_;
  VoteSlot votes_;
  std::uint64_t clock_ = 0;
};

/**
 * @brief Relative pose of one keyframe pair from its matches: bearings of the matched pixels
 * (pixels_a in the target keyframe, pixels_b in the source keyframe), RANSAC threshold from the
 * mean focal length of the two cameras.
 * @throw InputError as estimateRelativePose()
 */
RelativePoseResult keyframePairPose(const FeatureMatches& matches, const PinholeCamera& target_camera,
                                    const PinholeCamera& source_camera, const RelativePoseOptions& options);

/// What the front end found.
struct FrontEndResult {
  /// Status kInvalidInput with message when a requested keyframe is missing; otherwise kOk, also
  /// when no pair verified (see verified).
  Status status = Status::kOk;
  std::string message;
  /// Every candidate pair, the verified ones first by decreasing inlier count, then the others
  /// by decreasing match count.
  std::vector<CandidatePair> pairs;
  int verified = 0;        ///< pairs with pose.status kOk (the first `verified` of pairs)
  int keyframe_pairs = 0;  ///< keyframe pairs there were before the preselection
  int features_computed = 0;
  int features_cached = 0;
  int pairs_cached = 0;        ///< pairs whose matches and relative pose came from the PairCache
  bool votes_cached = false;   ///< the preselection's votes came from the PairCache, every row
  int vote_rows_computed = 0;  ///< source keyframes whose votes were computed (not from the PairCache)
  /// Pairs that verified in an earlier run, added from the PairCache because no preselected pair
  /// verified (KeyframeFrontEnd::run()) [-].
  int earlier_pairs = 0;
  double features_ms = 0.0;       ///< SIFT and matching
  double relative_pose_ms = 0.0;  ///< RANSAC and refinement of every candidate
};

/// Stage 1 of the merge (see the file comment). Built once from the options; keeps the feature
/// cache across runs.
class KeyframeFrontEnd {
 public:
  /// @throw InputError when the options are invalid
  explicit KeyframeFrontEnd(const MergeOptions& options);

  /**
   * @brief Features, preselection, matching and relative pose for the keyframes of two maps.
   * With more pairs than merge.max_candidate_pairs, the pairs with the most votes are matched in
   * full, then every pair within merge.local_keyframes of the best verified one. When none of them
   * verified, the pairs of these keyframes that verified in earlier runs are added from the
   * PairCache (FrontEndResult::earlier_pairs; no matching or RANSAC).
   * @param[in] source source map (its keyframes must outlive the result)
   * @param[in] target target map
   * @param[in] request keyframe ids to use (unset = every keyframe)
   * @param[in] source_key, target_key cache keys of the two maps (e.g. agent names)
   */
  FrontEndResult run(const AgentMap& source, const AgentMap& target, const MergeRequest& request,
                     const std::string& source_key = "source", const std::string& target_key = "target");

  FeatureCache& cache() { return cache_; }
  PairCache& pairCache() { return pair_cache_; }
  const MergeOptions& options() const { return options_; }

 private:
  std::vector<std::shared_ptr<const KeyframeFeatures>> featuresOf(const std::vector<const MapKeyframe*>& keyframes,
                                                                  const std::string& key, FrontEndResult* out);
  /// Matches the given (source, target) index pairs in full, adds them to out->pairs with their
  /// relative pose and re-sorts out->pairs (FrontEndResult::pairs order).
  void matchPairs(const std::vector<const MapKeyframe*>& src, const std::vector<const MapKeyframe*>& tgt,
                  const std::vector<std::shared_ptr<const KeyframeFeatures>>& src_features,
                  const std::vector<std::shared_ptr<const KeyframeFeatures>>& tgt_features,
                  const std::vector<std::pair<std::size_t, std::size_t>>& pairs,
                  const std::vector<std::vector<int>>& votes, const PinholeCamera& source_camera,
                  const PinholeCamera& target_camera, FrontEndResult* out);
  MergeOptions options_;
  FeatureCache cache_;
  PairCache pair_cache_;
};

}  // namespace pcr_pro
