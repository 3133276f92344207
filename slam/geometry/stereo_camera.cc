#include "slam/geometry/stereo_camera.h"

#include <cmath>
#include <sstream>

#include <Eigen/SVD>

namespace twist::geometry {

absl::Status StereoCamera::Validate() const {
  auto finite_pos = [](double x) { return std::isfinite(x) && x > 0.0; };
  if (!finite_pos(fx) || !finite_pos(fy)) {
    return absl::InvalidArgumentError("camera focal lengths must be positive and finite: " +
                                      DebugString());
  }
  if (!finite_pos(baseline)) {
    return absl::InvalidArgumentError("stereo baseline must be positive (metres): " +
                                      DebugString());
  }
  if (width <= 0 || height <= 0) {
    return absl::InvalidArgumentError("image size must be positive: " + DebugString());
  }
  if (!std::isfinite(cx) || !std::isfinite(cy) || cx < 0 || cy < 0 || cx >= width ||
      cy >= height) {
    return absl::InvalidArgumentError("principal point must lie inside the image: " +
                                      DebugString());
  }
  return absl::OkStatus();
}

bool StereoCamera::ProjectChecked(const Eigen::Vector3d& p,
                                  Eigen::Vector2d* uv,
                                  Eigen::Matrix<double, 2, 3>* d_uv_d_p,
                                  double min_depth) const {
  if (!(p.z() > min_depth)) return false;
  const double inv_z = 1.0 / p.z();
  *uv = Eigen::Vector2d(fx * p.x() * inv_z + cx, fy * p.y() * inv_z + cy);
  if (d_uv_d_p != nullptr) {
    const double inv_z2 = inv_z * inv_z;
    *d_uv_d_p << fx * inv_z, 0.0, -fx * p.x() * inv_z2, 0.0, fy * inv_z, -fy * p.y() * inv_z2;
  }
  return true;
}

bool StereoCamera::ProjectStereoChecked(const Eigen::Vector3d& p,
                                        Eigen::Vector3d* uvr,
                                        Eigen::Matrix3d* d_uvr_d_p,
                                        double min_depth) const {
  if (!(p.z() > min_depth)) return false;
  const double inv_z = 1.0 / p.z();
  const double u = fx * p.x() * inv_z + cx;
  *uvr = Eigen::Vector3d(u, fy * p.y() * inv_z + cy, u - bf() * inv_z);
  if (d_uvr_d_p != nullptr) {
    const double inv_z2 = inv_z * inv_z;
    *d_uvr_d_p << fx * inv_z, 0.0, -fx * p.x() * inv_z2,  //
        0.0, fy * inv_z, -fy * p.y() * inv_z2,            //
        fx * inv_z, 0.0, -(fx * p.x() - bf()) * inv_z2;
  }
  return true;
}

Eigen::Vector3d StereoCamera::Backproject(const Eigen::Vector2d& uv, double depth) const {
  return Eigen::Vector3d((uv.x() - cx) / fx * depth, (uv.y() - cy) / fy * depth, depth);
}

Eigen::Vector3d StereoCamera::Bearing(const Eigen::Vector2d& uv) const {
  return Eigen::Vector3d((uv.x() - cx) / fx, (uv.y() - cy) / fy, 1.0).normalized();
}

std::optional<Eigen::Vector3d> StereoCamera::TriangulateStereo(double u_left,
                                                               double v,
                                                               double u_right,
                                                               double max_depth) const {
  const double disparity = u_left - u_right;
  if (!(disparity > 0.0)) return std::nullopt;
  const double depth = DisparityToDepth(disparity);
  if (!(depth <= max_depth)) return std::nullopt;
  return Backproject(Eigen::Vector2d(u_left, v), depth);
}

Eigen::Matrix<double, 3, 4> StereoCamera::LeftProjectionMatrix() const {
  Eigen::Matrix<double, 3, 4> P;
  P << fx, 0, cx, 0, 0, fy, cy, 0, 0, 0, 1, 0;
  return P;
}

Eigen::Matrix<double, 3, 4> StereoCamera::RightProjectionMatrix() const {
  Eigen::Matrix<double, 3, 4> P = LeftProjectionMatrix();
  P(0, 3) = -bf();
  return P;
}

std::string StereoCamera::DebugString() const {
  std::ostringstream os;
  os << "StereoCamera{fx=" << fx << " fy=" << fy << " cx=" << cx << " cy=" << cy
     << " baseline=" << baseline << " size=" << width << "x" << height << "}";
  return os.str();
}

std::optional<Eigen::Vector3d> TriangulateTwoView(const Eigen::Matrix<double, 3, 4>& P1,
                                                  const Eigen::Matrix<double, 3, 4>& P2,
                                                  const Eigen::Vector2d& x1,
                                                  const Eigen::Vector2d& x2) {
  Eigen::Matrix4d A;
  A.row(0) = x1.x() * P1.row(2) - P1.row(0);
  A.row(1) = x1.y() * P1.row(2) - P1.row(1);
  A.row(2) = x2.x() * P2.row(2) - P2.row(0);
  A.row(3) = x2.y() * P2.row(2) - P2.row(1);
  Eigen::JacobiSVD<Eigen::Matrix4d> svd(A, Eigen::ComputeFullV);
  const Eigen::Vector4d X = svd.matrixV().col(3);
  if (std::abs(X(3)) < 1e-12) return std::nullopt;
  return Eigen::Vector3d(X.head<3>() / X(3));
}

}  // namespace twist::geometry
