#include "slam/joints/joint.h"

#include <Eigen/Dense>
#include <array>
#include <cmath>
#include <string>
#include <vector>

#include "absl/strings/str_cat.h"
#include "glog/logging.h"

namespace twist::joints {
namespace {

using geometry::Matrix6d;
using geometry::SE3d;
using geometry::Vector6d;

struct JointTypeInfo {
  JointType type;
  const char* name;
  int dof;
};

constexpr std::array<JointTypeInfo, kNumJointTypes> kJointTypes = {{
    {JointType::kRigid, "rigid", 0},
    {JointType::kRevolute, "revolute", 1},
    {JointType::kPrismatic, "prismatic", 1},
    {JointType::kHelical, "helical", 1},
    {JointType::kCylindrical, "cylindrical", 2},
    {JointType::kSpherical, "spherical", 3},
    {JointType::kPlanar, "planar", 3},
    {JointType::kPointContact, "point_contact", 5},
    {JointType::kLineContact, "line_contact", 4},
    {JointType::kSphereCylinder, "sphere_cylinder", 4},
    {JointType::kSphericalWithFinger, "spherical_with_finger", 2},
    {JointType::kFree, "free", 6},
}};

const JointTypeInfo& Info(JointType type) {
  const int index = static_cast<int>(type);
  CHECK(index >= 0 && index < kNumJointTypes) << "invalid JointType " << index;
  return kJointTypes[index];
}

// Twist coordinates (v_x, v_y, v_z, ω_x, ω_y, ω_z) freed by each joint type
// (helical handled separately).
std::vector<int> FreeCoordinates(JointType type) {
  switch (type) {
    case JointType::kRigid:
      return {};
    case JointType::kRevolute:
      return {5};
    case JointType::kPrismatic:
      return {2};
    case JointType::kHelical:
      return {};  // coupled column, see FreedomBasis
    case JointType::kCylindrical:
      return {2, 5};
    case JointType::kSpherical:
      return {3, 4, 5};
    case JointType::kPlanar:
      return {0, 1, 5};
    case JointType::kPointContact:
      return {0, 1, 3, 4, 5};
    case JointType::kLineContact:
      return {0, 1, 3, 5};
    case JointType::kSphereCylinder:
      return {0, 3, 4, 5};
    case JointType::kSphericalWithFinger:
      return {3, 4};
    case JointType::kFree:
      return {0, 1, 2, 3, 4, 5};
  }
  LOG(FATAL) << "invalid JointType " << static_cast<int>(type);
  return {};
}

// Unit vector orthogonal to unit `a`, chosen deterministically (cross product
// with the canonical axis least aligned with a).
Eigen::Vector3d AnyOrthogonal(const Eigen::Vector3d& a) {
  Eigen::Index min_index = 0;
  a.cwiseAbs().minCoeff(&min_index);
  return a.cross(Eigen::Vector3d::Unit(min_index)).normalized();
}

// Right-handed rotation whose `axis_index` column (0 = x, 2 = z) is `direction`.
Eigen::Matrix3d FrameWithAxis(const Eigen::Vector3d& direction, int axis_index) {
  CHECK(direction.allFinite() && direction.norm() > 1e-12)
      << "joint axis/normal must be a finite non-zero vector, got " << direction.transpose();
  const Eigen::Vector3d d = direction.normalized();
  const Eigen::Vector3d u = AnyOrthogonal(d);
  const Eigen::Vector3d w = d.cross(u);  // (d, u, w) right-handed
  Eigen::Matrix3d r;
  if (axis_index == 2) {
    r.col(0) = u;
    r.col(1) = w;
    r.col(2) = d;
  } else {
    r.col(0) = d;
    r.col(1) = u;
    r.col(2) = w;
  }
  return r;
}

}  // namespace

const char* JointTypeName(JointType type) { return Info(type).name; }

absl::StatusOr<JointType> JointTypeFromName(std::string_view name) {
  std::string normalized(name);
  for (char& c : normalized) {
    if (c == '-' || c == ' ') c = '_';
    if (c >= 'A' && c <= 'Z') c = static_cast<char>(c - 'A' + 'a');
  }
  for (const JointTypeInfo& info : kJointTypes) {
    if (normalized == info.name) return info.type;
  }
  std::string expected;
  for (const JointTypeInfo& info : kJointTypes) {
    absl::StrAppend(&expected, expected.empty() ? "" : ", ", info.name);
  }
  return absl::InvalidArgumentError(absl::StrCat(
      "unknown joint type '", std::string(name), "' (expected one of: ", expected, ")"));
}

int DegreesOfFreedom(JointType type) { return Info(type).dof; }

Matrix6Xd FreedomBasis(JointType type, double pitch) {
  if (type == JointType::kHelical) {
    // Rotation about z coupled with translation along z: v_z = pitch · ω_z.
    Matrix6Xd a = Matrix6Xd::Zero(6, 1);
    a(2, 0) = pitch;
    a(5, 0) = 1.0;
    return a;
  }
  const std::vector<int> coords = FreeCoordinates(type);
  Matrix6Xd a = Matrix6Xd::Zero(6, static_cast<Eigen::Index>(coords.size()));
  for (size_t k = 0; k < coords.size(); ++k) a(coords[k], static_cast<Eigen::Index>(k)) = 1.0;
  return a;
}

Matrix6d JointProjector(JointType type, double pitch) {
  const Matrix6Xd a = FreedomBasis(type, pitch);
  if (a.cols() == 0) return Matrix6d::Zero();
  const Eigen::MatrixXd gram = a.transpose() * a;
  return a * gram.ldlt().solve(a.transpose());
}

Joint::Joint(JointType type, const SE3d& world_from_joint, double pitch)
    : type_(type), pitch_(pitch), world_from_joint_(world_from_joint) {
  Info(type);  // CHECKs the enum value
  CHECK(std::isfinite(pitch)) << "helical pitch must be finite";
}

Joint Joint::FromPlane(JointType type,
                       const Eigen::Vector3d& normal,
                       const Eigen::Vector3d& anchor) {
  return Joint(type, SE3d(FrameWithAxis(normal, 2), anchor));
}

Joint Joint::FromPlaneCoefficients(const Eigen::Vector4d& plane,
                                   const Eigen::Vector3d& near_point) {
  const Eigen::Vector3d n = plane.head<3>();
  const double norm = n.norm();
  CHECK(plane.allFinite() && norm > 1e-12) << "degenerate plane " << plane.transpose();
  const Eigen::Vector3d unit_normal = n / norm;
  const double signed_distance = unit_normal.dot(near_point) + plane[3] / norm;
  return FromPlane(JointType::kPlanar, unit_normal, near_point - signed_distance * unit_normal);
}

Joint Joint::FromAxis(JointType type,
                      const Eigen::Vector3d& direction,
                      const Eigen::Vector3d& point,
                      double pitch) {
  const int axis_index = type == JointType::kSphereCylinder ? 0 : 2;
  return Joint(type, SE3d(FrameWithAxis(direction, axis_index), point), pitch);
}

Joint Joint::FromCenter(JointType type,
                        const Eigen::Vector3d& center,
                        const Eigen::Vector3d& finger_axis) {
  return Joint(type, SE3d(FrameWithAxis(finger_axis, 2), center));
}

Matrix6d Joint::WorldProjector() const {
  const Matrix6d world_from_joint_ad = world_from_joint_.Adjoint();
  const Matrix6d joint_from_world_ad = world_from_joint_.Inverse().Adjoint();
  return world_from_joint_ad * JointProjector(type_, pitch_) * joint_from_world_ad;
}

Vector6d Joint::WorldToJoint(const Vector6d& twist_in_world) const {
  return world_from_joint_.Inverse().Adjoint() * twist_in_world;
}

Vector6d Joint::JointToWorld(const Vector6d& twist_in_joint) const {
  return world_from_joint_.Adjoint() * twist_in_joint;
}

Vector6d Joint::Project(const Vector6d& twist_in_world) const {
  return JointToWorld(JointProjector(type_, pitch_) * WorldToJoint(twist_in_world));
}

}  // namespace twist::joints
