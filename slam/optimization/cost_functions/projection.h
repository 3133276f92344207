// Shared pieces of the reprojection cost functions: the N-dimensional
// observation model (N = 2 mono (u, v), N = 3 stereo (u_left, v, u_right)),
// its Jacobian, and the derivatives of a transformed point with respect to
// SE(3) perturbations.
#pragma once

#include <Eigen/Core>

#include "slam/geometry/se3.h"
#include "slam/geometry/so3.h"
#include "slam/geometry/stereo_camera.h"

namespace twist::optimization {

// Points at or behind this depth (metres, camera frame) make a reprojection
// residual fail to evaluate (Evaluate returns false, Ceres rejects the step).
// Callers must only add observations of points in front of the camera.
inline constexpr double kMinProjectionDepth = 1e-6;

template <int N>
using ObservationVector = Eigen::Matrix<double, N, 1>;

// Projects a point in the left camera frame into the N-dim observation space.
template <int N, typename T>
Eigen::Matrix<T, N, 1> ProjectToObservation(const geometry::StereoCamera& camera,
                                            const Eigen::Matrix<T, 3, 1>& p_in_camera) {
  static_assert(N == 2 || N == 3, "observations are mono (2) or stereo (3)");
  if constexpr (N == 2) {
    return camera.Project(p_in_camera);
  } else {
    return camera.ProjectStereo(p_in_camera);
  }
}

// d(observation)/d(p_in_camera), N x 3.
template <int N>
Eigen::Matrix<double, N, 3> ProjectionJacobian(const geometry::StereoCamera& camera,
                                               const Eigen::Vector3d& p) {
  static_assert(N == 2 || N == 3, "observations are mono (2) or stereo (3)");
  const double inv_z = 1.0 / p.z();
  const double inv_z2 = inv_z * inv_z;
  Eigen::Matrix<double, N, 3> j;
  j.template topRows<2>() << camera.fx * inv_z, 0.0, -camera.fx * p.x() * inv_z2,  //
      0.0, camera.fy * inv_z, -camera.fy * p.y() * inv_z2;
  if constexpr (N == 3) {
    j.row(2) << camera.fx * inv_z, 0.0, -(camera.fx * p.x() - camera.bf()) * inv_z2;
  }
  return j;
}

// d(Exp(ε) · p)/dε at ε = 0 (left perturbation of a point already expressed
// in the perturbed frame's target): [I, -[p]x]. With right perturbation of a
// pose T, d(T·Exp(δ)·p)/dδ = R · PointPerturbationJacobian(p).
inline Eigen::Matrix<double, 3, 6> PointPerturbationJacobian(const Eigen::Vector3d& p) {
  Eigen::Matrix<double, 3, 6> j;
  j.leftCols<3>().setIdentity();
  j.rightCols<3>() = -geometry::SO3d::Hat(p);
  return j;
}

}  // namespace twist::optimization
