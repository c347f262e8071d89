/**
 * @file semi_dense.h
 * @brief A keyframe's semi-dense depth as LSD-SLAM produces it, sampled from an image and its
 * dense depth: only pixels with enough intensity gradient get an inverse depth, with a noise
 * that is larger on weak edges and, for a given gradient, the same in inverse depth over the
 * keyframe (as small-baseline stereo gives: the depth noise grows with depth²), and a few
 * outliers. Used by the simulator on rendered depth and by the real-data case builder on
 * Kinect depth. Deterministic from a seed.
 */
#pragma once

#include <opencv2/core.hpp>

#include <cstdint>

#include "pcr_pro/geometry/map_types.h"
#include "pcr_pro/geometry/types.h"
#include "pcr_pro/io/param_schema.h"

namespace pcr_pro {

/// Options of sampleSemiDense().
struct SemiDenseOptions {
  /// A pixel takes part when its intensity gradient (central differences of the 3x3-Gaussian
  /// smoothed grey image) is at least this [grey levels / px], > 0. LSD-SLAM uses 5 (minUseGrad).
  double min_gradient = 8.0;
  /// Standard deviation of the inverse-depth noise of a pixel whose gradient is
  /// reference_gradient, relative to the keyframe's mean true inverse depth (over the pixels
  /// that take part) [-], >= 0. LSD-SLAM normalises that mean to 1, so this is the noise in
  /// LSD's inverse-depth units. It scales with reference_gradient / gradient, clamped to
  /// [0.5, 4]: weak edges are less certain, as in LSD-SLAM's stereo. In depth the noise is
  /// this value times z² times the mean inverse depth: a pixel at the mean depth z̄ gets a
  /// relative depth noise of idepth_noise, one at 2 z̄ twice that.
  double idepth_noise = 0.01;
  /// Gradient at which the noise is idepth_noise [grey levels / px], > 0.
  double reference_gradient = 30.0;
  /// Spatial correlation of the noise [px], in [0, 10]: the per-pixel noise is white noise
  /// blurred by a Gaussian of this standard deviation (and rescaled to unit variance), as LSD's
  /// regularisation makes neighbouring inverse depths agree; 0 = independent pixels.
  double noise_correlation = 1.5;
  /// Fraction of the kept pixels whose inverse depth is wrong: the true one times a factor drawn
  /// log-uniformly from [1/3, 3] [-], in [0, 0.5]. They keep their pixel's variance, as LSD's
  /// outliers do.
  double outlier_fraction = 0.02;
  /// Keep one gradient pixel in this many, at random [-], >= 1.
  int subsample = 1;
};

/// @throw InputError naming the option ("semi_dense.min_gradient: must be > 0, got 0")
void validate(const SemiDenseOptions& options);

/// The schema of the options (block `semi_dense`; in the simulator's configuration `map.semi_dense`).
template <>
const ParamSchema<SemiDenseOptions>& paramSchema<SemiDenseOptions>();

/// The semi-dense depth of one keyframe.
struct SemiDenseKeyframe {
  cv::Mat idepth;      ///< CV_32FC1 inverse depth [1 / camera units], 0 = none
  cv::Mat idepth_var;  ///< CV_32FC1 variance of idepth [1 / camera units²], 0 where idepth is 0
  cv::Mat depth;       ///< CV_32FC1 1 / idepth where idepth > 0, else 0 [camera units]
  cv::Mat outlier;     ///< CV_8UC1, 255 where idepth is an outlier, else 0
  /// The kept pixels (idepth > 0) back-projected with their (noisy) depth, in row-major pixel
  /// order [camera units]
  Cloud points;
  int outliers = 0;    ///< how many of them are outliers
  double mean_true_idepth = 0.0;  ///< mean true inverse depth of the pixels that took part [1 / camera units]
};

/**
 * @brief Samples LSD-SLAM-like semi-dense depth from an image and its dense depth.
 * @param[in] grey CV_8UC1 image of the camera's size
 * @param[in] depth CV_32FC1 depth along the optical axis [camera units]; 0 / non-finite = none
 * @param[in] camera intrinsics
 * @param[in] options sampling options
 * @param[in] seed random seed: equal inputs and seeds give equal outputs
 * @throw InputError on invalid options or camera, or images of the wrong type or size
 */
SemiDenseKeyframe sampleSemiDense(const cv::Mat& grey, const cv::Mat& depth, const PinholeCamera& camera,
                                  const SemiDenseOptions& options, std::uint64_t seed);

}  // namespace pcr_pro
