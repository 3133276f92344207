// Ground-truth motion models of the synthetic generator.
//
// Frames follow DESIGN.md §3: world = first left camera frame, x right, y down,
// z forward. The road is the plane y = ground_y (ground_y > 0: the road lies
// below the camera). Every motion model is a *joint*: a planar motion only
// changes (x, z, yaw) of a body whose height and roll/pitch stay constant; a
// revolute motion only rotates a body about a fixed hinge axis. Poses are
// closed-form functions of time, so rendering and ground truth agree exactly.
#pragma once

#include <Eigen/Core>
#include <vector>

#include "slam/geometry/se3.h"

namespace twist::sim {

// State on the ground plane. Heading direction in world = (sin yaw, 0, cos yaw):
// yaw 0 looks along +z, positive yaw turns right (towards +x). This is a
// rotation by `yaw` about the world y axis (pointing down).
struct PlanarState {
  double x = 0.0;
  double z = 0.0;
  double yaw = 0.0;
  double speed = 0.0;  // m/s along the heading, >= 0
};

// One piece of a planar trajectory: constant longitudinal acceleration and
// constant path curvature (1/m, > 0 turns right) for `duration` seconds. A
// decelerating segment stops at speed 0 and stays stopped until its end.
struct PlanarSegment {
  double duration = 0.0;
  double accel = 0.0;
  double curvature = 0.0;
};

// Which body axis points along the heading.
enum class HeadingAxis {
  kZ,  // cameras: body z = heading, y = down
  kX,  // KITTI boxes (cars, pedestrians): body x = heading, y = down
};

// Planar trajectory (joint "planar" with the road normal). After the last
// segment the body keeps its final speed along a straight line.
class PlanarMotion {
 public:
  PlanarMotion() = default;
  PlanarMotion(const PlanarState& start, std::vector<PlanarSegment> segments, double body_y);

  // State at time t (s) from the start of the sequence; t < 0 extrapolates
  // backwards along the initial heading with the initial speed.
  PlanarState StateAt(double t) const;
  // world_from_body: rotation R_y(yaw) (camera) or R_y(yaw - π/2) (KITTI box),
  // translation (x, body_y, z).
  geometry::SE3d PoseAt(double t, HeadingAxis axis) const;
  double body_y() const { return body_y_; }
  const PlanarState& start() const { return start_; }
  // Total distance travelled from 0 to t.
  double DistanceAt(double t) const;

 private:
  struct SegmentStart {
    double t0;
    double s0;  // distance travelled at t0
    PlanarState state;
  };
  static PlanarState Advance(const PlanarState& s,
                             const PlanarSegment& seg,
                             double dt,
                             double* distance);

  PlanarState start_;
  std::vector<PlanarSegment> segments_;
  std::vector<SegmentStart> starts_;
  double body_y_ = 0.0;
};

// Rotation about a fixed hinge (joint "revolute"): the body pose is
//   world_from_body(t) = Rot(axis, angle(t)) about `hinge_point` · world_from_body_closed,
// angle(t) rises smoothly (C¹ smoothstep) from angle0 at t0 to angle1 at t1.
class RevoluteMotion {
 public:
  RevoluteMotion() = default;
  RevoluteMotion(const geometry::SE3d& world_from_body_closed,
                 const Eigen::Vector3d& hinge_point,
                 const Eigen::Vector3d& hinge_axis,
                 double angle0,
                 double angle1,
                 double t0,
                 double t1);

  double AngleAt(double t) const;
  geometry::SE3d PoseAt(double t) const;
  const Eigen::Vector3d& hinge_point() const { return hinge_point_; }
  const Eigen::Vector3d& hinge_axis() const { return hinge_axis_; }

 private:
  geometry::SE3d world_from_body_closed_;
  Eigen::Vector3d hinge_point_ = Eigen::Vector3d::Zero();
  Eigen::Vector3d hinge_axis_ = Eigen::Vector3d::UnitY();
  double angle0_ = 0.0, angle1_ = 0.0, t0_ = 0.0, t1_ = 1.0;
};

// Rotation about the world y axis by `angle`.
Eigen::Matrix3d RotY(double angle);

}  // namespace twist::sim
