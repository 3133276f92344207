// Static reprojection error (paper eq. track_stat and e_stat of eq. ba).
//
// Error model, N = 2 (mono: u, v) or N = 3 (rectified stereo: u_left, v,
// u_right):
//   r = s · (x_obs − π_N(camera_from_world · p_in_world))
// with s the scalar square-root information of the observation (typically
// 1/σ of its pyramid level, σ = scale_factor^level), so that
// ‖r‖² = (x − π)ᵀ Σ⁻¹ (x − π) with Σ = σ² I. Robust losses are added by the
// caller (ceres::HuberLoss in AddResidualBlock).
//
// Parameter blocks: camera_from_world as a 7-scalar SE(3) block
// [qx qy qz qw tx ty tz] with SE3Manifold (right perturbation), and the world
// point (3). The pose-only variant keeps the point as a constant.
//
// Analytic Jacobians (p_c = R p_w + t):
//   ∂r/∂δ   = −s · ∂π/∂p_c · R · [I, −[p_w]x]       (right perturbation δ = (v, ω))
//   ∂r/∂p_w = −s · ∂π/∂p_c · R
// ∂r/∂δ is mapped to the 7 ambient parameters with SE3LocalToAmbientJacobian.
// Evaluation fails (returns false) for points with depth ≤ kMinProjectionDepth.
#pragma once

#include <Eigen/Core>

#include "ceres/autodiff_cost_function.h"
#include "ceres/sized_cost_function.h"
#include "slam/geometry/se3.h"
#include "slam/geometry/stereo_camera.h"
#include "slam/optimization/cost_functions/projection.h"
#include "slam/optimization/manifolds/se3_manifold.h"

namespace twist::optimization {

// ----------------------------------------------------------------- autodiff
template <int N>
class ReprojectionFunctor {
 public:
  ReprojectionFunctor(const geometry::StereoCamera& camera,
                      const ObservationVector<N>& observed,
                      double sqrt_information)
      : camera_(camera), observed_(observed), sqrt_information_(sqrt_information) {}

  template <typename T>
  bool operator()(const T* camera_from_world, const T* point_in_world, T* residuals) const {
    const geometry::SE3<T> pose = geometry::SE3<T>::FromParams(camera_from_world);
    const Eigen::Matrix<T, 3, 1> p_c =
        pose * Eigen::Matrix<T, 3, 1>(point_in_world[0], point_in_world[1], point_in_world[2]);
    if (!(p_c.z() > T(kMinProjectionDepth))) return false;
    const Eigen::Matrix<T, N, 1> predicted = ProjectToObservation<N>(camera_, p_c);
    Eigen::Map<Eigen::Matrix<T, N, 1>> r(residuals);
    r = T(sqrt_information_) * (observed_.template cast<T>() - predicted);
    return true;
  }

  static ceres::CostFunction* Create(const geometry::StereoCamera& camera,
                                     const ObservationVector<N>& observed,
                                     double sqrt_information) {
    return new ceres::AutoDiffCostFunction<ReprojectionFunctor, N, 7, 3>(
        new ReprojectionFunctor(camera, observed, sqrt_information));
  }

 private:
  geometry::StereoCamera camera_;
  ObservationVector<N> observed_;
  double sqrt_information_;
};

template <int N>
class PoseOnlyReprojectionFunctor {
 public:
  PoseOnlyReprojectionFunctor(const geometry::StereoCamera& camera,
                              const ObservationVector<N>& observed,
                              double sqrt_information,
                              const Eigen::Vector3d& point_in_world)
      : inner_(camera, observed, sqrt_information), point_in_world_(point_in_world) {}

  template <typename T>
  bool operator()(const T* camera_from_world, T* residuals) const {
    const Eigen::Matrix<T, 3, 1> p = point_in_world_.cast<T>();
    return inner_(camera_from_world, p.data(), residuals);
  }

  static ceres::CostFunction* Create(const geometry::StereoCamera& camera,
                                     const ObservationVector<N>& observed,
                                     double sqrt_information,
                                     const Eigen::Vector3d& point_in_world) {
    return new ceres::AutoDiffCostFunction<PoseOnlyReprojectionFunctor, N, 7>(
        new PoseOnlyReprojectionFunctor(camera, observed, sqrt_information, point_in_world));
  }

 private:
  ReprojectionFunctor<N> inner_;
  Eigen::Vector3d point_in_world_;
};

// ----------------------------------------------------------------- analytic
namespace internal {

// Shared evaluation; jac_pose / jac_point may be null.
template <int N>
bool EvaluateStaticReprojection(const geometry::StereoCamera& camera,
                                const ObservationVector<N>& observed,
                                double s,
                                const double* camera_from_world,
                                const Eigen::Vector3d& p_w,
                                double* residuals,
                                double* jac_pose,
                                double* jac_point) {
  const geometry::SE3d pose = geometry::SE3d::FromParams(camera_from_world);
  const Eigen::Vector3d p_c = pose * p_w;
  if (!(p_c.z() > kMinProjectionDepth)) return false;
  Eigen::Map<Eigen::Matrix<double, N, 1>> r(residuals);
  r = s * (observed - ProjectToObservation<N>(camera, p_c));
  if (jac_pose == nullptr && jac_point == nullptr) return true;
  const Eigen::Matrix<double, N, 3> d_r_d_pw =
      -s * ProjectionJacobian<N>(camera, p_c) * pose.rotation();
  if (jac_pose != nullptr) {
    const Eigen::Matrix<double, N, 6> local = d_r_d_pw * PointPerturbationJacobian(p_w);
    SE3LocalToAmbientJacobian<N>(camera_from_world, local, jac_pose);
  }
  if (jac_point != nullptr) {
    Eigen::Map<Eigen::Matrix<double, N, 3, Eigen::RowMajor>> out(jac_point);
    out = d_r_d_pw;
  }
  return true;
}

}  // namespace internal

template <int N>
class ReprojectionCost final : public ceres::SizedCostFunction<N, 7, 3> {
 public:
  ReprojectionCost(const geometry::StereoCamera& camera,
                   const ObservationVector<N>& observed,
                   double sqrt_information)
      : camera_(camera), observed_(observed), sqrt_information_(sqrt_information) {}

  bool Evaluate(double const* const* parameters,
                double* residuals,
                double** jacobians) const override {
    return internal::EvaluateStaticReprojection<N>(camera_,
                                                   observed_,
                                                   sqrt_information_,
                                                   parameters[0],
                                                   Eigen::Vector3d(parameters[1]),
                                                   residuals,
                                                   jacobians != nullptr ? jacobians[0] : nullptr,
                                                   jacobians != nullptr ? jacobians[1] : nullptr);
  }

 private:
  geometry::StereoCamera camera_;
  ObservationVector<N> observed_;
  double sqrt_information_;
};

template <int N>
class PoseOnlyReprojectionCost final : public ceres::SizedCostFunction<N, 7> {
 public:
  PoseOnlyReprojectionCost(const geometry::StereoCamera& camera,
                           const ObservationVector<N>& observed,
                           double sqrt_information,
                           const Eigen::Vector3d& point_in_world)
      : camera_(camera),
        observed_(observed),
        sqrt_information_(sqrt_information),
        point_in_world_(point_in_world) {}

  bool Evaluate(double const* const* parameters,
                double* residuals,
                double** jacobians) const override {
    return internal::EvaluateStaticReprojection<N>(camera_,
                                                   observed_,
                                                   sqrt_information_,
                                                   parameters[0],
                                                   point_in_world_,
                                                   residuals,
                                                   jacobians != nullptr ? jacobians[0] : nullptr,
                                                   nullptr);
  }

 private:
  geometry::StereoCamera camera_;
  ObservationVector<N> observed_;
  double sqrt_information_;
  Eigen::Vector3d point_in_world_;
};

using MonoReprojectionCost = ReprojectionCost<2>;
using StereoReprojectionCost = ReprojectionCost<3>;
using MonoPoseOnlyReprojectionCost = PoseOnlyReprojectionCost<2>;
using StereoPoseOnlyReprojectionCost = PoseOnlyReprojectionCost<3>;

}  // namespace twist::optimization
