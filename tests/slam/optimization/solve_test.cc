// End-to-end use of the cost functions with Ceres: noise-free synthetic
// problems solved from perturbed starts recover the ground truth. Exercises
// the SE3 manifold, the analytic Jacobians and the joint projectors together.
#include <gtest/gtest.h>

#include <Eigen/Core>
#include <array>
#include <random>
#include <vector>

#include "ceres/loss_function.h"
#include "ceres/problem.h"
#include "ceres/solver.h"
#include "slam/geometry/se3.h"
#include "slam/geometry/stereo_camera.h"
#include "slam/joints/joint.h"
#include "slam/optimization/cost_functions/constant_velocity_cost.h"
#include "slam/optimization/cost_functions/dynamic_reprojection_cost.h"
#include "slam/optimization/cost_functions/reprojection_cost.h"
#include "slam/optimization/cost_functions/twist_tracking_cost.h"
#include "slam/optimization/manifolds/se3_manifold.h"

namespace twist::optimization {
namespace {

using geometry::Matrix6d;
using geometry::SE3d;
using geometry::StereoCamera;
using geometry::Vector6d;

StereoCamera Camera() {
  StereoCamera c;
  c.fx = c.fy = 700.0;
  c.cx = 620.0;
  c.cy = 188.0;
  c.baseline = 0.54;
  c.width = 1240;
  c.height = 376;
  return c;
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

 private:
  std::mt19937 rng_;
};

ceres::Solver::Options SolverOptions() {
  ceres::Solver::Options options;
  options.linear_solver_type = ceres::DENSE_QR;
  options.max_num_iterations = 50;
  options.function_tolerance = 1e-14;
  options.gradient_tolerance = 1e-14;
  options.parameter_tolerance = 1e-14;
  options.num_threads = 1;
  return options;
}

TEST(SolveTest, PoseOnlyStereoRecoversCameraPose) {
  Random random(1);
  const StereoCamera camera = Camera();
  for (int trial = 0; trial < 5; ++trial) {
    const SE3d truth = SE3d::Exp(random.Twist(1.0));
    ceres::Problem problem;
    double pose[7];
    (truth * SE3d::Exp(random.Twist(0.1))).ToParams(pose);
    problem.AddParameterBlock(pose, 7, new SE3Manifold);
    for (int i = 0; i < 60; ++i) {
      const double z = random.Uniform(4.0, 40.0);
      const Eigen::Vector3d p_c(random.Uniform(-0.7, 0.7) * z, random.Uniform(-0.25, 0.25) * z, z);
      const Eigen::Vector3d p_w = truth.Inverse() * p_c;
      problem.AddResidualBlock(
          new StereoPoseOnlyReprojectionCost(camera, camera.ProjectStereo(p_c), 1.0, p_w),
          new ceres::HuberLoss(2.0),
          pose);
    }
    ceres::Solver::Summary summary;
    ceres::Solve(SolverOptions(), &problem, &summary);
    ASSERT_TRUE(summary.IsSolutionUsable()) << summary.BriefReport();
    EXPECT_LT((SE3d::FromParams(pose).Inverse() * truth).Log().norm(), 1e-8)
        << summary.BriefReport();
  }
}

TEST(SolveTest, PlanarTwistTrackingRecoversConstrainedMotion) {
  Random random(2);
  const StereoCamera camera = Camera();
  // Road plane y = 1.6 below the camera (KITTI: y down), normal -y.
  const joints::Joint joint = joints::Joint::FromPlaneCoefficients(
      Eigen::Vector4d(0.0, -1.0, 0.0, 1.6), Eigen::Vector3d(2.0, 1.6, 15.0));
  const Matrix6d projector = joint.WorldProjector();
  for (int trial = 0; trial < 5; ++trial) {
    const SE3d camera_from_world = SE3d::Exp(0.05 * random.Twist(1.0));
    const SE3d world_from_object(Eigen::Matrix3d::Identity(),
                                 Eigen::Vector3d(random.Uniform(-3, 3), 1.0, 15.0));
    Vector6d motion = random.Twist(0.5);
    motion = projector * motion;  // allowed motion: in-plane translation + yaw
    const SE3d world_from_object_now = SE3d::Exp(motion) * world_from_object;
    ceres::Problem problem;
    Vector6d xi = Vector6d::Zero();
    for (int i = 0; i < 40; ++i) {
      TwistTrackingObservation<3> obs;
      obs.camera = camera;
      obs.camera_from_world = camera_from_world;
      obs.world_from_object_previous = world_from_object;
      obs.world_projector = projector;
      obs.point_in_object =
          Eigen::Vector3d(random.Uniform(-1, 1), random.Uniform(-0.7, 0.5), random.Uniform(-2, 2));
      obs.observed = camera.ProjectStereo(
          Eigen::Vector3d(camera_from_world * (world_from_object_now * obs.point_in_object)));
      problem.AddResidualBlock(
          new StereoTwistTrackingCost(obs), new ceres::HuberLoss(2.0), xi.data());
    }
    ceres::Solver::Summary summary;
    ceres::Solve(SolverOptions(), &problem, &summary);
    ASSERT_TRUE(summary.IsSolutionUsable()) << summary.BriefReport();
    // ξ itself is only determined up to the null space of Π; Πξ is the motion.
    EXPECT_LT((projector * xi - motion).norm(), 1e-8) << summary.BriefReport();
    // The estimated motion keeps the object on the road: no height change.
    const SE3d estimated = SE3d::Exp(projector * xi) * world_from_object;
    EXPECT_NEAR(estimated.translation().y(), world_from_object.translation().y(), 1e-9);
  }
}

TEST(SolveTest, DynamicWindowWithConstantVelocityRecoversTwists) {
  // Three frames of a car moving at constant planar velocity; object poses
  // fixed at a wrong linearisation point, corrected through ξ̃ only.
  Random random(3);
  const StereoCamera camera = Camera();
  const joints::Joint joint = joints::Joint::FromPlane(
      joints::JointType::kPlanar, Eigen::Vector3d(0, -1, 0), Eigen::Vector3d(0, 1.6, 0));
  const Matrix6d projector = joint.WorldProjector();
  const Vector6d velocity = projector * (Vector6d() << 0.8, 0.0, 0.3, 0.0, 0.05, 0.0).finished();
  std::vector<SE3d> truth = {SE3d(Eigen::Matrix3d::Identity(), Eigen::Vector3d(-2.0, 1.0, 14.0))};
  truth.push_back(SE3d::Exp(velocity) * truth[0]);
  truth.push_back(SE3d::Exp(velocity) * truth[1]);
  std::vector<Eigen::Vector3d> points;
  for (int i = 0; i < 30; ++i) {
    points.emplace_back(random.Uniform(-1, 1), random.Uniform(-0.7, 0.5), random.Uniform(-2, 2));
  }
  ceres::Problem problem;
  std::vector<Vector6d> twists(3, Vector6d::Zero());
  std::vector<std::array<double, 7>> poses(3);
  std::vector<std::array<double, 7>> cameras(3);
  for (int k = 0; k < 3; ++k) {
    // Linearisation point: truth moved by an allowed error, to be undone by ξ̃.
    (SE3d::Exp(projector * (0.05 * random.Twist(1.0))).Inverse() * truth[k])
        .ToParams(poses[k].data());
    SE3d().ToParams(cameras[k].data());
    problem.AddParameterBlock(cameras[k].data(), 7, new SE3Manifold);
    problem.SetParameterBlockConstant(cameras[k].data());
    problem.AddParameterBlock(poses[k].data(), 7, new SE3Manifold);
    problem.SetParameterBlockConstant(poses[k].data());
    for (Eigen::Vector3d& p_o : points) {
      problem.AddParameterBlock(p_o.data(), 3);
      problem.SetParameterBlockConstant(p_o.data());
      problem.AddResidualBlock(
          new StereoDynamicReprojectionCost(
              camera, camera.ProjectStereo(Eigen::Vector3d(truth[k] * p_o)), 1.0, projector),
          nullptr,
          cameras[k].data(),
          twists[k].data(),
          poses[k].data(),
          p_o.data());
    }
  }
  problem.AddResidualBlock(new ConstantVelocityCost(projector, Vector6d::Constant(10.0)),
                           nullptr,
                           twists[0].data(),
                           poses[0].data(),
                           twists[1].data(),
                           poses[1].data(),
                           twists[2].data(),
                           poses[2].data());
  ceres::Solver::Summary summary;
  ceres::Solve(SolverOptions(), &problem, &summary);
  ASSERT_TRUE(summary.IsSolutionUsable()) << summary.BriefReport();
  for (int k = 0; k < 3; ++k) {
    const SE3d corrected = SE3d::Exp(projector * twists[k]) * SE3d::FromParams(poses[k].data());
    EXPECT_LT((corrected.Inverse() * truth[k]).Log().norm(), 1e-8)
        << k << " " << summary.BriefReport();
  }
}

}  // namespace
}  // namespace twist::optimization
