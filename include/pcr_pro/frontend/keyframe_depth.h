/**
 * @file keyframe_depth.h
 * @brief Depth of keyframe pixels (PCR-Pro §Scale by Kalman filter): from the keyframe's depth
 * image when it has one, otherwise from the map cloud projected into the keyframe (z-buffer).
 *
 * Pixel convention (OpenCV): pixel (col, row) has its centre at (u, v) = (col, row) and covers
 * [col - 0.5, col + 0.5) x [row - 0.5, row + 0.5).
 */
#pragma once

#include <Eigen/Core>
#include <cstddef>
#include <vector>

#include "pcr_pro/geometry/map_types.h"
#include "pcr_pro/geometry/types.h"
#include "pcr_pro/io/param_schema.h"

namespace pcr_pro {

/// Options of the keyframe depth lookup.
struct KeyframeDepthOptions {
  /// Radius of the lookup neighbourhood: the pixels whose centre lies within this distance of
  /// the pixel containing the query [px], >= 0 (0 = only that pixel). A sparse projected cloud
  /// needs a few pixels to find a depth next to a feature.
  int neighborhood_radius_px = 2;
  /// Depths below this are treated as unknown [camera units], > 0.
  double min_depth = 1e-6;
  /// Depths above this are treated as unknown [camera units], 0 = no limit, else > min_depth.
  double max_depth = 0.0;
  /// Largest number of map points projected when the keyframe has no depth image; a larger
  /// cloud is subsampled to this many points spread evenly over its columns [points],
  /// 0 = project all points.
  int max_cloud_points_projected = 0;
  /// Largest relative depth spread accepted inside the lookup neighbourhood [-], >= 0: the
  /// lookup fails when (z_max - z_min) > depth_consistency * z_min over the neighbourhood's valid
  /// pixels (a depth edge or an occlusion leaking through a sparse cloud makes the depth
  /// ambiguous).
  double depth_consistency = 0.05;
  /// Keyframes whose depth has a per-pixel standard deviation (MapKeyframe::depth_stddev, e.g.
  /// LSD-SLAM's inverse-depth variance): the neighbourhood's pixels are weighted by
  /// exp(-d² / (2 spatial_sigma_px²)) / σ_idepth² (d: distance to the query [px]), so the
  /// semi-dense structure next to a feature gives its depth; 1 px keeps the pixels next to the
  /// feature dominant while LSD's edges one or two pixels away still count [px], > 0.
  double spatial_sigma_px = 1.0;
  /// Keyframes with a per-pixel standard deviation: the lookup fails when the looked-up inverse
  /// depth's relative standard deviation exceeds this [-], in (0, 1). Measured on real LSD-SLAM
  /// keyframes against Kinect depth (7-Scenes, lsd_slam_7scenes): pixels whose variance claims
  /// 5-10 % are wrong by more than 30 % in 30-90 % of the cases on the less converged keyframes,
  /// beyond 10 % almost all of them (a depth propagated from the previous keyframe at a wrong
  /// scale, with a variance far too small); up to 5 % their error is at the level of the Kinect
  /// reference itself. LSD's own viewer keeps σ_depth <= 0.03 keyframe units (about 3 % at the
  /// normalised mean depth). First-order propagation to depth (σ_z = σ_idepth / idepth²) is then
  /// unbiased to (σ/idepth)² = 0.25 %.
  double max_relative_stddev = 0.05;
};

/// Every parameter of KeyframeDepthOptions (YAML block `keyframe_depth`): key, type, default (the member initialiser), range, unit, doc.
template <>
const ParamSchema<KeyframeDepthOptions>& paramSchema<KeyframeDepthOptions>();

/// A looked-up depth and its uncertainty.
struct DepthSample {
  double depth = 0.0;   ///< depth along the optical axis [camera units]
  /// Standard deviation of depth [camera units]; 0 = unknown (no per-pixel uncertainty: depth
  /// images without depth_stddev, or the projected map cloud).
  double stddev = 0.0;
};

/// @throw InputError naming the option (e.g. "keyframe_depth.neighborhood_radius_px must be >= 0")
void validate(const KeyframeDepthOptions& options);

/**
 * @brief Per-pixel depth of one keyframe, and the 3D point behind a pixel.
 *
 * With a depth image (MapKeyframe::depth non-empty) the image is used as is (invalid values:
 * 0, non-finite, or outside [min_depth, max_depth]). Without one, the map cloud is transformed
 * into the keyframe camera, p_cam = pose⁻¹(p_map) [camera units], and projected into a z-buffer
 * that keeps the nearest depth per pixel; points behind the camera, outside the image or outside
 * [min_depth, max_depth] are dropped.
 *
 * The object keeps its own copy of the depth; the keyframe and cloud may go away. Queries are
 * const and thread-safe.
 */
class KeyframeDepth {
 public:
  /**
   * @param[in] keyframe keyframe (pose camera -> map; depth CV_32FC1 [camera units] or empty)
   * @param[in] camera intrinsics of the keyframe's images
   * @param[in] map_cloud map cloud in the map frame [map units]; used only when the keyframe has
   * no depth image (may then be empty: every lookup fails)
   * @param[in] options lookup options
   * @throw InputError on invalid options, an invalid camera, a pose scale that is not finite
   * and > 0, a depth image that is not CV_32FC1 of the camera's width x height, or a
   * depth_stddev that is not empty and not CV_32FC1 of the depth image's size (or given without
   * a depth image)
   */
  KeyframeDepth(const MapKeyframe& keyframe, const PinholeCamera& camera, const Cloud& map_cloud,
                const KeyframeDepthOptions& options = KeyframeDepthOptions());

  /**
   * @brief Depth at a pixel: the depth of the valid pixel of the neighbourhood nearest to
   * (u, v) (ties: the smaller depth), provided the neighbourhood is depth-consistent. With
   * per-pixel uncertainty (hasUncertainty()) the depth of sampleAt() instead.
   * @param[in] u column coordinate [px]
   * @param[in] v row coordinate [px]
   * @param[out] depth depth along the optical axis [camera units]; may be null
   * @return false when (u, v) is not finite or outside the image, when no valid pixel lies in the
   * neighbourhood, or when the neighbourhood's depths spread more than depth_consistency
   */
  bool depthAt(double u, double v, double* depth) const;

  /**
   * @brief Depth at a pixel with its standard deviation. Without per-pixel uncertainty as
   * depthAt() (stddev 0). With it (MapKeyframe::depth_stddev), in inverse depth, where LSD-SLAM's
   * noise is Gaussian: the weighted median m of the neighbourhood's inverse depths (weights
   * exp(-d²/(2 spatial_sigma_px²)) / σ²), the pixels within 3 σ of m (one surface: a pixel across
   * a depth edge or an outlier is left out), their weighted mean μ and mixture variance
   * Σ w (σ² + (ρ - μ)²) / Σ w: each pixel's own noise (not divided by their number, since LSD's
   * regularisation correlates neighbours) plus their spread, which covers the surface's slope
   * between the pixels and the feature. depth = 1 / μ, stddev = sqrt(variance) / μ².
   * @param[in] u column coordinate [px]
   * @param[in] v row coordinate [px]
   * @param[out] sample depth and stddev [camera units]; may be null
   * @return false as depthAt(); with per-pixel uncertainty also when the pixels within 3 σ of the
   * median hold no more than half of the weight (a depth edge) or the relative standard deviation
   * exceeds max_relative_stddev
   */
  bool sampleAt(double u, double v, DepthSample* sample) const;

  /**
   * @brief 3D point seen at a pixel, in the keyframe's camera frame but in map units:
   * P = pose.scale() * z * K⁻¹ [u v 1]ᵀ with z = depthAt(u, v).
   * @param[in] u column coordinate [px]
   * @param[in] v row coordinate [px]
   * @param[out] point camera-frame point [map units]; may be null
   * @return false when depthAt() fails (see there); point is then left untouched
   */
  bool pointAt(double u, double v, Eigen::Vector3d* point) const;

  /**
   * @brief As pointAt(), with the point's depth uncertainty: the standard deviation of the
   * depth in map units (pose.scale() * DepthSample::stddev); 0 when unknown.
   */
  bool pointAt(double u, double v, Eigen::Vector3d* point, double* depth_stddev) const;

  /// @return true when the depth has a per-pixel standard deviation (MapKeyframe::depth_stddev)
  bool hasUncertainty() const { return !idepth_stddev_.empty(); }

  /// @return true when the depth comes from the keyframe's depth image, false when projected
  bool usesDepthImage() const { return uses_depth_image_; }
  /// @return number of pixels with a valid depth
  int validPixels() const { return valid_pixels_; }
  /**
   * @brief The projected map cloud's own depth noise, as a fraction of the depth [-]; 0 when the
   * depth comes from a depth image or too few pixel pairs measure it (kMinNoisePairs).
   *
   * Measured on the z-buffer at the lookup's own scale: for every two valid pixels at most
   * neighborhood_radius_px apart, their relative depth difference 2 |z1 - z2| / (z1 + z2); the
   * robust standard deviation of that difference (1.4826 x its median absolute value, which a
   * depth edge between the two pixels does not move) divided by sqrt 2 is one pixel's. It holds
   * the map's noise along the rays where the cloud is dense enough for a lookup to succeed, plus
   * the surface's slope over the same pixels, which a lookup also suffers. Checked against the
   * true depth on simulated semi-dense maps (inverse-depth noise 0.01 and 0.03; lookups at random
   * pixels, their errors' robust spread 0.018-0.023 and 0.054-0.061) and on the 7-Scenes cases'
   * clouds against their Kinect depth images (0.024-0.033, which includes the Kinect's own noise);
   * see README, "How it works".
   */
  double projectedRelativeNoise() const { return projected_relative_noise_; }
  /// Fewest pixel pairs that projectedRelativeNoise() is measured from (below: 0, unknown): the
  /// median of n independent absolute Gaussian differences is known to 1.17 / sqrt(n) of itself,
  /// 10 % at 150 (pairs that share a pixel are not independent, so somewhat less well).
  static constexpr std::size_t kMinNoisePairs = 150;

 private:
  /// Fills idepth_ / idepth_stddev_ from the keyframe's depth_stddev. @throw InputError on a wrong type or size
  void setUncertainty(const MapKeyframe& keyframe);
  /// depthAt() without per-pixel uncertainty: nearest valid pixel, depth_consistency check.
  bool nearestDepth(double u, double v, double* depth) const;

  PinholeCamera camera_;
  KeyframeDepthOptions options_;
  double pose_scale_ = 1.0;
  bool uses_depth_image_ = false;
  int valid_pixels_ = 0;
  double projected_relative_noise_ = 0.0;
  /// Row-major width x height depths [camera units], 0 = unknown.
  std::vector<float> depth_;
  /// Row-major width x height inverse depths and their standard deviations [1 / camera units],
  /// when the keyframe has depth_stddev (empty otherwise); 0 = unknown.
  std::vector<float> idepth_, idepth_stddev_;
  /// Pixel offsets (dx, dy) of the neighbourhood disc.
  std::vector<Eigen::Vector2i> offsets_;
};

}  // namespace pcr_pro
