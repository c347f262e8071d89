// Randomised k-d forest over feature descriptors (see descriptor_index.h).
#include "pcr_pro/frontend/descriptor_index.h"

#include <algorithm>
#include <array>
#include <functional>
#include <limits>
#include <numeric>
#include <string>

#include "pcr_pro/geometry/types.h"

namespace pcr_pro {
namespace {

// Uniform integer in [0, n) from 64 random bits (multiply-shift: the same numbers with every
// standard library, unlike std::uniform_int_distribution; its bias, below n / 2^64, is nil here).
std::size_t uniformBelow(std::mt19937_64& rng, std::size_t n) {
  return static_cast<std::size_t>((static_cast<unsigned __int128>(rng()) * n) >> 64);
}

// Squared L2 distance; gives up (returning a value > limit) once the partial sum exceeds limit,
// checked every 16 values. Fixed summation order: the same inputs give the same bits.
float squaredDistance(const float* a, const float* b, int n, float limit) {
  float sum = 0.0f;
  int i = 0;
  for (; i + 16 <= n; i += 16) {
    float s0 = 0.0f, s1 = 0.0f, s2 = 0.0f, s3 = 0.0f;
    for (int j = i; j < i + 16; j += 4) {
      const float d0 = a[j] - b[j], d1 = a[j + 1] - b[j + 1], d2 = a[j + 2] - b[j + 2], d3 = a[j + 3] - b[j + 3];
      s0 += d0 * d0;
      s1 += d1 * d1;
      s2 += d2 * d2;
      s3 += d3 * d3;
    }
    sum += (s0 + s1) + (s2 + s3);
    if (sum > limit) return sum;
  }
  for (; i < n; ++i) {
    const float d = a[i] - b[i];
    sum += d * d;
  }
  return sum;
}

bool nearer(const DescriptorNeighbor& a, const DescriptorNeighbor& b) {
  return a.squared_distance < b.squared_distance || (a.squared_distance == b.squared_distance && a.index < b.index);
}

}  // namespace

DescriptorIndex::DescriptorIndex(const cv::Mat& descriptors, int trees, std::uint64_t seed) {
  if (descriptors.empty() || descriptors.type() != CV_32FC1) {
    throw InputError("DescriptorIndex: descriptors must be a non-empty single-channel CV_32F matrix");
  }
  if (trees < 1) throw InputError("DescriptorIndex: trees must be >= 1, got " + std::to_string(trees));
  descriptors_ = descriptors.isContinuous() ? descriptors : descriptors.clone();
  std::mt19937_64 rng(seed);
  std::vector<int> rows(static_cast<std::size_t>(descriptors_.rows));
  std::iota(rows.begin(), rows.end(), 0);
  trees_.reserve(static_cast<std::size_t>(trees));
  for (int t = 0; t < trees; ++t) trees_.push_back(buildTree(rows, rng));
}

void DescriptorIndex::chooseSplit(const int* rows, int n, std::mt19937_64& rng, int* dimension, float* value) const {
  const int dim = descriptors_.cols;
  const int sample = std::min(n, kVarianceSample);
  std::vector<double> mean(static_cast<std::size_t>(dim), 0.0), var(static_cast<std::size_t>(dim), 0.0);
  for (int i = 0; i < sample; ++i) {
    const float* d = descriptors_.ptr<float>(rows[i]);
    for (int j = 0; j < dim; ++j) mean[static_cast<std::size_t>(j)] += d[j];
  }
  for (double& m : mean) m /= sample;
  for (int i = 0; i < sample; ++i) {
    const float* d = descriptors_.ptr<float>(rows[i]);
    for (int j = 0; j < dim; ++j) {
      const double e = d[j] - mean[static_cast<std::size_t>(j)];
      var[static_cast<std::size_t>(j)] += e * e;
    }
  }
  std::vector<int> order(static_cast<std::size_t>(dim));
  std::iota(order.begin(), order.end(), 0);
  const int candidates = std::min(dim, kSplitCandidates);
  std::partial_sort(order.begin(), order.begin() + candidates, order.end(), [&](int a, int b) {
    const double va = var[static_cast<std::size_t>(a)], vb = var[static_cast<std::size_t>(b)];
    return va > vb || (va == vb && a < b);
  });
  *dimension = order[uniformBelow(rng, static_cast<std::size_t>(candidates))];
  *value = static_cast<float>(mean[static_cast<std::size_t>(*dimension)]);
}

DescriptorIndex::Tree DescriptorIndex::buildTree(std::vector<int> rows, std::mt19937_64& rng) const {
  // A random order of the rows: the variance sample of a node is then a random subset of it.
  for (std::size_t i = rows.size(); i > 1; --i) std::swap(rows[i - 1], rows[uniformBelow(rng, i)]);
  Tree tree;
  tree.reserve(2 * rows.size());
  tree.emplace_back();
  struct Pending {
    int node, begin, end;
  };
  std::vector<Pending> stack{{0, 0, static_cast<int>(rows.size())}};
  while (!stack.empty()) {
    const Pending p = stack.back();
    stack.pop_back();
    const int n = p.end - p.begin;
    if (n == 1) {
      tree[static_cast<std::size_t>(p.node)].left = rows[static_cast<std::size_t>(p.begin)];
      continue;
    }
    int* r = rows.data() + p.begin;
    int dimension = 0;
    float value = 0.0f;
    chooseSplit(r, n, rng, &dimension, &value);
    // Rows below the plane first, then those on it, then those above; the split index keeps the
    // rows on the plane where they balance the two halves best (half and half if all are on it).
    const auto at = [&](int i) { return descriptors_.ptr<float>(r[i])[dimension]; };
    int below = 0;
    for (int i = 0; i < n; ++i) {
      if (at(i) < value) std::swap(r[i], r[below++]);
    }
    int on = below;
    for (int i = below; i < n; ++i) {
      if (at(i) == value) std::swap(r[i], r[on++]);
    }
    int split = below > n / 2 ? below : (on < n / 2 ? on : n / 2);
    if (split == 0 || split == n) split = n / 2;
    const int left = static_cast<int>(tree.size());
    tree.emplace_back();
    tree.emplace_back();
    Node& node = tree[static_cast<std::size_t>(p.node)];
    node.dimension = dimension;
    node.value = value;
    node.left = left;
    node.right = left + 1;
    stack.push_back({left + 1, p.begin + split, p.end});
    stack.push_back({left, p.begin, p.begin + split});
  }
  return tree;
}

DescriptorIndex::Searcher::Searcher(const DescriptorIndex& index)
    : index_(index), visited_(static_cast<std::size_t>(index.size()), 0u) {}

void DescriptorIndex::Searcher::check(const float* query, int row, int k) {
  std::uint32_t& seen = visited_[static_cast<std::size_t>(row)];
  if (seen == stamp_) return;
  seen = stamp_;
  ++checked_;
  const bool full = static_cast<int>(best_.size()) == k;
  const float limit = full ? best_.back().squared_distance : std::numeric_limits<float>::infinity();
  const DescriptorNeighbor candidate{row, squaredDistance(query, index_.descriptors_.ptr<float>(row),
                                                          index_.descriptors_.cols, limit)};
  if (full && !nearer(candidate, best_.back())) return;
  if (full) best_.pop_back();
  best_.insert(std::upper_bound(best_.begin(), best_.end(), candidate, nearer), candidate);
}

void DescriptorIndex::Searcher::descend(const float* query, int tree, int node, float min_distance, int k) {
  const Tree& nodes = index_.trees_[static_cast<std::size_t>(tree)];
  for (;;) {
    const bool full = static_cast<int>(best_.size()) == k;
    if (full && min_distance > best_.back().squared_distance) return;
    const Node& n = nodes[static_cast<std::size_t>(node)];
    if (n.dimension < 0) {
      check(query, n.left, k);
      return;
    }
    const float diff = query[n.dimension] - n.value;
    const int near = diff < 0.0f ? n.left : n.right;
    const int far = diff < 0.0f ? n.right : n.left;
    const float far_distance = min_distance + diff * diff;
    if (!full || far_distance <= best_.back().squared_distance) {
      queue_.push_back(Branch{far_distance, tree, far});
      std::push_heap(queue_.begin(), queue_.end(), std::greater<Branch>());
    }
    node = near;
  }
}

void DescriptorIndex::Searcher::knn(const float* query, int k, int checks, std::vector<DescriptorNeighbor>* out) {
  if (k < 1 || checks < 1) throw InputError("DescriptorIndex::knn: k and checks must be >= 1");
  if (++stamp_ == 0) {  // wrapped: forget every stamp
    std::fill(visited_.begin(), visited_.end(), 0u);
    stamp_ = 1;
  }
  k = std::min(k, index_.size());
  queue_.clear();
  best_.clear();
  checked_ = 0;
  for (int t = 0; t < static_cast<int>(index_.trees_.size()); ++t) descend(query, t, 0, 0.0f, k);
  while (!queue_.empty() && (checked_ < checks || static_cast<int>(best_.size()) < k)) {
    std::pop_heap(queue_.begin(), queue_.end(), std::greater<Branch>());
    const Branch b = queue_.back();
    queue_.pop_back();
    descend(query, b.tree, b.node, b.min_distance, k);
  }
  *out = best_;
}

}  // namespace pcr_pro
