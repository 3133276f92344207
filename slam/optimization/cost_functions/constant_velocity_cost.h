// Constant-velocity term of the dynamic bundle adjustment (paper e_const).
//
// For three consecutive frames k ∈ {i−1, i, i+1} of one object, the corrected
// object poses are P_k = Exp(Π ξ̃_k) · world_from_object_k. The world-frame
// twists linking them are
//   a = Log(P_i · P_{i−1}⁻¹)        (so that P_i = Exp(a) P_{i−1})
//   b = Log(P_{i+1} · P_i⁻¹)
// and the residual is
//   r = W^{1/2} (Π b − Π a),   W = diag(w) (w given as its square roots).
// Robust loss (Huber) is added by the caller.
//
// Parameter blocks, in this order:
//   ξ̃_{i−1} (6), world_from_object_{i−1} (7, SE3Manifold),
//   ξ̃_i     (6), world_from_object_i     (7, SE3Manifold),
//   ξ̃_{i+1} (6), world_from_object_{i+1} (7, SE3Manifold).
// Set the pose blocks constant to optimise the objects through ξ̃ only.
//
// Analytic Jacobians. With ε_k a left perturbation of P_k (P_k <- Exp(ε_k) P_k):
//   ∂r/∂ε_{i−1} =  W^{1/2} Π J_r⁻¹(a)
//   ∂r/∂ε_i     = −W^{1/2} Π (J_l⁻¹(a) + J_r⁻¹(b))
//   ∂r/∂ε_{i+1} =  W^{1/2} Π J_l⁻¹(b)
// and ε_k = J_l(Π ξ̃_k) Π dξ̃_k for the twist blocks, ε_k = Ad(P_k) δ_k for a
// right perturbation δ_k of world_from_object_k. The paper's formula
// (Π ∂log/∂T (I₄ ⊗ R) ∂exp Π) is the same derivative written in Kronecker form
// with ∂exp taken at the identity, i.e. exact only at ξ̃ = 0; see docs/math.md.
#pragma once

#include <Eigen/Core>

#include "ceres/autodiff_cost_function.h"
#include "ceres/sized_cost_function.h"
#include "slam/geometry/se3.h"
#include "slam/optimization/manifolds/se3_manifold.h"

namespace twist::optimization {

// ----------------------------------------------------------------- autodiff
class ConstantVelocityFunctor {
 public:
  ConstantVelocityFunctor(const geometry::Matrix6d& world_projector,
                          const geometry::Vector6d& sqrt_weights)
      : world_projector_(world_projector), sqrt_weights_(sqrt_weights) {}

  template <typename T>
  bool operator()(const T* twist_prev,
                  const T* pose_prev,
                  const T* twist_curr,
                  const T* pose_curr,
                  const T* twist_next,
                  const T* pose_next,
                  T* residuals) const {
    using SE3T = geometry::SE3<T>;
    using Vector6T = Eigen::Matrix<T, 6, 1>;
    const Eigen::Matrix<T, 6, 6> pi = world_projector_.template cast<T>();
    auto corrected = [&pi](const T* twist, const T* pose) {
      return SE3T::Exp(pi * Eigen::Map<const Vector6T>(twist)) * SE3T::FromParams(pose);
    };
    const SE3T p_prev = corrected(twist_prev, pose_prev);
    const SE3T p_curr = corrected(twist_curr, pose_curr);
    const SE3T p_next = corrected(twist_next, pose_next);
    const Vector6T a = (p_curr * p_prev.Inverse()).Log();
    const Vector6T b = (p_next * p_curr.Inverse()).Log();
    Eigen::Map<Vector6T> r(residuals);
    r = sqrt_weights_.template cast<T>().asDiagonal() * (pi * (b - a));
    return true;
  }

  static ceres::CostFunction* Create(const geometry::Matrix6d& world_projector,
                                     const geometry::Vector6d& sqrt_weights) {
    return new ceres::AutoDiffCostFunction<ConstantVelocityFunctor, 6, 6, 7, 6, 7, 6, 7>(
        new ConstantVelocityFunctor(world_projector, sqrt_weights));
  }

 private:
  geometry::Matrix6d world_projector_;
  geometry::Vector6d sqrt_weights_;
};

// ----------------------------------------------------------------- analytic
class ConstantVelocityCost final : public ceres::SizedCostFunction<6, 6, 7, 6, 7, 6, 7> {
 public:
  ConstantVelocityCost(const geometry::Matrix6d& world_projector,
                       const geometry::Vector6d& sqrt_weights)
      : world_projector_(world_projector), sqrt_weights_(sqrt_weights) {}

  bool Evaluate(double const* const* parameters,
                double* residuals,
                double** jacobians) const override {
    using geometry::Matrix6d;
    using geometry::SE3d;
    using geometry::Vector6d;
    Vector6d eta[3];
    SE3d corrected[3];
    for (int k = 0; k < 3; ++k) {
      eta[k] = world_projector_ * Eigen::Map<const Vector6d>(parameters[2 * k]);
      corrected[k] = SE3d::Exp(eta[k]) * SE3d::FromParams(parameters[2 * k + 1]);
    }
    const Vector6d a = (corrected[1] * corrected[0].Inverse()).Log();
    const Vector6d b = (corrected[2] * corrected[1].Inverse()).Log();
    Eigen::Map<Vector6d> r(residuals);
    r = sqrt_weights_.asDiagonal() * (world_projector_ * (b - a));
    if (jacobians == nullptr) return true;

    const Matrix6d s_pi = sqrt_weights_.asDiagonal() * world_projector_;
    // ∂r/∂ε_k for the left perturbation of each corrected pose.
    const Matrix6d d_r_d_eps[3] = {
        s_pi * SE3d::RightJacobianInverse(a),
        -s_pi * (SE3d::LeftJacobianInverse(a) + SE3d::RightJacobianInverse(b)),
        s_pi * SE3d::LeftJacobianInverse(b),
    };
    for (int k = 0; k < 3; ++k) {
      if (jacobians[2 * k] != nullptr) {
        Eigen::Map<Eigen::Matrix<double, 6, 6, Eigen::RowMajor>> j(jacobians[2 * k]);
        j = d_r_d_eps[k] * SE3d::LeftJacobian(eta[k]) * world_projector_;
      }
      if (jacobians[2 * k + 1] != nullptr) {
        const Eigen::Matrix<double, 6, 6> local = d_r_d_eps[k] * corrected[k].Adjoint();
        SE3LocalToAmbientJacobian<6>(parameters[2 * k + 1], local, jacobians[2 * k + 1]);
      }
    }
    return true;
  }

 private:
  geometry::Matrix6d world_projector_;
  geometry::Vector6d sqrt_weights_;
};

}  // namespace twist::optimization
