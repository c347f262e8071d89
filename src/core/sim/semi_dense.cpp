#include "pcr_pro/sim/semi_dense.h"

#include <opencv2/imgproc.hpp>

#include <algorithm>
#include <cmath>
#include <random>
#include <vector>

#include "sim/sim_random.h"

namespace pcr_pro {
namespace {

using sim_detail::gaussian;
using sim_detail::uniform01;

// Unit-variance Gaussian noise with a Gaussian correlation of `sigma` px (white noise blurred,
// divided by the blur's gain sqrt(sum of squared weights)); empty when sigma is 0.
cv::Mat noiseField(cv::Size size, double sigma, std::uint64_t seed) {
  if (sigma <= 0.0) return cv::Mat();
  std::mt19937_64 rng(seed);
  cv::Mat white(size, CV_32FC1);
  float* data = white.ptr<float>(0);  // continuous
  const std::size_t n = white.total();
  for (std::size_t i = 0; i < n; i += 2) {
    double a = 0.0, b = 0.0;
    sim_detail::gaussianPair(rng, &a, &b);
    data[i] = static_cast<float>(a);
    if (i + 1 < n) data[i + 1] = static_cast<float>(b);
  }
  const int radius = static_cast<int>(std::ceil(4.0 * sigma));
  const cv::Mat k = cv::getGaussianKernel(2 * radius + 1, sigma, CV_64F);
  cv::Mat field;
  cv::sepFilter2D(white, field, CV_32F, k, k, cv::Point(-1, -1), 0.0, cv::BORDER_REFLECT);
  const double gain = cv::norm(k, cv::NORM_L2SQR);  // sum of squared 1D weights; 2D gain = gain^2
  field *= 1.0 / gain;
  return field;
}

}  // namespace

template <>
const ParamSchema<SemiDenseOptions>& paramSchema<SemiDenseOptions>() {
  using O = SemiDenseOptions;
  using R = ParamRange;
  static const ParamSchema<O> schema{"semi_dense", {
      {"min_gradient", &O::min_gradient, R::above(0), "grey levels / px", "a pixel with less gradient is left out"},
      {"idepth_noise", &O::idepth_noise, R::atLeast(0), "-", "inverse-depth noise at reference_gradient"},
      {"reference_gradient", &O::reference_gradient, R::above(0), "grey levels / px", "gradient of idepth_noise"},
      {"outlier_fraction", &O::outlier_fraction, R::closed(0, 0.5), "-", "fraction of wrong inverse depths"},
      {"subsample", &O::subsample, R::atLeast(1), "", "keep one gradient pixel in this many"},
      {"noise_correlation", &O::noise_correlation, R::closed(0, 10), "px", "spatial correlation of the noise"},
  }, ParamMessage::kNode};
  return schema;
}

void validate(const SemiDenseOptions& o) { checkRanges(paramSchema<SemiDenseOptions>(), o); }

SemiDenseKeyframe sampleSemiDense(const cv::Mat& grey, const cv::Mat& depth, const PinholeCamera& camera,
                                  const SemiDenseOptions& options, std::uint64_t seed) {
  validate(options);
  if (!camera.valid()) throw InputError("semi_dense: invalid camera");
  if (grey.type() != CV_8UC1 || grey.cols != camera.width || grey.rows != camera.height) {
    throw InputError("semi_dense: image must be CV_8UC1 of the camera's size");
  }
  if (depth.type() != CV_32FC1 || depth.size() != grey.size()) {
    throw InputError("semi_dense: depth must be CV_32FC1 of the image's size");
  }
  cv::Mat smooth, gx, gy;
  cv::GaussianBlur(grey, smooth, cv::Size(3, 3), 0.0);
  smooth.convertTo(smooth, CV_32F);
  // Central differences: (I(x+1) - I(x-1)) / 2.
  cv::Sobel(smooth, gx, CV_32F, 1, 0, 1, 0.5);
  cv::Sobel(smooth, gy, CV_32F, 0, 1, 1, 0.5);
  cv::Mat magnitude;
  cv::magnitude(gx, gy, magnitude);

  SemiDenseKeyframe out;
  out.idepth = cv::Mat(grey.size(), CV_32FC1, cv::Scalar(0.0f));
  out.idepth_var = cv::Mat(grey.size(), CV_32FC1, cv::Scalar(0.0f));
  out.depth = cv::Mat(grey.size(), CV_32FC1, cv::Scalar(0.0f));
  out.outlier = cv::Mat(grey.size(), CV_8UC1, cv::Scalar(0));
  // The pixels that take part: enough gradient and a depth. The one-pixel border has no central
  // difference (LSD skips it too).
  auto candidate = [&](int r, int c, double* g, double* z) {
    *g = magnitude.at<float>(r, c);
    *z = depth.at<float>(r, c);
    return *g >= options.min_gradient && std::isfinite(*z) && *z > 0.0;
  };
  double sum_idepth = 0.0;
  long count = 0;
  for (int r = 1; r + 1 < grey.rows; ++r) {
    for (int c = 1; c + 1 < grey.cols; ++c) {
      double g = 0.0, z = 0.0;
      if (candidate(r, c, &g, &z)) sum_idepth += 1.0 / z, ++count;
    }
  }
  if (count == 0) {
    out.points.resize(3, 0);
    return out;
  }
  out.mean_true_idepth = sum_idepth / static_cast<double>(count);
  std::mt19937_64 rng(seed);
  const cv::Mat field = noiseField(grey.size(), options.noise_correlation, sim_detail::subSeed(seed, 1));
  std::vector<Eigen::Vector3d> points;
  for (int r = 1; r + 1 < grey.rows; ++r) {
    for (int c = 1; c + 1 < grey.cols; ++c) {
      double g = 0.0, z = 0.0;
      if (!candidate(r, c, &g, &z)) continue;
      // Draw every random number of a candidate pixel, so that the stream does not depend on
      // which of them are kept.
      const double keep_draw = uniform01(rng), outlier_draw = uniform01(rng), factor_draw = uniform01(rng);
      const double noise_draw = field.empty() ? gaussian(rng) : field.at<float>(r, c);
      if (options.subsample > 1 && keep_draw * options.subsample >= 1.0) continue;
      const double true_idepth = 1.0 / z;
      const double rel = options.idepth_noise * std::clamp(options.reference_gradient / g, 0.5, 4.0);
      const double sigma = rel * out.mean_true_idepth;
      double idepth = true_idepth + sigma * noise_draw;
      const bool outlier = outlier_draw < options.outlier_fraction;
      if (outlier) idepth = true_idepth * std::exp((2.0 * factor_draw - 1.0) * std::log(3.0));
      if (!(idepth > 0.0)) continue;  // noise beyond infinity: LSD would not keep the pixel
      if (outlier) {
        out.outlier.at<std::uint8_t>(r, c) = 255;
        ++out.outliers;
      }
      out.idepth.at<float>(r, c) = static_cast<float>(idepth);
      out.idepth_var.at<float>(r, c) = static_cast<float>(std::max(sigma * sigma, 1e-20));
      const double zd = 1.0 / idepth;
      out.depth.at<float>(r, c) = static_cast<float>(zd);
      points.emplace_back(zd * (c - camera.cx) / camera.fx, zd * (r - camera.cy) / camera.fy, zd);
    }
  }
  out.points.resize(3, static_cast<Eigen::Index>(points.size()));
  for (std::size_t i = 0; i < points.size(); ++i) out.points.col(static_cast<Eigen::Index>(i)) = points[i];
  return out;
}

}  // namespace pcr_pro
