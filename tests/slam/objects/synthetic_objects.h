// Synthetic scenes for the object tests: a planar car on a road plane and a
// revolute door in a wall, with exact ground truth (projected known points).
#pragma once

#include <Eigen/Core>
#include <Eigen/Geometry>
#include <random>
#include <vector>

#include "slam/geometry/se3.h"
#include "slam/geometry/stereo_camera.h"
#include "slam/objects/twist_estimator.h"

namespace twist::objects::testing {

using geometry::Matrix6d;
using geometry::SE3d;
using geometry::Vector6d;

inline geometry::StereoCamera KittiLikeCamera() {
  geometry::StereoCamera cam;
  cam.fx = cam.fy = 718.856;
  cam.cx = 607.19;
  cam.cy = 185.22;
  cam.baseline = 0.537;
  cam.width = 1241;
  cam.height = 376;
  return cam;
}

// Π = Ad(world_from_joint) diag(mask) Ad(world_from_joint)⁻¹.
inline Matrix6d ProjectorFromMask(const SE3d& world_from_joint, const Vector6d& mask) {
  const Matrix6d ad = world_from_joint.Adjoint();
  return ad * Matrix6d(mask.asDiagonal()) * ad.inverse();
}

// Road: plane y = 1.65 (camera 1.65 m above it, y down). Joint frame: z up
// (world −y), x = world x, origin below `anchor` on the road.
inline SE3d RoadJointFrame(const Eigen::Vector3d& anchor) {
  Eigen::Matrix3d r;
  r.col(0) = Eigen::Vector3d::UnitX();
  r.col(2) = -Eigen::Vector3d::UnitY();
  r.col(1) = r.col(2).cross(r.col(0));
  return SE3d(r, Eigen::Vector3d(anchor.x(), 1.65, anchor.z()));
}

inline Matrix6d PlanarProjector(const SE3d& world_from_joint) {
  Vector6d m;
  m << 1, 1, 0, 0, 0, 1;
  return ProjectorFromMask(world_from_joint, m);
}
inline Matrix6d RevoluteProjector(const SE3d& world_from_joint) {
  Vector6d m;
  m << 0, 0, 0, 0, 0, 1;
  return ProjectorFromMask(world_from_joint, m);
}

// Points on the surface of a car-sized box in the object frame (x across,
// y along the car, z up from the road).
inline std::vector<Eigen::Vector3d> CarPoints(int n, std::mt19937_64* rng) {
  std::uniform_real_distribution<double> ux(-0.9, 0.9), uy(-2.2, 2.2), uz(0.3, 1.5);
  std::uniform_int_distribution<int> face(0, 2);
  std::vector<Eigen::Vector3d> pts;
  for (int k = 0; k < n; ++k) {
    Eigen::Vector3d p(ux(*rng), uy(*rng), uz(*rng));
    switch (face(*rng)) {
      case 0:
        p.x() = p.x() > 0 ? 0.9 : -0.9;
        break;
      case 1:
        p.y() = p.y() > 0 ? 2.2 : -2.2;
        break;
      default:
        p.z() = 1.5;
        break;
    }
    pts.push_back(p);
  }
  return pts;
}

// Observations of `points` (object frame) seen by camera_from_world after the
// object moved by Exp(true_twist) from world_from_object_previous.
inline std::vector<TwistObservation> Observe(const geometry::StereoCamera& cam,
                                             const SE3d& camera_from_world,
                                             const SE3d& world_from_object,
                                             const std::vector<Eigen::Vector3d>& points,
                                             bool stereo,
                                             double noise_px,
                                             std::mt19937_64* rng) {
  std::normal_distribution<double> g(0.0, noise_px > 0 ? noise_px : 1.0);
  std::vector<TwistObservation> obs;
  for (const Eigen::Vector3d& p : points) {
    const Eigen::Vector3d uvr =
        cam.ProjectStereo(Eigen::Vector3d(camera_from_world * (world_from_object * p)));
    TwistObservation o;
    o.point_in_object = p;
    o.uv = uvr.head<2>();
    if (stereo) o.u_right = uvr.z();
    if (noise_px > 0) {
      o.uv += Eigen::Vector2d(g(*rng), g(*rng));
      if (stereo) o.u_right += g(*rng);
    }
    obs.push_back(o);
  }
  return obs;
}

inline double RotationErrorDeg(const SE3d& a, const SE3d& b) {
  return (a.so3().Inverse() * b.so3()).Log().norm() * 180.0 / M_PI;
}
inline double TranslationError(const SE3d& a, const SE3d& b) {
  return (a.translation() - b.translation()).norm();
}
// The rotation of a step about the true step's axis, minus the true one
// (> 0: the estimate turned too far), in degrees.
inline double TurnExcessDeg(const SE3d& est_step, const SE3d& true_step) {
  const Eigen::AngleAxisd e(est_step.rotation());
  const Eigen::AngleAxisd t(true_step.rotation());
  return ((e.angle() * e.axis()).dot(t.axis()) - t.angle()) * 180.0 / M_PI;
}
// A world offset (CarSequence::set_measurement_glitch) that turns an object
// by `deg` about its own up axis (the object frame's z) through its origin,
// then moves it `ahead_m` along its heading (the object frame's y).
inline SE3d TurnedInPlace(const SE3d& world_from_object, double deg, double ahead_m = 0.0) {
  const Eigen::Vector3d centre = world_from_object.translation();
  const Eigen::Matrix3d axes = world_from_object.rotation();
  return SE3d(geometry::SO3d(), centre + ahead_m * axes.col(1)) *
         SE3d(geometry::SO3d::Exp(axes.col(2) * (deg * M_PI / 180.0)), Eigen::Vector3d::Zero()) *
         SE3d(geometry::SO3d(), -centre);
}

}  // namespace twist::objects::testing
