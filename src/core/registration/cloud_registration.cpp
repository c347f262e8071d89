#include "pcr_pro/registration/cloud_registration.h"

#include <chrono>
#include <memory>
#include <sstream>

#include "pcr_pro/geometry/normals.h"
#include "pcr_pro/registration/covariance.h"
#include "pcr_pro/registration/jackknife.h"
#include "pcr_pro/registration/filters.h"
#include "pcr_pro/registration/icp.h"
#include "pcr_pro/registration/scale_detection.h"

namespace pcr_pro {
namespace {

double msSince(std::chrono::steady_clock::time_point start) {
  return std::chrono::duration<double, std::milli>(std::chrono::steady_clock::now() - start).count();
}

}  // namespace

RegistrationReport registerClouds(const Cloud& source, const Cloud& target, const std::optional<Sim3>& initial,
                                  const RegistrationOptions& options, const KdTree* target_tree) {
  // Caller's mistakes throw (error rule, pcr_pro.h): invalid options, a tree for another cloud.
  validate(options);
  if (target_tree && (!options.filters.steps.empty() || target_tree->size() != target.cols())) {
    throw InputError("registerClouds: a target k-d tree needs an empty filter chain and the target's points");
  }
  const auto t_total = std::chrono::steady_clock::now();
  RegistrationReport report;
  // What the data does is a status: an empty cloud, like one the filters empty, is INVALID_INPUT.
  if (source.cols() == 0 || target.cols() == 0) {
    report.status = Status::kInvalidInput;
    report.message = std::string(source.cols() == 0 ? "source" : "target") + " cloud is empty";
    report.timings.total = msSince(t_total);
    return report;
  }

  auto t = std::chrono::steady_clock::now();
  const ScaleDetectionResult detection = detectScale(source, target, options.scale_detection);
  report.timings.scale = msSince(t);
  report.scale_difference_detected = detection.scale_difference_detected;
  report.detected_scale_ratio = detection.ratio;

  t = std::chrono::steady_clock::now();
  const Cloud src = applyFilterChain(source, options.filters);
  const Cloud tgt = applyFilterChain(target, options.filters);
  report.timings.filters = msSince(t);
  if (src.cols() == 0 || tgt.cols() == 0) {
    report.status = Status::kInvalidInput;
    report.message = std::string("the filters removed every point of the ") + (src.cols() == 0 ? "source" : "target") +
                     " cloud";
    report.timings.total = msSince(t_total);
    return report;
  }
  std::string shapeless = coincidentPoints(src, "source cloud");
  if (shapeless.empty()) shapeless = coincidentPoints(tgt, "target cloud");
  if (!shapeless.empty()) {
    report.status = Status::kInvalidInput;
    report.message = shapeless;
    report.timings.total = msSince(t_total);
    return report;
  }

  Sim3 start;
  if (initial) {
    start = *initial;
  } else if (options.icp.estimate_scale && detection.scale_difference_detected) {
    start = Sim3(detection.ratio, Eigen::Matrix3d::Identity(),
                 detection.target.centroid - detection.ratio * detection.source.centroid);
  }

  // Which way the ICP runs (IcpOptions::register_noisier_as_target): a source at least twice as
  // noisy (thickness variance, in target units at the start's scale) becomes the ICP's target.
  t = std::chrono::steady_clock::now();
  std::unique_ptr<KdTree> own_target_tree, source_tree;
  if (!target_tree) {
    own_target_tree = std::make_unique<KdTree>(tgt);
    target_tree = own_target_tree.get();
  }
  double ratio = 1.0;
  if (options.icp.register_noisier_as_target) {
    source_tree = std::make_unique<KdTree>(src);
    const int k = options.icp.normal_neighbors;
    ratio = noiseRatio(start.scale(), surfaceThickness2(*source_tree, k, kThicknessSamples),
                       surfaceThickness2(*target_tree, k, kThicknessSamples));
  }
  const bool reversed = options.icp.register_noisier_as_target && clearlyNoisier(ratio);
  const Cloud& moving = reversed ? tgt : src;
  const Cloud& fixed = reversed ? src : tgt;
  const IcpResult icp = alignIcp(moving, reversed ? *source_tree : *target_tree, reversed ? start.inverse() : start,
                                 options.icp);
  report.timings.icp = msSince(t);
  // The result as asked, S_target_source; lengths in the target's units.
  const Sim3 transform = reversed ? icp.transform.inverse() : icp.transform;
  report.transform = transform;
  report.icp_iterations = icp.iterations;
  report.correspondences = icp.correspondences;
  report.fitness_rmse = reversed ? icp.fitness_rmse * transform.scale() : icp.fitness_rmse;
  report.status = icp.status;
  report.message = icp.message;
  if (reversed) {
    report.reversed = true;
    std::ostringstream msg;
    msg.precision(3);
    msg << "registered the target onto the source (the source's surfaces are " << ratio << " times as thick): "
        << icp.message;
    report.message = msg.str();
  }
  if (icp.status == Status::kOk) {
    t = std::chrono::steady_clock::now();
    CovarianceResult cov = computeIcpCovariance(icp.matches, icp.transform, options.icp.error_metric,
                                                options.icp.estimate_scale, options.covariance);
    std::string jackknife;
    if (cov.status == Status::kOk && options.covariance.jackknife_blocks > 0) {
      const JackknifeSpread spread =
          jackknifeCovariance(moving, fixed, icp.transform, options.icp, options.covariance.jackknife_blocks);
      if (spread.ok) coverCovarianceResult(spread.covariance, icp.transform, options.icp.estimate_scale, &cov);
      jackknife = "; " + spread.message;
    }
    if (reversed && (cov.status == Status::kOk || cov.status == Status::kDegenerate)) {
      invertCovarianceResult(transform, &cov);
    }
    report.timings.covariance = msSince(t);
    if (cov.status == Status::kOk || cov.status == Status::kDegenerate) {
      report.covariance = cov.covariance;
      report.information = cov.information;
      report.condition_number = cov.condition_number;
      report.noise_stddev = cov.noise_stddev;
      if (options.icp.estimate_scale) report.scale_stddev = cov.scale_stddev;
    }
    report.message += jackknife;
    if (cov.status != Status::kOk) {
      report.status = cov.status;
      report.message = cov.message;
    }
  }
  report.timings.total = msSince(t_total);
  return report;
}

}  // namespace pcr_pro
