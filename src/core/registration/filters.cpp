#include "pcr_pro/registration/filters.h"

#include <algorithm>
#include <array>
#include <cstdint>
#include <cmath>
#include <limits>
#include <random>
#include <string>
#include <unordered_map>

#include "pcr_pro/geometry/kdtree.h"

namespace pcr_pro {
namespace {

Cloud selectColumns(const Cloud& cloud, const std::vector<Eigen::Index>& keep) {
  Cloud out(3, static_cast<Eigen::Index>(keep.size()));
  for (std::size_t i = 0; i < keep.size(); ++i) out.col(static_cast<Eigen::Index>(i)) = cloud.col(keep[i]);
  return out;
}

}  // namespace

const char* filterTypeName(FilterStep::Type type) {
  switch (type) {
    case FilterStep::Type::kCrop: return "crop";
    case FilterStep::Type::kVoxelGrid: return "voxel_grid";
    case FilterStep::Type::kOutlierRemoval: return "outlier_removal";
    case FilterStep::Type::kRandomSampling: return "random_sampling";
    case FilterStep::Type::kMaxPoints: return "max_points";
  }
  return "unknown";
}

template <>
const ParamSchema<CropOptions>& paramSchema<CropOptions>() {
  using O = CropOptions;
  static const ParamSchema<O> schema{"crop", {
      {"axis",
       TextParam<O>{+[](const O& o) { return std::string(1, "xyz"[o.axis >= 0 && o.axis <= 2 ? o.axis : 0]); },
                    +[](O* o, const std::string& s) {
                      const std::size_t i = std::string("xyz").find(s);
                      if (s.size() != 1 || i == std::string::npos) return false;
                      o->axis = static_cast<int>(i);
                      return true;
                    },
                    "x, y or z"},
       ParamRange::any(), "", "map axis the points are ranked on"},
      {"keep_fraction", &O::keep_fraction, ParamRange::openClosed(0, 1), "-", "fraction of the points kept"},
      {"keep",
       TextParam<O>{+[](const O& o) { return std::string(o.keep_lower ? "lower" : "upper"); },
                    +[](O* o, const std::string& s) {
                      if (s != "lower" && s != "upper") return false;
                      o->keep_lower = s == "lower";
                      return true;
                    },
                    "lower or upper"},
       ParamRange::any(), "", "which end is kept (PCR-Pro keeps the lower part of outdoor clouds, without the sky)"},
  }};
  return schema;
}

template <>
const ParamSchema<VoxelGridOptions>& paramSchema<VoxelGridOptions>() {
  static const ParamSchema<VoxelGridOptions> schema{"voxel_grid", {
      {"leaf_size", &VoxelGridOptions::leaf_size, ParamRange::atLeast(0), "target units", "voxel edge; 0 = off"},
  }};
  return schema;
}

template <>
const ParamSchema<OutlierRemovalOptions>& paramSchema<OutlierRemovalOptions>() {
  using O = OutlierRemovalOptions;
  static const ParamSchema<O> schema{"outlier_removal", {
      {"mean_k", &O::mean_k, ParamRange::atLeast(1), "", "neighbours per point"},
      {"stddev_multiplier", &O::stddev_multiplier, ParamRange::atLeast(0), "-",
       "points whose mean neighbour distance exceeds mean + multiplier x stddev are removed"},
  }};
  return schema;
}

template <>
const ParamSchema<RandomSamplingOptions>& paramSchema<RandomSamplingOptions>() {
  using O = RandomSamplingOptions;
  static const ParamSchema<O> schema{"random_sampling", {
      {"keep_ratio", &O::keep_ratio, ParamRange::openClosed(0, 1), "-", "fraction of the points kept"},
      {"seed", &O::seed, ParamRange::any(), "", "random seed"},
  }};
  return schema;
}

template <>
const ParamSchema<MaxPointsOptions>& paramSchema<MaxPointsOptions>() {
  using O = MaxPointsOptions;
  static const ParamSchema<O> schema{"max_points", {
      {"max_points", &O::max_points, ParamRange::atLeast(0), "points",
       "cap by uniform random subsampling (scale-free, unlike voxel_grid); 0 = off"},
      {"seed", &O::seed, ParamRange::any(), "", "random seed"},
  }};
  return schema;
}

void validate(const CropOptions& o) {
  if (o.axis < 0 || o.axis > 2) throw InputError("crop.axis must be 0 (x), 1 (y) or 2 (z)");
  checkRanges(paramSchema<CropOptions>(), o);
}
void validate(const VoxelGridOptions& o) {
  checkRanges(paramSchema<VoxelGridOptions>(), o);
}
void validate(const OutlierRemovalOptions& o) {
  checkRanges(paramSchema<OutlierRemovalOptions>(), o);
}
void validate(const RandomSamplingOptions& o) {
  checkRanges(paramSchema<RandomSamplingOptions>(), o);
}
void validate(const MaxPointsOptions& o) {
  checkRanges(paramSchema<MaxPointsOptions>(), o);
}
void validate(const FilterChainOptions& o) {
  for (const FilterStep& s : o.steps) {
    switch (s.type) {
      case FilterStep::Type::kCrop: validate(s.crop); break;
      case FilterStep::Type::kVoxelGrid: validate(s.voxel_grid); break;
      case FilterStep::Type::kOutlierRemoval: validate(s.outlier_removal); break;
      case FilterStep::Type::kRandomSampling: validate(s.random_sampling); break;
      case FilterStep::Type::kMaxPoints: validate(s.max_points); break;
    }
  }
}

Cloud cropFilter(const Cloud& cloud, const CropOptions& o) {
  validate(o);
  const Eigen::Index n = cloud.cols();
  if (n == 0 || o.keep_fraction >= 1.0) return cloud;
  const auto keep_n = static_cast<Eigen::Index>(std::ceil(o.keep_fraction * static_cast<double>(n)));
  std::vector<Eigen::Index> order(static_cast<std::size_t>(n));
  for (Eigen::Index i = 0; i < n; ++i) order[static_cast<std::size_t>(i)] = i;
  const auto by_coord = [&](Eigen::Index a, Eigen::Index b) {
    return o.keep_lower ? cloud(o.axis, a) < cloud(o.axis, b) : cloud(o.axis, a) > cloud(o.axis, b);
  };
  std::nth_element(order.begin(), order.begin() + (keep_n - 1), order.end(), by_coord);
  order.resize(static_cast<std::size_t>(keep_n));
  std::sort(order.begin(), order.end());  // keep the original point order
  return selectColumns(cloud, order);
}

Cloud voxelGridFilter(const Cloud& cloud, const VoxelGridOptions& o) {
  validate(o);
  if (o.leaf_size <= 0.0 || cloud.cols() == 0) return cloud;
  struct Cell {
    Eigen::Vector3d sum = Eigen::Vector3d::Zero();
    int count = 0;
    Eigen::Index first = 0;
  };
  if (!cloud.allFinite()) throw InputError("voxel_grid: the cloud has non-finite points");
  const Eigen::Vector3d origin = cloud.rowwise().minCoeff();
  const double inv = 1.0 / o.leaf_size;
  // Integer voxel indices must be exact and castable: refuse a leaf so small for this cloud that
  // they pass 2^52 (beyond that a double no longer holds every integer, and past 2^63 the cast
  // would be undefined).
  const double extent = (cloud.rowwise().maxCoeff() - origin).maxCoeff();
  if (!(extent * inv < 4503599627370496.0)) {  // 2^52
    throw InputError("voxel_grid.leaf_size " + std::to_string(o.leaf_size) + " is too small for a cloud " +
                     std::to_string(extent) + " across (more than 2^52 voxels)");
  }
  using Key = std::array<int64_t, 3>;
  struct KeyHash {
    std::size_t operator()(const Key& k) const {
      uint64_t h = static_cast<uint64_t>(k[0]) * 0x9E3779B97F4A7C15ull;
      h ^= static_cast<uint64_t>(k[1]) + 0x632BE59BD9B4E019ull + (h << 6) + (h >> 2);
      h ^= static_cast<uint64_t>(k[2]) + 0x85EBCA77C2B2AE63ull + (h << 6) + (h >> 2);
      return static_cast<std::size_t>(h);
    }
  };
  std::unordered_map<Key, Cell, KeyHash> cells;
  cells.reserve(static_cast<std::size_t>(cloud.cols()));
  for (Eigen::Index i = 0; i < cloud.cols(); ++i) {
    const Eigen::Vector3d v = ((cloud.col(i) - origin) * inv).array().floor();
    const Key key{static_cast<int64_t>(v.x()), static_cast<int64_t>(v.y()), static_cast<int64_t>(v.z())};
    Cell& c = cells[key];
    if (c.count == 0) c.first = i;
    c.sum += cloud.col(i);
    ++c.count;
  }
  // Emit in order of first appearance so the result is deterministic.
  std::vector<const Cell*> ordered;
  ordered.reserve(cells.size());
  for (const auto& kv : cells) ordered.push_back(&kv.second);
  std::sort(ordered.begin(), ordered.end(), [](const Cell* a, const Cell* b) { return a->first < b->first; });
  Cloud out(3, static_cast<Eigen::Index>(ordered.size()));
  for (std::size_t i = 0; i < ordered.size(); ++i) {
    out.col(static_cast<Eigen::Index>(i)) = ordered[i]->sum / ordered[i]->count;
  }
  return out;
}

Cloud outlierRemovalFilter(const Cloud& cloud, const OutlierRemovalOptions& o) {
  validate(o);
  const Eigen::Index n = cloud.cols();
  if (n <= o.mean_k) return cloud;
  KdTree tree(cloud);
  std::vector<double> mean_dist(static_cast<std::size_t>(n));
#pragma omp parallel
  {
    std::vector<Eigen::Index> idx;
    std::vector<double> d2;
#pragma omp for schedule(dynamic, 256)
    for (Eigen::Index i = 0; i < n; ++i) {
      tree.knn(cloud.col(i), o.mean_k + 1, &idx, &d2);  // the first neighbour is the point itself
      double sum = 0.0;
      for (std::size_t j = 1; j < d2.size(); ++j) sum += std::sqrt(d2[j]);
      mean_dist[static_cast<std::size_t>(i)] = d2.size() > 1 ? sum / static_cast<double>(d2.size() - 1) : 0.0;
    }
  }
  double mean = 0.0, sq = 0.0;
  for (double d : mean_dist) mean += d;
  mean /= static_cast<double>(n);
  for (double d : mean_dist) sq += (d - mean) * (d - mean);
  const double stddev = std::sqrt(sq / static_cast<double>(std::max<Eigen::Index>(n - 1, 1)));
  const double threshold = mean + o.stddev_multiplier * stddev;
  std::vector<Eigen::Index> keep;
  keep.reserve(static_cast<std::size_t>(n));
  for (Eigen::Index i = 0; i < n; ++i) {
    if (mean_dist[static_cast<std::size_t>(i)] <= threshold) keep.push_back(i);
  }
  return selectColumns(cloud, keep);
}

Cloud randomSamplingFilter(const Cloud& cloud, const RandomSamplingOptions& o) {
  validate(o);
  if (o.keep_ratio >= 1.0) return cloud;
  std::mt19937 rng(o.seed);
  std::bernoulli_distribution keep_point(o.keep_ratio);
  std::vector<Eigen::Index> keep;
  keep.reserve(static_cast<std::size_t>(static_cast<double>(cloud.cols()) * o.keep_ratio) + 1);
  for (Eigen::Index i = 0; i < cloud.cols(); ++i) {
    if (keep_point(rng)) keep.push_back(i);
  }
  return selectColumns(cloud, keep);
}

std::vector<Eigen::Index> maxPointsIndices(Eigen::Index n, const MaxPointsOptions& o) {
  validate(o);
  std::vector<Eigen::Index> order(static_cast<std::size_t>(std::max<Eigen::Index>(0, n)));
  for (Eigen::Index i = 0; i < n; ++i) order[static_cast<std::size_t>(i)] = i;
  if (o.max_points == 0 || n <= o.max_points) return order;
  // Partial Fisher-Yates: the first max_points entries become a uniform sample.
  std::mt19937 rng(o.seed);
  for (int i = 0; i < o.max_points; ++i) {
    std::uniform_int_distribution<Eigen::Index> pick(i, n - 1);
    std::swap(order[static_cast<std::size_t>(i)], order[static_cast<std::size_t>(pick(rng))]);
  }
  order.resize(static_cast<std::size_t>(o.max_points));
  std::sort(order.begin(), order.end());
  return order;
}

Cloud maxPointsFilter(const Cloud& cloud, const MaxPointsOptions& o) {
  validate(o);
  if (o.max_points == 0 || cloud.cols() <= o.max_points) return cloud;
  return selectColumns(cloud, maxPointsIndices(cloud.cols(), o));
}

Cloud applyFilterChain(const Cloud& cloud, const FilterChainOptions& options) {
  validate(options);
  Cloud out = cloud;
  for (const FilterStep& s : options.steps) {
    switch (s.type) {
      case FilterStep::Type::kCrop: out = cropFilter(out, s.crop); break;
      case FilterStep::Type::kVoxelGrid: out = voxelGridFilter(out, s.voxel_grid); break;
      case FilterStep::Type::kOutlierRemoval: out = outlierRemovalFilter(out, s.outlier_removal); break;
      case FilterStep::Type::kRandomSampling: out = randomSamplingFilter(out, s.random_sampling); break;
      case FilterStep::Type::kMaxPoints: out = maxPointsFilter(out, s.max_points); break;
    }
  }
  return out;
}

std::string coincidentPoints(const Cloud& cloud, const std::string& name) {
  if (cloud.cols() == 0) return "";
  const Eigen::Vector3d spread = cloud.rowwise().maxCoeff() - cloud.rowwise().minCoeff();
  const double magnitude = cloud.cwiseAbs().maxCoeff();
  if (spread.maxCoeff() > 16.0 * std::numeric_limits<float>::epsilon() * magnitude) return "";
  return "every point of the " + name + " (" + std::to_string(cloud.cols()) +
         " after the filters) is at the same place: there is no shape to register";
}

}  // namespace pcr_pro
