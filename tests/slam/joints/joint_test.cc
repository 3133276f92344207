#include "slam/joints/joint.h"

#include <gtest/gtest.h>

#include <Eigen/Dense>
#include <cmath>
#include <random>
#include <vector>

namespace twist::joints {
namespace {

using geometry::Matrix6d;
using geometry::SE3d;
using geometry::SO3d;
using geometry::Vector6d;

constexpr double kPitch = 0.35;  // m/rad, for helical joints

std::vector<JointType> AllTypes() {
  std::vector<JointType> types;
  for (int i = 0; i < kNumJointTypes; ++i) types.push_back(static_cast<JointType>(i));
  return types;
}

double PitchFor(JointType type) { return type == JointType::kHelical ? kPitch : 0.0; }

class Random {
 public:
  explicit Random(unsigned seed) : rng_(seed) {}
  double Uniform(double lo, double hi) {
    return std::uniform_real_distribution<double>(lo, hi)(rng_);
  }
  Eigen::Vector3d Vector(double scale) {
    return Eigen::Vector3d(Uniform(-scale, scale), Uniform(-scale, scale), Uniform(-scale, scale));
  }
  Vector6d Twist(double scale) {
    Vector6d xi;
    xi << Vector(scale), Vector(scale);
    return xi;
  }
  SE3d Pose() { return SE3d::Exp(Twist(3.0)); }

 private:
  std::mt19937 rng_;
};

int Rank(const Matrix6d& m) {
  Eigen::FullPivLU<Matrix6d> lu(m);
  lu.setThreshold(1e-9);
  return static_cast<int>(lu.rank());
}

// Velocity of the point p under the (world) twist η: v + ω × p.
Eigen::Vector3d PointVelocity(const Vector6d& eta, const Eigen::Vector3d& p) {
  return eta.head<3>() + eta.tail<3>().cross(p);
}

TEST(JointTypeTest, NamesRoundTripAndDegreesOfFreedom) {
  const int expected_dof[kNumJointTypes] = {0, 1, 1, 1, 2, 3, 3, 5, 4, 4, 2, 6};
  for (JointType type : AllTypes()) {
    const absl::StatusOr<JointType> parsed = JointTypeFromName(JointTypeName(type));
    ASSERT_TRUE(parsed.ok()) << parsed.status();
    EXPECT_EQ(*parsed, type);
    EXPECT_EQ(DegreesOfFreedom(type), expected_dof[static_cast<int>(type)]) << JointTypeName(type);
    EXPECT_EQ(FreedomBasis(type, PitchFor(type)).cols(), DegreesOfFreedom(type));
  }
  EXPECT_EQ(*JointTypeFromName("Sphere-Cylinder"), JointType::kSphereCylinder);
  const absl::StatusOr<JointType> bad = JointTypeFromName("hinge");
  ASSERT_FALSE(bad.ok());
  EXPECT_NE(bad.status().message().find("hinge"), std::string::npos);
  EXPECT_NE(bad.status().message().find("revolute"), std::string::npos);
}

TEST(JointProjectorTest, SymmetricIdempotentWithRankEqualToDof) {
  for (JointType type : AllTypes()) {
    for (double pitch : {0.0, kPitch, -2.0}) {
      if (type != JointType::kHelical && pitch != 0.0) continue;
      SCOPED_TRACE(JointTypeName(type));
      const Matrix6d pi = JointProjector(type, pitch);
      EXPECT_LT((pi - pi.transpose()).norm(), 1e-12);
      EXPECT_LT((pi * pi - pi).norm(), 1e-12);
      EXPECT_EQ(Rank(pi), DegreesOfFreedom(type));
      EXPECT_NEAR(pi.trace(), DegreesOfFreedom(type), 1e-12);
      const Matrix6Xd a = FreedomBasis(type, pitch);
      EXPECT_LT((pi * a - a).norm(), 1e-12);  // the basis is left untouched
    }
  }
  // The paper's planar example.
  Matrix6d planar = Matrix6d::Zero();
  planar(0, 0) = planar(1, 1) = planar(5, 5) = 1.0;
  EXPECT_EQ(JointProjector(JointType::kPlanar), planar);
  EXPECT_EQ(JointProjector(JointType::kRigid), Matrix6d::Zero());
  EXPECT_EQ(JointProjector(JointType::kFree), Matrix6d::Identity());
}

TEST(JointProjectorTest, HelicalCouplesTranslationAndRotation) {
  const Matrix6d pi = JointProjector(JointType::kHelical, kPitch);
  Random random(1);
  for (int trial = 0; trial < 20; ++trial) {
    const Vector6d projected = pi * random.Twist(1.0);
    EXPECT_NEAR(projected[2], kPitch * projected[5], 1e-12);
    EXPECT_LT(projected.head<2>().norm() + projected.segment<2>(3).norm(), 1e-12);
  }
}

TEST(JointWorldProjectorTest, IsTheAdjointConjugateOfTheJointProjector) {
  Random random(2);
  for (JointType type : AllTypes()) {
    SCOPED_TRACE(JointTypeName(type));
    for (int trial = 0; trial < 10; ++trial) {
      const Joint joint(type, random.Pose(), PitchFor(type));
      const Matrix6d pi = joint.WorldProjector();
      EXPECT_LT((pi * pi - pi).norm(), 1e-10);
      EXPECT_EQ(Rank(pi), DegreesOfFreedom(type));
      const Matrix6d ad = joint.world_from_joint().Adjoint();
      EXPECT_LT((pi - ad * JointProjector(type, PitchFor(type)) * ad.inverse()).norm(), 1e-10);
      const Vector6d xi = random.Twist(1.0);
      EXPECT_LT((joint.JointToWorld(joint.WorldToJoint(xi)) - xi).norm(), 1e-10);
      EXPECT_LT((joint.Project(xi) - pi * xi).norm(), 1e-10);
      // T Exp(ξ_l) T⁻¹ = Exp(Ad(T) ξ_l): the world twist moves like the joint twist.
      const Vector6d xi_l = random.Twist(0.5);
      const SE3d lhs =
          joint.world_from_joint() * SE3d::Exp(xi_l) * joint.world_from_joint().Inverse();
      EXPECT_LT((lhs.matrix() - SE3d::Exp(joint.JointToWorld(xi_l)).matrix()).norm(), 1e-10);
    }
  }
}

// For every joint and random ξ, Exp(Πξ) stays in the joint's freedom space:
// the log of the motion seen in the joint frame is Π_l ξ_l.
TEST(JointMotionTest, LogOfMotionInJointFrameLiesInFreedomSpace) {
  Random random(3);
  for (JointType type : AllTypes()) {
    SCOPED_TRACE(JointTypeName(type));
    const Matrix6d pi_l = JointProjector(type, PitchFor(type));
    for (int trial = 0; trial < 50; ++trial) {
      const Joint joint(type, random.Pose(), PitchFor(type));
      const Vector6d xi = random.Twist(0.8);
      const SE3d motion = SE3d::Exp(joint.WorldProjector() * xi);
      const SE3d motion_in_joint =
          joint.world_from_joint().Inverse() * motion * joint.world_from_joint();
      const Vector6d log = motion_in_joint.Log();
      EXPECT_LT((log - pi_l * log).norm(), 1e-9);
      EXPECT_LT((log - pi_l * joint.WorldToJoint(xi)).norm(), 1e-9);
    }
  }
}

// Instantaneous (first-order) kinematics: the velocity field of Πξ respects
// each joint's contact conditions exactly, for every joint type.
TEST(JointMotionTest, VelocityFieldRespectsContactConditions) {
  Random random(4);
  for (int trial = 0; trial < 50; ++trial) {
    const SE3d frame = random.Pose();
    const Eigen::Matrix3d r = frame.rotation();
    const Eigen::Vector3d o = frame.translation();
    const Eigen::Vector3d x = r.col(0), y = r.col(1), z = r.col(2);
    const Vector6d xi = random.Twist(1.0);
    auto eta_for = [&](JointType type) {
      return Joint(type, frame, PitchFor(type)).WorldProjector() * xi;
    };
    const double s = random.Uniform(-3.0, 3.0);
    const Eigen::Vector3d off_axis = o + random.Vector(2.0);

    // Rigid: nothing moves.
    EXPECT_LT(eta_for(JointType::kRigid).norm(), 1e-12);
    // Revolute: points on the axis are still, rotation only about the axis.
    const Vector6d rev = eta_for(JointType::kRevolute);
    EXPECT_LT(PointVelocity(rev, o + s * z).norm(), 1e-9);
    EXPECT_LT(rev.tail<3>().cross(z).norm(), 1e-9);
    // Prismatic: no rotation, translation along the axis.
    const Vector6d pri = eta_for(JointType::kPrismatic);
    EXPECT_LT(pri.tail<3>().norm(), 1e-12);
    EXPECT_LT(pri.head<3>().cross(z).norm(), 1e-9);
    // Helical: axis points slide along the axis at pitch × angular rate.
    const Vector6d hel = eta_for(JointType::kHelical);
    const double rate = hel.tail<3>().dot(z);
    EXPECT_LT(hel.tail<3>().cross(z).norm(), 1e-9);
    EXPECT_LT((PointVelocity(hel, o + s * z) - kPitch * rate * z).norm(), 1e-9);
    // Cylindrical: axis points slide along the axis, rotation about it.
    const Vector6d cyl = eta_for(JointType::kCylindrical);
    EXPECT_LT(PointVelocity(cyl, o + s * z).cross(z).norm(), 1e-9);
    EXPECT_LT(cyl.tail<3>().cross(z).norm(), 1e-9);
    // Spherical: centre still.
    EXPECT_LT(PointVelocity(eta_for(JointType::kSpherical), o).norm(), 1e-9);
    // Planar: no velocity along the normal anywhere, rotation about the normal.
    const Vector6d pla = eta_for(JointType::kPlanar);
    EXPECT_NEAR(PointVelocity(pla, off_axis).dot(z), 0.0, 1e-9);
    EXPECT_LT(pla.tail<3>().cross(z).norm(), 1e-9);
    // Point contact: the contact point does not leave the plane.
    EXPECT_NEAR(PointVelocity(eta_for(JointType::kPointContact), o).dot(z), 0.0, 1e-9);
    // Line contact: no point of the contact line (along x) leaves the plane,
    // no rotation about y (it would lift the line).
    const Vector6d lin = eta_for(JointType::kLineContact);
    EXPECT_NEAR(PointVelocity(lin, o + s * x).dot(z), 0.0, 1e-9);
    EXPECT_NEAR(lin.tail<3>().dot(y), 0.0, 1e-9);
    // Sphere-cylinder: the sphere centre moves along the cylinder axis x only.
    EXPECT_LT(PointVelocity(eta_for(JointType::kSphereCylinder), o).cross(x).norm(), 1e-9);
    // Spherical with finger: centre still, no spin about the finger axis z.
    const Vector6d fin = eta_for(JointType::kSphericalWithFinger);
    EXPECT_LT(PointVelocity(fin, o).norm(), 1e-9);
    EXPECT_NEAR(fin.tail<3>().dot(z), 0.0, 1e-9);
    // Free: untouched.
    EXPECT_LT((eta_for(JointType::kFree) - xi).norm(), 1e-9);
    // Blocked directions are removed: e.g. a pure vertical push on a planar joint.
    Vector6d push = Vector6d::Zero();
    push.head<3>() = z;
    EXPECT_LT((Joint(JointType::kPlanar, frame).WorldProjector() * push).norm(), 1e-9);
  }
}

// Finite motions for joints whose freedoms form a subgroup: Exp(Πξ) keeps the
// constraint exactly, however large ξ is.
TEST(JointMotionTest, FiniteMotionsKeepSubgroupConstraints) {
  Random random(5);
  for (int trial = 0; trial < 50; ++trial) {
    const SE3d frame = random.Pose();
    const Eigen::Vector3d o = frame.translation();
    const Eigen::Vector3d z = frame.rotation().col(2);
    const Vector6d xi = random.Twist(1.5);
    const Eigen::Vector3d p = o + random.Vector(3.0);
    const double s = random.Uniform(-3.0, 3.0);
    auto motion_for = [&](JointType type) {
      return SE3d::Exp(Joint(type, frame, PitchFor(type)).WorldProjector() * xi);
    };

    EXPECT_LT((motion_for(JointType::kRigid).matrix() - Eigen::Matrix4d::Identity()).norm(), 1e-12);

    // Planar: points keep their height over the plane, the normal stays parallel.
    const SE3d planar = motion_for(JointType::kPlanar);
    EXPECT_NEAR((planar * p - o).dot(z), (p - o).dot(z), 1e-9);
    EXPECT_LT((planar.rotation() * z - z).norm(), 1e-9);

    // Revolute: axis points fixed, distances to the axis and heights along it kept.
    const SE3d revolute = motion_for(JointType::kRevolute);
    EXPECT_LT((revolute * (o + s * z) - (o + s * z)).norm(), 1e-9);
    EXPECT_NEAR((revolute * p - o).dot(z), (p - o).dot(z), 1e-9);
    EXPECT_NEAR((revolute * p - o).cross(z).norm(), (p - o).cross(z).norm(), 1e-9);

    // Prismatic: no rotation, translation along the axis.
    const SE3d prismatic = motion_for(JointType::kPrismatic);
    EXPECT_LT((prismatic.rotation() - Eigen::Matrix3d::Identity()).norm(), 1e-12);
    EXPECT_LT(prismatic.translation().cross(z).norm(), 1e-9);

    // Helical: axis points advance by pitch × rotation angle.
    const SE3d helical = motion_for(JointType::kHelical);
    const double angle = helical.so3().Log().dot(z);
    EXPECT_LT(helical.so3().Log().cross(z).norm(), 1e-9);
    EXPECT_LT((helical * (o + s * z) - (o + s * z) - kPitch * angle * z).norm(), 1e-9);

    // Cylindrical: axis points stay on the axis, the axis direction is kept.
    const SE3d cylindrical = motion_for(JointType::kCylindrical);
    EXPECT_LT((cylindrical * (o + s * z) - o).cross(z).norm(), 1e-9);
    EXPECT_LT((cylindrical.rotation() * z - z).norm(), 1e-9);

    // Spherical and spherical-with-finger: centre fixed; distances to it kept.
    for (JointType type : {JointType::kSpherical, JointType::kSphericalWithFinger}) {
      const SE3d spherical = motion_for(type);
      EXPECT_LT((spherical * o - o).norm(), 1e-9) << JointTypeName(type);
      EXPECT_NEAR((spherical * p - o).norm(), (p - o).norm(), 1e-9);
    }
    // Finger: the rotation vector has no component along the finger axis.
    EXPECT_NEAR(motion_for(JointType::kSphericalWithFinger).so3().Log().dot(z), 0.0, 1e-9);

    EXPECT_LT((motion_for(JointType::kFree).matrix() - SE3d::Exp(xi).matrix()).norm(), 1e-9);
  }
}

TEST(JointFrameTest, FramesFromParentGeometry) {
  Random random(6);
  for (int trial = 0; trial < 20; ++trial) {
    const Eigen::Vector3d direction = random.Vector(1.0) * random.Uniform(0.5, 5.0);
    const Eigen::Vector3d point = random.Vector(5.0);
    const Eigen::Vector3d unit = direction.normalized();

    const Joint plane = Joint::FromPlane(JointType::kPlanar, direction, point);
    EXPECT_EQ(plane.type(), JointType::kPlanar);
    EXPECT_LT((plane.world_from_joint().rotation().col(2) - unit).norm(), 1e-12);
    EXPECT_LT((plane.world_from_joint().translation() - point).norm(), 1e-12);
    EXPECT_NEAR(plane.world_from_joint().rotation().determinant(), 1.0, 1e-12);

    // Plane coefficients, scaled arbitrarily; origin = near point projected.
    const double d = -unit.dot(point);
    const Eigen::Vector4d coeffs = 2.5 * Eigen::Vector4d(unit.x(), unit.y(), unit.z(), d);
    const Eigen::Vector3d near = point + random.Vector(2.0);
    const Joint from_coeffs = Joint::FromPlaneCoefficients(coeffs, near);
    const Eigen::Vector3d origin = from_coeffs.world_from_joint().translation();
    EXPECT_NEAR(unit.dot(origin) + d, 0.0, 1e-9);         // on the plane
    EXPECT_LT((near - origin).cross(unit).norm(), 1e-9);  // straight below/above
    EXPECT_LT((from_coeffs.WorldProjector() - plane.WorldProjector()).norm(),
              1e-9);  // same planar joint

    const Joint axis = Joint::FromAxis(JointType::kHelical, direction, point, kPitch);
    EXPECT_LT((axis.world_from_joint().rotation().col(2) - unit).norm(), 1e-12);
    EXPECT_DOUBLE_EQ(axis.pitch(), kPitch);
    // Another point on the same axis gives the same world projector.
    const Joint shifted =
        Joint::FromAxis(JointType::kHelical, -direction, point + 3.0 * unit, kPitch);
    EXPECT_LT((shifted.WorldProjector() - axis.WorldProjector()).norm(), 1e-9);

    const Joint annular = Joint::FromAxis(JointType::kSphereCylinder, direction, point);
    EXPECT_LT((annular.world_from_joint().rotation().col(0) - unit).norm(), 1e-12);

    const Joint ball = Joint::FromCenter(JointType::kSphericalWithFinger, point, direction);
    EXPECT_LT((ball.world_from_joint().translation() - point).norm(), 1e-12);
    EXPECT_LT((ball.world_from_joint().rotation().col(2) - unit).norm(), 1e-12);
  }
}

}  // namespace
}  // namespace twist::joints
