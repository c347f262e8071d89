/**
 * @file feature_matching.h
 * @brief Keyframe matching (PCR-Pro §Keyframe Matching): SIFT features on one keyframe image,
 * approximate k-NN matching between two keyframes (a seeded randomised k-d forest, FLANN's
 * method: descriptor_index.h), Lowe's ratio test and a symmetric (mutual best)
 * check.
 *
 * Extraction and matching are separate so that a pipeline can extract the features of every
 * keyframe once and then match as many keyframe pairs as it likes.
 */
#pragma once

#include <Eigen/Core>
#include <cstddef>
#include <cstdint>
#include <memory>
#include <opencv2/core.hpp>
#include <vector>

#include "pcr_pro/geometry/types.h"
#include "pcr_pro/io/param_schema.h"

namespace pcr_pro {

/// Options of the keyframe matching stage (YAML block `matching`).
struct FeatureMatchingOptions {
  /// The image is resized by this factor (area interpolation) before SIFT, and the keypoints are
  /// mapped back to full-resolution pixels [-], in (0, 1]. SIFT's cost grows with the pixel
  /// count (0.75: about 2/3 of full size; 0.5: 1/3). The smallest-scale features go first;
  /// at 0.5 a wide-baseline pair of the test frames (3 -> 5) is left with too few matches for a
  /// correct relative pose, at 0.75 it is not.
  double image_scale = 0.75;
  /// SIFT: number of best features kept per image, ranked by contrast; 0 keeps all [-], >= 0.
  int nfeatures = 2000;
  /// SIFT: number of layers in each octave of the scale space [-], >= 1.
  int n_octave_layers = 3;
  /// SIFT: contrast threshold that rejects weak features in low-contrast regions, in the units
  /// of OpenCV's SIFT (image intensity normalised to [0, 1], divided by n_octave_layers) [-], > 0.
  double contrast_threshold = 0.04;
  /// SIFT: edge threshold, the largest ratio of principal curvatures kept (rejects edge-like
  /// features) [-], > 0.
  double edge_threshold = 10.0;
  /// SIFT: standard deviation of the Gaussian applied to the input image at octave 0 [px], > 0.
  double sigma = 1.6;
  /// Randomised k-d trees of the descriptor index (DescriptorIndex, FLANN's method) [-], >= 1.
  int flann_trees = 4;
  /// Descriptors compared per query in the index (more = slower and more exact) [-], >= 1.
  int flann_checks = 64;
  /// Lowe's ratio test: a match is kept when its descriptor distance is below ratio_test times
  /// the distance to the second nearest neighbour [-], in (0, 1].
  double ratio_test = 0.8;
  /// Symmetric (cross) check: keep a match a->b only when a is also the nearest neighbour of b
  /// in the other direction [-].
  bool symmetric = true;
  /// Fewest matches for a keyframe pair to be usable [matches], >= 0. Applied by the caller
  /// (the pipeline reports NOT_ENOUGH_MATCHES); matchFeatures() returns every good match.
  int min_matches = 15;
  /// Seed of the descriptor index's random generator (its trees): equal features and seeds give
  /// equal matches and votes, bit for bit [-].
  std::uint64_t seed = kDefaultSeed;
};

/// Every parameter of FeatureMatchingOptions (YAML block `matching`): key, type, default (the member initialiser), range, unit, doc.
template <>
const ParamSchema<FeatureMatchingOptions>& paramSchema<FeatureMatchingOptions>();

/**
 * @brief Checks every field of the options.
 * @param[in] options options to check
 * @throw InputError naming the first invalid key, e.g. "matching.ratio_test must be in (0, 1]"
 */
void validate(const FeatureMatchingOptions& options);

/// SIFT features of one keyframe image.
struct KeyframeFeatures {
  /// Keypoints; pt is in pixels of the input image [px].
  std::vector<cv::KeyPoint> keypoints;
  /// One CV_32F row of 128 values per keypoint (empty when there are no keypoints).
  cv::Mat descriptors;
};

/// Good matches between keyframe a and keyframe b; all vectors have the same length.
struct FeatureMatches {
  std::vector<Eigen::Vector2d> pixels_a;  ///< keypoint position in image a (u, v) [px]
  std::vector<Eigen::Vector2d> pixels_b;  ///< keypoint position in image b (u, v) [px]
  std::vector<int> index_a;               ///< index into KeyframeFeatures::keypoints of a
  std::vector<int> index_b;               ///< index into KeyframeFeatures::keypoints of b
  std::vector<float> distances;           ///< L2 descriptor distance [SIFT descriptor units]

  /// @return the number of matches
  std::size_t size() const { return index_a.size(); }
  /// @return true when there is no match
  bool empty() const { return index_a.empty(); }
};

/**
 * @brief Detects SIFT keypoints and computes their descriptors (OpenCV cv::SIFT).
 * @param[in] gray8 8-bit single-channel image (CV_8UC1); an empty image gives no features
 * @param[in] options SIFT options (validated here)
 * @return the keypoints and their descriptors (none for a featureless image)
 * @throw InputError when gray8 is not empty and not CV_8UC1, or when the options are invalid
 */
KeyframeFeatures extractFeatures(const cv::Mat& gray8, const FeatureMatchingOptions& options);

/**
 * @brief Matches the features of two keyframes: approximate k-NN (k = 2, a DescriptorIndex of the
 * larger side seeded with options.seed) from a to b, Lowe's ratio
 * test, then (when options.symmetric) the mutual-best check: the exact nearest neighbour in a of
 * each b descriptor that some a descriptor chose must be that a descriptor. With the symmetric
 * check on, the smaller of the two descriptor sets is the query side, for speed: the ratio test
 * is then applied from that side (mutual matches do not depend on the direction, the ratio
 * test does).
 *
 * Each keypoint of a and of b appears in at most one match when the symmetric check is on.
 * Returns no match (never throws for this reason) when either side has fewer than 2 keypoints
 * or empty descriptors. Descriptors that are not CV_32F are converted to CV_32F.
 * The index owns its random generator (options.seed): the same features and options give the
 * same matches, bit for bit, in any order of calls and whatever else uses random numbers.
 * @param[in] a features of keyframe a
 * @param[in] b features of keyframe b
 * @param[in] options matching options (validated here)
 * @return the good matches, sorted by increasing descriptor distance
 * @throw InputError when the options are invalid, when a non-empty descriptor matrix does not
 * have one row per keypoint, or when the descriptor lengths of a and b differ
 */
FeatureMatches matchFeatures(const KeyframeFeatures& a, const KeyframeFeatures& b,
                             const FeatureMatchingOptions& options);

/**
 * @brief Cheap keyframe-pair scores for choosing which pairs to match in full: one descriptor
 * index (seeded with options.seed) over the descriptors of every keyframe in `targets`; each descriptor of each keyframe in
 * `sources` votes for the target keyframe of its nearest descriptor when that neighbour passes
 * the ratio test against the nearest descriptor of any other target keyframe (among the 4
 * nearest; a descriptor whose 4 nearest all lie in one keyframe votes for it).
 * @param[in] sources features of the source keyframes
 * @param[in] targets features of the target keyframes
 * @param[in] options matching options (flann_trees, flann_checks, ratio_test, seed; validated here)
 * @return votes[s][t] for source keyframe s and target keyframe t [descriptors]
 * @throw InputError as matchFeatures()
 */
std::vector<std::vector<int>> keyframePairVotes(const std::vector<const KeyframeFeatures*>& sources,
                                                const std::vector<const KeyframeFeatures*>& targets,
                                                const FeatureMatchingOptions& options);

class DescriptorIndex;

/**
 * @brief The target side of keyframePairVotes(), kept: the descriptor index over every target
 * keyframe's descriptors. A source keyframe's votes depend only on its own descriptors and on
 * this index (each row is searched on its own), so the votes of keyframes added to a growing
 * source map cost one row each while the target keyframes stay the same (PairCache): on the
 * bench's 50 x 50 keyframes, building the index takes about 130 ms and each row about 4 ms.
 */
class KeyframeVoteIndex {
 public:
  /**
   * @param[in] targets features of the target keyframes (read here, not kept)
   * @param[in] options matching options (flann_trees, flann_checks, ratio_test, seed; validated here)
   * @throw InputError as keyframePairVotes()
   */
  KeyframeVoteIndex(const std::vector<const KeyframeFeatures*>& targets, const FeatureMatchingOptions& options);
  ~KeyframeVoteIndex();
  KeyframeVoteIndex(const KeyframeVoteIndex&) = delete;
  KeyframeVoteIndex& operator=(const KeyframeVoteIndex&) = delete;

  /// @return number of target keyframes (the length of each row of votes)
  std::size_t targets() const { return targets_; }
  /**
   * @brief Votes of each source keyframe for each target keyframe, as keyframePairVotes(); the
   * rows are searched on the OpenMP threads, each as it would be alone. Thread-safe.
   * @return votes[s][t] [descriptors]
   * @throw InputError when a source's descriptors are unusable or of another length
   */
  std::vector<std::vector<int>> votes(const std::vector<const KeyframeFeatures*>& sources) const;

 private:
  FeatureMatchingOptions options_;
  std::size_t targets_ = 0;
  int length_ = -1;            // descriptor length; -1 without any target descriptor
  std::vector<int> owner_;     // target keyframe of each indexed descriptor
  std::unique_ptr<DescriptorIndex> index_;  // null with fewer than 2 target descriptors
};

}  // namespace pcr_pro
