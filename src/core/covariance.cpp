#include "pcr_pro/core/covariance.h"

#include <Eigen/Eigenvalues>
#include <Eigen/LU>

#include <cmath>
#include <sstream>

#include "pcr_pro/core/kdtree.h"
#include "pcr_pro/core/normals.h"

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

}  // namespace

void validate(const CovarianceOptions& o) {
  if (!(o.sensor_noise_stddev >= 0.0) || !std::isfinite(o.sensor_noise_stddev)) {
    throw InputError("covariance.sensor_noise_stddev must be >= 0");
  }
  if (!(o.degeneracy_condition_threshold > 1.0)) throw InputError("covariance.degeneracy_condition_threshold must be > 1");
  if (o.normal_neighbors < 3) throw InputError("covariance.normal_neighbors must be >= 3");
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

  // O(n) accumulation in u coordinates: H = Σ JᵀJ, G = Σ (∂g/∂y)(∂g/∂y)ᵀ, O = geometric information.
  Matrix7d h = Matrix7d::Zero(), g = Matrix7d::Zero(), obs = Matrix7d::Zero();
  double sum_r2 = 0.0;
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

  // Noise: configured, or from the residuals (each cloud contributes σ² per coordinate).
  double sigma2 = o.sensor_noise_stddev * o.sensor_noise_stddev;
  if (!(sigma2 > 0.0)) {
    const double dof = plane ? static_cast<double>(n - d) : static_cast<double>(3 * n - d);
    sigma2 = sum_r2 / (2.0 * dof);
  }
  res.noise_stddev = std::sqrt(sigma2);

  // Degeneracy from the geometric information over the pose (and scale) directions.
  Eigen::SelfAdjointEigenSolver<Eigen::MatrixXd> oeig(obs.topLeftCorner(d, d));
  const Eigen::VectorXd oev = oeig.eigenvalues();  // ascending
  const double max_ev = oev(d - 1);
  res.condition_number = oev(0) > 0.0 ? max_ev / oev(0) : std::numeric_limits<double>::infinity();
  Eigen::MatrixXd null_dirs(d, 0);
  for (int k = 0; k < d; ++k) {
    if (!(oev(k) * o.degeneracy_condition_threshold > max_ev)) {
      null_dirs.conservativeResize(d, null_dirs.cols() + 1);
      null_dirs.col(null_dirs.cols() - 1) = oeig.eigenvectors().col(k);
    }
  }

  // Censi on the observable subspace V_o (unobservable directions V_n are kept out of every
  // inversion): cov_o = σ² H_o⁻¹ (G_o + H_o) H_o⁻¹ with X_o = V_oᵀ X V_o; the H term is the
  // target-point noise, G the source-point noise.
  const Eigen::Index k_obs = d - null_dirs.cols();
  const Eigen::MatrixXd v_obs = oeig.eigenvectors().rightCols(k_obs);
  const Eigen::MatrixXd h_o = v_obs.transpose() * h.topLeftCorner(d, d) * v_obs;
  const Eigen::MatrixXd g_o = v_obs.transpose() * g.topLeftCorner(d, d) * v_obs;
  const Eigen::MatrixXd h_o_inv = h_o.inverse();
  Eigen::MatrixXd cov_o = sigma2 * h_o_inv * (g_o + h_o) * h_o_inv;
  cov_o = 0.5 * (cov_o + cov_o.transpose()).eval();
  const Eigen::MatrixXd info_o = cov_o.inverse();

  // Back to u (d x d): unobservable directions get an effectively unbounded variance and no
  // information at all.
  Matrix7d cov_u = Matrix7d::Zero(), info_u = Matrix7d::Zero();
  cov_u.topLeftCorner(d, d) = v_obs * cov_o * v_obs.transpose();
  info_u.topLeftCorner(d, d) = v_obs * info_o * v_obs.transpose();
  const double big = 1e6 * rho * rho;
  for (Eigen::Index k = 0; k < null_dirs.cols(); ++k) {
    cov_u.topLeftCorner(d, d) += big * null_dirs.col(k) * null_dirs.col(k).transpose();
  }

  // u -> δ. Covariance: the 6x6 pose block is the marginal. Information of the pose marginal:
  // the Schur complement of the scale in the joint information.
  const Matrix7d kmat = centroidToOrigin(c, rho);
  const Matrix7d kinv = kmat.inverse();
  const Matrix7d cov7 = kmat * cov_u * kmat.transpose();  // log scale as 7th variable
  res.covariance = cov7.topLeftCorner<6, 6>();
  const Matrix7d info7 = kinv.transpose() * info_u * kinv;
  res.information = info7.topLeftCorner<6, 6>();
  if (with_scale && info7(6, 6) > 0.0) {
    res.information -= info7.block<6, 1>(0, 6) * info7.block<1, 6>(6, 0) / info7(6, 6);
  }
  res.information = 0.5 * (res.information + res.information.transpose()).eval();

  if (with_scale) {
    Vector7d jd = Vector7d::Ones();
    jd(6) = transform.scale();  // δσ = δs / s
    res.covariance7 = jd.asDiagonal() * cov7 * jd.asDiagonal();
    res.scale_stddev = std::sqrt(std::max(0.0, res.covariance7(6, 6)));
  } else {
    res.covariance7.topLeftCorner<6, 6>() = res.covariance;
  }

  if (null_dirs.cols() > 0) {
    // Name the dominant component of the weakest direction, mapped back to δ.
    const Vector7d weakest = (Vector7d() << null_dirs.col(0), Eigen::VectorXd::Zero(7 - d)).finished();
    Vector7d w = kmat * weakest;
    w.head<3>() *= inv_rho;  // compare translation and rotation on the same footing
    Eigen::Index arg = 0;
    w.cwiseAbs().maxCoeff(&arg);
    std::ostringstream msg;
    msg << "covariance: " << null_dirs.cols() << " unobservable direction(s), weakest along " << kDirectionNames[arg]
        << " (condition number " << res.condition_number << " > " << o.degeneracy_condition_threshold << ")";
    res.status = Status::kDegenerate;
    res.message = msg.str();
  } else {
    res.status = Status::kOk;
    std::ostringstream msg;
    msg << "covariance from " << n << " correspondences, noise " << res.noise_stddev << ", condition number "
        << res.condition_number;
    res.message = msg.str();
  }
  return res;
}

}  // namespace pcr_pro
