#include "pcr_pro/frontend/relative_pose.h"

#include <Eigen/Eigenvalues>
#include <algorithm>
#include <cctype>
#include <cmath>
#include <exception>
#include <functional>
#include <memory>
#include <opengv/relative_pose/CentralRelativeAdapter.hpp>
#include <opengv/relative_pose/methods.hpp>
#include <opengv/sac/Ransac.hpp>
#include <opengv/sac_problems/relative_pose/CentralRelativePoseSacProblem.hpp>
#include <random>
#include <sstream>

#include "pcr_pro/frontend/relative_pose_covariance.h"
#include "pcr_pro/geometry/sim3.h"

namespace pcr_pro {
namespace {

using SacProblem = opengv::sac_problems::relative_pose::CentralRelativePoseSacProblem;

// Refinement: at most this many refine / re-select rounds; stop earlier once the inliers are
// unchanged and the rotation plus translation direction moved less than this [rad].
constexpr int kMaxRefinementRounds = 10;
constexpr double kRefinementConvergedRad = 1e-7;
// A refinement round is rejected when it keeps fewer than this fraction of the inliers [-].
constexpr double kMinKeptSupport = 0.5;

SacProblem::algorithm_t toOpengv(RelativePoseAlgorithm algorithm) {
  switch (algorithm) {
    case RelativePoseAlgorithm::kNister:
      return SacProblem::NISTER;
    case RelativePoseAlgorithm::kStewenius:
      return SacProblem::STEWENIUS;
    case RelativePoseAlgorithm::kSevenPt:
      return SacProblem::SEVENPT;
    case RelativePoseAlgorithm::kEightPt:
      return SacProblem::EIGHTPT;
  }
  return SacProblem::STEWENIUS;
}

bool isFinite(const Eigen::MatrixXd& m) { return m.allFinite(); }

// RMS distance of unit bearings from their best-fitting plane through the origin [rad]:
// sqrt of the smallest eigenvalue of mean(f fᵀ). Zero when all bearings lie on one image
// line (or coincide).
double planeSpread(const opengv::bearingVectors_t& bearings, const std::vector<int>& indices) {
  if (indices.empty()) return 0.0;
  Eigen::Matrix3d m = Eigen::Matrix3d::Zero();
  for (int i : indices) {
    const Eigen::Vector3d& f = bearings[static_cast<std::size_t>(i)];
    m += f * f.transpose();
  }
  m /= static_cast<double>(indices.size());
  Eigen::SelfAdjointEigenSolver<Eigen::Matrix3d> eig(m, Eigen::EigenvaluesOnly);
  return std::sqrt(std::max(0.0, eig.eigenvalues()(0)));
}

// Checks both cameras; fills *message and returns false when degenerate.
bool spreadOk(const opengv::bearingVectors_t& target, const opengv::bearingVectors_t& source,
              const std::vector<int>& indices, double min_spread_rad, const char* what, std::string* message) {
  const double spread_t = planeSpread(target, indices);
  const double spread_s = planeSpread(source, indices);
  if (spread_t >= min_spread_rad && spread_s >= min_spread_rad) return true;
  std::ostringstream os;
  os << "relative pose: degenerate " << what << " (" << indices.size()
     << " correspondences on one image line or point; spread target " << spread_t << " rad, source " << spread_s
     << " rad, minimum " << min_spread_rad << " rad)";
  *message = os.str();
  return false;
}

/// The correspondences with finite, non-zero bearings on both sides, normalised; original_index
/// maps each back to its index in the caller's lists.
struct ValidBearings {
  opengv::bearingVectors_t target, source;
  std::vector<int> original_index;
};

ValidBearings validBearings(const std::vector<Eigen::Vector3d>& bearings_target,
                            const std::vector<Eigen::Vector3d>& bearings_source) {
  ValidBearings out;
  const std::size_t n_given = bearings_target.size();
  out.target.reserve(n_given);
  out.source.reserve(n_given);
  out.original_index.reserve(n_given);
  for (std::size_t i = 0; i < n_given; ++i) {
    const Eigen::Vector3d& ft = bearings_target[i];
    const Eigen::Vector3d& fs = bearings_source[i];
    if (!ft.allFinite() || !fs.allFinite()) continue;
    const double nt = ft.norm();
    const double ns = fs.norm();
    if (!(nt > 1e-12) || !(ns > 1e-12) || !std::isfinite(nt) || !std::isfinite(ns)) continue;
    out.target.push_back(ft / nt);
    out.source.push_back(fs / ns);
    out.original_index.push_back(static_cast<int>(i));
  }
  return out;
}

/**
 * OpenGV's optimize_nonlinear stops early on its flat cost (it squares the (1 - cos) terms), so
 * refine -> re-select inliers is repeated until the inliers and the pose settle.
 * @return true when the model was refined at least once
 */
bool refineModel(opengv::relative_pose::CentralRelativeAdapter* adapter, SacProblem& problem, double threshold,
                 int sample_size, opengv::transformation_t* model, std::vector<int>* inliers) {
  bool refined = false;
  for (int round = 0; round < kMaxRefinementRounds && static_cast<int>(inliers->size()) >= sample_size; ++round) {
    adapter->setR12(model->block<3, 3>(0, 0));
    adapter->sett12(model->col(3).normalized());
    const opengv::transformation_t optimised = opengv::relative_pose::optimize_nonlinear(*adapter, *inliers);
    if (!isFinite(optimised) || !(optimised.col(3).norm() > 1e-12)) break;
    std::vector<int> refined_inliers;
    problem.selectWithinDistance(optimised, threshold, refined_inliers);
    // A refinement that loses most of the support has left the basin of the RANSAC model:
    // keep the model of the previous round.
    if (static_cast<double>(refined_inliers.size()) < kMinKeptSupport * static_cast<double>(inliers->size())) break;
    const double change = rotationDistance(optimised.block<3, 3>(0, 0), model->block<3, 3>(0, 0)) +
                          std::acos(std::min(1.0, optimised.col(3).normalized().dot(model->col(3).normalized())));
    const bool same_inliers = refined_inliers == *inliers;
    *model = optimised;
    *inliers = refined_inliers;
    refined = true;
    if (same_inliers && change < kRefinementConvergedRad) break;
  }
  return refined;
}

/// The RANSAC (and refined) model and its inliers as the result: rotation, direction, inliers in
/// the caller's indices, and the status of the inlier and spread checks.
void finishResult(const opengv::transformation_t& model, const std::vector<int>& inliers, const ValidBearings& valid,
                  std::size_t n_given, bool refined, double min_spread_rad, const RelativePoseOptions& options,
                  RelativePoseResult* result) {
  const opengv::bearingVectors_t& target = valid.target;
  const opengv::bearingVectors_t& source = valid.source;
  const Eigen::Matrix3d r = model.block<3, 3>(0, 0);
  const Eigen::Vector3d t = model.col(3);
  const double t_norm = t.norm();
  if (!r.allFinite() || !t.allFinite() || !(t_norm > 1e-12)) {
    result->status = Status::kRelativePoseFailed;
    result->message = "relative pose: the estimated model is not finite or has no translation";
    return;
  }
  result->rotation = projectToRotation(r);
  result->translation_direction = t / t_norm;
  if (!result->rotation.allFinite()) {
    result->status = Status::kRelativePoseFailed;
    result->message = "relative pose: the estimated rotation is not finite";
    result->rotation.setIdentity();
    result->translation_direction.setZero();
    return;
  }

  result->inliers.reserve(inliers.size());
  for (int i : inliers) result->inliers.push_back(valid.original_index[static_cast<std::size_t>(i)]);
  std::sort(result->inliers.begin(), result->inliers.end());
  result->inlier_count = static_cast<int>(result->inliers.size());
  result->inlier_ratio = static_cast<double>(result->inlier_count) / static_cast<double>(n_given);

  std::ostringstream os;
  os << result->inlier_count << " inliers of " << n_given << " correspondences ("
     << relativePoseAlgorithmName(options.algorithm) << (refined ? ", refined" : "") << ")";
  if (result->inlier_count < options.min_inliers || result->inlier_ratio < options.min_inlier_ratio) {
    result->status = Status::kNotEnoughMatches;
    os << ", need at least " << options.min_inliers << " inliers and an inlier ratio of " << options.min_inlier_ratio;
    result->message = "relative pose: " + os.str();
    return;
  }
  if (!spreadOk(target, source, inliers, min_spread_rad, "inliers", &result->message)) {
    result->status = Status::kDegenerate;
    return;
  }
  result->status = Status::kOk;
  result->message = "relative pose: " + os.str();
}

}  // namespace

const char* relativePoseAlgorithmName(RelativePoseAlgorithm algorithm) {
  switch (algorithm) {
    case RelativePoseAlgorithm::kNister:
      return "NISTER";
    case RelativePoseAlgorithm::kStewenius:
      return "STEWENIUS";
    case RelativePoseAlgorithm::kSevenPt:
      return "SEVENPT";
    case RelativePoseAlgorithm::kEightPt:
      return "EIGHTPT";
  }
  return "UNKNOWN";
}

bool parseRelativePoseAlgorithm(const std::string& name, RelativePoseAlgorithm* algorithm) {
  std::string upper = name;
  std::transform(upper.begin(), upper.end(), upper.begin(),
                 [](unsigned char c) { return static_cast<char>(std::toupper(c)); });
  for (RelativePoseAlgorithm a : {RelativePoseAlgorithm::kNister, RelativePoseAlgorithm::kStewenius,
                                  RelativePoseAlgorithm::kSevenPt, RelativePoseAlgorithm::kEightPt}) {
    if (upper == relativePoseAlgorithmName(a)) {
      if (algorithm != nullptr) *algorithm = a;
      return true;
    }
  }
  return false;
}

int relativePoseSampleSize(RelativePoseAlgorithm algorithm) {
  switch (algorithm) {
    case RelativePoseAlgorithm::kNister:
    case RelativePoseAlgorithm::kStewenius:
      return 8;
    case RelativePoseAlgorithm::kSevenPt:
    case RelativePoseAlgorithm::kEightPt:
      return 9;
  }
  return 9;
}

template <>
const ParamSchema<RelativePoseOptions>& paramSchema<RelativePoseOptions>() {
  using O = RelativePoseOptions;
  using R = ParamRange;
  static const ParamSchema<O> schema{"relative_pose", {
      {"algorithm",
       TextParam<O>{+[](const O& o) { return std::string(relativePoseAlgorithmName(o.algorithm)); },
                    +[](O* o, const std::string& s) { return parseRelativePoseAlgorithm(s, &o->algorithm); },
                    "NISTER, STEWENIUS, SEVENPT or EIGHTPT"},
       R::any(), "", "OpenGV minimal solver inside RANSAC"},
      {"pixel_error", &O::pixel_error, R::above(0), "px",
       "inlier threshold psi (RANSAC threshold 2(1 - cos(atan(psi/f)))), and the 1-sigma of an offset common to all "
       "of one image's keypoints in each pair's rotation covariance"},
      {"max_iterations", &O::max_iterations, R::atLeast(1), "", "RANSAC iteration limit"},
      {"probability", &O::probability, R::open(0, 1), "-", "RANSAC confidence"},
      {"nonlinear_refinement", &O::nonlinear_refinement, R::any(), "",
       "refine on the inliers and re-select them, then to their Sampson optimum"},
      {"min_inliers", &O::min_inliers, R::atLeast(5), "", "fewer inliers: the keyframe pair is rejected"},
      {"min_inlier_ratio", &O::min_inlier_ratio, R::closed(0, 1), "-", "smaller inlier fraction: rejected"},
      {"min_spread_px", &O::min_spread_px, R::atLeast(0), "px at focal length",
       "degeneracy guard: inlier bearings spread less than this (on one image line) are rejected"},
  }};
  return schema;
}

void validate(const RelativePoseOptions& options) {
  if (!parseRelativePoseAlgorithm(relativePoseAlgorithmName(options.algorithm), nullptr)) {
    throw InputError("relative_pose.algorithm must be one of NISTER, STEWENIUS, SEVENPT, EIGHTPT");
  }
  checkRanges(paramSchema<RelativePoseOptions>(), options);
}

double ransacThreshold(double pixel_error, double focal_px) {
  return 2.0 * (1.0 - std::cos(std::atan(pixel_error / focal_px)));
}

RelativePoseResult estimateRelativePose(const std::vector<Eigen::Vector3d>& bearings_target,
                                        const std::vector<Eigen::Vector3d>& bearings_source, double focal_px,
                                        const RelativePoseOptions& options) {
  validate(options);
  if (bearings_target.size() != bearings_source.size()) {
    throw InputError("estimateRelativePose: " + std::to_string(bearings_target.size()) + " target bearings but " +
                     std::to_string(bearings_source.size()) + " source bearings");
  }
  if (!(focal_px > 0.0) || !std::isfinite(focal_px)) {
    throw InputError("estimateRelativePose: focal length must be a finite number > 0 px");
  }

  RelativePoseResult result;
  const std::size_t n_given = bearings_target.size();

  // OpenGV sees only the valid correspondences (viewpoint 1 = target, viewpoint 2 = source).
  const ValidBearings valid = validBearings(bearings_target, bearings_source);
  const opengv::bearingVectors_t& target = valid.target;
  const opengv::bearingVectors_t& source = valid.source;

  const int sample_size = relativePoseSampleSize(options.algorithm);
  const int needed = std::max(sample_size, options.min_inliers);
  const int n_valid = static_cast<int>(target.size());
  if (n_valid < needed) {
    std::ostringstream os;
    os << "relative pose: " << n_valid << " valid correspondences of " << n_given << ", need at least " << needed;
    result.status = Status::kNotEnoughMatches;
    result.message = os.str();
    return result;
  }

  const double min_spread_rad = std::atan(options.min_spread_px / focal_px);
  std::vector<int> all_valid(static_cast<std::size_t>(n_valid));
  for (int i = 0; i < n_valid; ++i) all_valid[static_cast<std::size_t>(i)] = i;
  if (!spreadOk(target, source, all_valid, min_spread_rad, "input", &result.message)) {
    result.status = Status::kDegenerate;
    return result;
  }

  const double threshold = ransacThreshold(options.pixel_error, focal_px);
  opengv::transformation_t model;
  std::vector<int> inliers;  // indices into target/source
  bool refined = false;
  try {
    opengv::relative_pose::CentralRelativeAdapter adapter(target, source);
    auto problem = std::make_shared<SacProblem>(adapter, toOpengv(options.algorithm), /*randomSeed=*/false);
    // OpenGV binds a copy of its generator, seeded with 12345, into rng_gen_ at construction:
    // re-seed the generator and bind it anew, so that options.seed decides the samples.
    problem->rng_alg_.seed(static_cast<std::mt19937::result_type>(options.seed ^ (options.seed >> 32)));
    problem->rng_gen_ = std::make_shared<std::function<int()>>(std::bind(*problem->rng_dist_, problem->rng_alg_));
    opengv::sac::Ransac<SacProblem> ransac;
    ransac.sac_model_ = problem;
    ransac.threshold_ = threshold;
    ransac.max_iterations_ = options.max_iterations;
    ransac.probability_ = options.probability;
    if (!ransac.computeModel() || !isFinite(ransac.model_coefficients_)) {
      result.status = Status::kRelativePoseFailed;
      result.message = "relative pose: RANSAC found no model (" +
                       std::string(relativePoseAlgorithmName(options.algorithm)) + ", " + std::to_string(n_valid) +
                       " correspondences)";
      return result;
    }
    model = ransac.model_coefficients_;
    inliers = ransac.inliers_;

    if (options.nonlinear_refinement) refined = refineModel(&adapter, *problem, threshold, sample_size, &model, &inliers);
  } catch (const std::exception& e) {
    result.status = Status::kRelativePoseFailed;
    result.message = std::string("relative pose: OpenGV failed: ") + e.what();
    return result;
  }

  finishResult(model, inliers, valid, n_given, refined, min_spread_rad, options, &result);
  // OpenGV's refinement stops short of its optimum (refineOnSampsonError()): the pose is taken on
  // to the optimum of the cost whose curvature its covariance is.
  if (options.nonlinear_refinement && result.status == Status::kOk) {
    refineOnSampsonError(bearings_target, bearings_source, &result);
  }
  return result;
}

}  // namespace pcr_pro
