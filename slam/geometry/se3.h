// SE(3), templated on the scalar so that ceres::Jet flows through.
//
// Project-wide conventions (DESIGN.md §3, STYLE.md §2.4):
//  - Twists ξ = (v, ω): translation FIRST, as in the TwistSLAM paper.
//    Hat(ξ) = [[ [ω]x, v ], [0, 0]].
//  - Poses are named by their frames: `b_from_a` maps points in frame a to
//    frame b: p_in_b = b_from_a * p_in_a; d_from_a = d_from_c * c_from_a.
//  - Adjoint for this ordering: Ad(T) = [[R, [t]x R], [0, R]], so that
//    T Exp(ξ) T⁻¹ = Exp(Ad(T) ξ).
//  - Right perturbation on manifolds: T ⊞ δ = T · Exp(δ).
//  - Ceres parameter blocks store a pose as 7 scalars [qx, qy, qz, qw, tx, ty, tz]
//    (Hamilton quaternion in Eigen's coeffs() order, then translation).
//  - SI units, radians; timestamps elsewhere are int64 nanoseconds.
#pragma once

#include <Eigen/Core>
#include <Eigen/Geometry>

#include "slam/geometry/so3.h"

namespace twist::geometry {

template <typename T>
class SE3 {
 public:
  using Scalar = T;
  using Vector3 = Eigen::Matrix<T, 3, 1>;
  using Vector6 = Eigen::Matrix<T, 6, 1>;
  using Matrix3 = Eigen::Matrix<T, 3, 3>;
  using Matrix4 = Eigen::Matrix<T, 4, 4>;
  using Matrix6 = Eigen::Matrix<T, 6, 6>;
  using Matrix34 = Eigen::Matrix<T, 3, 4>;
  using Quaternion = Eigen::Quaternion<T>;

  static constexpr int kNumParameters = 7;  // [qx qy qz qw tx ty tz]
  static constexpr int kDoF = 6;

  SE3() : t_(Vector3::Zero()) {}
  SE3(const SO3<T>& so3, const Vector3& t) : so3_(so3), t_(t) {}
  SE3(const Quaternion& q, const Vector3& t) : so3_(q), t_(t) {}
  SE3(const Matrix3& R, const Vector3& t) : so3_(R), t_(t) {}
  // From a 4x4 homogeneous matrix or a 3x4 [R|t].
  static SE3 FromMatrix(const Matrix4& m) {
    return SE3(Matrix3(m.template topLeftCorner<3, 3>()),
               Vector3(m.template topRightCorner<3, 1>()));
  }
  static SE3 FromMatrix3x4(const Matrix34& m) {
    return SE3(Matrix3(m.template leftCols<3>()), Vector3(m.col(3)));
  }
  // From / to a 7-scalar Ceres parameter block.
  static SE3 FromParams(const T* p) {
    return SE3(Quaternion(p[3], p[0], p[1], p[2]), Vector3(p[4], p[5], p[6]));
  }
  // FromParams without renormalising the quaternion (SO3::FromUnitQuaternionExact):
  // FromParamsExact(p).ToParams(q) gives q == p bit for bit. For parameters
  // that ToParams wrote; the quaternion must already be unit.
  static SE3 FromParamsExact(const T* p) {
    return SE3(SO3<T>::FromUnitQuaternionExact(Quaternion(p[3], p[0], p[1], p[2])),
               Vector3(p[4], p[5], p[6]));
  }
  void ToParams(T* p) const {
    const Quaternion& q = so3_.unit_quaternion();
    p[0] = q.x();
    p[1] = q.y();
    p[2] = q.z();
    p[3] = q.w();
    p[4] = t_.x();
    p[5] = t_.y();
    p[6] = t_.z();
  }

  static SE3 Identity() { return SE3(); }

  // Exponential map: ξ = (v, ω) -> [Exp(ω), J_l(ω) v].
  static SE3 Exp(const Vector6& xi) {
    const Vector3 v = xi.template head<3>();
    const Vector3 omega = xi.template tail<3>();
    return SE3(SO3<T>::Exp(omega), SO3<T>::LeftJacobian(omega) * v);
  }

  // Logarithm: (v, ω) with ω = Log(R), v = J_l(ω)⁻¹ t.
  Vector6 Log() const {
    const Vector3 omega = so3_.Log();
    Vector6 xi;
    xi.template head<3>() = SO3<T>::LeftJacobianInverse(omega) * t_;
    xi.template tail<3>() = omega;
    return xi;
  }

  static Matrix4 Hat(const Vector6& xi) {
    Matrix4 m = Matrix4::Zero();
    m.template topLeftCorner<3, 3>() = SO3<T>::Hat(xi.template tail<3>());
    m.template topRightCorner<3, 1>() = xi.template head<3>();
    return m;
  }
  static Vector6 Vee(const Matrix4& m) {
    Vector6 xi;
    xi.template head<3>() = m.template topRightCorner<3, 1>();
    xi.template tail<3>() = SO3<T>::Vee(m.template topLeftCorner<3, 3>());
    return xi;
  }

  SE3 Inverse() const {
    const SO3<T> r_inv = so3_.Inverse();
    return SE3(r_inv, -(r_inv * t_));
  }
  SE3 operator*(const SE3& other) const { return SE3(so3_ * other.so3_, so3_ * other.t_ + t_); }
  Vector3 operator*(const Vector3& p) const { return so3_ * p + t_; }

  // Ad(T) = [[R, [t]x R], [0, R]] for (v, ω) ordering.
  Matrix6 Adjoint() const {
    const Matrix3 R = so3_.matrix();
    Matrix6 ad = Matrix6::Zero();
    ad.template topLeftCorner<3, 3>() = R;
    ad.template topRightCorner<3, 3>() = SO3<T>::Hat(t_) * R;
    ad.template bottomRightCorner<3, 3>() = R;
    return ad;
  }

  // Left Jacobian of SE(3) for (v, ω) ordering:
  //   Exp(ξ + δ) ≈ Exp(J_l(ξ) δ) Exp(ξ).
  // J_l = [[J_l(ω), Q(v, ω)], [0, J_l(ω)]] with Q the classic Barfoot block.
  static Matrix6 LeftJacobian(const Vector6& xi) {
    const Vector3 omega = xi.template tail<3>();
    const Matrix3 Jl = SO3<T>::LeftJacobian(omega);
    Matrix6 J = Matrix6::Zero();
    J.template topLeftCorner<3, 3>() = Jl;
    J.template bottomRightCorner<3, 3>() = Jl;
    J.template topRightCorner<3, 3>() = QBlock(xi);
    return J;
  }
  // Right Jacobian: Exp(ξ + δ) ≈ Exp(ξ) Exp(J_r(ξ) δ); J_r(ξ) = J_l(-ξ).
  static Matrix6 RightJacobian(const Vector6& xi) { return LeftJacobian(-xi); }

  static Matrix6 LeftJacobianInverse(const Vector6& xi) {
    const Vector3 omega = xi.template tail<3>();
    const Matrix3 Jl_inv = SO3<T>::LeftJacobianInverse(omega);
    Matrix6 J = Matrix6::Zero();
    J.template topLeftCorner<3, 3>() = Jl_inv;
    J.template bottomRightCorner<3, 3>() = Jl_inv;
    J.template topRightCorner<3, 3>() = -Jl_inv * QBlock(xi) * Jl_inv;
    return J;
  }
  static Matrix6 RightJacobianInverse(const Vector6& xi) { return LeftJacobianInverse(-xi); }

  // Geodesic interpolation with right increments: this · Exp(s · Log(this⁻¹ other)).
  SE3 Interpolate(const SE3& other, const T& s) const {
    return (*this) * Exp(s * (Inverse() * other).Log());
  }

  Matrix4 matrix() const {
    Matrix4 m = Matrix4::Identity();
    m.template topLeftCorner<3, 3>() = so3_.matrix();
    m.template topRightCorner<3, 1>() = t_;
    return m;
  }
  Matrix34 matrix3x4() const {
    Matrix34 m;
    m.template leftCols<3>() = so3_.matrix();
    m.col(3) = t_;
    return m;
  }

  const SO3<T>& so3() const { return so3_; }
  SO3<T>& so3() { return so3_; }
  Matrix3 rotation() const { return so3_.matrix(); }
  const Quaternion& unit_quaternion() const { return so3_.unit_quaternion(); }
  const Vector3& translation() const { return t_; }
  Vector3& translation() { return t_; }

  template <typename U>
  SE3<U> cast() const {
    return SE3<U>(so3_.template cast<U>(), t_.template cast<U>());
  }

 private:
  // Q(v, ω) of the SE(3) left Jacobian (Barfoot, "State Estimation for
  // Robotics", eq. 7.86), written for twist ordering (v, ω).
  static Matrix3 QBlock(const Vector6& xi) {
    using std::cos;
    using std::sin;
    using std::sqrt;
    const Vector3 v = xi.template head<3>();
    const Vector3 omega = xi.template tail<3>();
    const Matrix3 V = SO3<T>::Hat(v);
    const Matrix3 W = SO3<T>::Hat(omega);
    const T theta_sq = omega.squaredNorm();
    T c1, c2, c3;
    if (theta_sq < T(SmallAngle<T>::kJacobianThetaSq)) {
      // Series to θ⁸: the closed forms below lose ~ε/θ⁴ relative accuracy.
      const T t2 = theta_sq;
      c1 = T(1.0 / 6.0) -
           t2 * (T(1.0 / 120.0) -
                 t2 * (T(1.0 / 5040.0) - t2 * (T(1.0 / 362880.0) - t2 / T(39916800.0))));
      c2 = T(1.0 / 24.0) -
           t2 * (T(1.0 / 720.0) -
                 t2 * (T(1.0 / 40320.0) - t2 * (T(1.0 / 3628800.0) - t2 / T(479001600.0))));
      c3 = T(1.0 / 120.0) -
           t2 * (T(2.0 / 5040.0) - t2 * (T(3.0 / 362880.0) -
                                         t2 * (T(4.0 / 39916800.0) - t2 * T(5.0 / 6227020800.0))));
    } else {
      const T theta = sqrt(theta_sq);
      const T s = sin(theta);
      const T c = cos(theta);
      c1 = (theta - s) / (theta_sq * theta);
      c2 = (theta_sq + T(2.0) * c - T(2.0)) / (T(2.0) * theta_sq * theta_sq);
      c3 = (T(2.0) * theta - T(3.0) * s + theta * c) / (T(2.0) * theta_sq * theta_sq * theta);
    }
    const Matrix3 WV = W * V;
    const Matrix3 VW = V * W;
    const Matrix3 WVW = WV * W;
    return T(0.5) * V + c1 * (WV + VW + WVW) + c2 * (W * WV + VW * W - T(3.0) * WVW) +
           c3 * (WVW * W + W * WVW);
  }

  SO3<T> so3_;
  Vector3 t_;
};

using SE3d = SE3<double>;
using Vector6d = Eigen::Matrix<double, 6, 1>;
using Matrix6d = Eigen::Matrix<double, 6, 6>;

}  // namespace twist::geometry
