// Rectified stereo pinhole camera (KITTI convention: x right, y down, z forward;
// the right camera sits at +baseline along x of the left camera).
#pragma once

#include <optional>
#include <string>

#include <Eigen/Core>

#include "absl/status/status.h"

namespace twist::geometry {

struct StereoCamera {
  double fx = 0.0;
  double fy = 0.0;
  double cx = 0.0;
  double cy = 0.0;
  double baseline = 0.0;  // metres, > 0
  int width = 0;          // pixels
  int height = 0;

  // OK when focal lengths, baseline and size are positive and finite, and the
  // principal point lies inside the image.
  absl::Status Validate() const;

  // fx * baseline: disparity (px) = bf / depth (m).
  double bf() const { return fx * baseline; }
  double DisparityToDepth(double disparity) const { return bf() / disparity; }
  double DepthToDisparity(double depth) const { return bf() / depth; }

  bool InImage(const Eigen::Vector2d& uv, double border = 0.0) const {
    return uv.x() >= border && uv.y() >= border && uv.x() < width - border &&
           uv.y() < height - border;
  }

  // Pinhole projection of a point in the left camera frame. Generic so that
  // ceres::Jet flows through; no validity check (see ProjectChecked).
  template <typename T>
  Eigen::Matrix<T, 2, 1> Project(const Eigen::Matrix<T, 3, 1>& p_in_cam) const {
    const T inv_z = T(1.0) / p_in_cam.z();
    return Eigen::Matrix<T, 2, 1>(T(fx) * p_in_cam.x() * inv_z + T(cx),
                                  T(fy) * p_in_cam.y() * inv_z + T(cy));
  }
  // Projection into (u_left, v, u_right).
  template <typename T>
  Eigen::Matrix<T, 3, 1> ProjectStereo(const Eigen::Matrix<T, 3, 1>& p_in_cam) const {
    const T inv_z = T(1.0) / p_in_cam.z();
    const T u = T(fx) * p_in_cam.x() * inv_z + T(cx);
    return Eigen::Matrix<T, 3, 1>(u, T(fy) * p_in_cam.y() * inv_z + T(cy), u - T(bf()) * inv_z);
  }

  // Returns false for points at or behind `min_depth`. d_uv_d_p (optional)
  // receives the 2x3 Jacobian of the projection.
  bool ProjectChecked(const Eigen::Vector3d& p_in_cam,
                      Eigen::Vector2d* uv,
                      Eigen::Matrix<double, 2, 3>* d_uv_d_p = nullptr,
                      double min_depth = 1e-6) const;
  // Same for the stereo projection (u_l, v, u_r); d_uvr_d_p is 3x3.
  bool ProjectStereoChecked(const Eigen::Vector3d& p_in_cam,
                            Eigen::Vector3d* uvr,
                            Eigen::Matrix3d* d_uvr_d_p = nullptr,
                            double min_depth = 1e-6) const;

  // Back-projection of pixel (u, v) at depth z (m) into the left camera frame.
  Eigen::Vector3d Backproject(const Eigen::Vector2d& uv, double depth) const;
  // Unit-norm viewing ray through pixel (u, v).
  Eigen::Vector3d Bearing(const Eigen::Vector2d& uv) const;

  // Triangulates a rectified stereo match (u_left, v) <-> (u_right, v).
  // nullopt when the disparity is not positive or the depth exceeds max_depth.
  std::optional<Eigen::Vector3d> TriangulateStereo(double u_left,
                                                   double v,
                                                   double u_right,
                                                   double max_depth = 1e9) const;

  // Projection matrices P_left = K[I|0], P_right = K[I|-b e_x] (3x4).
  Eigen::Matrix<double, 3, 4> LeftProjectionMatrix() const;
  Eigen::Matrix<double, 3, 4> RightProjectionMatrix() const;

  std::string DebugString() const;
};

// Linear (DLT) two-view triangulation from camera_from_world 3x4 matrices
// (normalised coordinates, i.e. K removed) and bearing-plane observations.
// Returns nullopt when the configuration is degenerate.
std::optional<Eigen::Vector3d> TriangulateTwoView(const Eigen::Matrix<double, 3, 4>& cam1_from_world,
                                                  const Eigen::Matrix<double, 3, 4>& cam2_from_world,
                                                  const Eigen::Vector2d& xn1,
                                                  const Eigen::Vector2d& xn2);

}  // namespace twist::geometry
