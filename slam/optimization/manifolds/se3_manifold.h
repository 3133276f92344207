// SE(3) as a ceres::Manifold on the 7-scalar pose block
// [qx, qy, qz, qw, tx, ty, tz] (see slam/geometry/se3.h).
//
// Right perturbation, tangent δ = (v, ω) translation first:
//   Plus(T, δ)  = T · Exp(δ)
//   Minus(S, T) = Log(T⁻¹ · S)
// Plus renormalises the quaternion of its result. Minus uses the logarithm on
// the quaternion double cover WITHOUT choosing the shortest representative
// (rotation angle in [0, 2π)), like Ceres's QuaternionManifold, so that
// Plus(T, Minus(S, T)) == S holds coefficient-wise even when the two
// quaternions lie in opposite hemispheres.
//
// At δ = 0 (unit quaternion q = (q_v, q_w), rotation R):
//   PlusJacobian  P = [[0, ½ Q(q)], [R, 0]]      (7 x 6)
//   MinusJacobian M = [[0, Rᵀ], [2 Q(q)ᵀ, 0]]    (6 x 7)
// with Q(q) = [[q_w I + [q_v]x], [-q_vᵀ]] (4 x 3, orthonormal columns), so
// M = P⁺ (pseudo-inverse) and M P = I₆.
//
// Analytic cost functions compute their Jacobian with respect to the tangent
// perturbation δ (J_δ, rows x 6) and hand Ceres the ambient Jacobian
// J_amb = J_δ M (rows x 7): Ceres multiplies by P, and J_amb P = J_δ exactly.
#pragma once

#include <Eigen/Core>

#include "ceres/manifold.h"
#include "slam/geometry/se3.h"

namespace twist::optimization {

class SE3Manifold final : public ceres::Manifold {
 public:
  static constexpr int kAmbientSize = 7;
  static constexpr int kTangentSize = 6;

  int AmbientSize() const override { return kAmbientSize; }
  int TangentSize() const override { return kTangentSize; }

  bool Plus(const double* x, const double* delta, double* x_plus_delta) const override;
  bool PlusJacobian(const double* x, double* jacobian) const override;
  bool Minus(const double* y, const double* x, double* y_minus_x) const override;
  bool MinusJacobian(const double* x, double* jacobian) const override;
};

// Row-major 7x6 PlusJacobian / 6x7 MinusJacobian at pose block x, as Eigen
// matrices (the quaternion of x is normalised first).
Eigen::Matrix<double, 7, 6, Eigen::RowMajor> SE3PlusJacobian(const double* x);
Eigen::Matrix<double, 6, 7, Eigen::RowMajor> SE3MinusJacobian(const double* x);

// Writes J_amb = J_local · MinusJacobian(x) into the row-major (rows x 7)
// array `ambient` (a Ceres Jacobian block). See the header comment.
template <int kRows>
void SE3LocalToAmbientJacobian(const double* x,
                               const Eigen::Matrix<double, kRows, 6>& local,
                               double* ambient) {
  Eigen::Map<Eigen::Matrix<double, kRows, 7, Eigen::RowMajor>> out(ambient);
  out.noalias() = local * SE3MinusJacobian(x);
}

}  // namespace twist::optimization
