// SO(3), templated on the scalar so that ceres::Jet flows through.
//
// Conventions (the whole project follows them; see also se3.h):
//  - Rotations are stored as unit Hamilton quaternions (Eigen), w >= 0 is NOT
//    enforced on storage but Log() picks the shortest representative.
//  - Exp/Log map between so(3) (rotation vectors, radians) and SO(3).
//  - Right perturbation on manifolds: R ⊞ δ = R · Exp(δ).
//  - Hat(a) is the skew-symmetric matrix [a]_x with Hat(a) b = a × b.
#pragma once

#include <Eigen/Core>
#include <Eigen/Geometry>
#include <cmath>

namespace twist::geometry {

// Thresholds below which closed forms are replaced by Taylor expansions.
// Chosen so that the truncation error of the series (O(θ^4) relative) is far
// below double precision epsilon at the switch point.
template <typename T>
struct SmallAngle {
  static constexpr double kThetaSq = 1e-10;
  // The Jacobian coefficients ((1 - cos θ)/θ², (θ - sin θ)/θ³, ...) cancel
  // catastrophically well above kThetaSq (relative error ~ ε/θ⁴ for the
  // fourth-order ones), so they switch to their series (to θ⁸, truncation
  // < 1e-18 here) below θ = 0.1.
  static constexpr double kJacobianThetaSq = 1e-2;
};

template <typename T>
class SO3 {
 public:
  using Scalar = T;
  using Vector3 = Eigen::Matrix<T, 3, 1>;
  using Matrix3 = Eigen::Matrix<T, 3, 3>;
  using Quaternion = Eigen::Quaternion<T>;

  SO3() : q_(Quaternion::Identity()) {}
  explicit SO3(const Quaternion& q) : q_(q.normalized()) {}
  // Builds from a rotation matrix (assumed orthonormal up to round-off; the
  // quaternion is renormalised, which re-orthonormalises the rotation).
  explicit SO3(const Matrix3& R) : q_(Quaternion(R).normalized()) {}

  static SO3 Identity() { return SO3(); }

  // Adopts a quaternion that is already unit to round-off as it is, without
  // renormalising: a rotation written out with unit_quaternion() comes back
  // bit for bit (normalising again can change the last bits). The caller
  // guarantees the norm (e.g. checks it when reading a file).
  static SO3 FromUnitQuaternionExact(const Quaternion& q) {
    SO3 r;
    r.q_ = q;
    return r;
  }

  // Exponential map: rotation vector ω (angle θ = |ω| about ω/θ) -> rotation.
  static SO3 Exp(const Vector3& omega) {
    using std::cos;
    using std::sin;
    using std::sqrt;
    const T theta_sq = omega.squaredNorm();
    T real;
    T imag_factor;
    if (theta_sq < T(SmallAngle<T>::kThetaSq)) {
      // sin(θ/2)/θ ≈ 1/2 - θ²/48, cos(θ/2) ≈ 1 - θ²/8.
      imag_factor = T(0.5) - theta_sq / T(48.0);
      real = T(1.0) - theta_sq / T(8.0);
    } else {
      const T theta = sqrt(theta_sq);
      const T half = T(0.5) * theta;
      imag_factor = sin(half) / theta;
      real = cos(half);
    }
    SO3 out;
    out.q_ =
        Quaternion(real, imag_factor * omega.x(), imag_factor * omega.y(), imag_factor * omega.z());
    return out;
  }

  // Logarithm: rotation -> rotation vector with angle in [0, π]. Uses atan2 on
  // the quaternion, which stays accurate near 0 and near π.
  Vector3 Log() const {
    using std::atan2;
    using std::sqrt;
    Quaternion q = q_;
    if (q.w() < T(0)) q.coeffs() = -q.coeffs();  // shortest path
    const Vector3 imag = q.vec();
    const T sin_sq = imag.squaredNorm();
    T factor;
    if (sin_sq < T(SmallAngle<T>::kThetaSq)) {
      // θ = 2 atan(s/w) ≈ 2 s/w (1 - s²/(3w²)); factor = θ/s.
      const T w = q.w();
      factor = T(2.0) / w - T(2.0 / 3.0) * sin_sq / (w * w * w);
    } else {
      const T s = sqrt(sin_sq);
      factor = T(2.0) * atan2(s, q.w()) / s;
    }
    return factor * imag;
  }

  static Matrix3 Hat(const Vector3& a) {
    Matrix3 m;
    m << T(0), -a.z(), a.y(), a.z(), T(0), -a.x(), -a.y(), a.x(), T(0);
    return m;
  }
  static Vector3 Vee(const Matrix3& m) { return Vector3(m(2, 1), m(0, 2), m(1, 0)); }

  SO3 Inverse() const {
    SO3 out;
    out.q_ = q_.conjugate();
    return out;
  }
  SO3 operator*(const SO3& other) const {
    SO3 out;
    out.q_ = q_ * other.q_;
    // Keep the quaternion on the unit sphere over long products.
    out.q_.normalize();
    return out;
  }
  Vector3 operator*(const Vector3& p) const { return q_ * p; }

  Matrix3 matrix() const { return q_.toRotationMatrix(); }
  const Quaternion& unit_quaternion() const { return q_; }
  // Adjoint of SO(3) is the rotation matrix itself.
  Matrix3 Adjoint() const { return matrix(); }

  // Left Jacobian J_l(ω): Exp(ω + δ) ≈ Exp(J_l(ω) δ) Exp(ω).
  static Matrix3 LeftJacobian(const Vector3& omega) {
    using std::cos;
    using std::sin;
    using std::sqrt;
    const T theta_sq = omega.squaredNorm();
    const Matrix3 W = Hat(omega);
    T a, b;  // J_l = I + a W + b W²
    if (theta_sq < T(SmallAngle<T>::kJacobianThetaSq)) {
      const T t2 = theta_sq;
      a = T(1.0 / 2.0) - t2 * (T(1.0 / 24.0) -
                               t2 * (T(1.0 / 720.0) - t2 * (T(1.0 / 40320.0) - t2 / T(3628800.0))));
      b = T(1.0 / 6.0) - t2 * (T(1.0 / 120.0) - t2 * (T(1.0 / 5040.0) - t2 * (T(1.0 / 362880.0) -
                                                                              t2 / T(39916800.0))));
    } else {
      const T theta = sqrt(theta_sq);
      a = (T(1.0) - cos(theta)) / theta_sq;
      b = (theta - sin(theta)) / (theta_sq * theta);
    }
    return Matrix3::Identity() + a * W + b * W * W;
  }
  // Right Jacobian J_r(ω) = J_l(-ω): Exp(ω + δ) ≈ Exp(ω) Exp(J_r(ω) δ).
  static Matrix3 RightJacobian(const Vector3& omega) { return LeftJacobian(-omega); }

  static Matrix3 LeftJacobianInverse(const Vector3& omega) {
    using std::cos;
    using std::sin;
    using std::sqrt;
    const T theta_sq = omega.squaredNorm();
    const Matrix3 W = Hat(omega);
    T c;  // J_l^{-1} = I - W/2 + c W²
    if (theta_sq < T(SmallAngle<T>::kJacobianThetaSq)) {
      const T t2 = theta_sq;
      c = T(1.0 / 12.0) +
          t2 * (T(1.0 / 720.0) +
                t2 * (T(1.0 / 30240.0) + t2 * (T(1.0 / 1209600.0) + t2 / T(47900160.0))));
    } else {
      const T theta = sqrt(theta_sq);
      // (1 + cos θ) / (2 θ sin θ) written as cot(θ/2) / (2θ): finite at θ = π.
      const T half = T(0.5) * theta;
      c = T(1.0) / theta_sq - cos(half) / (T(2.0) * theta * sin(half));
    }
    return Matrix3::Identity() - T(0.5) * W + c * W * W;
  }
  static Matrix3 RightJacobianInverse(const Vector3& omega) { return LeftJacobianInverse(-omega); }

  // Geodesic interpolation: this · Exp(s · Log(this⁻¹ · other)), s ∈ [0, 1].
  SO3 Interpolate(const SO3& other, const T& s) const {
    return (*this) * Exp(s * (Inverse() * other).Log());
  }

  template <typename U>
  SO3<U> cast() const {
    SO3<U> out(q_.template cast<U>());
    return out;
  }

 private:
  Quaternion q_;
};

using SO3d = SO3<double>;

}  // namespace twist::geometry
