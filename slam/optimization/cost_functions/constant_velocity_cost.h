// Motion-prior terms of the dynamic bundle adjustment (paper e_const, and its
// constant-acceleration counterpart).
//
// For consecutive frames k of one object, the corrected object poses are
// P_k = Exp(Π ξ̃_k) · world_from_object_k, and the world-frame steps linking
// them are s_k = Log(P_{k+1} · P_k⁻¹) (so that P_{k+1} = Exp(s_k) P_k). A
// motion prior is a finite difference of the steps,
//   r = W^{1/2} Π Σ_k c_k s_k,   W = diag(w) (w given as its square roots):
//   constant velocity (3 frames):     c = (−1, 1),      r = W^{1/2} Π (s_1 − s_0)
//   constant acceleration (4 frames): c = (1, −2, 1),   r = W^{1/2} Π (s_2 − 2 s_1 + s_0)
// Robust loss (Huber) is added by the caller. The code evaluates any
// r = M Σ_k c_k s_k (StepCombinationCost/Functor, M a residual map); the
// normal-step prior at the end of this file is the other instance.
//
// Parameter blocks, in this order, for each frame k:
//   ξ̃_k (6), world_from_object_k (7, SE3Manifold).
// Set the pose blocks constant to optimise the objects through ξ̃ only.
//
// Analytic Jacobians. With ε_k a left perturbation of P_k (P_k <- Exp(ε_k) P_k),
//   ∂s_k/∂ε_k = −J_r⁻¹(s_k),   ∂s_k/∂ε_{k+1} = J_l⁻¹(s_k),
// so ∂r/∂ε_k = W^{1/2} Π (c_{k−1} J_l⁻¹(s_{k−1}) − c_k J_r⁻¹(s_k)) (terms with
// an index out of range are absent). For three frames this is
//   ∂r/∂ε_{i−1} =  W^{1/2} Π J_r⁻¹(a)
//   ∂r/∂ε_i     = −W^{1/2} Π (J_l⁻¹(a) + J_r⁻¹(b))
//   ∂r/∂ε_{i+1} =  W^{1/2} Π J_l⁻¹(b)
// with a = s_0, b = s_1. Then ε_k = J_l(Π ξ̃_k) Π dξ̃_k for the twist blocks,
// ε_k = Ad(P_k) δ_k for a right perturbation δ_k of world_from_object_k. The
// paper's formula (Π ∂log/∂T (I₄ ⊗ R) ∂exp Π) is the same derivative written in
// Kronecker form with ∂exp taken at the identity, i.e. exact only at ξ̃ = 0;
// see docs/math.md.
//
// Why both (docs/math.md §13): a constant-velocity prior holds a car that
// brakes or accelerates back, and in a sliding window whose oldest frame is
// fixed that pull is kept every time the window slides, so a braking car
// drifts by ~2 cm per frame. A constant-acceleration prior is unbiased while
// the acceleration is constant.
#pragma once

#include <Eigen/Core>
#include <algorithm>
#include <array>
#include <tuple>
#include <utility>

#include "ceres/autodiff_cost_function.h"
#include "ceres/sized_cost_function.h"
#include "slam/geometry/se3.h"
#include "slam/optimization/manifolds/se3_manifold.h"

namespace twist::optimization {

namespace motion_prior_internal {

// r = M Σ_k c_k Log(P_{k+1} P_k⁻¹) for kPoses corrected poses given as
// (twist, pose) parameter pairs, M (kResiduals × 6) the residual map
// (W^{1/2} Π for the motion priors).
template <typename T, int kPoses, int kResiduals>
void Residual(const geometry::Matrix6d& world_projector,
              const Eigen::Matrix<double, kResiduals, 6>& residual_map,
              const std::array<double, kPoses - 1>& coefficients,
              const std::array<const T*, 2 * kPoses>& parameters,
              T* residuals) {
  using SE3T = geometry::SE3<T>;
  using Vector6T = Eigen::Matrix<T, 6, 1>;
  const Eigen::Matrix<T, 6, 6> pi = world_projector.template cast<T>();
  SE3T corrected[kPoses];
  for (int k = 0; k < kPoses; ++k) {
    corrected[k] = SE3T::Exp(pi * Eigen::Map<const Vector6T>(parameters[2 * k])) *
                   SE3T::FromParams(parameters[2 * k + 1]);
  }
  Vector6T combination = Vector6T::Zero();
  for (int k = 0; k + 1 < kPoses; ++k) {
    combination += T(coefficients[k]) * (corrected[k + 1] * corrected[k].Inverse()).Log();
  }
  Eigen::Map<Eigen::Matrix<T, kResiduals, 1>> r(residuals);
  r = residual_map.template cast<T>() * combination;
}

// The analytic residual and Jacobians of Residual (see the header comment).
template <int kPoses, int kResiduals>
bool Evaluate(const geometry::Matrix6d& world_projector,
              const Eigen::Matrix<double, kResiduals, 6>& residual_map,
              const std::array<double, kPoses - 1>& coefficients,
              double const* const* parameters,
              double* residuals,
              double** jacobians) {
  using geometry::Matrix6d;
  using geometry::SE3d;
  using geometry::Vector6d;
  using JacobianLocal = Eigen::Matrix<double, kResiduals, 6>;
  Vector6d eta[kPoses];
  SE3d corrected[kPoses];
  for (int k = 0; k < kPoses; ++k) {
    eta[k] = world_projector * Eigen::Map<const Vector6d>(parameters[2 * k]);
    corrected[k] = SE3d::Exp(eta[k]) * SE3d::FromParams(parameters[2 * k + 1]);
  }
  Vector6d steps[kPoses - 1];
  Vector6d combination = Vector6d::Zero();
  for (int k = 0; k + 1 < kPoses; ++k) {
    steps[k] = (corrected[k + 1] * corrected[k].Inverse()).Log();
    combination += coefficients[k] * steps[k];
  }
  Eigen::Map<Eigen::Matrix<double, kResiduals, 1>> r(residuals);
  r = residual_map * combination;
  if (jacobians == nullptr) return true;

  for (int k = 0; k < kPoses; ++k) {
    if (jacobians[2 * k] == nullptr && jacobians[2 * k + 1] == nullptr) continue;
    // ∂r/∂ε_k for the left perturbation of corrected pose k.
    Matrix6d d_step = Matrix6d::Zero();
    if (k > 0) d_step += coefficients[k - 1] * SE3d::LeftJacobianInverse(steps[k - 1]);
    if (k + 1 < kPoses) d_step -= coefficients[k] * SE3d::RightJacobianInverse(steps[k]);
    const JacobianLocal d_r_d_eps = residual_map * d_step;
    if (jacobians[2 * k] != nullptr) {
      Eigen::Map<Eigen::Matrix<double, kResiduals, 6, Eigen::RowMajor>> j(jacobians[2 * k]);
      j = d_r_d_eps * SE3d::LeftJacobian(eta[k]) * world_projector;
    }
    if (jacobians[2 * k + 1] != nullptr) {
      const JacobianLocal local = d_r_d_eps * corrected[k].Adjoint();
      SE3LocalToAmbientJacobian<kResiduals>(parameters[2 * k + 1], local, jacobians[2 * k + 1]);
    }
  }
  return true;
}

// c_k of the finite difference over kPoses poses (3: velocity, 4: acceleration).
template <int kPoses>
constexpr std::array<double, kPoses - 1> Coefficients() {
  static_assert(kPoses == 3 || kPoses == 4, "constant velocity or constant acceleration");
  if constexpr (kPoses == 3) {
    return {-1.0, 1.0};
  } else {
    return {1.0, -2.0, 1.0};
  }
}

// Parameter block sizes (twist 6, pose 7) × kPoses, as a Ceres size list.
template <int kResiduals, typename Functor, size_t... I>
ceres::CostFunction* NewAutoDiff(Functor* functor, std::index_sequence<I...>) {
  return new ceres::AutoDiffCostFunction<Functor, kResiduals, (I % 2 == 0 ? 6 : 7)...>(functor);
}
template <int kResiduals, typename Sequence>
struct Sized;
template <int kResiduals, size_t... I>
struct Sized<kResiduals, std::index_sequence<I...>> {
  using type = ceres::SizedCostFunction<kResiduals, (I % 2 == 0 ? 6 : 7)...>;
};

// M = W^{1/2} Π.
inline Eigen::Matrix<double, 6, 6> WeightedProjector(const geometry::Matrix6d& world_projector,
                                                     const geometry::Vector6d& sqrt_weights) {
  return sqrt_weights.asDiagonal() * world_projector;
}

}  // namespace motion_prior_internal

// ----------------------------------------------------------------- autodiff
// r = M Σ_k c_k s_k over kPoses (twist, pose) pairs, evaluated literally.
template <int kPoses, int kResiduals>
class StepCombinationFunctor {
 public:
  StepCombinationFunctor(const geometry::Matrix6d& world_projector,
                         const Eigen::Matrix<double, kResiduals, 6>& residual_map,
                         const std::array<double, kPoses - 1>& coefficients)
      : world_projector_(world_projector),
        residual_map_(residual_map),
        coefficients_(coefficients) {}

  // (ξ̃_0, pose_0, ..., ξ̃_{kPoses−1}, pose_{kPoses−1}, residuals).
  template <typename T, typename... Rest>
  bool operator()(const T* twist_0, Rest... rest) const {
    static_assert(sizeof...(Rest) == 2 * kPoses, "2 blocks per pose, then the residuals");
    const std::array<const T*, 2 * kPoses + 1> all = {twist_0, rest...};
    std::array<const T*, 2 * kPoses> parameters;
    std::copy_n(all.begin(), 2 * kPoses, parameters.begin());
    T* residuals = std::get<2 * kPoses - 1>(std::make_tuple(rest...));
    motion_prior_internal::Residual<T, kPoses, kResiduals>(
        world_projector_, residual_map_, coefficients_, parameters, residuals);
    return true;
  }

  static ceres::CostFunction* Create(const geometry::Matrix6d& world_projector,
                                     const Eigen::Matrix<double, kResiduals, 6>& residual_map,
                                     const std::array<double, kPoses - 1>& coefficients) {
    return motion_prior_internal::NewAutoDiff<kResiduals>(
        new StepCombinationFunctor(world_projector, residual_map, coefficients),
        std::make_index_sequence<2 * kPoses>());
  }

 private:
  geometry::Matrix6d world_projector_;
  Eigen::Matrix<double, kResiduals, 6> residual_map_;
  std::array<double, kPoses - 1> coefficients_;
};

// ----------------------------------------------------------------- analytic
template <int kPoses, int kResiduals>
class StepCombinationCost
    : public motion_prior_internal::Sized<kResiduals, std::make_index_sequence<2 * kPoses>>::type {
 public:
  StepCombinationCost(const geometry::Matrix6d& world_projector,
                      const Eigen::Matrix<double, kResiduals, 6>& residual_map,
                      const std::array<double, kPoses - 1>& coefficients)
      : world_projector_(world_projector),
        residual_map_(residual_map),
        coefficients_(coefficients) {}

  bool Evaluate(double const* const* parameters,
                double* residuals,
                double** jacobians) const override {
    return motion_prior_internal::Evaluate<kPoses, kResiduals>(
        world_projector_, residual_map_, coefficients_, parameters, residuals, jacobians);
  }

 private:
  geometry::Matrix6d world_projector_;
  Eigen::Matrix<double, kResiduals, 6> residual_map_;
  std::array<double, kPoses - 1> coefficients_;
};

// The motion priors: M = W^{1/2} Π, c of Coefficients<kPoses>.
template <int kPoses>
class MotionPriorFunctor : public StepCombinationFunctor<kPoses, 6> {
 public:
  MotionPriorFunctor(const geometry::Matrix6d& world_projector,
                     const geometry::Vector6d& sqrt_weights)
      : StepCombinationFunctor<kPoses, 6>(
            world_projector,
            motion_prior_internal::WeightedProjector(world_projector, sqrt_weights),
            motion_prior_internal::Coefficients<kPoses>()) {}

  static ceres::CostFunction* Create(const geometry::Matrix6d& world_projector,
                                     const geometry::Vector6d& sqrt_weights) {
    return motion_prior_internal::NewAutoDiff<6>(
        new MotionPriorFunctor(world_projector, sqrt_weights),
        std::make_index_sequence<2 * kPoses>());
  }
};

template <int kPoses>
class MotionPriorCost final : public StepCombinationCost<kPoses, 6> {
 public:
  MotionPriorCost(const geometry::Matrix6d& world_projector, const geometry::Vector6d& sqrt_weights)
      : StepCombinationCost<kPoses, 6>(
            world_projector,
            motion_prior_internal::WeightedProjector(world_projector, sqrt_weights),
            motion_prior_internal::Coefficients<kPoses>()) {}
};

using ConstantVelocityFunctor = MotionPriorFunctor<3>;
using ConstantAccelerationFunctor = MotionPriorFunctor<4>;
using ConstantVelocityCost = MotionPriorCost<3>;
using ConstantAccelerationCost = MotionPriorCost<4>;

// A prior on the translation of one step along a unit world direction n
// (the normal of a planar joint's plane, which the object is given a soft
// freedom along): r = (nᵀ v(s_0)) / σ, s_0 = Log(P_1 P_0⁻¹), v its
// translation part; two (twist, pose) pairs, Π the object's (extended)
// world projector.
inline Eigen::Matrix<double, 1, 6> NormalStepMap(const Eigen::Vector3d& normal, double sigma) {
  Eigen::Matrix<double, 1, 6> m = Eigen::Matrix<double, 1, 6>::Zero();
  m.leftCols<3>() = normal.transpose() / sigma;
  return m;
}
using NormalStepFunctor = StepCombinationFunctor<2, 1>;
using NormalStepCost = StepCombinationCost<2, 1>;

}  // namespace twist::optimization
