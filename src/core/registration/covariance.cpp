#include "pcr_pro/registration/covariance.h"

#include <Eigen/Cholesky>
#include <Eigen/Eigenvalues>
#include <Eigen/LU>

#include <algorithm>
#include <cmath>
#include <cstdint>
#include <cstring>
#include <limits>
#include <map>
#include <numeric>
#include <random>
#include <sstream>
#include <unordered_set>
#include <vector>

#include "pcr_pro/geometry/kdtree.h"
#include "pcr_pro/geometry/normals.h"
#include "pcr_pro/geometry/similarity_fit.h"

namespace pcr_pro {
namespace {


using Matrix73d = Eigen::Matrix<double, 7, 3>;
using Vector7d = Eigen::Matrix<double, 7, 1>;

// Change of variables from the normalised, centroid-referenced perturbation u to the contract's
// origin-referenced δ: δ = K u, K = Tc D. u_t = δt about the centroid c, u_r = ρ δω, u_s = ρ δσ,
// so that every component of u is a displacement [target units].
Matrix7d centroidToOrigin(const Eigen::Vector3d& c, double rho) {
  Matrix7d tc = Matrix7d::Identity();
  tc.block<3, 3>(0, 3) = skew(c);
  tc.block<3, 1>(0, 6) = -c;
  Vector7d d;
  d << 1, 1, 1, 1 / rho, 1 / rho, 1 / rho, 1 / rho;
  return tc * d.asDiagonal();
}

const char* kDirectionNames[7] = {"x", "y", "z", "rot_x", "rot_y", "rot_z", "scale"};

// The distinct matched target points (several source points may share one).
Cloud distinctTargets(const Cloud& targets) {
  struct Hash {
    std::size_t operator()(const Eigen::Vector3d& p) const {
      std::size_t h = 0;
      for (int k = 0; k < 3; ++k) {
        std::uint64_t bits = 0;
        const double v = p(k);
        std::memcpy(&bits, &v, sizeof bits);
        h ^= std::hash<std::uint64_t>()(bits) + 0x9e3779b97f4a7c15ULL + (h << 6) + (h >> 2);
      }
      return h;
    }
  };
  std::unordered_set<Eigen::Vector3d, Hash> seen;
  seen.reserve(static_cast<std::size_t>(targets.cols()));
  Cloud out(3, targets.cols());
  Eigen::Index k = 0;
  for (Eigen::Index i = 0; i < targets.cols(); ++i) {
    if (seen.insert(targets.col(i)).second) out.col(k++) = targets.col(i);
  }
  return out.leftCols(k);
}

Cloud pick(const Cloud& cloud, const std::vector<Eigen::Index>& order, std::size_t begin, std::size_t end) {
  Cloud out(3, static_cast<Eigen::Index>(end - begin));
  for (std::size_t i = begin; i < end; ++i) out.col(static_cast<Eigen::Index>(i - begin)) = cloud.col(order[i]);
  return out;
}

struct Calibration {
  double kappa = 1.0;  // mean split-sample NEES per degree of freedom
  int splits = 0;      // splits that contributed
};

// Split-sample calibration (see covariance.h): re-registers disjoint random halves of the
// matched source and target points from the converged pose and compares their disagreement
// with the closed-form prediction.
Calibration splitSampleCalibration(const Correspondences& matches, const Sim3& transform, ErrorMetric metric,
                                   bool with_scale, const CovarianceOptions& o) {
  Calibration cal;
  const Cloud targets = distinctTargets(matches.target);
  std::mt19937 rng(12345u);
  std::vector<Eigen::Index> src_order(static_cast<std::size_t>(matches.source.cols()));
  std::vector<Eigen::Index> tgt_order(static_cast<std::size_t>(targets.cols()));
  IcpOptions io;
  io.error_metric = metric;
  io.estimate_scale = with_scale;
  io.max_source_points = 0;
  // The matches are already the kept ones: no trimming; the halves are re-registered by the same
  // overlap-aware, robust ICP as the whole (IcpOptions defaults), whose errors are measured.
  io.trim_ratio = 1.0;

  io.max_iterations = 8;     // the halves start at the converged pose: a few re-matchings suffice
  io.normal_neighbors = o.normal_neighbors;
  CovarianceOptions closed = o;
  closed.model = CovarianceModel::kClosedForm;
  const auto cap = [&](std::size_t size) {
    return o.calibration_max_points > 0 ? std::min(size, static_cast<std::size_t>(o.calibration_max_points)) : size;
  };
  const std::size_t ns = cap(src_order.size()), nt = cap(tgt_order.size());
  // The random splits are drawn first, in order, so that the result does not depend on how
  // the splits are then spread over threads.
  const auto splits = static_cast<std::size_t>(o.calibration_splits);
  std::vector<std::vector<Eigen::Index>> src_orders(splits), tgt_orders(splits);
  for (std::size_t split = 0; split < splits; ++split) {
    std::iota(src_order.begin(), src_order.end(), 0);
    std::iota(tgt_order.begin(), tgt_order.end(), 0);
    std::shuffle(src_order.begin(), src_order.end(), rng);
    std::shuffle(tgt_order.begin(), tgt_order.end(), rng);
    src_orders[split] = src_order;
    tgt_orders[split] = tgt_order;
  }
  std::vector<double> nees(splits, -1.0);  // < 0: the split did not contribute
#pragma omp parallel for schedule(dynamic)
  for (std::size_t split = 0; split < splits; ++split) {
    Sim3 est[2];
    Matrix6d cov[2];
    bool ok = true;
    for (int half = 0; half < 2 && ok; ++half) {
      const Cloud src = pick(matches.source, src_orders[split], half * ns / 2, (half + 1) * ns / 2);
      const Cloud tgt = pick(targets, tgt_orders[split], half * nt / 2, (half + 1) * nt / 2);
      if (src.cols() < 20 || tgt.cols() < 20) {
        ok = false;
        break;
      }
      const IcpResult r = alignIcp(src, tgt, transform, io);
      // An iteration-capped half still measures the disagreement; too few matches does not.
      if (r.correspondences < io.min_correspondences || !r.transform.matrix().allFinite()) {
        ok = false;
        break;
      }
      const CovarianceResult c = computeIcpCovariance(r.matches, r.transform, metric, with_scale, closed);
      if (c.status != Status::kOk) {
        ok = false;
        break;
      }
      est[half] = r.transform;
      cov[half] = c.covariance;
    }
    if (!ok) continue;
    const Vector6d d = poseDifference(est[0], est[1]);
    const Eigen::LDLT<Matrix6d> ldlt(cov[0] + cov[1]);
    if (ldlt.info() != Eigen::Success) continue;
    nees[split] = d.dot(ldlt.solve(d)) / 6.0;
  }
  double sum = 0.0;
  for (double v : nees) {
    if (v >= 0.0) {
      sum += v;
      ++cal.splits;
    }
  }
  if (cal.splits > 0) cal.kappa = sum / cal.splits;
  return cal;
}

}  // namespace

const char* covarianceModelName(CovarianceModel model) {
  switch (model) {
    case CovarianceModel::kClosedForm: return "closed_form";
    case CovarianceModel::kCalibrated: return "calibrated";
    case CovarianceModel::kBlocks: return "blocks";
  }
  return "calibrated";
}

bool parseCovarianceModel(const std::string& name, CovarianceModel* model) {
  if (name == "closed_form") {
    *model = CovarianceModel::kClosedForm;
    return true;
  }
  if (name == "calibrated") {
    *model = CovarianceModel::kCalibrated;
    return true;
  }
  if (name == "blocks") {
    *model = CovarianceModel::kBlocks;
    return true;
  }
  return false;
}

template <>
const ParamSchema<CovarianceOptions>& paramSchema<CovarianceOptions>() {
  using O = CovarianceOptions;
  using R = ParamRange;
  static const ParamSchema<O> schema{"covariance", {
      {"model",
       TextParam<O>{+[](const O& o) { return std::string(covarianceModelName(o.model)); },
                    +[](O* o, const std::string& s) { return parseCovarianceModel(s, &o->model); },
                    "closed_form, calibrated or blocks"},
       R::any(), "",
       "closed_form: Censi's closed form; calibrated: closed form x max(1, kappa) from re-registered halves; blocks: "
       "closed form covering the spread between spatial blocks of the correspondences"},
      {"calibration_splits", &O::calibration_splits, R::atLeast(1), "", "random half splits averaged for kappa (calibrated)"},
      {"calibration_max_points", &O::calibration_max_points, R::atLeast(100).orZero(), "points",
       "matches re-registered for kappa (calibrated); 0 = all"},
      {"sensor_noise_stddev", &O::sensor_noise_stddev, R::atLeast(0), "target units",
       "per-coordinate point noise; 0 = estimated from the residuals"},
      {"degeneracy_condition_threshold", &O::degeneracy_condition_threshold, R::above(1), "-",
       "condition number above which a direction is unobservable"},
      {"normal_neighbors", &O::normal_neighbors, R::atLeast(3), "", "neighbours for the normals of matched points"},
      {"jackknife_blocks", &O::jackknife_blocks, R::atLeast(3).orZero(), "",
       "spatial blocks left out one at a time, the registration re-run without each; the covariance covers their "
       "spread; 0 = off"},
  }};
  return schema;
}

void validate(const CovarianceOptions& o) {
  checkRanges(paramSchema<CovarianceOptions>(), o);
}

namespace {

// Spatial blocks of the block spread, and the fewest correspondences a block needs: sixteen
// blocks of a room-sized overlap are about a metre across, the scale at which map distortion and
// partial-overlap bias vary; fifty correspondences keep a block's own noise small against that.
constexpr int kMaxBlocks = 16;
constexpr Eigen::Index kMinBlockSize = 50;

}  // namespace

std::vector<std::vector<Eigen::Index>> spatialBlocks(const Cloud& points, int blocks) {
  std::vector<std::vector<Eigen::Index>> out(1);
  out[0].resize(static_cast<std::size_t>(points.cols()));
  std::iota(out[0].begin(), out[0].end(), 0);
  while (static_cast<int>(out.size()) < blocks) {
    auto largest =
        std::max_element(out.begin(), out.end(), [](const auto& a, const auto& b) { return a.size() < b.size(); });
    if (static_cast<Eigen::Index>(largest->size()) < 2 * kMinBlockSize) break;
    std::vector<Eigen::Index> idx = std::move(*largest);
    Eigen::Vector3d lo = Eigen::Vector3d::Constant(std::numeric_limits<double>::infinity()), hi = -lo;
    for (Eigen::Index i : idx) {
      lo = lo.cwiseMin(points.col(i));
      hi = hi.cwiseMax(points.col(i));
    }
    int axis = 0;
    (hi - lo).maxCoeff(&axis);
    const auto mid = idx.begin() + static_cast<std::ptrdiff_t>(idx.size() / 2);
    std::nth_element(idx.begin(), mid, idx.end(),
                     [&](Eigen::Index a, Eigen::Index b) { return points(axis, a) < points(axis, b); });
    std::vector<Eigen::Index> second(mid, idx.end());
    idx.resize(idx.size() / 2);
    *largest = std::move(idx);
    out.push_back(std::move(second));
  }
  return out;
}

// The covariance's blocks (translation at `centre`, rotation, log scale) without their cross
// terms, each 3x3 block made isotropic with its trace when asked (blockDiagonalAt(),
// isotropicBlocksAt()).
namespace {
Matrix7d blocksAt(const Matrix7d& covariance, const Eigen::Vector3d& centre, bool isotropic) {
  // δ = K u with u's translation at the centre (rho 1: u's rotation and scale are δ's).
  const Matrix7d k = centroidToOrigin(centre, 1.0);
  const Matrix7d kinv = k.inverse();
  const Matrix7d u = kinv * covariance * kinv.transpose();
  Matrix7d blocks = Matrix7d::Zero();
  for (int b = 0; b < 6; b += 3) {
    const Eigen::Matrix3d block = u.block<3, 3>(b, b);
    blocks.block<3, 3>(b, b) = isotropic ? Eigen::Matrix3d(Eigen::Matrix3d::Identity() * (block.trace() / 3.0)) : block;
  }
  blocks(6, 6) = u(6, 6);
  const Matrix7d out = k * blocks * k.transpose();
  return 0.5 * (out + out.transpose());
}
}  // namespace

Matrix7d blockDiagonalAt(const Matrix7d& covariance, const Eigen::Vector3d& centre) {
  return blocksAt(covariance, centre, false);
}

Matrix7d isotropicBlocksAt(const Matrix7d& covariance, const Eigen::Vector3d& centre) {
  return blocksAt(covariance, centre, true);
}

Matrix7d logScaleCovariance(const CovarianceResult& c, double scale) {
  Matrix7d out = Matrix7d::Zero();
  if (c.with_scale) {
    out = c.covariance7;
    out.row(6) /= scale;
    out.col(6) /= scale;
  } else {
    out.topLeftCorner<6, 6>() = c.covariance;
  }
  return out;
}

Matrix6d positivePartInformation(const Matrix6d& covariance) {
  Matrix6d info = Matrix6d::Zero();
  if (!covariance.allFinite()) return info;
  const Eigen::SelfAdjointEigenSolver<Matrix6d> eig(0.5 * (covariance + covariance.transpose()));
  const double largest = eig.eigenvalues().cwiseAbs().maxCoeff();
  for (int i = 0; i < 6; ++i) {
    const double l = eig.eigenvalues()(i);
    if (l > 1e-14 * largest) info += eig.eigenvectors().col(i) * eig.eigenvectors().col(i).transpose() / l;
  }
  return 0.5 * (info + info.transpose());
}

ReportedUncertainty degenerateUncertainty(const Matrix6d& covariance, const CovarianceResult* icp_closed_form) {
  const bool finite = covariance.allFinite();
  if (!finite && icp_closed_form != nullptr) return {icp_closed_form->covariance, icp_closed_form->information};
  ReportedUncertainty out;
  if (finite) out.covariance = covariance;
  out.information = positivePartInformation(covariance);  // zero when not finite
  return out;
}

BlockSpread blockSpreadCovariance(const Correspondences& m, const Sim3& transform, ErrorMetric metric,
                                  bool with_scale, const std::vector<PointMatch3>* anchors) {
  BlockSpread out;
  const int d = with_scale ? 7 : 6;
  const Cloud moved = transform.apply(m.source);
  if (moved.cols() == 0 || m.target.cols() != moved.cols()) return out;
  const bool plane = metric == ErrorMetric::kPointToPlane && m.target_normals.cols() == moved.cols();
  const double sigma = std::max({m.residual_scale, m.spacing / kNoiseFloorPerSpacing, 1e-300});
  const int wanted = static_cast<int>(std::min<Eigen::Index>(kMaxBlocks, moved.cols() / kMinBlockSize));
  const std::vector<std::vector<Eigen::Index>> blocks = spatialBlocks(moved, std::max(1, wanted));
  Matrix7d h = Matrix7d::Zero();
  std::vector<Vector7d> gradients;
  for (const auto& block : blocks) {
    Vector7d g = Vector7d::Zero();
    for (Eigen::Index i : block) {
      const Eigen::Vector3d y = moved.col(i);
      const Eigen::Vector3d r3 = y - m.target.col(i);
      const double w = (m.weights.size() == moved.cols() ? m.weights(i) : 1.0) / (sigma * sigma);
      const Eigen::Matrix<double, 3, 7> j3 = similarityJacobian(y);
      if (plane) {
        const Eigen::Vector3d n = m.target_normals.col(i);
        const Eigen::Matrix<double, 1, 7> j = n.transpose() * j3;
        h.noalias() += w * j.transpose() * j;
        g.noalias() += w * j.transpose() * n.dot(r3);
      } else {
        h.noalias() += w * j3.transpose() * j3;
        g.noalias() += w * j3.transpose() * r3;
      }
    }
    gradients.push_back(g);
  }
  if (anchors) {
    std::map<int, Vector7d> groups;
    for (const PointMatch3& a : *anchors) {
      auto it = groups.find(a.group);
      if (it == groups.end()) it = groups.emplace(a.group, Vector7d::Zero()).first;
      addAnchorNormalEquations(a, transform, Eigen::Vector3d::Zero(), &h, &it->second);
    }
    for (const auto& entry : groups) gradients.push_back(entry.second);
  }
  out.clusters = static_cast<int>(gradients.size());
  out.information = h;
  if (!with_scale) out.information.row(6).setZero(), out.information.col(6).setZero();
  const Eigen::LDLT<Eigen::MatrixXd> ldlt(h.topLeftCorner(d, d));
  if (out.clusters < 3 || ldlt.info() != Eigen::Success || !ldlt.isPositive()) return out;
  const Eigen::MatrixXd hinv = ldlt.solve(Eigen::MatrixXd::Identity(d, d));
  Eigen::MatrixXd meat = Eigen::MatrixXd::Zero(d, d);
  for (const Vector7d& g : gradients) meat += g.head(d) * g.head(d).transpose();
  meat *= static_cast<double>(out.clusters) / (out.clusters - 1);
  out.sandwich.topLeftCorner(d, d) = hinv * meat * hinv;
  out.ok = out.sandwich.allFinite();
  return out;
}

namespace {

// Sums of the O(n) accumulation in u coordinates (see computeIcpCovariance()).
struct UAccumulation {
  Matrix7d h = Matrix7d::Zero();    // Σ JᵀJ
  Matrix7d g = Matrix7d::Zero();    // Σ (∂g/∂y)(∂g/∂y)ᵀ
  Matrix7d obs = Matrix7d::Zero();  // geometric information
  double sum_r2 = 0.0;              // Σ squared residuals
};

// O(n) accumulation in u coordinates: H = Σ JᵀJ, G = Σ (∂g/∂y)(∂g/∂y)ᵀ, O = geometric information.
UAccumulation accumulateU(const Correspondences& matches, const Cloud& y_all, const Cloud& normals,
                          const Eigen::Vector3d& c, double inv_rho, bool plane) {
  UAccumulation acc;
  Matrix7d& h = acc.h;
  Matrix7d& g = acc.g;
  Matrix7d& obs = acc.obs;
  double& sum_r2 = acc.sum_r2;
  const Eigen::Index n = matches.source.cols();
  for (Eigen::Index i = 0; i < n; ++i) {
    const Eigen::Vector3d y = y_all.col(i);
    const Eigen::Vector3d q = matches.target.col(i);
    const Eigen::Vector3d a = y - c;
    const Eigen::Vector3d r = y - q;
    const Eigen::Vector3d nrm = normals.col(i);
    Vector7d an;
    an << nrm, a.cross(nrm) * inv_rho, nrm.dot(a) * inv_rho;
    obs.noalias() += an * an.transpose();
    if (plane) {
      const double rp = nrm.dot(r);
      Matrix73d b = Matrix73d::Zero();
      b.block<3, 3>(3, 0) = -skew(nrm) * inv_rho;
      b.block<1, 3>(6, 0) = nrm.transpose() * inv_rho;
      const Matrix73d dgdy = an * nrm.transpose() + b * rp;
      h.noalias() += an * an.transpose();
      g.noalias() += dgdy * dgdy.transpose();
      sum_r2 += rp * rp;
    } else {
      Matrix73d jt;  // Jᵀ (7x3): residual r = y - q w.r.t. u
      jt.block<3, 3>(0, 0).setIdentity();
      jt.block<3, 3>(3, 0) = skew(a) * inv_rho;  // (−[a]x)ᵀ
      jt.block<1, 3>(6, 0) = a.transpose() * inv_rho;
      Matrix73d dgdy;
      dgdy.block<3, 3>(0, 0).setIdentity();
      dgdy.block<3, 3>(3, 0) = skew(q - c) * inv_rho;
      dgdy.block<1, 3>(6, 0) = (r + a).transpose() * inv_rho;
      h.noalias() += jt * jt.transpose();
      g.noalias() += dgdy * dgdy.transpose();
      sum_r2 += r.squaredNorm();
    }
  }
  return acc;
}

// Noise: configured, or from the residuals (each cloud contributes σ² per coordinate), never
// below a floor set by the clouds' own resolution, a fiftieth of their point spacing h: real
// maps' noise is far above it (it never binds on them), but a map registered with itself has
// zero residuals and would otherwise claim an exact pose (information of 1e23 and more).
// Returns σ² per coordinate [target units²].
double noiseVariance(const Correspondences& matches, const CovarianceOptions& o, bool plane, int d, double sum_r2) {
  const Eigen::Index n = matches.source.cols();
  double sigma2 = o.sensor_noise_stddev * o.sensor_noise_stddev;
  if (!(sigma2 > 0.0)) {
    const double dof = plane ? static_cast<double>(n - d) : static_cast<double>(3 * n - d);
    sigma2 = sum_r2 / (2.0 * dof);
    double spacing = matches.spacing;
    if (!(spacing > 0.0)) {
      const KdTree spacing_tree(distinctTargets(matches.target));
      spacing = medianSpacing(spacing_tree);
    }
    sigma2 = std::max(sigma2, std::pow(spacing / kNoiseFloorPerSpacing, 2));
  }
  return sigma2;
}

// The eigenvectors of the geometric information whose eigenvalue is below its largest over the
// degeneracy threshold: the unobservable directions (d x k).
Eigen::MatrixXd nullDirections(const Eigen::SelfAdjointEigenSolver<Eigen::MatrixXd>& oeig, int d,
                               const CovarianceOptions& o) {
  const Eigen::VectorXd oev = oeig.eigenvalues();  // ascending
  const double max_ev = oev(d - 1);
  Eigen::MatrixXd null_dirs(d, 0);
  for (int k = 0; k < d; ++k) {
    if (!(oev(k) * o.degeneracy_condition_threshold > max_ev)) {
      null_dirs.conservativeResize(d, null_dirs.cols() + 1);
      null_dirs.col(null_dirs.cols() - 1) = oeig.eigenvectors().col(k);
    }
  }
  return null_dirs;
}

// The covariance and information of the observable subspace, back in u (d x d blocks of 7x7).
struct UCovariance {
  Matrix7d cov = Matrix7d::Zero();
  Matrix7d info = Matrix7d::Zero();
};

// Censi on the observable subspace V_o (unobservable directions V_n are kept out of every
// inversion): cov_o = σ² H_o⁻¹ (G_o + H_o) H_o⁻¹ with X_o = V_oᵀ X V_o; the H term is the
// target-point noise, G the source-point noise. The calibrated model inflates cov_o (and sets
// res->inflation and res->calibration_splits_used). Back to u, unobservable directions get an
// effectively unbounded variance and no information at all.
UCovariance observableCovariance(const UAccumulation& acc, const Eigen::MatrixXd& eigenvectors,
                                 const Eigen::MatrixXd& null_dirs, int d, double sigma2, double rho,
                                 const Correspondences& matches, const Sim3& transform, ErrorMetric metric,
                                 bool with_scale, const CovarianceOptions& o, CovarianceResult* res) {
  const Eigen::Index k_obs = d - null_dirs.cols();
  const Eigen::MatrixXd v_obs = eigenvectors.rightCols(k_obs);
  const Eigen::MatrixXd h_o = v_obs.transpose() * acc.h.topLeftCorner(d, d) * v_obs;
  const Eigen::MatrixXd g_o = v_obs.transpose() * acc.g.topLeftCorner(d, d) * v_obs;
  const Eigen::MatrixXd h_o_inv = h_o.inverse();
  Eigen::MatrixXd cov_o = sigma2 * h_o_inv * (g_o + h_o) * h_o_inv;
  cov_o = 0.5 * (cov_o + cov_o.transpose()).eval();
  if (o.model == CovarianceModel::kCalibrated) {
    const Calibration cal = splitSampleCalibration(matches, transform, metric, with_scale, o);
    res->inflation = std::max(1.0, cal.kappa);
    res->calibration_splits_used = cal.splits;
    cov_o *= res->inflation;
  }
  const Eigen::MatrixXd info_o = cov_o.inverse();

  UCovariance u;
  u.cov.topLeftCorner(d, d) = v_obs * cov_o * v_obs.transpose();
  u.info.topLeftCorner(d, d) = v_obs * info_o * v_obs.transpose();
  const double big = 1e6 * rho * rho;
  for (Eigen::Index k = 0; k < null_dirs.cols(); ++k) {
    u.cov.topLeftCorner(d, d) += big * null_dirs.col(k) * null_dirs.col(k).transpose();
  }
  return u;
}

// res->covariance7 from the 7x7 covariance with log scale as 7th variable (δσ = δs / s) and
// res->scale_stddev; without scale, the pose block res->covariance (already set).
void setCovariance7(const Matrix7d& cov7, const Sim3& transform, bool with_scale, CovarianceResult* res) {
  if (with_scale) {
    Vector7d jd = Vector7d::Ones();
    jd(6) = transform.scale();  // δσ = δs / s
    res->covariance7 = jd.asDiagonal() * cov7 * jd.asDiagonal();
    res->scale_stddev = std::sqrt(std::max(0.0, res->covariance7(6, 6)));
  } else {
    res->covariance7.topLeftCorner<6, 6>() = res->covariance;
  }
}

// u -> δ. Covariance: the 6x6 pose block is the marginal. Information of the pose marginal:
// the Schur complement of the scale in the joint information.
void fromUToDelta(const UCovariance& u, const Matrix7d& kmat, const Sim3& transform, bool with_scale,
                  CovarianceResult* res) {
  const Matrix7d kinv = kmat.inverse();
  const Matrix7d cov7 = kmat * u.cov * kmat.transpose();  // log scale as 7th variable
  res->covariance = cov7.topLeftCorner<6, 6>();
  const Matrix7d info7 = kinv.transpose() * u.info * kinv;
  res->information = info7.topLeftCorner<6, 6>();
  if (with_scale && info7(6, 6) > 0.0) {
    res->information -= info7.block<6, 1>(0, 6) * info7.block<1, 6>(6, 0) / info7(6, 6);
  }
  res->information = 0.5 * (res->information + res->information.transpose()).eval();
  setCovariance7(cov7, transform, with_scale, res);
}

// The DEGENERATE status and a message naming the dominant component of the weakest direction,
// mapped back to δ.
void setDegenerate(const Eigen::MatrixXd& null_dirs, const Matrix7d& kmat, int d, double inv_rho,
                   const CovarianceOptions& o, CovarianceResult* res) {
  const Vector7d weakest = (Vector7d() << null_dirs.col(0), Eigen::VectorXd::Zero(7 - d)).finished();
  Vector7d w = kmat * weakest;
  w.head<3>() *= inv_rho;  // compare translation and rotation on the same footing
  Eigen::Index arg = 0;
  w.cwiseAbs().maxCoeff(&arg);
  std::ostringstream msg;
  msg << "covariance: " << null_dirs.cols() << " unobservable direction(s), weakest along " << kDirectionNames[arg]
      << " (condition number " << res->condition_number << " > " << o.degeneracy_condition_threshold << ")";
  res->status = Status::kDegenerate;
  res->message = msg.str();
}

// The blocks model: widen res's covariance to cover the spread between spatial blocks.
void applyBlockSpread(const Correspondences& matches, const Sim3& transform, ErrorMetric metric, bool with_scale,
                      CovarianceResult* res) {
  const BlockSpread spread = blockSpreadCovariance(matches, transform, metric, with_scale);
  if (spread.ok) {
    res->inflation = coverCovarianceResult(spread.sandwich, transform, with_scale, res);
    res->calibration_splits_used = spread.clusters;
  }
}

// The OK message: model, correspondences, noise, condition number and the model's inflation.
std::string okMessage(const CovarianceResult& res, Eigen::Index n, const CovarianceOptions& o) {
  std::ostringstream msg;
  msg << "covariance (" << covarianceModelName(o.model) << ") from " << n << " correspondences, noise "
      << res.noise_stddev << ", condition number " << res.condition_number;
  if (o.model == CovarianceModel::kCalibrated) {
    msg << ", inflation " << res.inflation << " from " << res.calibration_splits_used << " split(s)";
  } else if (o.model == CovarianceModel::kBlocks) {
    msg << ", block spread x" << res.inflation << " over " << res.calibration_splits_used << " block(s)";
  }
  return msg.str();
}

}  // namespace

double coverCovarianceResult(const Matrix7d& spread, const Sim3& transform, bool with_scale, CovarianceResult* res) {
  double factor = 1.0;
  const Matrix7d covered = coveringCovariance(logScaleCovariance(*res, transform.scale()), spread, &factor);
  res->covariance = covered.topLeftCorner<6, 6>();
  res->information = res->covariance.ldlt().solve(Matrix6d::Identity());
  res->information = 0.5 * (res->information + res->information.transpose()).eval();
  setCovariance7(covered, transform, with_scale, res);
  return factor;
}

void invertCovarianceResult(const Sim3& forward, CovarianceResult* res) {
  // The result is of S = forward^-1; with left perturbations (similarity_fit.h) the covariance of
  // S^-1 is Ad(S^-1) C Ad(S^-1)^T. The log scale's column of the adjoint carries the translation,
  // so the scale's uncertainty enters the inverted translation's.
  const Matrix7d ad = similarityAdjoint(forward);
  Matrix7d c = ad * logScaleCovariance(*res, forward.inverse().scale()) * ad.transpose();
  c = 0.5 * (c + c.transpose()).eval();
  const Matrix6d before = res->information;
  res->covariance = c.topLeftCorner<6, 6>();
  Matrix6d information = Matrix6d::Constant(std::numeric_limits<double>::quiet_NaN());
  if (res->status == Status::kOk) {
    information = res->covariance.ldlt().solve(Matrix6d::Identity());
    information = 0.5 * (information + information.transpose()).eval();
  }
  if (!information.allFinite()) {
    // A degenerate result's information is zero along the unobservable directions, which the
    // congruence keeps (the scale's cross terms left out: the pose marginal of a degenerate
    // result is a bound, not an estimate).
    const Eigen::FullPivLU<Matrix6d> lu(ad.topLeftCorner<6, 6>());
    information = lu.isInvertible() ? Matrix6d(lu.inverse().transpose() * before * lu.inverse()) : Matrix6d::Zero();
  }
  res->information = information;
  setCovariance7(c, forward, res->with_scale, res);
  res->noise_stddev *= forward.scale();
}

CovarianceResult computeIcpCovariance(const Correspondences& matches, const Sim3& transform, ErrorMetric metric,
                                      bool with_scale, const CovarianceOptions& o) {
  validate(o);
  CovarianceResult res;
  res.with_scale = with_scale;
  const Eigen::Index n = matches.source.cols();
  res.correspondences = static_cast<int>(n);
  const int d = with_scale ? 7 : 6;
  if (n < d + 1 || matches.target.cols() != n) {
    res.status = Status::kIcpNotConverged;
    res.message = "covariance: need at least " + std::to_string(d + 1) + " correspondences, have " + std::to_string(n);
    return res;
  }
  const bool plane = metric == ErrorMetric::kPointToPlane;
  if (plane && matches.target_normals.cols() != n) {
    throw InputError("covariance: point-to-plane needs one target normal per correspondence");
  }

  // Pre-pass: centroid and RMS radius of the transformed source points (the reference of u).
  const Cloud y_all = transform.apply(matches.source);
  const Eigen::Vector3d c = y_all.rowwise().mean();
  double rho = std::sqrt((y_all.colwise() - c).colwise().squaredNorm().mean());
  if (!(rho > 0.0)) rho = 1.0;
  const double inv_rho = 1.0 / rho;

  // Normals for the observability analysis: the ICP's own, or estimated on the matched targets.
  Cloud normals;
  if (matches.target_normals.cols() == n) {
    normals = matches.target_normals;
  } else {
    KdTree tree(matches.target);
    normals = estimateNormals(tree, o.normal_neighbors);
  }

  const UAccumulation acc = accumulateU(matches, y_all, normals, c, inv_rho, plane);

  double sigma2 = noiseVariance(matches, o, plane, d, acc.sum_r2);
  res.noise_stddev = std::sqrt(sigma2);
  // Correspondences that measure the same surfaces twice (symmetric matching) carry the
  // information once.
  sigma2 *= std::max(1.0, matches.redundancy);

  // Degeneracy from the geometric information over the pose (and scale) directions.
  Eigen::SelfAdjointEigenSolver<Eigen::MatrixXd> oeig(acc.obs.topLeftCorner(d, d));
  const Eigen::VectorXd oev = oeig.eigenvalues();  // ascending
  const double max_ev = oev(d - 1);
  res.condition_number = oev(0) > 0.0 ? max_ev / oev(0) : std::numeric_limits<double>::infinity();
  const Eigen::MatrixXd null_dirs = nullDirections(oeig, d, o);

  const UCovariance u = observableCovariance(acc, oeig.eigenvectors(), null_dirs, d, sigma2, rho, matches, transform,
                                             metric, with_scale, o, &res);
  const Matrix7d kmat = centroidToOrigin(c, rho);
  fromUToDelta(u, kmat, transform, with_scale, &res);

  if (null_dirs.cols() > 0) {
    setDegenerate(null_dirs, kmat, d, inv_rho, o, &res);
  } else {
    res.status = Status::kOk;
    if (o.model == CovarianceModel::kBlocks) applyBlockSpread(matches, transform, metric, with_scale, &res);
    res.message = okMessage(res, n, o);
  }
  return res;
}

}  // namespace pcr_pro
