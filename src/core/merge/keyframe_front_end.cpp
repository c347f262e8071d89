#include "pcr_pro/merge/keyframe_front_end.h"

#include <algorithm>
#include <chrono>
#include <cstring>
#include <exception>
#include <optional>
#include <set>
#include <tuple>

namespace pcr_pro {
namespace {

using Clock = std::chrono::steady_clock;

double msSince(Clock::time_point start) {
  return std::chrono::duration<double, std::milli>(Clock::now() - start).count();
}

// f(0) ... f(n - 1) on the OpenMP threads; when calls threw, one of their exceptions is rethrown
// here (an exception must not leave a parallel region).
template <typename F>
void forEachInParallel(std::size_t n, const F& f) {
  std::exception_ptr error;
#pragma omp parallel for schedule(dynamic)
  for (std::size_t k = 0; k < n; ++k) {
    try {
      f(k);
    } catch (...) {
#pragma omp critical(pcr_pro_front_end_error)
      if (!error) error = std::current_exception();
    }
  }
  if (error) std::rethrow_exception(error);
}

// FNV-1a over 8-byte words: every pixel counts, ~0.3 ms for a 640 x 480 image.
std::uint64_t mix(std::uint64_t h, std::uint64_t v) {
  h ^= v;
  return h * 0x100000001b3ULL;
}

std::uint64_t mixDouble(std::uint64_t h, double v) {
  std::uint64_t bits = 0;
  std::memcpy(&bits, &v, sizeof bits);
  return mix(h, bits);
}

std::uint64_t fingerprint(const cv::Mat& image, const FeatureMatchingOptions& o) {
  std::uint64_t h = 0xcbf29ce484222325ULL;
  h = mix(h, static_cast<std::uint64_t>(image.rows));
  h = mix(h, static_cast<std::uint64_t>(image.cols));
  h = mix(h, static_cast<std::uint64_t>(image.type()));
  const std::size_t row_bytes = image.cols * image.elemSize();
  for (int r = 0; r < image.rows; ++r) {
    const unsigned char* p = image.ptr<unsigned char>(r);
    std::size_t k = 0;
    for (; k + 8 <= row_bytes; k += 8) {
      std::uint64_t word = 0;
      std::memcpy(&word, p + k, 8);
      h = mix(h, word);
    }
    for (; k < row_bytes; ++k) h = mix(h, p[k]);
  }
  // The SIFT options change the features too.
  h = mixDouble(h, o.image_scale);
  h = mix(h, static_cast<std::uint64_t>(o.nfeatures));
  h = mix(h, static_cast<std::uint64_t>(o.n_octave_layers));
  h = mixDouble(h, o.contrast_threshold);
  h = mixDouble(h, o.edge_threshold);
  h = mixDouble(h, o.sigma);
  return h;
}

// The keyframes of a map to consider: the requested one, or all of them.
std::vector<const MapKeyframe*> selectKeyframes(const AgentMap& map, const std::optional<long>& id) {
  std::vector<const MapKeyframe*> out;
  for (const MapKeyframe& kf : map.keyframes) {
    if (!id || kf.id == *id) out.push_back(&kf);
  }
  return out;
}

bool sameCamera(const PinholeCamera& a, const PinholeCamera& b) {
  return a.fx == b.fx && a.fy == b.fy && a.cx == b.cx && a.cy == b.cy && a.width == b.width && a.height == b.height;
}

// Whether the weak pointers still point at exactly these features, in order.
bool sameFeatures(const std::vector<std::weak_ptr<const KeyframeFeatures>>& held,
                  const std::vector<PairCache::Features>& now) {
  if (held.size() != now.size()) return false;
  for (std::size_t i = 0; i < now.size(); ++i) {
    if (held[i].lock() != now[i]) return false;  // an expired one locks to null
  }
  return true;
}

}  // namespace

std::shared_ptr<const PairCache::PairResult> PairCache::find(const Features& target, const Features& source,
                                                             const PinholeCamera& target_camera,
                                                             const PinholeCamera& source_camera) {
  std::lock_guard<std::mutex> lock(mutex_);
  const auto it = slots_.find({target.get(), source.get()});
  if (it == slots_.end()) return nullptr;
  Slot& slot = it->second;
  // An expired pointer means the features at that address are new ones (a re-sent keyframe).
  if (slot.target.lock() != target || slot.source.lock() != source) return nullptr;
  if (!sameCamera(slot.target_camera, target_camera) || !sameCamera(slot.source_camera, source_camera)) return nullptr;
  slot.used = ++clock_;
  return slot.result;
}

void PairCache::store(const Features& target, const Features& source, const PinholeCamera& target_camera,
                      const PinholeCamera& source_camera, std::shared_ptr<const PairResult> result) {
  std::lock_guard<std::mutex> lock(mutex_);
  slots_[{target.get(), source.get()}] = Slot{target, source, target_camera, source_camera, std::move(result), ++clock_};
  if (slots_.size() > kMaxPairs) {
    auto oldest = slots_.begin();
    for (auto it = slots_.begin(); it != slots_.end(); ++it) {
      if (it->second.used < oldest->second.used) oldest = it;
    }
    slots_.erase(oldest);
  }
}

std::shared_ptr<const KeyframeVoteIndex> PairCache::findVoteIndex(const std::vector<Features>& targets) const {
  std::lock_guard<std::mutex> lock(mutex_);
  if (!votes_.index || !sameFeatures(votes_.targets, targets)) return nullptr;
  return votes_.index;
}

void PairCache::storeVoteIndex(const std::vector<Features>& targets, std::shared_ptr<const KeyframeVoteIndex> index) {
  std::lock_guard<std::mutex> lock(mutex_);
  votes_ = VoteSlot{{targets.begin(), targets.end()}, std::move(index), {}};
}

std::shared_ptr<const std::vector<int>> PairCache::findVoteRow(const std::shared_ptr<const KeyframeVoteIndex>& index,
                                                               const Features& source) const {
  std::lock_guard<std::mutex> lock(mutex_);
  if (!index || votes_.index != index) return nullptr;
  const auto it = votes_.rows.find(source.get());
  // An expired pointer means the features at that address are new ones (a re-sent keyframe).
  if (it == votes_.rows.end() || it->second.source.lock() != source) return nullptr;
  return it->second.votes;
}

void PairCache::storeVoteRow(const std::shared_ptr<const KeyframeVoteIndex>& index, const Features& source,
                             std::shared_ptr<const std::vector<int>> row) {
  std::lock_guard<std::mutex> lock(mutex_);
  if (!index || votes_.index != index) return;
  votes_.rows[source.get()] = VoteRow{source, std::move(row)};
}

void PairCache::prune() {
  std::lock_guard<std::mutex> lock(mutex_);
  for (auto it = slots_.begin(); it != slots_.end();) {
    const bool gone = it->second.target.expired() || it->second.source.expired();
    it = gone ? slots_.erase(it) : std::next(it);
  }
  for (auto it = votes_.rows.begin(); it != votes_.rows.end();) {
    it = it->second.source.expired() ? votes_.rows.erase(it) : std::next(it);
  }
}

void PairCache::clear() {
  std::lock_guard<std::mutex> lock(mutex_);
  slots_.clear();
  votes_ = VoteSlot();
}

std::size_t PairCache::size() const {
  std::lock_guard<std::mutex> lock(mutex_);
  return slots_.size();
}

std::shared_ptr<const KeyframeFeatures> FeatureCache::find(const std::string& map_key, const MapKeyframe& keyframe,
                                                           const FeatureMatchingOptions& options) const {
  const std::uint64_t f = fingerprint(keyframe.image, options);
  std::lock_guard<std::mutex> lock(mutex_);
  const auto it = entries_.find({map_key, keyframe.id});
  if (it == entries_.end() || it->second.fingerprint != f) return nullptr;
  return it->second.features;
}

void FeatureCache::store(const std::string& map_key, const MapKeyframe& keyframe,
                         const FeatureMatchingOptions& options, std::shared_ptr<const KeyframeFeatures> features) {
  const std::uint64_t f = fingerprint(keyframe.image, options);
  std::lock_guard<std::mutex> lock(mutex_);
  entries_[{map_key, keyframe.id}] = Entry{f, std::move(features)};
}

void FeatureCache::invalidate(const std::string& map_key, long keyframe_id) {
  std::lock_guard<std::mutex> lock(mutex_);
  entries_.erase({map_key, keyframe_id});
}

void FeatureCache::invalidateMap(const std::string& map_key) {
  std::lock_guard<std::mutex> lock(mutex_);
  for (auto it = entries_.begin(); it != entries_.end();) {
    it = it->first.first == map_key ? entries_.erase(it) : std::next(it);
  }
}

void FeatureCache::clear() {
  std::lock_guard<std::mutex> lock(mutex_);
  entries_.clear();
}

std::size_t FeatureCache::size() const {
  std::lock_guard<std::mutex> lock(mutex_);
  return entries_.size();
}

RelativePoseResult keyframePairPose(const FeatureMatches& matches, const PinholeCamera& target_camera,
                                    const PinholeCamera& source_camera, const RelativePoseOptions& options) {
  std::vector<Eigen::Vector3d> bt, bs;
  bt.reserve(matches.size());
  bs.reserve(matches.size());
  for (std::size_t k = 0; k < matches.pixels_a.size(); ++k) {
    bt.push_back(target_camera.bearing(matches.pixels_a[k].x(), matches.pixels_a[k].y()));
    bs.push_back(source_camera.bearing(matches.pixels_b[k].x(), matches.pixels_b[k].y()));
  }
  const double focal = 0.5 * (source_camera.focal() + target_camera.focal());
  return estimateRelativePose(bt, bs, focal, options);
}

KeyframeFrontEnd::KeyframeFrontEnd(const MergeOptions& options) : options_(options) { validate(options_); }

std::vector<std::shared_ptr<const KeyframeFeatures>> KeyframeFrontEnd::featuresOf(
    const std::vector<const MapKeyframe*>& keyframes, const std::string& key, FrontEndResult* out) {
  std::vector<std::shared_ptr<const KeyframeFeatures>> features(keyframes.size());
  std::vector<std::size_t> missing;
  for (std::size_t i = 0; i < keyframes.size(); ++i) {
    features[i] = cache_.find(key, *keyframes[i], options_.matching);
    if (features[i]) {
      ++out->features_cached;
    } else {
      missing.push_back(i);
    }
  }
#pragma omp parallel for schedule(dynamic)
  for (std::size_t k = 0; k < missing.size(); ++k) {
    const std::size_t i = missing[k];
    features[i] = std::make_shared<const KeyframeFeatures>(extractFeatures(keyframes[i]->image, options_.matching));
  }
  for (std::size_t i : missing) cache_.store(key, *keyframes[i], options_.matching, features[i]);
  out->features_computed += static_cast<int>(missing.size());
  return features;
}

FrontEndResult KeyframeFrontEnd::run(const AgentMap& source, const AgentMap& target, const MergeRequest& request,
                                     const std::string& source_key, const std::string& target_key) {
  FrontEndResult out;
  const std::vector<const MapKeyframe*> src = selectKeyframes(source, request.source_keyframe);
  const std::vector<const MapKeyframe*> tgt = selectKeyframes(target, request.target_keyframe);
  for (const auto& [list, which, id] : {std::make_tuple(&src, "source", request.source_keyframe),
                                         std::make_tuple(&tgt, "target", request.target_keyframe)}) {
    if (list->empty()) {
      out.status = Status::kInvalidInput;
      out.message = id ? std::string(which) + " keyframe " + std::to_string(*id) + " is not in the " + which + " map"
                       : std::string(which) + " map has no keyframes";
      return out;
    }
  }
  const auto t = Clock::now();
  const auto src_features = featuresOf(src, source_key, &out);
  const auto tgt_features = featuresOf(tgt, target_key, &out);
  pair_cache_.prune();  // entries of features the FeatureCache no longer holds

  // Pairs to match in full: all of them, or the max_candidate_pairs with the most votes.
  std::vector<std::pair<std::size_t, std::size_t>> pairs;
  for (std::size_t i = 0; i < src.size(); ++i) {
    for (std::size_t j = 0; j < tgt.size(); ++j) pairs.emplace_back(i, j);
  }
  out.keyframe_pairs = static_cast<int>(pairs.size());
  std::vector<std::vector<int>> votes;
  const auto max_pairs = static_cast<std::size_t>(options_.merge.max_candidate_pairs);
  if (max_pairs > 0 && pairs.size() > max_pairs) {
    // The index over the target keyframes, and each source keyframe's row of votes against it,
    // from the cache where they are there (a row is what the index gives that keyframe alone).
    std::shared_ptr<const KeyframeVoteIndex> index = pair_cache_.findVoteIndex(tgt_features);
    const bool index_cached = index != nullptr;
    if (!index) {
      std::vector<const KeyframeFeatures*> tf;
      for (const auto& f : tgt_features) tf.push_back(f.get());
      index = std::make_shared<const KeyframeVoteIndex>(tf, options_.matching);
      pair_cache_.storeVoteIndex(tgt_features, index);
    }
    votes.resize(src.size());
    std::vector<std::size_t> missing;
    std::vector<const KeyframeFeatures*> missing_features;
    for (std::size_t i = 0; i < src.size(); ++i) {
      if (const auto row = pair_cache_.findVoteRow(index, src_features[i])) {
        votes[i] = *row;
      } else {
        missing.push_back(i);
        missing_features.push_back(src_features[i].get());
      }
    }
    const std::vector<std::vector<int>> rows = index->votes(missing_features);
    for (std::size_t k = 0; k < missing.size(); ++k) {
      votes[missing[k]] = rows[k];
      pair_cache_.storeVoteRow(index, src_features[missing[k]], std::make_shared<const std::vector<int>>(rows[k]));
    }
    out.vote_rows_computed = static_cast<int>(missing.size());
    out.votes_cached = index_cached && missing.empty();
    std::stable_sort(pairs.begin(), pairs.end(), [&](const auto& a, const auto& b) {
      return votes[a.first][a.second] > votes[b.first][b.second];
    });
    pairs.resize(max_pairs);
  }
  const bool preselected = pairs.size() < static_cast<std::size_t>(out.keyframe_pairs);
  out.features_ms = msSince(t);
  matchPairs(src, tgt, src_features, tgt_features, pairs, votes, source.camera, target.camera, &out);
  // Where the maps overlap best, every pair: the edge is made of the pairs near the best one
  // (merge.local_keyframes, SimilarityInitializer), and the votes may have left some of them out.
  const int k = options_.merge.local_keyframes;
  if (preselected && k > 0 && !out.pairs.empty() && out.pairs.front().pose.status == Status::kOk) {
    const std::map<long, long> rs = keyframeRanks(source), rt = keyframeRanks(target);
    const long bs = rs.at(out.pairs.front().source->id), bt = rt.at(out.pairs.front().target->id);
    std::vector<std::pair<std::size_t, std::size_t>> extra;
    for (std::size_t i = 0; i < src.size(); ++i) {
      for (std::size_t j = 0; j < tgt.size(); ++j) {
        if (std::abs(rs.at(src[i]->id) - bs) > k || std::abs(rt.at(tgt[j]->id) - bt) > k) continue;
        if (std::find(pairs.begin(), pairs.end(), std::make_pair(i, j)) == pairs.end()) extra.emplace_back(i, j);
      }
    }
    matchPairs(src, tgt, src_features, tgt_features, extra, votes, source.camera, target.camera, &out);
  }
  // No preselected pair verified: a keyframe added since the last merge can take the
  // preselection's places with its votes (content no other keyframe of its map shows wins the
  // ratio test, content that overlapping keyframes share does not) and then fail. The pairs of
  // these keyframes that verified in earlier merges (PairCache) are candidates then too: they cost
  // no matching, and a map that merged does not stop merging because a keyframe was added.
  if (preselected && out.verified == 0) {
    std::set<std::pair<std::size_t, std::size_t>> tried(pairs.begin(), pairs.end());
    std::vector<std::pair<std::size_t, std::size_t>> earlier;
    for (std::size_t i = 0; i < src.size(); ++i) {
      for (std::size_t j = 0; j < tgt.size(); ++j) {
        if (tried.count({i, j})) continue;
        const auto cached = pair_cache_.find(tgt_features[j], src_features[i], target.camera, source.camera);
        if (cached && cached->pose.status == Status::kOk) earlier.emplace_back(i, j);
      }
    }
    if (!earlier.empty()) {
      matchPairs(src, tgt, src_features, tgt_features, earlier, votes, source.camera, target.camera, &out);
      out.earlier_pairs = static_cast<int>(earlier.size());
    }
  }
  return out;
}

void KeyframeFrontEnd::matchPairs(const std::vector<const MapKeyframe*>& src, const std::vector<const MapKeyframe*>& tgt,
                                  const std::vector<std::shared_ptr<const KeyframeFeatures>>& src_features,
                                  const std::vector<std::shared_ptr<const KeyframeFeatures>>& tgt_features,
                                  const std::vector<std::pair<std::size_t, std::size_t>>& pairs,
                                  const std::vector<std::vector<int>>& votes, const PinholeCamera& source_camera,
                                  const PinholeCamera& target_camera, FrontEndResult* out) {
  auto t = Clock::now();
  const std::size_t first = out->pairs.size();
  out->pairs.resize(first + pairs.size());
  std::vector<std::size_t> missing;  // pairs the PairCache does not hold
  for (std::size_t k = 0; k < pairs.size(); ++k) {
    CandidatePair& c = out->pairs[first + k];
    c.source = src[pairs[k].first];
    c.target = tgt[pairs[k].second];
    if (!votes.empty()) c.votes = votes[pairs[k].first][pairs[k].second];
    const auto cached = pair_cache_.find(tgt_features[pairs[k].second], src_features[pairs[k].first], target_camera,
                                         source_camera);
    if (cached) {
      c.matches = cached->matches;
      c.pose = cached->pose;
      c.cached = true;
      ++out->pairs_cached;
    } else {
      missing.push_back(k);
    }
  }
  // Each pair's matching and relative pose are seeded of their own (the descriptor index and
  // RANSAC), so the pairs run in parallel with the same results as in turn, or as from the cache.
  forEachInParallel(missing.size(), [&](std::size_t m) {
    const std::size_t k = missing[m];
    CandidatePair& c = out->pairs[first + k];
    c.matches = matchFeatures(*tgt_features[pairs[k].second], *src_features[pairs[k].first], options_.matching);
  });
  out->features_ms += msSince(t);

  t = Clock::now();
  forEachInParallel(missing.size(), [&](std::size_t m) {
    CandidatePair& c = out->pairs[first + missing[m]];
    if (static_cast<int>(c.matches.size()) < options_.matching.min_matches) {
      c.pose.status = Status::kNotEnoughMatches;
      c.pose.message = std::to_string(c.matches.size()) + " feature matches < matching.min_matches " +
                       std::to_string(options_.matching.min_matches);
      return;
    }
    c.pose = keyframePairPose(c.matches, target_camera, source_camera, options_.relative_pose);
  });
  for (std::size_t k : missing) {
    const CandidatePair& c = out->pairs[first + k];
    pair_cache_.store(tgt_features[pairs[k].second], src_features[pairs[k].first], target_camera, source_camera,
                      std::make_shared<const PairCache::PairResult>(PairCache::PairResult{c.matches, c.pose}));
  }
  out->relative_pose_ms += msSince(t);
  std::stable_sort(out->pairs.begin(), out->pairs.end(), [](const CandidatePair& a, const CandidatePair& b) {
    const bool va = a.pose.status == Status::kOk, vb = b.pose.status == Status::kOk;
    if (va != vb) return va;
    if (va) return a.pose.inlier_count > b.pose.inlier_count;
    return a.matches.size() > b.matches.size();
  });
  out->verified = 0;
  for (const CandidatePair& c : out->pairs) out->verified += c.pose.status == Status::kOk ? 1 : 0;
}

}  // namespace pcr_pro
