// Dynamic bundle-adjustment reprojection term (paper e_dyna of eq. ba).
//
// Error model, N = 2 (mono) or 3 (stereo):
//   r = s · W · (x_obs − π_N(camera_from_world_i · Exp(Π ξ̃_i) · world_from_object_i · p_in_object))
// Parameter blocks (in this order):
//   camera_from_world_i  7 [qx qy qz qw tx ty tz], SE3Manifold (right perturbation δ_c)
//   ξ̃_i                  6 twist correction in the world frame (Euclidean)
//   world_from_object_i  7 SE3Manifold (right perturbation δ_o); set it constant
//                          to optimise the object through ξ̃ only, as the paper does
//   p_in_object          3
// Constants: camera, observation, square-root information s, world projector Π
// and an N x N whitening matrix W (identity by default;
// objects::SolveDynamicBa uses it for a disparity with its own noise,
// objects::StereoWhitening).
//
// Analytic Jacobians (η = Πξ̃, p_w = w_T_o p_o, p'_w = Exp(η) p_w,
// p_c = R_cw p'_w + t_cw, R_η = rotation of Exp(η), D = −s W ∂π/∂p_c):
//   ∂r/∂δ_c = D · R_cw · [I, −[p'_w]x]
//   ∂r/∂ξ̃   = D · R_cw · [I, −[p'_w]x] · J_l(η) · Π
//   ∂r/∂δ_o = D · R_cw · R_η · R_wo · [I, −[p_o]x]
//   ∂r/∂p_o = D · R_cw · R_η · R_wo
// Pose-block Jacobians are mapped to the ambient 7 parameters with
// SE3LocalToAmbientJacobian. Evaluation fails for depth ≤ kMinProjectionDepth.
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
class DynamicReprojectionFunctor {
 public:
  DynamicReprojectionFunctor(
      const geometry::StereoCamera& camera,
      const ObservationVector<N>& observed,
      double sqrt_information,
      const geometry::Matrix6d& world_projector,
      const Eigen::Matrix<double, N, N>& whitening = Eigen::Matrix<double, N, N>::Identity())
      : camera_(camera),
        observed_(observed),
        sqrt_information_(sqrt_information),
        world_projector_(world_projector),
        whitening_(whitening) {}

  template <typename T>
  bool operator()(const T* camera_from_world,
                  const T* twist,
                  const T* world_from_object,
                  const T* point_in_object,
                  T* residuals) const {
    using SE3T = geometry::SE3<T>;
    const Eigen::Map<const Eigen::Matrix<T, 6, 1>> xi(twist);
    const Eigen::Matrix<T, 6, 1> eta = world_projector_.template cast<T>() * xi;
    const SE3T camera_from_object =
        SE3T::FromParams(camera_from_world) * SE3T::Exp(eta) * SE3T::FromParams(world_from_object);
    const Eigen::Matrix<T, 3, 1> p_c =
        camera_from_object *
        Eigen::Matrix<T, 3, 1>(point_in_object[0], point_in_object[1], point_in_object[2]);
    if (!(p_c.z() > T(kMinProjectionDepth))) return false;
    Eigen::Map<Eigen::Matrix<T, N, 1>> r(residuals);
    r = T(sqrt_information_) * whitening_.template cast<T>() *
        (observed_.template cast<T>() - ProjectToObservation<N>(camera_, p_c));
    return true;
  }

  static ceres::CostFunction* Create(
      const geometry::StereoCamera& camera,
      const ObservationVector<N>& observed,
      double sqrt_information,
      const geometry::Matrix6d& world_projector,
      const Eigen::Matrix<double, N, N>& whitening = Eigen::Matrix<double, N, N>::Identity()) {
    return new ceres::AutoDiffCostFunction<DynamicReprojectionFunctor, N, 7, 6, 7, 3>(
        new DynamicReprojectionFunctor(
            camera, observed, sqrt_information, world_projector, whitening));
  }

 private:
  geometry::StereoCamera camera_;
  ObservationVector<N> observed_;
  double sqrt_information_;
  geometry::Matrix6d world_projector_;
  Eigen::Matrix<double, N, N> whitening_;
};

// ----------------------------------------------------------------- analytic
template <int N>
class DynamicReprojectionCost final : public ceres::SizedCostFunction<N, 7, 6, 7, 3> {
 public:
  DynamicReprojectionCost(
      const geometry::StereoCamera& camera,
      const ObservationVector<N>& observed,
      double sqrt_information,
      const geometry::Matrix6d& world_projector,
      const Eigen::Matrix<double, N, N>& whitening = Eigen::Matrix<double, N, N>::Identity())
      : camera_(camera),
        observed_(observed),
        sqrt_information_(sqrt_information),
        world_projector_(world_projector),
        whitening_(whitening) {}

  bool Evaluate(double const* const* parameters,
                double* residuals,
                double** jacobians) const override {
    const geometry::SE3d camera_from_world = geometry::SE3d::FromParams(parameters[0]);
    const Eigen::Map<const geometry::Vector6d> xi(parameters[1]);
    const geometry::SE3d world_from_object = geometry::SE3d::FromParams(parameters[2]);
    const Eigen::Vector3d p_o(parameters[3]);

    const geometry::Vector6d eta = world_projector_ * xi;
    const geometry::SE3d motion = geometry::SE3d::Exp(eta);
    const Eigen::Vector3d p_w = world_from_object * p_o;
    const Eigen::Vector3d p_w_moved = motion * p_w;
    const Eigen::Vector3d p_c = camera_from_world * p_w_moved;
    if (!(p_c.z() > kMinProjectionDepth)) return false;
    Eigen::Map<Eigen::Matrix<double, N, 1>> r(residuals);
    r = sqrt_information_ * whitening_ * (observed_ - ProjectToObservation<N>(camera_, p_c));
    if (jacobians == nullptr) return true;

    // D · R_cw: derivative with respect to the moved world point.
    const Eigen::Matrix<double, N, 3> d_r_d_pw_moved = -sqrt_information_ * whitening_ *
                                                       ProjectionJacobian<N>(camera_, p_c) *
                                                       camera_from_world.rotation();
    const Eigen::Matrix<double, N, 6> d_r_d_left =
        d_r_d_pw_moved * PointPerturbationJacobian(p_w_moved);
    if (jacobians[0] != nullptr) {
      SE3LocalToAmbientJacobian<N>(parameters[0], d_r_d_left, jacobians[0]);
    }
    if (jacobians[1] != nullptr) {
      Eigen::Map<Eigen::Matrix<double, N, 6, Eigen::RowMajor>> j(jacobians[1]);
      j = d_r_d_left * geometry::SE3d::LeftJacobian(eta) * world_projector_;
    }
    if (jacobians[2] != nullptr || jacobians[3] != nullptr) {
      const Eigen::Matrix<double, N, 3> d_r_d_po =
          d_r_d_pw_moved * motion.rotation() * world_from_object.rotation();
      if (jacobians[2] != nullptr) {
        const Eigen::Matrix<double, N, 6> local = d_r_d_po * PointPerturbationJacobian(p_o);
        SE3LocalToAmbientJacobian<N>(parameters[2], local, jacobians[2]);
      }
      if (jacobians[3] != nullptr) {
        Eigen::Map<Eigen::Matrix<double, N, 3, Eigen::RowMajor>> j(jacobians[3]);
        j = d_r_d_po;
      }
    }
    return true;
  }

 private:
  geometry::StereoCamera camera_;
  ObservationVector<N> observed_;
  double sqrt_information_;
  geometry::Matrix6d world_projector_;
  Eigen::Matrix<double, N, N> whitening_;
};

using MonoDynamicReprojectionCost = DynamicReprojectionCost<2>;
using StereoDynamicReprojectionCost = DynamicReprojectionCost<3>;

}  // namespace twist::optimization
