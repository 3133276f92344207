#include "slam/optimization/manifolds/se3_manifold.h"

#include <Eigen/Geometry>
#include <cmath>

namespace twist::optimization {
namespace {

using geometry::SO3d;

Eigen::Quaterniond NormalizedQuaternion(const double* x) {
  return Eigen::Quaterniond(x[3], x[0], x[1], x[2]).normalized();
}

// Q(q) = d(q ⊗ [½ω, 1]) / d(½ω) at ω = 0, rows in coeffs() order (x, y, z, w).
Eigen::Matrix<double, 4, 3> QuaternionLeftBlock(const Eigen::Quaterniond& q) {
  Eigen::Matrix<double, 4, 3> m;
  m.topRows<3>() = q.w() * Eigen::Matrix3d::Identity() + SO3d::Hat(q.vec());
  m.bottomRows<1>() = -q.vec().transpose();
  return m;
}

// Logarithm of a unit quaternion on the double cover: angle 2·atan2(|v|, w)
// in [0, 2π), no hemisphere flip (so Exp(LogNoFlip(q)) == q, not -q).
Eigen::Vector3d LogNoFlip(const Eigen::Quaterniond& q) {
  const double sin_sq = q.vec().squaredNorm();
  if (q.w() > 0.0 && sin_sq < 1e-20) {
    // θ/sin(θ/2) = 2·atan(s/w)/s ≈ 2/w - (2/3) s²/w³.
    return (2.0 / q.w() - (2.0 / 3.0) * sin_sq / (q.w() * q.w() * q.w())) * q.vec();
  }
  if (sin_sq == 0.0) {
    // q = -1: the identity rotation reached through a 2π turn; no finite
    // logarithm on the cover, fall back to the rotation's own (zero) log.
    return Eigen::Vector3d::Zero();
  }
  const double s = std::sqrt(sin_sq);
  return (2.0 * std::atan2(s, q.w()) / s) * q.vec();
}

}  // namespace

bool SE3Manifold::Plus(const double* x, const double* delta, double* x_plus_delta) const {
  const Eigen::Quaterniond q = NormalizedQuaternion(x);
  const Eigen::Map<const Eigen::Vector3d> t(x + 4);
  const Eigen::Map<const Eigen::Matrix<double, 6, 1>> d(delta);
  const Eigen::Vector3d omega = d.tail<3>();
  const Eigen::Quaterniond dq = SO3d::Exp(omega).unit_quaternion();
  const Eigen::Quaterniond q_out = (q * dq).normalized();
  const Eigen::Vector3d t_out = t + q * (SO3d::LeftJacobian(omega) * d.head<3>());
  x_plus_delta[0] = q_out.x();
  x_plus_delta[1] = q_out.y();
  x_plus_delta[2] = q_out.z();
  x_plus_delta[3] = q_out.w();
  x_plus_delta[4] = t_out.x();
  x_plus_delta[5] = t_out.y();
  x_plus_delta[6] = t_out.z();
  return true;
}

bool SE3Manifold::PlusJacobian(const double* x, double* jacobian) const {
  Eigen::Map<Eigen::Matrix<double, 7, 6, Eigen::RowMajor>> out(jacobian);
  out = SE3PlusJacobian(x);
  return true;
}

bool SE3Manifold::Minus(const double* y, const double* x, double* y_minus_x) const {
  const Eigen::Quaterniond qx = NormalizedQuaternion(x);
  const Eigen::Quaterniond qy = NormalizedQuaternion(y);
  const Eigen::Map<const Eigen::Vector3d> tx(x + 4);
  const Eigen::Map<const Eigen::Vector3d> ty(y + 4);
  const Eigen::Quaterniond q_rel = qx.conjugate() * qy;
  const Eigen::Vector3d t_rel = qx.conjugate() * (ty - tx);
  const Eigen::Vector3d omega = LogNoFlip(q_rel);
  Eigen::Map<Eigen::Matrix<double, 6, 1>> out(y_minus_x);
  out.head<3>() = SO3d::LeftJacobianInverse(omega) * t_rel;
  out.tail<3>() = omega;
  return true;
}

bool SE3Manifold::MinusJacobian(const double* x, double* jacobian) const {
  Eigen::Map<Eigen::Matrix<double, 6, 7, Eigen::RowMajor>> out(jacobian);
  out = SE3MinusJacobian(x);
  return true;
}

Eigen::Matrix<double, 7, 6, Eigen::RowMajor> SE3PlusJacobian(const double* x) {
  const Eigen::Quaterniond q = NormalizedQuaternion(x);
  Eigen::Matrix<double, 7, 6, Eigen::RowMajor> p =
      Eigen::Matrix<double, 7, 6, Eigen::RowMajor>::Zero();
  p.block<4, 3>(0, 3) = 0.5 * QuaternionLeftBlock(q);
  p.block<3, 3>(4, 0) = q.toRotationMatrix();
  return p;
}

Eigen::Matrix<double, 6, 7, Eigen::RowMajor> SE3MinusJacobian(const double* x) {
  const Eigen::Quaterniond q = NormalizedQuaternion(x);
  Eigen::Matrix<double, 6, 7, Eigen::RowMajor> m =
      Eigen::Matrix<double, 6, 7, Eigen::RowMajor>::Zero();
  m.block<3, 3>(0, 4) = q.toRotationMatrix().transpose();
  m.block<3, 4>(3, 0) = 2.0 * QuaternionLeftBlock(q).transpose();
  return m;
}

}  // namespace twist::optimization
