// Constrained twist reprojection of object tracking (paper eq. dyna_tracking).
//
// Error model, N = 2 (mono) or 3 (stereo, u_right as third row):
//   r(ξ) = s · W · (x_obs − π_N(camera_from_world_i · Exp(Π ξ) · world_from_object_{i−1} ·
//   p_in_object))
// Parameter: ξ ∈ R⁶, the object's twist in the world frame ((v, ω), Euclidean
// block, no manifold). Constants: camera_from_world_i, world_from_object_{i−1},
// the 6x6 world projector Π (joints::Joint::WorldProjector()), the point in the
// object frame, the camera, the scalar square-root information s (1/σ, e.g.
// from the MAD scale of the residuals) and an N x N whitening matrix W
// (identity by default; objects::EstimateObjectTwist uses it for the point's
// own uncertainty).
//
// Analytic Jacobian, valid at every ξ (η = Πξ, p_w = Exp(η) · w_T_o · p_o,
// p_c = R_cw p_w + t_cw):
//   ∂r/∂ξ = −s · W · ∂π/∂p_c · R_cw · [I, −[p_w]x] · J_l(η) · Π
// J_l is the SE(3) left Jacobian: Exp(η + dη) = Exp(J_l(η) dη) Exp(η). The
// paper's Kronecker-form formula (∂exp evaluated at the identity) equals this
// expression at ξ = 0 only (J_l(0) = I); see docs/math.md.
// Evaluation fails for points with depth ≤ kMinProjectionDepth.
#pragma once

#include <Eigen/Core>

#include "ceres/autodiff_cost_function.h"
#include "ceres/sized_cost_function.h"
#include "slam/geometry/se3.h"
#include "slam/geometry/stereo_camera.h"
#include "slam/optimization/cost_functions/projection.h"

namespace twist::optimization {

// Constants shared by both twins.
template <int N>
struct TwistTrackingObservation {
  geometry::StereoCamera camera;
  ObservationVector<N> observed = ObservationVector<N>::Zero();
  double sqrt_information = 1.0;
  Eigen::Matrix<double, N, N> whitening = Eigen::Matrix<double, N, N>::Identity();
  geometry::SE3d camera_from_world;                                     // current frame i (fixed)
  geometry::SE3d world_from_object_previous;                            // frame i−1 (fixed)
  geometry::Matrix6d world_projector = geometry::Matrix6d::Identity();  // Π
  Eigen::Vector3d point_in_object = Eigen::Vector3d::Zero();
  // TwistDepthTrackingCost only: the point's one-σ uncertainty vector d_o in
  // the object frame.
  Eigen::Vector3d point_sigma_in_object = Eigen::Vector3d::Zero();
};

// ----------------------------------------------------------------- autodiff
// The residual of both autodiff twins for the point p_o (object frame).
template <int N, typename T>
bool TwistTrackingResidual(const TwistTrackingObservation<N>& obs,
                           const T* twist,
                           const Eigen::Matrix<T, 3, 1>& p_o,
                           T* residuals) {
  using SE3T = geometry::SE3<T>;
  const Eigen::Map<const Eigen::Matrix<T, 6, 1>> xi(twist);
  const Eigen::Matrix<T, 6, 1> eta = obs.world_projector.template cast<T>() * xi;
  const SE3T camera_from_object = obs.camera_from_world.template cast<T>() * SE3T::Exp(eta) *
                                  obs.world_from_object_previous.template cast<T>();
  const Eigen::Matrix<T, 3, 1> p_c = camera_from_object * p_o;
  if (!(p_c.z() > T(kMinProjectionDepth))) return false;
  Eigen::Map<Eigen::Matrix<T, N, 1>> r(residuals);
  r = T(obs.sqrt_information) * obs.whitening.template cast<T>() *
      (obs.observed.template cast<T>() - ProjectToObservation<N>(obs.camera, p_c));
  return true;
}

template <int N>
class TwistTrackingFunctor {
 public:
  explicit TwistTrackingFunctor(const TwistTrackingObservation<N>& obs) : obs_(obs) {}

  template <typename T>
  bool operator()(const T* twist, T* residuals) const {
    return TwistTrackingResidual<N, T>(
        obs_, twist, obs_.point_in_object.template cast<T>(), residuals);
  }

  static ceres::CostFunction* Create(const TwistTrackingObservation<N>& obs) {
    return new ceres::AutoDiffCostFunction<TwistTrackingFunctor, N, 6>(
        new TwistTrackingFunctor(obs));
  }

 private:
  TwistTrackingObservation<N> obs_;
};

// ----------------------------------------------------------------- analytic
template <int N>
class TwistTrackingCost final : public ceres::SizedCostFunction<N, 6> {
 public:
  explicit TwistTrackingCost(const TwistTrackingObservation<N>& obs)
      : obs_(obs), point_in_world_previous_(obs.world_from_object_previous * obs.point_in_object) {}

  bool Evaluate(double const* const* parameters,
                double* residuals,
                double** jacobians) const override {
    const Eigen::Map<const geometry::Vector6d> xi(parameters[0]);
    const geometry::Vector6d eta = obs_.world_projector * xi;
    const Eigen::Vector3d p_w = geometry::SE3d::Exp(eta) * point_in_world_previous_;
    const Eigen::Vector3d p_c = obs_.camera_from_world * p_w;
    if (!(p_c.z() > kMinProjectionDepth)) return false;
    Eigen::Map<Eigen::Matrix<double, N, 1>> r(residuals);
    r = obs_.sqrt_information * obs_.whitening *
        (obs_.observed - ProjectToObservation<N>(obs_.camera, p_c));
    if (jacobians != nullptr && jacobians[0] != nullptr) {
      Eigen::Map<Eigen::Matrix<double, N, 6, Eigen::RowMajor>> j(jacobians[0]);
      j = -obs_.sqrt_information * obs_.whitening * ProjectionJacobian<N>(obs_.camera, p_c) *
          obs_.camera_from_world.rotation() * PointPerturbationJacobian(p_w) *
          geometry::SE3d::LeftJacobian(eta) * obs_.world_projector;
    }
    return true;
  }

 private:
  TwistTrackingObservation<N> obs_;
  Eigen::Vector3d point_in_world_previous_;
};

// ------------------------------------------ with the point's own error
// The same error with the point moved along its uncertain direction, a second
// parameter δ (in units of its σ; its prior N(0, 1) is a separate residual):
//   r(ξ, δ) = s · W · (x_obs − π_N(camera_from_world_i · Exp(Π ξ) ·
//                                  world_from_object_{i−1} · (p_o + δ d_o)))
// Jacobians (p_w = Exp(η) · w_T_o · (p_o + δ d_o)):
//   ∂r/∂ξ = −s · W · ∂π/∂p_c · R_cw · [I, −[p_w]x] · J_l(η) · Π
//   ∂r/∂δ = −s · W · ∂π/∂p_c · R_cw · R(Exp η) · R_wo · d_o
template <int N>
class TwistDepthTrackingFunctor {
 public:
  explicit TwistDepthTrackingFunctor(const TwistTrackingObservation<N>& obs) : obs_(obs) {}

  template <typename T>
  bool operator()(const T* twist, const T* delta, T* residuals) const {
    const Eigen::Matrix<T, 3, 1> p_o = obs_.point_in_object.template cast<T>() +
                                       delta[0] * obs_.point_sigma_in_object.template cast<T>();
    return TwistTrackingResidual<N, T>(obs_, twist, p_o, residuals);
  }

  static ceres::CostFunction* Create(const TwistTrackingObservation<N>& obs) {
    return new ceres::AutoDiffCostFunction<TwistDepthTrackingFunctor, N, 6, 1>(
        new TwistDepthTrackingFunctor(obs));
  }

 private:
  TwistTrackingObservation<N> obs_;
};

template <int N>
class TwistDepthTrackingCost final : public ceres::SizedCostFunction<N, 6, 1> {
 public:
  explicit TwistDepthTrackingCost(const TwistTrackingObservation<N>& obs)
      : obs_(obs),
        point_in_world_previous_(obs.world_from_object_previous * obs.point_in_object),
        sigma_in_world_(obs.world_from_object_previous.rotation() * obs.point_sigma_in_object) {}

  bool Evaluate(double const* const* parameters,
                double* residuals,
                double** jacobians) const override {
    const Eigen::Map<const geometry::Vector6d> xi(parameters[0]);
    const double delta = parameters[1][0];
    const geometry::Vector6d eta = obs_.world_projector * xi;
    const geometry::SE3d motion = geometry::SE3d::Exp(eta);
    const Eigen::Vector3d p_w = motion * (point_in_world_previous_ + delta * sigma_in_world_);
    const Eigen::Vector3d p_c = obs_.camera_from_world * p_w;
    if (!(p_c.z() > kMinProjectionDepth)) return false;
    Eigen::Map<Eigen::Matrix<double, N, 1>> r(residuals);
    r = obs_.sqrt_information * obs_.whitening *
        (obs_.observed - ProjectToObservation<N>(obs_.camera, p_c));
    if (jacobians == nullptr) return true;
    const Eigen::Matrix<double, N, 3> d_r_d_pw = -obs_.sqrt_information * obs_.whitening *
                                                 ProjectionJacobian<N>(obs_.camera, p_c) *
                                                 obs_.camera_from_world.rotation();
    if (jacobians[0] != nullptr) {
      Eigen::Map<Eigen::Matrix<double, N, 6, Eigen::RowMajor>> j(jacobians[0]);
      j = d_r_d_pw * PointPerturbationJacobian(p_w) * geometry::SE3d::LeftJacobian(eta) *
          obs_.world_projector;
    }
    if (jacobians[1] != nullptr) {
      Eigen::Map<Eigen::Matrix<double, N, 1>> j(jacobians[1]);
      j = d_r_d_pw * (motion.rotation() * sigma_in_world_);
    }
    return true;
  }

 private:
  TwistTrackingObservation<N> obs_;
  Eigen::Vector3d point_in_world_previous_;
  Eigen::Vector3d sigma_in_world_;
};

using MonoTwistTrackingCost = TwistTrackingCost<2>;
using StereoTwistTrackingCost = TwistTrackingCost<3>;

}  // namespace twist::optimization
