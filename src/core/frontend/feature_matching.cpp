#include "pcr_pro/frontend/feature_matching.h"

#include <Eigen/Core>

#include <algorithm>
#include <cmath>
#include <opencv2/features2d.hpp>
#include <opencv2/imgproc.hpp>
#include <string>

#include "pcr_pro/frontend/descriptor_index.h"

namespace pcr_pro {
namespace {

// Rows of a descriptor matrix usable for matching: CV_32F, one row per keypoint.
// Returns an empty matrix when the side cannot take part in k-NN matching with k = 2.
cv::Mat usableDescriptors(const KeyframeFeatures& f, const char* side) {
  if (f.descriptors.empty()) return cv::Mat();
  if (f.descriptors.rows != static_cast<int>(f.keypoints.size())) {
    throw InputError(std::string("matchFeatures: keyframe ") + side + " has " + std::to_string(f.keypoints.size()) +
                     " keypoints but " + std::to_string(f.descriptors.rows) + " descriptor rows");
  }
  if (f.descriptors.rows < 2 || f.descriptors.channels() != 1) return cv::Mat();
  if (f.descriptors.type() == CV_32F) return f.descriptors;
  cv::Mat converted;
  f.descriptors.convertTo(converted, CV_32F);
  return converted;
}

// query -> train: approximate k-NN (k = 2) in a seeded descriptor index of `train` with the ratio
// test, then (options.symmetric) the mutual check: the exact nearest query descriptor of each
// chosen train descriptor (a few hundred scans, cheaper than a second index, and exact) must be
// the one that chose it. Distances are L2 (not squared), as the ratio test wants them.
std::vector<cv::DMatch> ratioAndMutual(const cv::Mat& query, const cv::Mat& train, const FeatureMatchingOptions& options) {
  const DescriptorIndex index(train, options.flann_trees, options.seed);
  DescriptorIndex::Searcher searcher(index);
  std::vector<DescriptorNeighbor> nn;
  std::vector<cv::DMatch> good;
  good.reserve(static_cast<std::size_t>(query.rows));
  for (int q = 0; q < query.rows; ++q) {
    searcher.knn(query.ptr<float>(q), 2, options.flann_checks, &nn);
    if (nn.size() < 2) continue;
    const float best = std::sqrt(nn[0].squared_distance), second = std::sqrt(nn[1].squared_distance);
    if (!std::isfinite(best) || !std::isfinite(second)) continue;
    if (!(best < options.ratio_test * second)) continue;
    good.emplace_back(q, nn[0].index, best);
  }
  if (!options.symmetric) return good;
  using RowMatrix = Eigen::Matrix<float, Eigen::Dynamic, Eigen::Dynamic, Eigen::RowMajor>;
  using ConstRows = Eigen::Map<const RowMatrix, 0, Eigen::OuterStride<>>;
  const ConstRows eq(query.ptr<float>(), query.rows, query.cols, Eigen::OuterStride<>(query.step1()));
  const ConstRows et(train.ptr<float>(), train.rows, train.cols, Eigen::OuterStride<>(train.step1()));
  std::vector<int> best_query_of_train(static_cast<std::size_t>(train.rows), -1);
  std::vector<cv::DMatch> mutual;
  mutual.reserve(good.size());
  for (const cv::DMatch& m : good) {
    int& back = best_query_of_train[static_cast<std::size_t>(m.trainIdx)];
    if (back < 0) {
      Eigen::Index arg = 0;
      (eq.rowwise() - et.row(m.trainIdx)).rowwise().squaredNorm().minCoeff(&arg);
      back = static_cast<int>(arg);
    }
    if (back == m.queryIdx) mutual.push_back(m);
  }
  return mutual;
}

}  // namespace

template <>
const ParamSchema<FeatureMatchingOptions>& paramSchema<FeatureMatchingOptions>() {
  using O = FeatureMatchingOptions;
  using R = ParamRange;
  static const ParamSchema<O> schema{"matching", {
      {"image_scale", &O::image_scale, R::openClosed(0, 1), "-",
       "keyframe image resized by this factor before SIFT (keypoints mapped back); 0.75 costs about 2/3 of full size, "
       "set 1 for small or low-texture images"},
      {"nfeatures", &O::nfeatures, R::atLeast(0), "", "best SIFT features kept per image; 0 = all"},
      {"n_octave_layers", &O::n_octave_layers, R::atLeast(1), "", "layers per octave of the SIFT scale space"},
      {"contrast_threshold", &O::contrast_threshold, R::above(0), "OpenCV SIFT units", "rejects low-contrast features"},
      {"edge_threshold", &O::edge_threshold, R::above(0), "-", "rejects edge-like features"},
      {"sigma", &O::sigma, R::above(0), "px", "Gaussian at octave 0"},
      {"flann_trees", &O::flann_trees, R::atLeast(1), "", "randomised k-d trees of the FLANN index"},
      {"flann_checks", &O::flann_checks, R::atLeast(1), "", "leaves visited per FLANN query"},
      {"ratio_test", &O::ratio_test, R::openClosed(0, 1), "-", "Lowe ratio test"},
      {"symmetric", &O::symmetric, R::any(), "", "keep only mutual best matches"},
      {"min_matches", &O::min_matches, R::atLeast(0), "", "fewer good matches: the keyframe pair is not used"},
  }};
  return schema;
}

void validate(const FeatureMatchingOptions& options) {
  checkRanges(paramSchema<FeatureMatchingOptions>(), options);
}

KeyframeFeatures extractFeatures(const cv::Mat& gray8, const FeatureMatchingOptions& options) {
  validate(options);
  KeyframeFeatures features;
  if (gray8.empty()) return features;
  if (gray8.type() != CV_8UC1) {
    throw InputError("extractFeatures: image must be 8-bit single-channel (CV_8UC1), got type " +
                     std::to_string(gray8.type()) + " with " + std::to_string(gray8.channels()) + " channel(s)");
  }
  cv::Ptr<cv::SIFT> sift = cv::SIFT::create(options.nfeatures, options.n_octave_layers, options.contrast_threshold,
                                            options.edge_threshold, options.sigma);
  // OpenCV's SIFT doubles the image first with a resize that puts pixel x of the image at (x + 0.5)
  // * 2 - 0.5 = 2x + 0.5 of the doubled one, and reports a keypoint found there at half its doubled
  // coordinate: every keypoint lands a quarter pixel right of and below where it is, in the image
  // SIFT ran on (opencv/opencv issue 23123; the "precise upscale" that removes it came after the
  // OpenCV 4.6 of Debian 12 and is off by default). The same shift in both keyframes of a pair
  // nearly cancels when their cameras are alike; with two different cameras it is a different angle
  // in each, and on simulated maps of two cameras it made the keyframe estimate's 6-DoF NEES 5-32,
  // over-confident (docs/DESIGN.md). Test: FeatureMatching.KeypointsHaveNoSubpixelBias.
  constexpr float kSiftShift = 0.25f;
  if (options.image_scale < 1.0) {
    const cv::Size size(std::max(1, cvRound(gray8.cols * options.image_scale)),
                        std::max(1, cvRound(gray8.rows * options.image_scale)));
    cv::Mat small;
    cv::resize(gray8, small, size, 0.0, 0.0, cv::INTER_AREA);
    sift->detectAndCompute(small, cv::noArray(), features.keypoints, features.descriptors);
    // Back to full-resolution pixels: pixel centres map as (x + 0.5) * full / small - 0.5.
    const float sx = static_cast<float>(gray8.cols) / static_cast<float>(size.width);
    const float sy = static_cast<float>(gray8.rows) / static_cast<float>(size.height);
    for (cv::KeyPoint& k : features.keypoints) {
      k.pt.x = (k.pt.x - kSiftShift + 0.5f) * sx - 0.5f;
      k.pt.y = (k.pt.y - kSiftShift + 0.5f) * sy - 0.5f;
      k.size *= 0.5f * (sx + sy);
    }
  } else {
    sift->detectAndCompute(gray8, cv::noArray(), features.keypoints, features.descriptors);
    for (cv::KeyPoint& k : features.keypoints) k.pt -= cv::Point2f(kSiftShift, kSiftShift);
  }
  if (features.keypoints.empty()) features.descriptors.release();
  return features;
}

FeatureMatches matchFeatures(const KeyframeFeatures& a, const KeyframeFeatures& b,
                             const FeatureMatchingOptions& options) {
  validate(options);
  FeatureMatches result;
  const cv::Mat desc_a = usableDescriptors(a, "a");
  const cv::Mat desc_b = usableDescriptors(b, "b");
  if (desc_a.empty() || desc_b.empty()) return result;
  if (desc_a.cols != desc_b.cols) {
    throw InputError("matchFeatures: descriptor lengths differ (" + std::to_string(desc_a.cols) + " vs " +
                     std::to_string(desc_b.cols) + ")");
  }

  // With the symmetric check on, the smaller descriptor set queries an index of the larger
  // one (fewer queries); the ratio test then applies from the smaller side.
  const bool swap = options.symmetric && desc_a.rows > desc_b.rows;
  std::vector<cv::DMatch> good = swap ? ratioAndMutual(desc_b, desc_a, options) : ratioAndMutual(desc_a, desc_b, options);
  if (swap) {
    for (cv::DMatch& m : good) std::swap(m.queryIdx, m.trainIdx);
  }
  // Without the symmetric check several a-keypoints may share one b-keypoint: that is kept,
  // as in the plain ratio-test matcher.
  std::sort(good.begin(), good.end(), [](const cv::DMatch& l, const cv::DMatch& r) { return l.distance < r.distance; });

  result.pixels_a.reserve(good.size());
  result.pixels_b.reserve(good.size());
  result.index_a.reserve(good.size());
  result.index_b.reserve(good.size());
  result.distances.reserve(good.size());
  for (const cv::DMatch& m : good) {
    const cv::Point2f& pa = a.keypoints[static_cast<std::size_t>(m.queryIdx)].pt;
    const cv::Point2f& pb = b.keypoints[static_cast<std::size_t>(m.trainIdx)].pt;
    result.pixels_a.emplace_back(pa.x, pa.y);
    result.pixels_b.emplace_back(pb.x, pb.y);
    result.index_a.push_back(m.queryIdx);
    result.index_b.push_back(m.trainIdx);
    result.distances.push_back(m.distance);
  }
  return result;
}

std::vector<std::vector<int>> keyframePairVotes(const std::vector<const KeyframeFeatures*>& sources,
                                                const std::vector<const KeyframeFeatures*>& targets,
                                                const FeatureMatchingOptions& options) {
  return KeyframeVoteIndex(targets, options).votes(sources);
}

KeyframeVoteIndex::KeyframeVoteIndex(const std::vector<const KeyframeFeatures*>& targets,
                                     const FeatureMatchingOptions& options)
    : options_(options), targets_(targets.size()) {
  validate(options_);
  std::vector<cv::Mat> parts;
  for (std::size_t t = 0; t < targets.size(); ++t) {
    const cv::Mat d = usableDescriptors(*targets[t], "target");
    if (d.empty()) continue;
    if (length_ >= 0 && d.cols != length_) throw InputError("keyframePairVotes: descriptor lengths differ");
    length_ = d.cols;
    parts.push_back(d);
    owner_.insert(owner_.end(), static_cast<std::size_t>(d.rows), static_cast<int>(t));
  }
  if (owner_.size() < 2) return;
  cv::Mat all;
  cv::vconcat(parts, all);
  index_ = std::make_unique<DescriptorIndex>(all, options_.flann_trees, options_.seed);
}

KeyframeVoteIndex::~KeyframeVoteIndex() = default;

std::vector<std::vector<int>> KeyframeVoteIndex::votes(const std::vector<const KeyframeFeatures*>& sources) const {
  std::vector<std::vector<int>> votes(sources.size(), std::vector<int>(targets_, 0));
  if (!index_) return votes;
  std::vector<cv::Mat> queries;
  for (std::size_t s = 0; s < sources.size(); ++s) {
    queries.push_back(usableDescriptors(*sources[s], "source"));
    if (!queries.back().empty() && queries.back().cols != length_) {
      throw InputError("keyframePairVotes: descriptor lengths differ");
    }
  }
  // The ratio test on distances, compared squared: d0 < r * dk  <=>  d0^2 < r^2 * dk^2.
  const float ratio2 = static_cast<float>(options_.ratio_test * options_.ratio_test);
  // Each source keyframe's row of votes on its own thread (a searcher per thread; the index is
  // only read): the same votes as in turn, and as each row alone.
#pragma omp parallel
  {
    DescriptorIndex::Searcher searcher(*index_);
    std::vector<DescriptorNeighbor> m;
#pragma omp for schedule(dynamic)
    for (std::size_t s = 0; s < sources.size(); ++s) {
      const cv::Mat& q = queries[s];
      for (int row = 0; row < q.rows; ++row) {
        searcher.knn(q.ptr<float>(row), 4, options_.flann_checks, &m);
        if (m.empty()) continue;
        const int best = owner_[static_cast<std::size_t>(m[0].index)];
        bool accept = true;
        for (std::size_t k = 1; k < m.size(); ++k) {
          if (owner_[static_cast<std::size_t>(m[k].index)] != best) {
            accept = m[0].squared_distance < ratio2 * m[k].squared_distance;
            break;
          }
        }
        if (accept) ++votes[s][static_cast<std::size_t>(best)];
      }
    }
  }
  return votes;
}

}  // namespace pcr_pro
