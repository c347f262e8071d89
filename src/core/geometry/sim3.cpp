#include "pcr_pro/geometry/sim3.h"

#include <Eigen/SVD>

#include <cmath>

namespace pcr_pro {

Sim3::Sim3() : scale_(1.0), rotation_(Eigen::Matrix3d::Identity()), translation_(Eigen::Vector3d::Zero()) {}

Sim3::Sim3(double scale, const Eigen::Matrix3d& rotation, const Eigen::Vector3d& translation)
    : scale_(scale), rotation_(rotation), translation_(translation) {}

Sim3::Sim3(double scale, const Eigen::Quaterniond& q, const Eigen::Vector3d& translation)
    : scale_(scale), rotation_(q.normalized().toRotationMatrix()), translation_(translation) {}

Sim3 Sim3::fromMatrix(const Eigen::Matrix4d& m) {
  if (!m.allFinite()) throw InputError("transform matrix has non-finite entries");
  if (m.row(3).cwiseAbs().head<3>().maxCoeff() > 1e-9 || std::abs(m(3, 3) - 1.0) > 1e-9) {
    throw InputError("transform matrix: last row must be 0 0 0 1");
  }
  const Eigen::Matrix3d sr = m.topLeftCorner<3, 3>();
  const double det = sr.determinant();
  if (!(det > 1e-300)) throw InputError("transform matrix: rotation block is singular or a reflection");
  const double s = std::cbrt(det);
  return Sim3(s, projectToRotation(sr / s), m.topRightCorner<3, 1>());
}

Eigen::Matrix4d Sim3::matrix() const {
  Eigen::Matrix4d m = Eigen::Matrix4d::Identity();
  m.topLeftCorner<3, 3>() = scale_ * rotation_;
  m.topRightCorner<3, 1>() = translation_;
  return m;
}

Cloud Sim3::apply(const Cloud& cloud) const {
  Cloud out = (scale_ * rotation_) * cloud;
  out.colwise() += translation_;
  return out;
}

Sim3 Sim3::inverse() const {
  const Eigen::Matrix3d rt = rotation_.transpose();
  return Sim3(1.0 / scale_, rt, -(rt * translation_) / scale_);
}

Sim3 Sim3::operator*(const Sim3& o) const {
  return Sim3(scale_ * o.scale_, rotation_ * o.rotation_, scale_ * (rotation_ * o.translation_) + translation_);
}

double Sim3::rotationAngle() const { return Eigen::AngleAxisd(rotation_).angle(); }

double rotationDistance(const Eigen::Matrix3d& ra, const Eigen::Matrix3d& rb) {
  return Eigen::AngleAxisd(projectToRotation(ra * rb.transpose())).angle();
}

Eigen::Matrix3d skew(const Eigen::Vector3d& v) {
  Eigen::Matrix3d m;
  m << 0, -v.z(), v.y(), v.z(), 0, -v.x(), -v.y(), v.x(), 0;
  return m;
}

Eigen::Matrix3d expSO3(const Eigen::Vector3d& w) {
  const double angle = w.norm();
  if (angle < 1e-12) return Eigen::Matrix3d::Identity() + skew(w);
  return Eigen::AngleAxisd(angle, w / angle).toRotationMatrix();
}

Eigen::Matrix3d projectToRotation(const Eigen::Matrix3d& m) {
  Eigen::JacobiSVD<Eigen::Matrix3d> svd(m, Eigen::ComputeFullU | Eigen::ComputeFullV);
  Eigen::Matrix3d d = Eigen::Matrix3d::Identity();
  if ((svd.matrixU() * svd.matrixV().transpose()).determinant() < 0) d(2, 2) = -1;
  return svd.matrixU() * d * svd.matrixV().transpose();
}

}  // namespace pcr_pro
