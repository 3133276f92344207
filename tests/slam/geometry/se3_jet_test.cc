// SE3/SO3 with ceres::Jet: the templates compile for Jets and their automatic
// derivatives equal the closed-form Jacobians, including at ξ = 0 exactly
// (where the small-angle branches are taken).
#include <gtest/gtest.h>

#include <Eigen/Core>
#include <random>

#include "ceres/jet.h"
#include "slam/geometry/se3.h"
#include "slam/geometry/so3.h"

namespace twist::geometry {
namespace {

using Jet6 = ceres::Jet<double, 6>;
using Vector6J = Eigen::Matrix<Jet6, 6, 1>;
using Vector3J = Eigen::Matrix<Jet6, 3, 1>;

Vector6J Seed(const Vector6d& x) {
  Vector6J j;
  for (int i = 0; i < 6; ++i) j[i] = Jet6(x[i], i);
  return j;
}

template <int M>
Eigen::Matrix<double, M, 6> Derivative(const Eigen::Matrix<Jet6, M, 1>& y) {
  Eigen::Matrix<double, M, 6> d;
  for (int r = 0; r < M; ++r) d.row(r) = y[r].v.transpose();
  return d;
}

template <int M>
Eigen::Matrix<double, M, 1> Value(const Eigen::Matrix<Jet6, M, 1>& y) {
  Eigen::Matrix<double, M, 1> v;
  for (int r = 0; r < M; ++r) v[r] = y[r].a;
  return v;
}

std::vector<Vector6d> Samples() {
  std::mt19937 rng(99);
  std::uniform_real_distribution<double> u(-1.0, 1.0);
  std::vector<Vector6d> out = {Vector6d::Zero()};
  for (double scale : {1e-7, 1e-3, 0.05, 0.5, 1.5}) {
    for (int i = 0; i < 10; ++i) {
      Vector6d xi;
      for (int k = 0; k < 6; ++k) xi[k] = u(rng);
      xi.tail<3>() *= scale;
      xi.head<3>() *= 3.0;
      out.push_back(xi);
    }
  }
  return out;
}

TEST(SE3JetTest, ExpActionDerivativeIsPointJacobianTimesLeftJacobian) {
  const Eigen::Vector3d p(0.7, -1.2, 2.5);
  for (const Vector6d& xi : Samples()) {
    const Vector3J y = SE3<Jet6>::Exp(Seed(xi)) * p.cast<Jet6>();
    const Eigen::Vector3d moved = SE3d::Exp(xi) * p;
    EXPECT_LT((Value<3>(y) - moved).norm(), 1e-12);
    Eigen::Matrix<double, 3, 6> expected;
    expected << Eigen::Matrix3d::Identity(), -SO3d::Hat(moved);
    expected = expected * SE3d::LeftJacobian(xi);
    EXPECT_LT((Derivative<3>(y) - expected).norm(), 1e-10) << xi.transpose();
  }
}

TEST(SE3JetTest, LogOfRightPerturbationHasInverseRightJacobian) {
  for (const Vector6d& xi : Samples()) {
    const SE3<Jet6> t = SE3d::Exp(xi).cast<Jet6>();
    // d Log(T Exp(δ))/dδ at δ = 0 is J_r⁻¹(Log T).
    const Vector6J log = (t * SE3<Jet6>::Exp(Seed(Vector6d::Zero()))).Log();
    EXPECT_LT((Value<6>(log) - xi).norm(), 1e-10);
    EXPECT_LT((Derivative<6>(log) - SE3d::RightJacobianInverse(xi)).norm(), 1e-9) << xi.transpose();
    // And d Log(Exp(δ) T)/dδ = J_l⁻¹.
    const Vector6J log_left = (SE3<Jet6>::Exp(Seed(Vector6d::Zero())) * t).Log();
    EXPECT_LT((Derivative<6>(log_left) - SE3d::LeftJacobianInverse(xi)).norm(), 1e-9);
  }
}

TEST(SE3JetTest, ComposeInverseParamsAndAdjointWithJets) {
  const Vector6d a(0.3, -0.2, 1.0, 0.4, -0.1, 0.7);
  const Vector6d b(-1.0, 0.5, 0.2, -0.3, 0.8, 0.05);
  const SE3<Jet6> ta = SE3<Jet6>::Exp(Seed(a));
  const SE3<Jet6> tb = SE3d::Exp(b).cast<Jet6>();
  Jet6 params[7];
  (ta * tb).Inverse().ToParams(params);
  const SE3<Jet6> back = SE3<Jet6>::FromParams(params);
  const Eigen::Matrix<Jet6, 4, 4> m = back.matrix();
  const Eigen::Matrix4d expected = (SE3d::Exp(a) * SE3d::Exp(b)).Inverse().matrix();
  for (int r = 0; r < 4; ++r)
    for (int c = 0; c < 4; ++c) EXPECT_NEAR(m(r, c).a, expected(r, c), 1e-12);
  // Adjoint and interpolation instantiate for Jets.
  const Eigen::Matrix<Jet6, 6, 6> ad = ta.Adjoint();
  EXPECT_NEAR(ad(0, 0).a, SE3d::Exp(a).Adjoint()(0, 0), 1e-12);
  const SE3<Jet6> mid = ta.Interpolate(tb, Jet6(0.5));
  EXPECT_TRUE(std::isfinite(mid.translation().x().a));
  // d(SO3 Exp)/dω at ω = 0 of the rotated vector is −[p]x.
  const Eigen::Matrix<Jet6, 3, 1> omega(Jet6(0.0, 3), Jet6(0.0, 4), Jet6(0.0, 5));
  const Eigen::Vector3d p(1.0, 2.0, 3.0);
  const Vector3J rp = SO3<Jet6>::Exp(omega) * p.cast<Jet6>();
  const Eigen::Matrix<double, 3, 6> d = Derivative<3>(rp);
  EXPECT_LT((d.rightCols<3>() + SO3d::Hat(p)).norm(), 1e-12);
  EXPECT_LT(d.leftCols<3>().norm(), 1e-15);
}

}  // namespace
}  // namespace twist::geometry
