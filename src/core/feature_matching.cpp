#include "pcr_pro/core/feature_matching.h"

#include <algorithm>
#include <cmath>
#include <opencv2/features2d.hpp>
#include <opencv2/flann.hpp>
#include <string>

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

cv::FlannBasedMatcher makeMatcher(const FeatureMatchingOptions& options) {
  return cv::FlannBasedMatcher(cv::makePtr<cv::flann::KDTreeIndexParams>(options.flann_trees),
                               cv::makePtr<cv::flann::SearchParams>(options.flann_checks));
}

}  // namespace

void validate(const FeatureMatchingOptions& options) {
  if (!(options.nfeatures >= 0)) throw InputError("matching.nfeatures must be >= 0");
  if (!(options.n_octave_layers >= 1)) throw InputError("matching.n_octave_layers must be >= 1");
  if (!(options.contrast_threshold > 0.0) || !std::isfinite(options.contrast_threshold)) {
    throw InputError("matching.contrast_threshold must be a finite number > 0");
  }
  if (!(options.edge_threshold > 0.0) || !std::isfinite(options.edge_threshold)) {
    throw InputError("matching.edge_threshold must be a finite number > 0");
  }
  if (!(options.sigma > 0.0) || !std::isfinite(options.sigma)) {
    throw InputError("matching.sigma must be a finite number > 0");
  }
  if (!(options.flann_trees >= 1)) throw InputError("matching.flann_trees must be >= 1");
  if (!(options.flann_checks >= 1)) throw InputError("matching.flann_checks must be >= 1");
  if (!(options.ratio_test > 0.0 && options.ratio_test <= 1.0)) {
    throw InputError("matching.ratio_test must be in (0, 1]");
  }
  if (!(options.min_matches >= 0)) throw InputError("matching.min_matches must be >= 0");
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
  sift->detectAndCompute(gray8, cv::noArray(), features.keypoints, features.descriptors);
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

  // a -> b: two nearest neighbours for the ratio test.
  std::vector<std::vector<cv::DMatch>> knn_ab;
  makeMatcher(options).knnMatch(desc_a, desc_b, knn_ab, 2);

  // b -> a: nearest neighbour of every b descriptor, for the mutual-best check.
  std::vector<int> best_a_of_b;
  if (options.symmetric) {
    std::vector<std::vector<cv::DMatch>> knn_ba;
    makeMatcher(options).knnMatch(desc_b, desc_a, knn_ba, 1);
    best_a_of_b.assign(static_cast<std::size_t>(desc_b.rows), -1);
    for (const auto& m : knn_ba) {
      if (m.empty()) continue;
      const int qb = m[0].queryIdx;
      if (qb >= 0 && qb < desc_b.rows) best_a_of_b[static_cast<std::size_t>(qb)] = m[0].trainIdx;
    }
  }

  std::vector<cv::DMatch> good;
  good.reserve(knn_ab.size());
  for (const auto& m : knn_ab) {
    if (m.size() < 2) continue;
    const cv::DMatch& best = m[0];
    const cv::DMatch& second = m[1];
    if (best.queryIdx < 0 || best.queryIdx >= desc_a.rows || best.trainIdx < 0 || best.trainIdx >= desc_b.rows) {
      continue;
    }
    if (!std::isfinite(best.distance) || !std::isfinite(second.distance)) continue;
    if (!(best.distance < options.ratio_test * second.distance)) continue;
    if (options.symmetric && best_a_of_b[static_cast<std::size_t>(best.trainIdx)] != best.queryIdx) continue;
    good.push_back(best);
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

}  // namespace pcr_pro
