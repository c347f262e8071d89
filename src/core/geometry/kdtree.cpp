#include "pcr_pro/geometry/kdtree.h"

#include <nanoflann.hpp>

#include <cstdint>
#include <limits>

namespace pcr_pro {
namespace {

struct CloudAdaptor {
  const Cloud* cloud;
  std::size_t kdtree_get_point_count() const { return static_cast<std::size_t>(cloud->cols()); }
  double kdtree_get_pt(std::size_t idx, std::size_t dim) const {
    return (*cloud)(static_cast<Eigen::Index>(dim), static_cast<Eigen::Index>(idx));
  }
  template <class Bbox>
  bool kdtree_get_bbox(Bbox& /*bb*/) const {
    return false;
  }
};

// A nanoflann result set that stops the search at the first point closer than its radius.
class FirstCloser {
 public:
  explicit FirstCloser(double squared_radius) : radius2_(squared_radius) {}
  double worstDist() const { return radius2_; }
  bool addPoint(double /*dist*/, uint32_t /*index*/) {
    found_ = true;
    return false;  // stop the search
  }
  bool full() const { return found_; }
  bool found() const { return found_; }

 private:
  double radius2_;
  bool found_ = false;
};

using Tree = nanoflann::KDTreeSingleIndexAdaptor<nanoflann::L2_Simple_Adaptor<double, CloudAdaptor>, CloudAdaptor, 3,
                                                 uint32_t>;
}  // namespace

struct KdTree::Impl {
  Cloud points;
  CloudAdaptor adaptor;
  std::unique_ptr<Tree> tree;
};

KdTree::KdTree(const Cloud& cloud) : impl_(new Impl) {
  impl_->points = cloud;
  impl_->adaptor.cloud = &impl_->points;
  if (cloud.cols() > 0) {
    impl_->tree.reset(new Tree(3, impl_->adaptor, nanoflann::KDTreeSingleIndexAdaptorParams(12)));
  }
}

KdTree::~KdTree() = default;

Eigen::Index KdTree::size() const { return impl_->points.cols(); }

const Cloud& KdTree::points() const { return impl_->points; }

Eigen::Index KdTree::nearest(const Eigen::Vector3d& query, double* squared_distance) const {
  if (!impl_->tree) return -1;
  uint32_t index = 0;
  double d2 = 0.0;
  nanoflann::KNNResultSet<double, uint32_t> result(1);
  result.init(&index, &d2);
  impl_->tree->findNeighbors(result, query.data(), nanoflann::SearchParams());
  if (squared_distance) *squared_distance = d2;
  return static_cast<Eigen::Index>(index);
}

Eigen::Index KdTree::nearest(const Eigen::Vector3d& query, double* squared_distance, Eigen::Index hint) const {
  if (!impl_->tree || hint < 0 || hint >= impl_->points.cols()) return nearest(query, squared_distance);
  // The hint's distance, widened by far more than the rounding of nanoflann's own sum, bounds the
  // search from the start: the hint itself (or a nearer point) is always found.
  constexpr double kWiden = 1.0 + 1e-9;
  const double bound = (impl_->points.col(hint) - query).squaredNorm() * kWiden;
  uint32_t index = static_cast<uint32_t>(hint);
  double d2 = 0.0;
  nanoflann::KNNResultSet<double, uint32_t> result(1);
  result.init(&index, &d2);
  d2 = bound > 0.0 ? bound : std::numeric_limits<double>::min();
  impl_->tree->findNeighbors(result, query.data(), nanoflann::SearchParams());
  if (result.size() == 0) {  // not even the hint within the bound (cannot happen): search in full
    return nearest(query, squared_distance);
  }
  if (squared_distance) *squared_distance = d2;
  return static_cast<Eigen::Index>(index);
}

bool KdTree::anyCloserThan(const Eigen::Vector3d& query, double squared_radius) const {
  if (!impl_->tree || !(squared_radius > 0.0)) return false;
  FirstCloser result(squared_radius);
  impl_->tree->findNeighbors(result, query.data(), nanoflann::SearchParams());
  return result.found();
}

void KdTree::knn(const Eigen::Vector3d& query, int k, std::vector<Eigen::Index>* indices,
                 std::vector<double>* squared_distances) const {
  indices->clear();
  squared_distances->clear();
  if (!impl_->tree || k <= 0) return;
  std::vector<uint32_t> idx(static_cast<std::size_t>(k));
  squared_distances->resize(static_cast<std::size_t>(k));
  const std::size_t found = impl_->tree->knnSearch(query.data(), static_cast<std::size_t>(k), idx.data(),
                                                   squared_distances->data());
  squared_distances->resize(found);
  indices->assign(idx.begin(), idx.begin() + static_cast<std::ptrdiff_t>(found));
}

}  // namespace pcr_pro
