#include "pcr_pro/sim/semi_dense.h"

#include <opencv2/imgproc.hpp>

#include <algorithm>
#include <cmath>
#include <random>
#include <sstream>
#include <vector>

namespace pcr_pro {
namespace {

std::string num(double v) {
  std::ostringstream s;
  s << v;
  return s.str();
}

// Portable draws from a 64-bit Mersenne twister (the standard distributions' algorithms are not
// fixed by the standard, so the same seed could give other data with another library).
double uniform01(std::mt19937_64& rng) { return static_cast<double>(rng() >> 11) * (1.0 / 9007199254740992.0); }

double gaussian(std::mt19937_64& rng) {
  const double u1 = std::max(uniform01(rng), 1e-300);
  const double u2 = uniform01(rng);
  return std::sqrt(-2.0 * std::log(u1)) * std::cos(2.0 * M_PI * u2);
}

}  // namespace

void validate(const SemiDenseOptions& o) {
  auto fail = [](const std::string& key, const std::string& what, double v) {
    throw InputError("semi_dense." + key + ": must be " + what + ", got " + num(v));
  };
  if (!(o.min_gradient > 0.0) || !std::isfinite(o.min_gradient)) fail("min_gradient", "> 0", o.min_gradient);
  if (!(o.idepth_noise >= 0.0) || !std::isfinite(o.idepth_noise)) fail("idepth_noise", ">= 0", o.idepth_noise);
  if (!(o.reference_gradient > 0.0) || !std::isfinite(o.reference_gradient)) {
    fail("reference_gradient", "> 0", o.reference_gradient);
  }
  if (!(o.outlier_fraction >= 0.0 && o.outlier_fraction <= 0.5)) fail("outlier_fraction", "in [0, 0.5]", o.outlier_fraction);
  if (o.subsample < 1) fail("subsample", ">= 1", o.subsample);
}

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

  SemiDenseKeyframe out;
  out.idepth = cv::Mat(grey.size(), CV_32FC1, cv::Scalar(0.0f));
  out.idepth_var = cv::Mat(grey.size(), CV_32FC1, cv::Scalar(0.0f));
  out.depth = cv::Mat(grey.size(), CV_32FC1, cv::Scalar(0.0f));
  std::mt19937_64 rng(seed);
  std::vector<Eigen::Vector3d> points;
  // The one-pixel border has no central difference (LSD skips it too).
  for (int r = 1; r + 1 < grey.rows; ++r) {
    for (int c = 1; c + 1 < grey.cols; ++c) {
      const double g = std::hypot(gx.at<float>(r, c), gy.at<float>(r, c));
      const double z = depth.at<float>(r, c);
      if (g < options.min_gradient || !std::isfinite(z) || z <= 0.0) continue;
      // Draw every random number of a candidate pixel, so that the stream does not depend on
      // which of them are kept.
      const double keep_draw = uniform01(rng), outlier_draw = uniform01(rng), factor_draw = uniform01(rng);
      const double noise_draw = gaussian(rng);
      if (options.subsample > 1 && keep_draw * options.subsample >= 1.0) continue;
      const double true_idepth = 1.0 / z;
      const double rel = options.idepth_noise * std::clamp(options.reference_gradient / g, 0.5, 4.0);
      const double sigma = rel * true_idepth;
      double idepth = true_idepth + sigma * noise_draw;
      if (outlier_draw < options.outlier_fraction) {
        idepth = true_idepth * std::exp((2.0 * factor_draw - 1.0) * std::log(3.0));
        ++out.outliers;
      }
      if (!(idepth > 0.0)) continue;
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
