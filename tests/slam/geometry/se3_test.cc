// Group properties, exp/log edge cases and Jacobians of SO3/SE3 on many
// seeded random samples; derivatives checked against central differences.
#include "slam/geometry/se3.h"

#include <gtest/gtest.h>

#include <Eigen/Dense>
#include <cmath>
#include <functional>
#include <random>

#include "slam/geometry/so3.h"

namespace twist::geometry {
namespace {

constexpr double kPi = 3.14159265358979323846;
constexpr int kSamples = 200;

class Random {
 public:
  explicit Random(unsigned seed) : rng_(seed) {}
  double Uniform(double lo, double hi) {
    return std::uniform_real_distribution<double>(lo, hi)(rng_);
  }
  Eigen::Vector3d Vector(double scale) {
    return Eigen::Vector3d(Uniform(-scale, scale), Uniform(-scale, scale), Uniform(-scale, scale));
  }
  Eigen::Vector3d Direction() { return Vector(1.0).normalized(); }
  // Rotation vector with angle uniform in [0, max_angle].
  Eigen::Vector3d RotationVector(double max_angle) { return Uniform(0.0, max_angle) * Direction(); }
  Vector6d Twist(double translation_scale, double max_angle) {
    Vector6d xi;
    xi << Vector(translation_scale), RotationVector(max_angle);
    return xi;
  }
  SO3d Rotation() {
    Eigen::Quaterniond q(Uniform(-1, 1), Uniform(-1, 1), Uniform(-1, 1), Uniform(-1, 1));
    return SO3d(q);
  }
  SE3d Pose() { return SE3d(Rotation(), Vector(5.0)); }

 private:
  std::mt19937 rng_;
};

// exp of a 4x4 (or 3x3) matrix by scaling and squaring of the Taylor series:
// an independent reference for Exp.
template <typename Matrix>
Matrix MatrixExponential(const Matrix& a) {
  int squarings = 0;
  double norm = a.norm();
  while (norm > 0.1) {
    norm /= 2.0;
    ++squarings;
  }
  const Matrix scaled = a / std::pow(2.0, squarings);
  Matrix term = Matrix::Identity();
  Matrix sum = Matrix::Identity();
  for (int k = 1; k < 25; ++k) {
    term = term * scaled / static_cast<double>(k);
    sum += term;
  }
  for (int i = 0; i < squarings; ++i) sum = sum * sum;
  return sum;
}

// Central-difference Jacobian of f: R^n -> R^m at x.
template <int M, int N>
Eigen::Matrix<double, M, N> NumericJacobian(
    const std::function<Eigen::Matrix<double, M, 1>(const Eigen::Matrix<double, N, 1>&)>& f,
    const Eigen::Matrix<double, N, 1>& x,
    double h = 1e-6) {
  Eigen::Matrix<double, M, N> j;
  for (int i = 0; i < N; ++i) {
    Eigen::Matrix<double, N, 1> dx = Eigen::Matrix<double, N, 1>::Zero();
    dx[i] = h;
    j.col(i) = (f(x + dx) - f(x - dx)) / (2.0 * h);
  }
  return j;
}

double RotationDistance(const SO3d& a, const SO3d& b) { return (a.Inverse() * b).Log().norm(); }

// -------------------------------------------------------------------- SO3
TEST(SO3Test, HatVee) {
  Random random(1);
  for (int i = 0; i < kSamples; ++i) {
    const Eigen::Vector3d a = random.Vector(3.0), b = random.Vector(3.0);
    EXPECT_LT((SO3d::Hat(a) * b - a.cross(b)).norm(), 1e-12);
    EXPECT_EQ(SO3d::Vee(SO3d::Hat(a)), a);
    EXPECT_LT((SO3d::Hat(a) + SO3d::Hat(a).transpose()).norm(), 1e-15);
  }
}

TEST(SO3Test, ExpMatchesMatrixExponentialAndLogInvertsIt) {
  Random random(2);
  for (int i = 0; i < kSamples; ++i) {
    const Eigen::Vector3d omega = random.RotationVector(kPi - 1e-3);
    const SO3d r = SO3d::Exp(omega);
    EXPECT_LT((r.matrix() - MatrixExponential<Eigen::Matrix3d>(SO3d::Hat(omega))).norm(), 1e-12);
    EXPECT_NEAR(r.matrix().determinant(), 1.0, 1e-12);
    EXPECT_LT((r.matrix() * r.matrix().transpose() - Eigen::Matrix3d::Identity()).norm(), 1e-12);
    EXPECT_LT((r.Log() - omega).norm(), 1e-11);
  }
}

TEST(SO3Test, ExpLogNearZero) {
  Random random(3);
  for (double angle : {0.0, 1e-300, 1e-15, 1e-10, 1e-6, 1e-5, 1e-4, 1e-2, 0.0999, 0.1001}) {
    for (int i = 0; i < 20; ++i) {
      const Eigen::Vector3d omega = angle * random.Direction();
      const SO3d r = SO3d::Exp(omega);
      EXPECT_LE((r.Log() - omega).norm(), 1e-15 + 1e-13 * angle) << angle;
      EXPECT_LT((r.matrix() - MatrixExponential<Eigen::Matrix3d>(SO3d::Hat(omega))).norm(),
                1e-15 + 1e-13 * angle);
    }
  }
}

TEST(SO3Test, ExpLogNearAndAtPi) {
  Random random(4);
  for (double eps : {1e-3, 1e-6, 1e-9, 1e-12, 0.0}) {
    for (int i = 0; i < 20; ++i) {
      const Eigen::Vector3d axis = random.Direction();
      const Eigen::Vector3d omega = (kPi - eps) * axis;
      const SO3d r = SO3d::Exp(omega);
      const Eigen::Vector3d log = r.Log();
      EXPECT_LE(log.norm(), kPi + 1e-12);
      // Exp(Log(R)) == R always; Log(Exp(ω)) == ω below π, ±ω at exactly π.
      EXPECT_LT((SO3d::Exp(log).matrix() - r.matrix()).norm(), 1e-10) << eps;
      if (eps > 0.0) {
        EXPECT_LT((log - omega).norm(), 1e-9) << eps;
      } else {
        EXPECT_LT(std::min((log - omega).norm(), (log + omega).norm()), 1e-9);
      }
    }
  }
  // Rotation matrices of exactly π (diag(1,-1,-1) etc.).
  for (int k = 0; k < 3; ++k) {
    Eigen::Matrix3d m = -Eigen::Matrix3d::Identity();
    m(k, k) = 1.0;
    const Eigen::Vector3d log = SO3d(m).Log();
    EXPECT_NEAR(log.norm(), kPi, 1e-12);
    EXPECT_NEAR(std::abs(log[k]), kPi, 1e-12);
    EXPECT_LT((SO3d::Exp(log).matrix() - m).norm(), 1e-12);
  }
}

TEST(SO3Test, LogChoosesShortestRepresentative) {
  Random random(5);
  for (int i = 0; i < kSamples; ++i) {
    const SO3d r = random.Rotation();
    EXPECT_LE(r.Log().norm(), kPi + 1e-12);
    EXPECT_LT((SO3d::Exp(r.Log()).matrix() - r.matrix()).norm(), 1e-11);
    // -q is the same rotation and has the same log.
    const SO3d flipped(Eigen::Quaterniond(-r.unit_quaternion().coeffs()));
    EXPECT_LT((flipped.Log() - r.Log()).norm(), 1e-11);
  }
}

TEST(SO3Test, GroupAxioms) {
  Random random(6);
  for (int i = 0; i < kSamples; ++i) {
    const SO3d a = random.Rotation(), b = random.Rotation(), c = random.Rotation();
    EXPECT_LT((((a * b) * c).matrix() - (a * (b * c)).matrix()).norm(), 1e-12);
    EXPECT_LT(((a * a.Inverse()).matrix() - Eigen::Matrix3d::Identity()).norm(), 1e-12);
    EXPECT_LT(((a * b).matrix() - a.matrix() * b.matrix()).norm(), 1e-12);
    const Eigen::Vector3d p = random.Vector(5.0);
    EXPECT_LT((a * p - a.matrix() * p).norm(), 1e-12);
    EXPECT_LT((a.Adjoint() - a.matrix()).norm(), 1e-15);
    // R Exp(ω) Rᵀ = Exp(R ω).
    const Eigen::Vector3d omega = random.RotationVector(2.0);
    EXPECT_LT(
        ((a * SO3d::Exp(omega) * a.Inverse()).matrix() - SO3d::Exp(a.matrix() * omega).matrix())
            .norm(),
        1e-12);
  }
}

TEST(SO3Test, JacobiansMatchCentralDifferences) {
  Random random(7);
  for (double max_angle : {1e-4, 0.09, 0.11, 1.0, 3.0}) {
    for (int i = 0; i < 40; ++i) {
      const Eigen::Vector3d omega = max_angle * random.Direction() * random.Uniform(0.5, 1.0);
      const SO3d r = SO3d::Exp(omega);
      // J_l: Log(Exp(ω + δ) Exp(ω)⁻¹) ≈ J_l δ.
      const Eigen::Matrix3d jl = NumericJacobian<3, 3>(
          [&](const Eigen::Vector3d& d) {
            return Eigen::Vector3d((SO3d::Exp(omega + d) * r.Inverse()).Log());
          },
          Eigen::Vector3d::Zero());
      EXPECT_LT((SO3d::LeftJacobian(omega) - jl).norm(), 1e-8) << max_angle;
      // J_r: Log(Exp(ω)⁻¹ Exp(ω + δ)) ≈ J_r δ.
      const Eigen::Matrix3d jr = NumericJacobian<3, 3>(
          [&](const Eigen::Vector3d& d) {
            return Eigen::Vector3d((r.Inverse() * SO3d::Exp(omega + d)).Log());
          },
          Eigen::Vector3d::Zero());
      EXPECT_LT((SO3d::RightJacobian(omega) - jr).norm(), 1e-8);
      // Inverses: d Log(Exp(ε) R)/dε = J_l⁻¹, d Log(R Exp(ε))/dε = J_r⁻¹.
      const Eigen::Matrix3d jl_inv = NumericJacobian<3, 3>(
          [&](const Eigen::Vector3d& e) { return Eigen::Vector3d((SO3d::Exp(e) * r).Log()); },
          Eigen::Vector3d::Zero());
      EXPECT_LT((SO3d::LeftJacobianInverse(omega) - jl_inv).norm(), 1e-7);
      const Eigen::Matrix3d jr_inv = NumericJacobian<3, 3>(
          [&](const Eigen::Vector3d& e) { return Eigen::Vector3d((r * SO3d::Exp(e)).Log()); },
          Eigen::Vector3d::Zero());
      EXPECT_LT((SO3d::RightJacobianInverse(omega) - jr_inv).norm(), 1e-7);
      EXPECT_LT((SO3d::LeftJacobian(omega) * SO3d::LeftJacobianInverse(omega) -
                 Eigen::Matrix3d::Identity())
                    .norm(),
                1e-12);
    }
  }
}

TEST(SO3Test, Interpolation) {
  Random random(8);
  for (int i = 0; i < kSamples; ++i) {
    const SO3d a = random.Rotation();
    const SO3d b = a * SO3d::Exp(random.RotationVector(3.0));
    EXPECT_LT(RotationDistance(a.Interpolate(b, 0.0), a), 1e-12);
    EXPECT_LT(RotationDistance(a.Interpolate(b, 1.0), b), 1e-10);
    const double s = random.Uniform(0.0, 1.0);
    const SO3d m = a.Interpolate(b, s);
    EXPECT_NEAR(RotationDistance(a, m), s * RotationDistance(a, b), 1e-10);
    EXPECT_NEAR(RotationDistance(m, b), (1.0 - s) * RotationDistance(a, b), 1e-10);
  }
}

// -------------------------------------------------------------------- SE3
TEST(SE3Test, HatVeeAndExpMatchesMatrixExponential) {
  Random random(11);
  for (int i = 0; i < kSamples; ++i) {
    const Vector6d xi = random.Twist(3.0, kPi - 1e-3);
    EXPECT_LT((SE3d::Vee(SE3d::Hat(xi)) - xi).norm(), 1e-15);
    const Eigen::Matrix4d expected = MatrixExponential<Eigen::Matrix4d>(SE3d::Hat(xi));
    EXPECT_LT((SE3d::Exp(xi).matrix() - expected).norm(), 1e-11);
    EXPECT_LT((SE3d::Exp(xi).Log() - xi).norm(), 1e-10);
  }
}

TEST(SE3Test, ExpLogEdgeCases) {
  Random random(12);
  for (double angle :
       {0.0, 1e-300, 1e-12, 1e-8, 1e-5, 1e-3, 0.0999, 0.1001, 1.0, kPi - 1e-3, kPi - 1e-7}) {
    for (int i = 0; i < 20; ++i) {
      Vector6d xi;
      xi << random.Vector(3.0), angle * random.Direction();
      const SE3d t = SE3d::Exp(xi);
      EXPECT_LT((t.Log() - xi).norm(), 1e-12 + 1e-8 * angle) << angle;
      const Eigen::Matrix4d expected = MatrixExponential<Eigen::Matrix4d>(SE3d::Hat(xi));
      EXPECT_LT((t.matrix() - expected).norm(), 1e-11) << angle;
    }
  }
  // Exactly π: Exp(Log(T)) == T.
  for (int i = 0; i < 20; ++i) {
    Vector6d xi;
    xi << random.Vector(3.0), kPi * random.Direction();
    const SE3d t = SE3d::Exp(xi);
    EXPECT_LT((SE3d::Exp(t.Log()).matrix() - t.matrix()).norm(), 1e-9);
  }
}

TEST(SE3Test, GroupAxiomsAndParams) {
  Random random(13);
  for (int i = 0; i < kSamples; ++i) {
    const SE3d a = random.Pose(), b = random.Pose(), c = random.Pose();
    EXPECT_LT((((a * b) * c).matrix() - (a * (b * c)).matrix()).norm(), 1e-11);
    EXPECT_LT(((a * a.Inverse()).matrix() - Eigen::Matrix4d::Identity()).norm(), 1e-12);
    EXPECT_LT(((a.Inverse() * a).matrix() - Eigen::Matrix4d::Identity()).norm(), 1e-12);
    EXPECT_LT(((a * b).matrix() - a.matrix() * b.matrix()).norm(), 1e-11);
    const Eigen::Vector3d p = random.Vector(5.0);
    EXPECT_LT((a * p - (a.matrix() * p.homogeneous()).head<3>()).norm(), 1e-12);
    // 7-scalar parameter block and matrix round trips.
    double params[7];
    a.ToParams(params);
    EXPECT_LT((SE3d::FromParams(params).matrix() - a.matrix()).norm(), 1e-14);
    EXPECT_EQ(params[3], a.unit_quaternion().w());
    EXPECT_EQ(params[4], a.translation().x());
    EXPECT_LT((SE3d::FromMatrix(a.matrix()).matrix() - a.matrix()).norm(), 1e-12);
    EXPECT_LT((SE3d::FromMatrix3x4(a.matrix3x4()).matrix() - a.matrix()).norm(), 1e-12);
  }
}

// Products renormalised once are not always fixed points of Eigen's
// normalisation, so FromParams can change the last bits of a stored pose;
// FromParamsExact must not (saved sessions resume bit for bit).
TEST(SE3Test, FromParamsExactRestoresTheBits) {
  Random random(15);
  int renormalisation_changed_bits = 0;
  for (int i = 0; i < 2000; ++i) {
    const SE3d a = random.Pose() * random.Pose() * random.Pose();
    double p[7], q[7], r[7];
    a.ToParams(p);
    SE3d::FromParamsExact(p).ToParams(q);
    for (int k = 0; k < 7; ++k) ASSERT_EQ(q[k], p[k]) << "sample " << i << " param " << k;
    SE3d::FromParams(p).ToParams(r);
    for (int k = 0; k < 4; ++k) {
      if (r[k] != p[k]) {
        ++renormalisation_changed_bits;
        break;
      }
    }
  }
  // The case the exact variant exists for does occur.
  EXPECT_GT(renormalisation_changed_bits, 0);
}

TEST(SE3Test, AdjointIdentities) {
  Random random(14);
  for (int i = 0; i < kSamples; ++i) {
    const SE3d t = random.Pose(), u = random.Pose();
    const Vector6d xi = random.Twist(2.0, 2.5);
    // T Exp(ξ) T⁻¹ = Exp(Ad(T) ξ).
    EXPECT_LT(
        ((t * SE3d::Exp(xi) * t.Inverse()).matrix() - SE3d::Exp(t.Adjoint() * xi).matrix()).norm(),
        1e-10);
    // Hat form: T Hat(ξ) T⁻¹ = Hat(Ad ξ).
    EXPECT_LT(
        (t.matrix() * SE3d::Hat(xi) * t.Inverse().matrix() - SE3d::Hat(t.Adjoint() * xi)).norm(),
        1e-10);
    EXPECT_LT(((t * u).Adjoint() - t.Adjoint() * u.Adjoint()).norm(), 1e-10);
    EXPECT_LT((t.Inverse().Adjoint() - t.Adjoint().inverse()).norm(), 1e-10);
    // Paper eq. (adjoint): [[R, [t]x R], [0, R]].
    const Matrix6d ad = t.Adjoint();
    const Eigen::Matrix3d top_right = ad.topRightCorner<3, 3>();
    EXPECT_LT((top_right - SO3d::Hat(t.translation()) * t.rotation()).norm(), 1e-12);
    const Eigen::Matrix3d bottom_left = ad.bottomLeftCorner<3, 3>();
    EXPECT_EQ(bottom_left, Eigen::Matrix3d::Zero());
  }
}

TEST(SE3Test, JacobiansMatchCentralDifferences) {
  Random random(15);
  for (double max_angle : {0.0, 1e-5, 0.09, 0.11, 1.0, 3.0}) {
    for (int i = 0; i < 40; ++i) {
      const Vector6d xi = random.Twist(3.0, max_angle);
      const SE3d t = SE3d::Exp(xi);
      const Matrix6d jl = NumericJacobian<6, 6>(
          [&](const Vector6d& d) { return Vector6d((SE3d::Exp(xi + d) * t.Inverse()).Log()); },
          Vector6d::Zero());
      EXPECT_LT((SE3d::LeftJacobian(xi) - jl).norm(), 1e-7) << max_angle;
      const Matrix6d jr = NumericJacobian<6, 6>(
          [&](const Vector6d& d) { return Vector6d((t.Inverse() * SE3d::Exp(xi + d)).Log()); },
          Vector6d::Zero());
      EXPECT_LT((SE3d::RightJacobian(xi) - jr).norm(), 1e-7) << max_angle;
      const Matrix6d jl_inv = NumericJacobian<6, 6>(
          [&](const Vector6d& e) { return Vector6d((SE3d::Exp(e) * t).Log()); }, Vector6d::Zero());
      EXPECT_LT((SE3d::LeftJacobianInverse(xi) - jl_inv).norm(), 1e-7) << max_angle;
      const Matrix6d jr_inv = NumericJacobian<6, 6>(
          [&](const Vector6d& e) { return Vector6d((t * SE3d::Exp(e)).Log()); }, Vector6d::Zero());
      EXPECT_LT((SE3d::RightJacobianInverse(xi) - jr_inv).norm(), 1e-7) << max_angle;
      EXPECT_LT(
          (SE3d::LeftJacobian(xi) * SE3d::LeftJacobianInverse(xi) - Matrix6d::Identity()).norm(),
          1e-12);
      // J_l(ξ) = Ad(Exp ξ) J_r(ξ).
      EXPECT_LT((SE3d::LeftJacobian(xi) - t.Adjoint() * SE3d::RightJacobian(xi)).norm(), 1e-11);
      // d(Exp(ξ) p)/dξ = [I, −[Exp(ξ)p]x] J_l(ξ) (used by the twist costs).
      const Eigen::Vector3d p = random.Vector(4.0);
      Eigen::Matrix<double, 3, 6> point_jac;
      point_jac << Eigen::Matrix3d::Identity(), -SO3d::Hat(t * p);
      const Eigen::Matrix<double, 3, 6> numeric = NumericJacobian<3, 6>(
          [&](const Vector6d& x) { return Eigen::Vector3d(SE3d::Exp(x) * p); }, xi);
      EXPECT_LT((point_jac * SE3d::LeftJacobian(xi) - numeric).norm(), 1e-7);
    }
  }
}

// The Jacobian coefficients stay accurate in the range where the closed forms
// cancel catastrophically: compare with J_l = ∫₀¹ Ad(Exp(sξ)) ds (Simpson).
TEST(SE3Test, LeftJacobianAccurateForSmallRotations) {
  Random random(16);
  for (double angle : {1e-5, 1e-4, 1e-3, 0.05, 0.0999, 0.1001, 0.5}) {
    Vector6d xi;
    xi << random.Vector(3.0), angle * random.Direction();
    Matrix6d integral = Matrix6d::Zero();
    const int n = 2000;
    for (int k = 0; k <= n; ++k) {
      const double w = (k == 0 || k == n) ? 1.0 : (k % 2 == 1 ? 4.0 : 2.0);
      integral += w * SE3d::Exp((static_cast<double>(k) / n) * xi).Adjoint();
    }
    integral /= 3.0 * n;
    EXPECT_LT((SE3d::LeftJacobian(xi) - integral).norm(), 1e-12) << angle;
  }
}

TEST(SE3Test, Interpolation) {
  Random random(17);
  for (int i = 0; i < kSamples; ++i) {
    const SE3d a = random.Pose();
    const Vector6d xi = random.Twist(2.0, 3.0);
    const SE3d b = a * SE3d::Exp(xi);
    EXPECT_LT((a.Interpolate(b, 0.0).matrix() - a.matrix()).norm(), 1e-12);
    EXPECT_LT((a.Interpolate(b, 1.0).matrix() - b.matrix()).norm(), 1e-9);
    const double s = random.Uniform(0.0, 1.0);
    EXPECT_LT((a.Interpolate(b, s).matrix() - (a * SE3d::Exp(s * xi)).matrix()).norm(), 1e-9);
  }
}

}  // namespace
}  // namespace twist::geometry
