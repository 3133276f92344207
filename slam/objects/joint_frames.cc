#include "slam/objects/joint_frames.h"

#include <string>

#include "slam/semantic/plane_fitting.h"

namespace twist::objects {

using joints::Joint;
using joints::JointType;

absl::StatusOr<Joint> ResolveJoint(const JointSpec& spec) {
  const std::string name = joints::JointTypeName(spec.type);
  switch (spec.type) {
    case JointType::kFree:
    case JointType::kRigid:
      return Joint(spec.type, geometry::SE3d(geometry::SO3d(), spec.anchor));
    case JointType::kPlanar:
    case JointType::kPointContact:
    case JointType::kLineContact: {
      if (!spec.parent_plane || !(spec.parent_plane->head<3>().norm() > 0.0)) {
        return absl::FailedPreconditionError(name + " joint needs the parent cluster's plane");
      }
      if (spec.type == JointType::kPlanar) {
        return Joint::FromPlaneCoefficients(*spec.parent_plane, spec.anchor);
      }
      const Eigen::Vector4d& p = *spec.parent_plane;
      const Eigen::Vector3d n = semantic::PlaneNormal(p);
      const Eigen::Vector3d on_plane =
          spec.anchor - semantic::PointPlaneDistance(p, spec.anchor) * n;
      return Joint::FromPlane(spec.type, n, on_plane);
    }
    case JointType::kRevolute:
    case JointType::kPrismatic:
    case JointType::kCylindrical:
    case JointType::kHelical:
    case JointType::kSphereCylinder: {
      if (spec.axis_direction && spec.axis_point) {
        return Joint::FromAxis(spec.type, *spec.axis_direction, *spec.axis_point, spec.pitch);
      }
      if (spec.parent_plane && spec.parent_plane->head<3>().norm() > 0.0) {
        const Eigen::Vector4d& p = *spec.parent_plane;
        const Eigen::Vector3d n = semantic::PlaneNormal(p);
        const Eigen::Vector3d on_plane =
            spec.anchor - semantic::PointPlaneDistance(p, spec.anchor) * n;
        return Joint::FromAxis(spec.type, n, on_plane, spec.pitch);
      }
      return absl::FailedPreconditionError(name + " joint needs an axis or the parent's plane");
    }
    case JointType::kSpherical:
    case JointType::kSphericalWithFinger:
      return Joint::FromCenter(spec.type, spec.anchor);
  }
  return absl::InvalidArgumentError("unknown joint type");
}

Joint ResolveJointOrFree(const JointSpec& spec) {
  absl::StatusOr<Joint> j = ResolveJoint(spec);
  if (j.ok()) return *j;
  return Joint(JointType::kFree, geometry::SE3d(geometry::SO3d(), spec.anchor));
}

}  // namespace twist::objects
