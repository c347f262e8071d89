// LSD-SLAM keyframe points with the LSD viewer's filters (see lsd_keyframe.h).
#include "pcr_pro/io/lsd_keyframe.h"

#include <cmath>
#include <random>
#include <sstream>

#include "pcr_pro/geometry/types.h"

namespace pcr_pro {

template <>
const ParamSchema<LsdFilterOptions>& paramSchema<LsdFilterOptions>() {
  using O = LsdFilterOptions;
  using R = ParamRange;
  static const ParamSchema<O> schema{"lsd", {
      {"scaled_depth_var_th", &O::scaled_depth_var_th, R::above(0), "keyframe depth units^2",
       "keep an LSD point when idepth_var x depth^4 <= this (LSD viewer scaledDepthVarTH)"},
      {"abs_depth_var_th", &O::abs_depth_var_th, R::above(0), "map units^2",
       "keep an LSD point when idepth_var x depth^4 x scale^2 <= this (LSD viewer absDepthVarTH)"},
      {"min_near_support", &O::min_near_support, R::closed(0, 9), "pixels",
       "keep an LSD point when this many pixels of its 3x3 neighbourhood (itself included) have an inverse depth "
       "within sqrt(2 idepth_var) of its own (LSD viewer minNearSupport)"},
      {"sparsify_factor", &O::sparsify_factor, R::atLeast(1), "-",
       "keep one LSD point in this many, at random with a fixed seed per keyframe (LSD viewer sparsifyFactor)"},
  }, ParamMessage::kNode, '.'};
  return schema;
}

void validate(const LsdFilterOptions& o) {
  checkRanges(paramSchema<LsdFilterOptions>(), o);
}

LsdPoints extractPoints(const LsdKeyframe& kf, const LsdFilterOptions& o) {
  LsdPoints out;
  const int w = kf.idepth.cols, h = kf.idepth.rows;
  out.depth = cv::Mat::zeros(h, w, CV_32FC1);
  std::vector<Eigen::Vector3d> points;
  const double scale = kf.cam_to_world.scale();
  // Deterministic sparsification: one fixed-seed generator per keyframe id.
  std::mt19937 rng(static_cast<std::mt19937::result_type>(kf.id * 2654435761UL + 1));
  std::uniform_int_distribution<int> pick(0, std::max(0, o.sparsify_factor - 1));
  for (int y = 1; y < h - 1; ++y) {
    const float* id_row = kf.idepth.ptr<float>(y);
    const float* var_row = kf.idepth_var.ptr<float>(y);
    for (int x = 1; x < w - 1; ++x) {
      const float idepth = id_row[x];
      if (!(idepth > 0.0f) || !std::isfinite(idepth)) continue;
      if (o.sparsify_factor > 1 && pick(rng) != 0) continue;
      const double var = var_row[x];
      if (!std::isfinite(var) || var < 0.0) continue;
      const double depth = 1.0 / idepth;
      const double depth4 = depth * depth * depth * depth;
      // Written so that NaN (0 * inf for a tiny idepth with zero variance) fails the test too.
      if (!(var * depth4 <= o.scaled_depth_var_th)) continue;
      if (!(var * depth4 * scale * scale <= o.abs_depth_var_th)) continue;
      if (o.min_near_support > 1) {
        int support = 0;
        for (int dy = -1; dy <= 1; ++dy) {
          const float* nb_row = kf.idepth.ptr<float>(y + dy);
          for (int dx = -1; dx <= 1; ++dx) {
            const float nb = nb_row[x + dx];
            if (!(nb > 0.0f)) continue;
            const double diff = nb - idepth;
            if (diff * diff < 2.0 * var) ++support;
          }
        }
        if (support < o.min_near_support) continue;
      }
      const Eigen::Vector3d p((x - kf.camera.cx) / kf.camera.fx * depth, (y - kf.camera.cy) / kf.camera.fy * depth,
                              depth);
      if (!p.allFinite() || !std::isfinite(static_cast<float>(depth))) continue;
      points.push_back(p);
      out.depth.at<float>(y, x) = static_cast<float>(depth);
    }
  }
  out.camera_points.resize(3, static_cast<Eigen::Index>(points.size()));
  for (std::size_t i = 0; i < points.size(); ++i) out.camera_points.col(static_cast<Eigen::Index>(i)) = points[i];
  return out;
}

MapKeyframe toKeyframe(const LsdKeyframe& lsd) {
  MapKeyframe kf;
  kf.id = lsd.id;
  kf.image = lsd.image;
  kf.pose = lsd.cam_to_world;
  const int w = lsd.idepth.cols, h = lsd.idepth.rows;
  kf.depth = cv::Mat::zeros(h, w, CV_32FC1);
  kf.depth_stddev = cv::Mat::zeros(h, w, CV_32FC1);
  for (int y = 0; y < h; ++y) {
    const float* id_row = lsd.idepth.ptr<float>(y);
    const float* var_row = lsd.idepth_var.ptr<float>(y);
    float* depth_row = kf.depth.ptr<float>(y);
    float* stddev_row = kf.depth_stddev.ptr<float>(y);
    for (int x = 0; x < w; ++x) {
      const double idepth = id_row[x], var = var_row[x];
      // Written so that NaN fails too.
      if (!(idepth > 0.0 && std::isfinite(idepth) && var > 0.0 && std::isfinite(var))) continue;
      const float depth = static_cast<float>(1.0 / idepth);
      const float stddev = static_cast<float>(std::sqrt(var) / (idepth * idepth));
      if (!(std::isfinite(depth) && depth > 0.0f && std::isfinite(stddev) && stddev > 0.0f)) continue;
      depth_row[x] = depth;
      stddev_row[x] = stddev;
    }
  }
  return kf;
}

}  // namespace pcr_pro
