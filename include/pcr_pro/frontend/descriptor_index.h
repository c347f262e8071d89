/**
 * @file descriptor_index.h
 * @brief Approximate nearest neighbours of feature descriptors: a forest of randomised k-d trees
 * searched best-bin-first across all trees with a budget of checked descriptors (Silpa-Anan &
 * Hartley 2008; the method of FLANN's KDTreeIndex, Muja & Lowe 2009).
 *
 * The index owns its randomness: one std::mt19937_64 seeded by the caller draws the order of the
 * descriptors and the split dimensions of every tree. The same descriptors and seed give the same
 * trees and the same answers, whatever else the process does with random numbers (FLANN draws
 * from the C library's one shared generator).
 *
 * Building: every tree splits its descriptors recursively at the mean of one dimension, chosen at
 * random among the kSplitCandidates dimensions of largest variance (estimated on at most
 * kVarianceSample descriptors of the node), until one descriptor is left per leaf. The trees
 * differ only by their random choices, so that their errors are nearly independent.
 * Searching: each tree is descended to the query's leaf; every branch not taken goes into one
 * priority queue shared by all trees, keyed by the squared distance from the query to the
 * splitting planes crossed on the way. Branches are then taken from the queue, nearest first,
 * until `checks` distinct descriptors were compared with the query (and k were found).
 */
#pragma once

#include <cstdint>
#include <opencv2/core.hpp>
#include <random>
#include <vector>

namespace pcr_pro {

/// One neighbour found by DescriptorIndex::knn().
struct DescriptorNeighbor {
  int index = -1;               ///< row of the indexed descriptor matrix
  float squared_distance = 0;   ///< squared L2 distance to the query [descriptor units^2]
};

class DescriptorIndex {
 public:
  /// Split dimensions are drawn among this many of largest variance.
  static constexpr int kSplitCandidates = 5;
  /// The mean and variance of a node are estimated on at most this many of its descriptors.
  static constexpr int kVarianceSample = 100;

  /**
   * @brief Builds the forest.
   * @param[in] descriptors CV_32F, one descriptor per row, at least one row (shared, not copied:
   *   the caller must not modify it while the index lives)
   * @param[in] trees number of randomised trees [-], >= 1
   * @param[in] seed seed of the index's own random generator
   * @throw InputError when descriptors is empty or not single-channel CV_32F, or trees < 1
   */
  DescriptorIndex(const cv::Mat& descriptors, int trees, std::uint64_t seed);

  /// @return number of indexed descriptors
  int size() const { return descriptors_.rows; }
  /// @return descriptor length [values]
  int dimension() const { return descriptors_.cols; }

  /**
   * @brief Searches the forest; thread-safe (each Searcher keeps its own scratch memory, so use
   * one Searcher per thread).
   */
  class Searcher {
   public:
    explicit Searcher(const DescriptorIndex& index);
    /**
     * @brief The k (approximate) nearest indexed descriptors of a query.
     * @param[in] query dimension() values
     * @param[in] k neighbours wanted [-], >= 1
     * @param[in] checks budget: the search stops once this many distinct descriptors were
     *   compared and k neighbours are known [descriptors], >= 1
     * @param[out] out min(k, size()) neighbours, nearest first (ties: lower index first)
     */
    void knn(const float* query, int k, int checks, std::vector<DescriptorNeighbor>* out);

   private:
    struct Branch {
      float min_distance;  // lower bound on the squared distance of the branch's descriptors
      int tree;
      int node;
      bool operator>(const Branch& other) const { return min_distance > other.min_distance; }
    };
    void descend(const float* query, int tree, int node, float min_distance, int k);
    void check(const float* query, int row, int k);

    const DescriptorIndex& index_;
    std::vector<std::uint32_t> visited_;  // query stamp of the last check of each descriptor
    std::uint32_t stamp_ = 0;
    std::vector<Branch> queue_;           // min-heap
    std::vector<DescriptorNeighbor> best_;
    int checked_ = 0;
  };

 private:
  // A node: a split (dimension >= 0, children) or a leaf (dimension < 0, `left` = descriptor row).
  struct Node {
    int dimension = -1;
    float value = 0.0f;
    int left = -1;
    int right = -1;
  };
  using Tree = std::vector<Node>;  // nodes[0] is the root

  Tree buildTree(std::vector<int> rows, std::mt19937_64& rng) const;
  void chooseSplit(const int* rows, int n, std::mt19937_64& rng, int* dimension, float* value) const;

  cv::Mat descriptors_;
  std::vector<Tree> trees_;
};

}  // namespace pcr_pro
