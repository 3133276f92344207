// Every cost family: analytic == autodiff (residuals and tangent-space
// Jacobians) and both == finite differences (ceres::GradientChecker) at many
// seeded random points.
#include <memory>
#include <random>
#include <vector>

#include <Eigen/Core>
#include <gtest/gtest.h>

#include "ceres/gradient_checker.h"
#include "ceres/manifold.h"
#include "slam/geometry/se3.h"
#include "slam/geometry/stereo_camera.h"
#include "slam/optimization/cost_functions/reprojection_cost.h"
#include "slam/optimization/manifolds/se3_manifold.h"

namespace twist::optimization {
namespace {

using geometry::SE3d;
using geometry::StereoCamera;
using geometry::Vector6d;
using Eigen::MatrixXd;
using Eigen::VectorXd;

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
  double Uniform(double lo, double hi) { return std::uniform_real_distribution<double>(lo, hi)(rng_); }
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
    const MatrixXd ambient = Eigen::Map<const Eigen::Matrix<double, Eigen::Dynamic, Eigen::Dynamic, Eigen::RowMajor>>(
        jac_storage[i].data(), num_residuals, sizes[i]);
    if (manifolds[i] != nullptr) {
      Eigen::Matrix<double, Eigen::Dynamic, Eigen::Dynamic, Eigen::RowMajor> plus(manifolds[i]->AmbientSize(),
                                                                                   manifolds[i]->TangentSize());
      EXPECT_TRUE(manifolds[i]->PlusJacobian(params[i].data(), plus.data()));
      out.local_jacobians.push_back(ambient * plus);
    } else {
      out.local_jacobians.push_back(ambient);
    }
  }
  return out;
}

// Relative comparison scaled by the magnitude of the reference.
void ExpectNear(const MatrixXd& actual, const MatrixXd& expected, double rel_tol, const char* what) {
  ASSERT_EQ(actual.rows(), expected.rows()) << what;
  ASSERT_EQ(actual.cols(), expected.cols()) << what;
  const double scale = std::max(1.0, expected.cwiseAbs().maxCoeff());
  EXPECT_LE((actual - expected).cwiseAbs().maxCoeff(), rel_tol * scale)
      << what << "\nactual:\n" << actual << "\nexpected:\n" << expected;
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
        ProjectToObservation<N>(camera, Eigen::Vector3d(camera_from_world * p_w)) + random.Noise<N>(3.0);
    const double sqrt_info = random.Uniform(0.3, 1.0);
    const std::vector<double> pose = PoseParams(camera_from_world);
    const std::vector<double> point(p_w.data(), p_w.data() + 3);

    {
      SCOPED_TRACE("pose + point");
      ReprojectionCost<N> analytic(camera, observed, sqrt_info);
      std::unique_ptr<ceres::CostFunction> autodiff(ReprojectionFunctor<N>::Create(camera, observed, sqrt_info));
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
  const SE3d camera_from_world = SE3d::Exp((Vector6d() << 0.1, -0.2, 0.3, 0.05, -0.1, 0.2).finished());
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

}  // namespace
}  // namespace twist::optimization
