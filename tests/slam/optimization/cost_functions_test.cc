// Every cost family: analytic == autodiff (residuals and tangent-space
// Jacobians) and both == finite differences (ceres::GradientChecker) at many
// seeded random points.
#include <gtest/gtest.h>

#include <Eigen/Core>
#include <algorithm>
#include <memory>
#include <random>
#include <vector>

#include "ceres/gradient_checker.h"
#include "ceres/manifold.h"
#include "slam/geometry/se3.h"
#include "slam/geometry/stereo_camera.h"
#include "slam/optimization/cost_functions/constant_velocity_cost.h"
#include "slam/optimization/cost_functions/dynamic_reprojection_cost.h"
#include "slam/optimization/cost_functions/reprojection_cost.h"
#include "slam/optimization/cost_functions/twist_tracking_cost.h"
#include "slam/optimization/manifolds/se3_manifold.h"

namespace twist::optimization {
namespace {

using Eigen::MatrixXd;
using Eigen::VectorXd;
using geometry::Matrix6d;
using geometry::SE3d;
using geometry::SO3d;
using geometry::StereoCamera;
using geometry::Vector6d;

constexpr int kTrials = 25;

StereoCamera KittiLikeCamera() {
  StereoCamera camera;
  camera.fx = 718.856;
  camera.fy = 718.856;
  camera.cx = 607.19;
  camera.cy = 185.22;
  camera.baseline = 0.537;
  camera.width = 1241;
  camera.height = 376;
  return camera;
}

class Random {
 public:
  explicit Random(unsigned seed) : rng_(seed) {}
  double Uniform(double lo, double hi) {
    return std::uniform_real_distribution<double>(lo, hi)(rng_);
  }
  Vector6d Twist(double scale) {
    Vector6d xi;
    for (int i = 0; i < 6; ++i) xi[i] = Uniform(-scale, scale);
    return xi;
  }
  SE3d Pose(double scale) { return SE3d::Exp(Twist(scale)); }
  // A point in front of the camera, depth 3..30 m, roughly inside the image.
  Eigen::Vector3d PointInCamera() {
    const double z = Uniform(3.0, 30.0);
    return Eigen::Vector3d(Uniform(-0.6, 0.6) * z, Uniform(-0.2, 0.2) * z, z);
  }
  // A world projector Π = Ad(T) Π_l Ad(T)⁻¹ as produced by a joint with a
  // random frame T: Π_l selects `dof` random twist coordinates of the joint
  // frame (non-symmetric in the world frame, like the real thing).
  Matrix6d WorldProjector(int dof) {
    std::vector<int> coords = {0, 1, 2, 3, 4, 5};
    std::shuffle(coords.begin(), coords.end(), rng_);
    Matrix6d pi_l = Matrix6d::Zero();
    for (int k = 0; k < dof; ++k) pi_l(coords[k], coords[k]) = 1.0;
    const Matrix6d ad = Pose(3.0).Adjoint();
    return ad * pi_l * ad.inverse();
  }
  template <int N>
  ObservationVector<N> Noise(double sigma) {
    ObservationVector<N> n;
    for (int i = 0; i < N; ++i) n[i] = Uniform(-sigma, sigma);
    return n;
  }

 private:
  std::mt19937 rng_;
};

std::vector<double> PoseParams(const SE3d& pose) {
  std::vector<double> p(7);
  pose.ToParams(p.data());
  return p;
}

// Evaluates `cost` at `params`; returns residuals and tangent-space Jacobians
// (ambient Jacobian times the manifold's PlusJacobian where one is given).
struct Evaluation {
  VectorXd residuals;
  std::vector<MatrixXd> local_jacobians;
};

Evaluation Evaluate(const ceres::CostFunction& cost,
                    const std::vector<std::vector<double>>& params,
                    const std::vector<const ceres::Manifold*>& manifolds) {
  const int num_residuals = cost.num_residuals();
  const std::vector<int32_t>& sizes = cost.parameter_block_sizes();
  std::vector<const double*> param_ptrs;
  for (const auto& p : params) param_ptrs.push_back(p.data());
  std::vector<std::vector<double>> jac_storage(sizes.size());
  std::vector<double*> jac_ptrs;
  for (size_t i = 0; i < sizes.size(); ++i) {
    jac_storage[i].assign(num_residuals * sizes[i], 0.0);
    jac_ptrs.push_back(jac_storage[i].data());
  }
  Evaluation out;
  out.residuals.resize(num_residuals);
  EXPECT_TRUE(cost.Evaluate(param_ptrs.data(), out.residuals.data(), jac_ptrs.data()));
  for (size_t i = 0; i < sizes.size(); ++i) {
    const MatrixXd ambient =
        Eigen::Map<const Eigen::Matrix<double, Eigen::Dynamic, Eigen::Dynamic, Eigen::RowMajor>>(
            jac_storage[i].data(), num_residuals, sizes[i]);
    if (manifolds[i] != nullptr) {
      Eigen::Matrix<double, Eigen::Dynamic, Eigen::Dynamic, Eigen::RowMajor> plus(
          manifolds[i]->AmbientSize(), manifolds[i]->TangentSize());
      EXPECT_TRUE(manifolds[i]->PlusJacobian(params[i].data(), plus.data()));
      out.local_jacobians.push_back(ambient * plus);
    } else {
      out.local_jacobians.push_back(ambient);
    }
  }
  return out;
}

// Relative comparison scaled by the magnitude of the reference.
void ExpectNear(const MatrixXd& actual,
                const MatrixXd& expected,
                double rel_tol,
                const char* what) {
  ASSERT_EQ(actual.rows(), expected.rows()) << what;
  ASSERT_EQ(actual.cols(), expected.cols()) << what;
  const double scale = std::max(1.0, expected.cwiseAbs().maxCoeff());
  EXPECT_LE((actual - expected).cwiseAbs().maxCoeff(), rel_tol * scale) << what << "\nactual:\n"
                                                                        << actual << "\nexpected:\n"
                                                                        << expected;
}

void ExpectAnalyticMatchesAutodiff(const ceres::CostFunction& analytic,
                                   const ceres::CostFunction& autodiff,
                                   const std::vector<std::vector<double>>& params,
                                   const std::vector<const ceres::Manifold*>& manifolds) {
  ASSERT_EQ(analytic.num_residuals(), autodiff.num_residuals());
  ASSERT_EQ(analytic.parameter_block_sizes(), autodiff.parameter_block_sizes());
  const Evaluation a = Evaluate(analytic, params, manifolds);
  const Evaluation b = Evaluate(autodiff, params, manifolds);
  ExpectNear(a.residuals, b.residuals, 1e-10, "residuals");
  for (size_t i = 0; i < params.size(); ++i) {
    ExpectNear(a.local_jacobians[i], b.local_jacobians[i], 1e-9, "local jacobian");
  }
}

void ExpectMatchesFiniteDifferences(const ceres::CostFunction& cost,
                                    const std::vector<std::vector<double>>& params,
                                    const std::vector<const ceres::Manifold*>& manifolds) {
  ceres::NumericDiffOptions options;
  options.ridders_relative_initial_step_size = 1e-3;
  ceres::GradientChecker checker(&cost, &manifolds, options);
  ceres::GradientChecker::ProbeResults results;
  std::vector<const double*> param_ptrs;
  for (const auto& p : params) param_ptrs.push_back(p.data());
  EXPECT_TRUE(checker.Probe(param_ptrs.data(), 1e-6, &results)) << results.error_log;
}

void CheckCostPair(const ceres::CostFunction& analytic,
                   const ceres::CostFunction& autodiff,
                   const std::vector<std::vector<double>>& params,
                   const std::vector<const ceres::Manifold*>& manifolds) {
  ExpectAnalyticMatchesAutodiff(analytic, autodiff, params, manifolds);
  ExpectMatchesFiniteDifferences(analytic, params, manifolds);
  ExpectMatchesFiniteDifferences(autodiff, params, manifolds);
}

// ------------------------------------------------------------ (a) static
template <int N>
void CheckStaticReprojection(unsigned seed) {
  Random random(seed);
  const StereoCamera camera = KittiLikeCamera();
  SE3Manifold se3;
  for (int trial = 0; trial < kTrials; ++trial) {
    const SE3d camera_from_world = random.Pose(2.0);
    const Eigen::Vector3d p_w = camera_from_world.Inverse() * random.PointInCamera();
    const ObservationVector<N> observed =
        ProjectToObservation<N>(camera, Eigen::Vector3d(camera_from_world * p_w)) +
        random.Noise<N>(3.0);
    const double sqrt_info = random.Uniform(0.3, 1.0);
    const std::vector<double> pose = PoseParams(camera_from_world);
    const std::vector<double> point(p_w.data(), p_w.data() + 3);

    {
      SCOPED_TRACE("pose + point");
      ReprojectionCost<N> analytic(camera, observed, sqrt_info);
      std::unique_ptr<ceres::CostFunction> autodiff(
          ReprojectionFunctor<N>::Create(camera, observed, sqrt_info));
      CheckCostPair(analytic, *autodiff, {pose, point}, {&se3, nullptr});
    }
    {
      SCOPED_TRACE("pose only");
      PoseOnlyReprojectionCost<N> analytic(camera, observed, sqrt_info, p_w);
      std::unique_ptr<ceres::CostFunction> autodiff(
          PoseOnlyReprojectionFunctor<N>::Create(camera, observed, sqrt_info, p_w));
      CheckCostPair(analytic, *autodiff, {pose}, {&se3});
    }
  }
}

TEST(StaticReprojectionCostTest, MonoAnalyticMatchesAutodiffAndFiniteDifferences) {
  CheckStaticReprojection<2>(11);
}

TEST(StaticReprojectionCostTest, StereoAnalyticMatchesAutodiffAndFiniteDifferences) {
  CheckStaticReprojection<3>(12);
}

TEST(StaticReprojectionCostTest, ResidualIsWeightedObservedMinusPredicted) {
  const StereoCamera camera = KittiLikeCamera();
  const SE3d camera_from_world =
      SE3d::Exp((Vector6d() << 0.1, -0.2, 0.3, 0.05, -0.1, 0.2).finished());
  const Eigen::Vector3d p_w(1.0, 0.5, 12.0);
  const Eigen::Vector3d p_c = camera_from_world * p_w;
  const Eigen::Vector3d predicted(camera.fx * p_c.x() / p_c.z() + camera.cx,
                                  camera.fy * p_c.y() / p_c.z() + camera.cy,
                                  camera.fx * (p_c.x() - camera.baseline) / p_c.z() + camera.cx);
  const Eigen::Vector3d observed = predicted + Eigen::Vector3d(1.0, -2.0, 0.5);
  StereoReprojectionCost cost(camera, observed, 0.5);
  const std::vector<double> pose = PoseParams(camera_from_world);
  const double* params[] = {pose.data(), p_w.data()};
  Eigen::Vector3d r;
  ASSERT_TRUE(cost.Evaluate(params, r.data(), nullptr));
  EXPECT_LT((r - Eigen::Vector3d(0.5, -1.0, 0.25)).norm(), 1e-9);
}

TEST(StaticReprojectionCostTest, FailsBehindCamera) {
  const StereoCamera camera = KittiLikeCamera();
  const std::vector<double> pose = PoseParams(SE3d::Identity());
  const Eigen::Vector3d p_w(0.0, 0.0, -2.0);
  const double* params[] = {pose.data(), p_w.data()};
  Eigen::Vector2d r;
  MonoReprojectionCost analytic(camera, Eigen::Vector2d(600, 200), 1.0);
  EXPECT_FALSE(analytic.Evaluate(params, r.data(), nullptr));
  std::unique_ptr<ceres::CostFunction> autodiff(
      ReprojectionFunctor<2>::Create(camera, Eigen::Vector2d(600, 200), 1.0));
  EXPECT_FALSE(autodiff->Evaluate(params, r.data(), nullptr));
}

// ------------------------------------------------------------ (b) tracking
// A random tracking observation of a point in front of the camera under the
// random twist *xi.
template <int N>
TwistTrackingObservation<N> RandomTwistObservation(Random* random, int trial, Vector6d* xi) {
  TwistTrackingObservation<N> obs;
  obs.camera = KittiLikeCamera();
  obs.sqrt_information = random->Uniform(0.3, 1.0);
  obs.camera_from_world = random->Pose(2.0);
  obs.world_from_object_previous = random->Pose(3.0);
  obs.world_projector = random->WorldProjector(trial % 7);
  *xi = random->Twist(0.6);
  const Eigen::Vector3d p_c = random->PointInCamera();
  obs.point_in_object = (obs.camera_from_world * SE3d::Exp(obs.world_projector * *xi) *
                         obs.world_from_object_previous)
                            .Inverse() *
                        p_c;
  obs.observed = ProjectToObservation<N>(obs.camera, p_c) + random->Noise<N>(3.0);
  return obs;
}

template <int N>
void CheckTwistTracking(unsigned seed) {
  Random random(seed);
  for (int trial = 0; trial < kTrials; ++trial) {
    Vector6d xi;
    const TwistTrackingObservation<N> obs = RandomTwistObservation<N>(&random, trial, &xi);
    const std::vector<double> twist(xi.data(), xi.data() + 6);
    TwistTrackingCost<N> analytic(obs);
    std::unique_ptr<ceres::CostFunction> autodiff(TwistTrackingFunctor<N>::Create(obs));
    CheckCostPair(analytic, *autodiff, {twist}, {nullptr});
  }
}

// With the point's own error as a second parameter (and a whitening W that
// is not the identity).
template <int N>
void CheckTwistDepthTracking(unsigned seed) {
  Random random(seed);
  for (int trial = 0; trial < kTrials; ++trial) {
    Vector6d xi;
    TwistTrackingObservation<N> obs = RandomTwistObservation<N>(&random, trial, &xi);
    const ObservationVector<N> g = random.Noise<N>(1.0);
    obs.whitening = Eigen::Matrix<double, N, N>::Identity() -
                    random.Uniform(0.1, 0.9) * g.normalized() * g.normalized().transpose();
    obs.point_sigma_in_object = 0.3 * obs.point_in_object.normalized();
    const std::vector<double> twist(xi.data(), xi.data() + 6);
    const std::vector<double> delta = {random.Uniform(-1.0, 1.0)};
    TwistDepthTrackingCost<N> analytic(obs);
    std::unique_ptr<ceres::CostFunction> autodiff(TwistDepthTrackingFunctor<N>::Create(obs));
    CheckCostPair(analytic, *autodiff, {twist, delta}, {nullptr, nullptr});
  }
}

TEST(TwistTrackingCostTest, MonoAnalyticMatchesAutodiffAndFiniteDifferences) {
  CheckTwistTracking<2>(21);
}
TEST(TwistTrackingCostTest, WithThePointsErrorAnalyticMatchesAutodiffAndFiniteDifferences) {
  CheckTwistDepthTracking<2>(23);
  CheckTwistDepthTracking<3>(24);
}
TEST(TwistTrackingCostTest, StereoAnalyticMatchesAutodiffAndFiniteDifferences) {
  CheckTwistTracking<3>(22);
}

// The paper's Kronecker-form Jacobian
//   ∂π/∂p_c (X̄ᵀ ⊗ I₃)(I₄ ⊗ R_cw)(w_T_oᵀ ⊗ I₃) ∂exp Π
// (X̄ the homogeneous object point, ∂exp the derivative of the top 3x4 block of
// exp at the identity, vec column-major) equals our Jacobian at ξ = 0 and
// not elsewhere.
Eigen::Matrix<double, 2, 6> PaperTrackingJacobian(const TwistTrackingObservation<2>& obs) {
  auto kron = [](const Eigen::MatrixXd& a, const Eigen::MatrixXd& b) {
    Eigen::MatrixXd out(a.rows() * b.rows(), a.cols() * b.cols());
    for (int i = 0; i < a.rows(); ++i)
      for (int j = 0; j < a.cols(); ++j)
        out.block(i * b.rows(), j * b.cols(), b.rows(), b.cols()) = a(i, j) * b;
    return out;
  };
  Eigen::MatrixXd d_exp = Eigen::MatrixXd::Zero(12, 6);
  for (int c = 0; c < 3; ++c) d_exp.block(3 * c, 3, 3, 3) = -SO3d::Hat(Eigen::Vector3d::Unit(c));
  d_exp.block(9, 0, 3, 3).setIdentity();
  const Eigen::Vector4d x_bar = obs.point_in_object.homogeneous();
  const Eigen::Matrix3d i3 = Eigen::Matrix3d::Identity();
  const Eigen::Matrix4d i4 = Eigen::Matrix4d::Identity();
  // Only the top 3x4 block of exp(·)·w_T_o·X̄ moves, so (w_T_oᵀ ⊗ I₃) acts on
  // vec of the 3x4 block.
  const Eigen::MatrixXd m =
      kron(x_bar.transpose(), i3) * kron(i4, obs.camera_from_world.rotation()) *
      kron(obs.world_from_object_previous.matrix().transpose(), i3) * d_exp * obs.world_projector;
  const Eigen::Vector3d p_c =
      obs.camera_from_world * (obs.world_from_object_previous * obs.point_in_object);
  // The residual is observed − predicted, hence the sign.
  return -obs.sqrt_information * ProjectionJacobian<2>(obs.camera, p_c) * m;
}

TEST(TwistTrackingCostTest, PaperKroneckerJacobianMatchesOnlyAtZeroTwist) {
  Random random(23);
  for (int trial = 0; trial < kTrials; ++trial) {
    TwistTrackingObservation<2> obs;
    obs.camera = KittiLikeCamera();
    obs.camera_from_world = random.Pose(1.0);
    obs.world_from_object_previous = random.Pose(2.0);
    obs.world_projector = random.WorldProjector(3 + trial % 4);
    obs.point_in_object =
        (obs.camera_from_world * obs.world_from_object_previous).Inverse() * random.PointInCamera();
    obs.observed = Eigen::Vector2d(600.0, 180.0);
    TwistTrackingCost<2> cost(obs);
    const Eigen::Matrix<double, 2, 6> paper = PaperTrackingJacobian(obs);
    auto jacobian_at = [&cost](const Vector6d& xi) {
      const double* params[] = {xi.data()};
      Eigen::Vector2d r;
      Eigen::Matrix<double, 2, 6, Eigen::RowMajor> j;
      double* jacs[] = {j.data()};
      EXPECT_TRUE(cost.Evaluate(params, r.data(), jacs));
      return Eigen::Matrix<double, 2, 6>(j);
    };
    ExpectNear(jacobian_at(Vector6d::Zero()), paper, 1e-10, "paper jacobian at xi = 0");
    // Away from zero the identity-based formula is only an approximation.
    const Vector6d xi = random.Twist(0.5);
    EXPECT_GT((jacobian_at(xi) - paper).norm(), 1e-3 * paper.norm());
  }
}

// ------------------------------------------------------------ (c) dynamic BA
template <int N>
void CheckDynamicReprojection(unsigned seed) {
  Random random(seed);
  const StereoCamera camera = KittiLikeCamera();
  SE3Manifold se3;
  for (int trial = 0; trial < kTrials; ++trial) {
    const SE3d camera_from_world = random.Pose(2.0);
    const SE3d world_from_object = random.Pose(3.0);
    const Matrix6d projector = random.WorldProjector(trial % 7);
    const Vector6d xi = random.Twist(0.6);
    const Eigen::Vector3d p_c = random.PointInCamera();
    const Eigen::Vector3d p_o =
        (camera_from_world * SE3d::Exp(projector * xi) * world_from_object).Inverse() * p_c;
    const ObservationVector<N> observed =
        ProjectToObservation<N>(camera, p_c) + random.Noise<N>(3.0);
    const double sqrt_info = random.Uniform(0.3, 1.0);
    // Every other trial with a whitening W that mixes the rows (a random
    // lower-triangular matrix, like objects::StereoWhitening's).
    Eigen::Matrix<double, N, N> whitening = Eigen::Matrix<double, N, N>::Identity();
    if (trial % 2 == 1) {
      for (int r = 0; r < N; ++r) {
        whitening(r, r) = random.Uniform(0.5, 3.0);
        for (int c = 0; c < r; ++c) whitening(r, c) = random.Uniform(-3.0, 3.0);
      }
    }
    DynamicReprojectionCost<N> analytic(camera, observed, sqrt_info, projector, whitening);
    std::unique_ptr<ceres::CostFunction> autodiff(
        DynamicReprojectionFunctor<N>::Create(camera, observed, sqrt_info, projector, whitening));
    {
      // The whitened residual is W times the plain one.
      const std::vector<double> cw = PoseParams(camera_from_world),
                                wo = PoseParams(world_from_object);
      const double* params[] = {cw.data(), xi.data(), wo.data(), p_o.data()};
      ObservationVector<N> plain, whitened;
      ASSERT_TRUE(DynamicReprojectionCost<N>(camera, observed, sqrt_info, projector)
                      .Evaluate(params, plain.data(), nullptr));
      ASSERT_TRUE(analytic.Evaluate(params, whitened.data(), nullptr));
      ExpectNear(whitened, whitening * plain, 1e-9, "whitened residual");
    }
    CheckCostPair(analytic,
                  *autodiff,
                  {PoseParams(camera_from_world),
                   std::vector<double>(xi.data(), xi.data() + 6),
                   PoseParams(world_from_object),
                   std::vector<double>(p_o.data(), p_o.data() + 3)},
                  {&se3, nullptr, &se3, nullptr});
  }
}

TEST(DynamicReprojectionCostTest, MonoAnalyticMatchesAutodiffAndFiniteDifferences) {
  CheckDynamicReprojection<2>(31);
}
TEST(DynamicReprojectionCostTest, StereoAnalyticMatchesAutodiffAndFiniteDifferences) {
  CheckDynamicReprojection<3>(32);
}

// ------------------------------------------- (d) constant velocity / acceleration
// A step-combination cost against its autodiff twin and finite differences:
// random poses, twists, weights and projectors of every rank. `make` gives
// the (analytic, autodiff) pair for a projector.
template <int kPoses, typename Make>
void CheckStepCombination(uint64_t seed, Make make) {
  Random random(seed);
  SE3Manifold se3;
  for (int trial = 0; trial < kTrials; ++trial) {
    const Matrix6d projector = random.WorldProjector(trial % 7);
    std::vector<std::vector<double>> params;
    std::vector<const ceres::Manifold*> manifolds;
    SE3d pose = random.Pose(3.0);
    for (int k = 0; k < kPoses; ++k) {
      const Vector6d xi = random.Twist(0.3);
      params.emplace_back(xi.data(), xi.data() + 6);
      params.push_back(PoseParams(pose));
      manifolds.insert(manifolds.end(), {nullptr, &se3});
      pose = SE3d::Exp(random.Twist(0.6)) * pose;
    }
    auto [analytic, autodiff] = make(projector, &random);
    CheckCostPair(*analytic, *autodiff, params, manifolds);
  }
}

template <int kPoses>
void CheckMotionPrior(uint64_t seed) {
  CheckStepCombination<kPoses>(seed, [](const Matrix6d& projector, Random* random) {
    Vector6d sqrt_weights;
    for (int i = 0; i < 6; ++i) sqrt_weights[i] = random->Uniform(0.5, 3.0);
    return std::make_pair(
        std::unique_ptr<ceres::CostFunction>(new MotionPriorCost<kPoses>(projector, sqrt_weights)),
        std::unique_ptr<ceres::CostFunction>(
            MotionPriorFunctor<kPoses>::Create(projector, sqrt_weights)));
  });
}

TEST(ConstantVelocityCostTest, AnalyticMatchesAutodiffAndFiniteDifferences) {
  CheckMotionPrior<3>(41);
}
TEST(ConstantAccelerationCostTest, AnalyticMatchesAutodiffAndFiniteDifferences) {
  CheckMotionPrior<4>(43);
}

TEST(ConstantVelocityCostTest, ZeroForConstantVelocityMotion) {
  Random random(42);
  const Matrix6d projector = random.WorldProjector(3);
  const Vector6d velocity = projector * random.Twist(0.5);
  const SE3d p0 = random.Pose(2.0);
  const SE3d p1 = SE3d::Exp(velocity) * p0;
  const SE3d p2 = SE3d::Exp(velocity) * p1;
  const std::vector<double> zero(6, 0.0);
  const std::vector<double> q0 = PoseParams(p0), q1 = PoseParams(p1), q2 = PoseParams(p2);
  const double* params[] = {zero.data(), q0.data(), zero.data(), q1.data(), zero.data(), q2.data()};
  ConstantVelocityCost cost(projector, Vector6d::Ones());
  Vector6d r;
  ASSERT_TRUE(cost.Evaluate(params, r.data(), nullptr));
  EXPECT_LT(r.norm(), 1e-10);
  // An acceleration shows up.
  const SE3d p2_fast = SE3d::Exp(2.0 * velocity) * p1;
  const std::vector<double> q2_fast = PoseParams(p2_fast);
  params[5] = q2_fast.data();
  ASSERT_TRUE(cost.Evaluate(params, r.data(), nullptr));
  EXPECT_LT((r - velocity).norm(), 1e-9);
}

TEST(ConstantAccelerationCostTest, ZeroForConstantAccelerationMotionWhereConstantVelocityIsNot) {
  Random random(44);
  const Matrix6d projector = random.WorldProjector(3);
  const Vector6d velocity = projector * random.Twist(0.5);
  const Vector6d acceleration = projector * random.Twist(0.05);
  std::vector<SE3d> poses = {random.Pose(2.0)};
  for (int k = 0; k < 3; ++k) {
    poses.push_back(SE3d::Exp(velocity + k * acceleration) * poses.back());
  }
  const std::vector<double> zero(6, 0.0);
  std::vector<std::vector<double>> q;
  for (const SE3d& p : poses) q.push_back(PoseParams(p));
  const double* params[] = {zero.data(),
                            q[0].data(),
                            zero.data(),
                            q[1].data(),
                            zero.data(),
                            q[2].data(),
                            zero.data(),
                            q[3].data()};
  ConstantAccelerationCost cost(projector, Vector6d::Ones());
  Vector6d r;
  ASSERT_TRUE(cost.Evaluate(params, r.data(), nullptr));
  EXPECT_LT(r.norm(), 1e-9);
  // The constant-velocity term of the same motion reads the acceleration.
  ConstantVelocityCost velocity_cost(projector, Vector6d::Ones());
  ASSERT_TRUE(velocity_cost.Evaluate(params, r.data(), nullptr));
  EXPECT_LT((r - acceleration).norm(), 1e-9);
  // A change of acceleration (jerk) shows up.
  const SE3d p3_jerk = SE3d::Exp(velocity + 3.0 * acceleration) * poses[2];
  const std::vector<double> q3_jerk = PoseParams(p3_jerk);
  params[7] = q3_jerk.data();
  ASSERT_TRUE(cost.Evaluate(params, r.data(), nullptr));
  EXPECT_LT((r - acceleration).norm(), 1e-9);
}

// ------------------------------------------------------------ (e) normal step
TEST(NormalStepCostTest, AnalyticMatchesAutodiffAndFiniteDifferences) {
  CheckStepCombination<2>(45, [](const Matrix6d& projector, Random* random) {
    const Eigen::Vector3d normal = random->Twist(1.0).head<3>().normalized();
    const Eigen::Matrix<double, 1, 6> map = NormalStepMap(normal, random->Uniform(0.005, 0.05));
    return std::make_pair(
        std::unique_ptr<ceres::CostFunction>(new NormalStepCost(projector, map, {1.0})),
        std::unique_ptr<ceres::CostFunction>(NormalStepFunctor::Create(projector, map, {1.0})));
  });
}

TEST(NormalStepCostTest, ReadsTheStepAlongTheNormalOnly) {
  // A car on a road tilted by 0.1 rad: a step along the road and a turn about
  // the road's normal give 0; 2 cm along the normal gives 2 cm / σ.
  const Eigen::Vector3d normal(0.0, -std::cos(0.1), std::sin(0.1));
  const Eigen::Vector3d forward(0.0, std::sin(0.1), std::cos(0.1));
  const SE3d p0(geometry::SO3d(), Eigen::Vector3d(2.0, 1.5, 20.0));
  Vector6d in_plane;
  in_plane << forward * 1.2, normal * 0.05;
  // A rotation about the normal through the car keeps the translation in the plane.
  const SE3d p1 = SE3d(geometry::SO3d(), p0.translation()) * SE3d::Exp(in_plane) *
                  SE3d(geometry::SO3d(), -p0.translation()) * p0;
  const SE3d p2 = SE3d(geometry::SO3d(), 0.02 * normal) * p1;
  const std::vector<double> zero(6, 0.0);
  const std::vector<double> q0 = PoseParams(p0), q1 = PoseParams(p1), q2 = PoseParams(p2);
  NormalStepCost cost(Matrix6d::Identity(), NormalStepMap(normal, 0.01), {1.0});
  double r = 0.0;
  const double* in_plane_params[] = {zero.data(), q0.data(), zero.data(), q1.data()};
  ASSERT_TRUE(cost.Evaluate(in_plane_params, &r, nullptr));
  EXPECT_NEAR(r, 0.0, 1e-12);
  const double* lifted_params[] = {zero.data(), q1.data(), zero.data(), q2.data()};
  ASSERT_TRUE(cost.Evaluate(lifted_params, &r, nullptr));
  EXPECT_NEAR(r, 2.0, 1e-12);
}

}  // namespace
}  // namespace twist::optimization
