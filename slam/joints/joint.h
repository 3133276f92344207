// Mechanical joints (ISO 3952) as subspaces of allowed twists (paper §IV-E).
//
// Every joint type has a freedom basis A_l (6 x dof) expressed in the joint
// frame F_l, with twists ordered (v, ω). Convention for the joint frame: its z
// axis is the joint's principal direction (plane normal, rotation/slide axis,
// contact normal); see FreedomBasis() for each type.
#pragma once

#include <string>
#include <string_view>

#include <Eigen/Core>

#include "absl/status/statusor.h"
#include "slam/geometry/se3.h"

namespace twist::joints {

enum class JointType {
  kRigid = 0,                // 0 dof
  kRevolute = 1,             // ω_z
  kPrismatic = 2,            // v_z
  kHelical = 3,              // ω_z with v_z = pitch · ω_z (pitch in m/rad)
  kCylindrical = 4,          // v_z, ω_z
  kSpherical = 5,            // ω_x, ω_y, ω_z
  kPlanar = 6,               // v_x, v_y, ω_z (plane normal = z)
  kPointContact = 7,         // v_x, v_y, ω_x, ω_y, ω_z (contact normal = z)
  kLineContact = 8,          // v_x, v_y, ω_x, ω_z (normal z, line along x)
  kSphereCylinder = 9,       // v_x, ω_x, ω_y, ω_z (linear annular, axis x)
  kSphericalWithFinger = 10, // ω_x, ω_y (finger blocks ω_z)
  kFree = 11,                // 6 dof
};
inline constexpr int kNumJointTypes = 12;

const char* JointTypeName(JointType type);
// Accepts the names of JointTypeName ("planar", "revolute", "sphere_cylinder", ...).
absl::StatusOr<JointType> JointTypeFromName(std::string_view name);
int DegreesOfFreedom(JointType type);

using Matrix6Xd = Eigen::Matrix<double, 6, Eigen::Dynamic>;

// A_l in the joint frame (6 x dof, columns orthonormal except helical).
Matrix6Xd FreedomBasis(JointType type, double pitch = 0.0);
// Π_l = A_l (A_lᵀ A_l)⁻¹ A_lᵀ (zero matrix for rigid).
geometry::Matrix6d JointProjector(JointType type, double pitch = 0.0);

// A joint placed in the world: type + world_from_joint.
class Joint {
 public:
  Joint() = default;
  Joint(JointType type, const geometry::SE3d& world_from_joint, double pitch = 0.0);

  // Planar / point contact: z = unit normal, origin = anchor projected onto the plane.
  static Joint FromPlane(JointType type, const Eigen::Vector3d& normal, const Eigen::Vector3d& anchor);
  // Planar joint from plane coefficients (a,b,c,d) (aᵀx + d = 0) and a point
  // near the object (projected onto the plane for the origin).
  static Joint FromPlaneCoefficients(const Eigen::Vector4d& plane, const Eigen::Vector3d& near_point);
  // Revolute / prismatic / cylindrical / helical / sphere-cylinder: z (or x for
  // sphere-cylinder) = unit axis direction, origin = point on the axis.
  static Joint FromAxis(JointType type,
                        const Eigen::Vector3d& direction,
                        const Eigen::Vector3d& point,
                        double pitch = 0.0);
  // Spherical / spherical with finger: origin = centre (finger axis = z).
  static Joint FromCenter(JointType type,
                          const Eigen::Vector3d& center,
                          const Eigen::Vector3d& finger_axis = Eigen::Vector3d::UnitZ());

  JointType type() const { return type_; }
  double pitch() const { return pitch_; }
  const geometry::SE3d& world_from_joint() const { return world_from_joint_; }

  // Π = Ad(world_from_joint) Π_l Ad(joint_from_world).
  geometry::Matrix6d WorldProjector() const;
  // Twist in world frame -> joint frame and back (adjoint maps).
  geometry::Vector6d WorldToJoint(const geometry::Vector6d& twist_in_world) const;
  geometry::Vector6d JointToWorld(const geometry::Vector6d& twist_in_joint) const;
  // Π · twist_in_world: the part of a world twist the joint allows.
  geometry::Vector6d Project(const geometry::Vector6d& twist_in_world) const;

 private:
  JointType type_ = JointType::kFree;
  double pitch_ = 0.0;
  geometry::SE3d world_from_joint_;
};

}  // namespace twist::joints
