// Joint frames of dynamic clusters from their parents' geometry (paper
// §IV-B/E): a car's planar joint lies in its parent road's plane, a door's
// revolute joint on a hinge axis in its wall.
#pragma once

#include <Eigen/Core>
#include <optional>

#include "absl/status/statusor.h"
#include "slam/joints/joint.h"

namespace twist::objects {

// What is known about a dynamic cluster's parent and the cluster itself.
struct JointSpec {
  joints::JointType type = joints::JointType::kFree;
  double pitch = 0.0;                           // helical only
  std::optional<Eigen::Vector4d> parent_plane;  // (a, b, c, d) of the parent cluster
  // Axis (revolute, prismatic, cylindrical, helical, sphere-cylinder) through
  // axis_point with direction axis_direction, world frame.
  std::optional<Eigen::Vector3d> axis_direction;
  std::optional<Eigen::Vector3d> axis_point;
  Eigen::Vector3d anchor = Eigen::Vector3d::Zero();  // a point of the object (centroid)
};

// Builds the joint in the world:
//  - free / rigid: joint frame = world axes at the anchor;
//  - planar, point contact, line contact: from the parent plane
//    (Joint::FromPlaneCoefficients / FromPlane), origin = anchor projected;
//  - axis joints: from the axis; if only the parent plane is known the axis
//    is taken as the plane normal through the anchor's projection (a
//    turntable-like revolute joint);
//  - spherical joints: centred on the anchor.
// FailedPrecondition when the geometry the joint needs is missing (the caller
// may fall back to a free joint and retry when the parent's plane exists).
absl::StatusOr<joints::Joint> ResolveJoint(const JointSpec& spec);

// The same, falling back to a free joint at the anchor when the geometry is
// missing.
joints::Joint ResolveJointOrFree(const JointSpec& spec);

}  // namespace twist::objects
