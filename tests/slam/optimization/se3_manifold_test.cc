#include "slam/optimization/manifolds/se3_manifold.h"

#include <gtest/gtest.h>

#include <Eigen/Core>
#include <random>

#include "ceres/manifold_test_utils.h"
#include "slam/geometry/se3.h"

namespace twist::optimization {
namespace {

using geometry::SE3d;
using geometry::Vector6d;
// Names EXPECT_THAT_MANIFOLD_INVARIANTS_HOLD expects unqualified.
using ceres::HasCorrectMinusJacobianAt;
using ceres::HasCorrectPlusJacobianAt;
using ceres::HasCorrectRightMultiplyByPlusJacobianAt;
using ceres::MinusPlusIsIdentityAt;
using ceres::MinusPlusJacobianIsIdentityAt;
using ceres::PlusMinusIsIdentityAt;
using ceres::Vector;
using ceres::XMinusXIsZeroAt;
using ceres::XPlusZeroIsXAt;

Vector6d RandomTwist(std::mt19937& rng, double scale) {
  std::uniform_real_distribution<double> u(-1.0, 1.0);
  Vector6d xi;
  for (int i = 0; i < 6; ++i) xi[i] = scale * u(rng);
  return xi;
}

Vector Params(const SE3d& pose) {
  Vector p(7);
  pose.ToParams(p.data());
  return p;
}

TEST(SE3ManifoldTest, InvariantsHoldAtRandomPoints) {
  std::mt19937 rng(42);
  const SE3Manifold manifold;
  for (int trial = 0; trial < 200; ++trial) {
    const Vector x = Params(SE3d::Exp(RandomTwist(rng, 2.0)));
    // |ω| < π so that Minus(Plus(x, δ), x) == δ.
    const Vector delta = RandomTwist(rng, 1.5);
    Vector y = Params(SE3d::Exp(RandomTwist(rng, 2.0)));
    if (trial % 2 == 1) y.head<4>() = -y.head<4>();  // other hemisphere of the cover
    EXPECT_THAT_MANIFOLD_INVARIANTS_HOLD(manifold, x, delta, y, 1e-8);
  }
}

TEST(SE3ManifoldTest, InvariantsHoldNearIdentityAndHalfTurn) {
  const SE3Manifold manifold;
  const double pi = 3.14159265358979323846;
  std::mt19937 rng(7);
  for (double angle : {0.0, 1e-9, 1e-5, pi - 1e-6, pi}) {
    Vector6d xi = RandomTwist(rng, 1.0);
    xi.tail<3>() = angle * xi.tail<3>().normalized();
    const Vector x = Params(SE3d::Exp(xi));
    const Vector delta = RandomTwist(rng, 0.3);
    const Vector y = Params(SE3d::Exp(xi) * SE3d::Exp(RandomTwist(rng, 0.5)));
    EXPECT_THAT_MANIFOLD_INVARIANTS_HOLD(manifold, x, delta, y, 1e-8);
  }
}

TEST(SE3ManifoldTest, PlusIsRightMultiplicationByExp) {
  std::mt19937 rng(3);
  const SE3Manifold manifold;
  for (int trial = 0; trial < 50; ++trial) {
    const SE3d pose = SE3d::Exp(RandomTwist(rng, 2.0));
    const Vector6d delta = RandomTwist(rng, 1.0);
    const Vector x = Params(pose);
    Eigen::Matrix<double, 7, 1> out;
    ASSERT_TRUE(manifold.Plus(x.data(), delta.data(), out.data()));
    const SE3d expected = pose * SE3d::Exp(delta);
    EXPECT_LT((SE3d::FromParams(out.data()).matrix() - expected.matrix()).norm(), 1e-12);
  }
}

TEST(SE3ManifoldTest, MinusJacobianIsPseudoInverseOfPlusJacobian) {
  std::mt19937 rng(5);
  for (int trial = 0; trial < 50; ++trial) {
    const Vector x = Params(SE3d::Exp(RandomTwist(rng, 2.0)));
    const Eigen::Matrix<double, 7, 6> p = SE3PlusJacobian(x.data());
    const Eigen::Matrix<double, 6, 7> m = SE3MinusJacobian(x.data());
    const Eigen::Matrix<double, 6, 7> pinv = (p.transpose() * p).inverse() * p.transpose();
    EXPECT_LT((m - pinv).norm(), 1e-12);
    // LocalToAmbient followed by Ceres's right multiplication recovers the local Jacobian.
    const Eigen::Matrix<double, 2, 6> local = Eigen::Matrix<double, 2, 6>::Random();
    Eigen::Matrix<double, 2, 7, Eigen::RowMajor> ambient;
    SE3LocalToAmbientJacobian<2>(x.data(), local, ambient.data());
    EXPECT_LT((ambient * p - local).norm(), 1e-12);
  }
}

}  // namespace
}  // namespace twist::optimization
