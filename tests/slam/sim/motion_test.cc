#include "slam/sim/motion.h"

#include <gtest/gtest.h>

#include <cmath>

namespace twist::sim {
namespace {

// Reference: explicit Euler with a tiny step of the same kinematics.
PlanarState Integrate(PlanarState s, const std::vector<PlanarSegment>& segs, double t_end) {
  const double dt = 1e-5;
  double t = 0.0;
  size_t k = 0;
  double seg_end = segs.empty() ? 1e18 : segs[0].duration;
  while (t < t_end - 1e-12) {
    while (k < segs.size() && t >= seg_end - 1e-12) {
      ++k;
      seg_end += k < segs.size() ? segs[k].duration : 1e18;
    }
    const double a = k < segs.size() ? segs[k].accel : 0.0;
    const double kappa = k < segs.size() ? segs[k].curvature : 0.0;
    const double h = std::min(dt, std::min(t_end, seg_end) - t);
    const double v_new = std::max(0.0, s.speed + a * h);
    const double ds = 0.5 * (s.speed + v_new) * h;
    const double yaw_mid = s.yaw + 0.5 * kappa * ds;
    s.x += ds * std::sin(yaw_mid);
    s.z += ds * std::cos(yaw_mid);
    s.yaw += kappa * ds;
    s.speed = v_new;
    t += h;
  }
  return s;
}

TEST(PlanarMotion, ClosedFormMatchesIntegration) {
  const std::vector<PlanarSegment> segs = {
      {1.0, 0.0, 0.0}, {2.0, -1.5, 0.0}, {1.5, 0.0, 0.125}, {1.0, 2.0, -0.05}, {3.0, -4.0, 0.02}};
  const PlanarMotion motion(PlanarState{1.0, 2.0, 0.3, 8.0}, segs, 1.65);
  for (double t : {0.0, 0.5, 1.0, 2.2, 3.7, 4.9, 5.5, 7.0, 9.0}) {
    const PlanarState a = motion.StateAt(t);
    const PlanarState b = Integrate(PlanarState{1.0, 2.0, 0.3, 8.0}, segs, t);
    EXPECT_NEAR(a.x, b.x, 1e-4) << t;
    EXPECT_NEAR(a.z, b.z, 1e-4) << t;
    EXPECT_NEAR(a.yaw, b.yaw, 1e-6) << t;
    EXPECT_NEAR(a.speed, b.speed, 1e-6) << t;
  }
}

TEST(PlanarMotion, BrakingStopsAndStays) {
  const PlanarMotion motion(PlanarState{0, 0, 0, 10.0}, {{5.0, -4.0, 0.0}}, 1.65);
  EXPECT_NEAR(motion.StateAt(2.5).speed, 0.0, 1e-12);
  EXPECT_NEAR(motion.StateAt(2.5).z, 12.5, 1e-9);
  EXPECT_NEAR(motion.StateAt(4.0).z, 12.5, 1e-9);
  EXPECT_NEAR(motion.StateAt(9.0).z, 12.5, 1e-9);
  EXPECT_NEAR(motion.DistanceAt(9.0), 12.5, 1e-9);
}

TEST(PlanarMotion, PoseIsPlanarWithTheRightHeadingAxis) {
  const PlanarMotion motion(PlanarState{0, 0, 0.4, 5.0}, {{2.0, 0.0, 0.1}}, 1.65);
  for (double t : {0.0, 1.0, 2.5}) {
    const PlanarState s = motion.StateAt(t);
    const Eigen::Vector3d heading(std::sin(s.yaw), 0.0, std::cos(s.yaw));
    const geometry::SE3d cam = motion.PoseAt(t, HeadingAxis::kZ);
    const geometry::SE3d box = motion.PoseAt(t, HeadingAxis::kX);
    EXPECT_NEAR((cam.rotation().col(2) - heading).norm(), 0.0, 1e-12);
    EXPECT_NEAR((box.rotation().col(0) - heading).norm(), 0.0, 1e-12);
    EXPECT_NEAR((box.rotation().col(1) - Eigen::Vector3d::UnitY()).norm(), 0.0, 1e-12);
    EXPECT_DOUBLE_EQ(box.translation().y(), 1.65);
  }
}

TEST(RevoluteMotion, HingeStaysFixedAndAngleIsSmooth) {
  const geometry::SE3d closed(RotY(-M_PI / 2), Eigen::Vector3d(7.1, 1.5, 14.5));
  const Eigen::Vector3d hinge(7.1, 1.65, 14.0);
  const RevoluteMotion door(closed, hinge, Eigen::Vector3d::UnitY(), 0.0, -1.4, 2.0, 7.0);
  EXPECT_DOUBLE_EQ(door.AngleAt(0.0), 0.0);
  EXPECT_DOUBLE_EQ(door.AngleAt(2.0), 0.0);
  EXPECT_NEAR(door.AngleAt(4.5), -0.7, 1e-12);
  EXPECT_DOUBLE_EQ(door.AngleAt(9.0), -1.4);
  const Eigen::Vector3d hinge_in_body = closed.Inverse() * hinge;
  for (double t = 0.0; t < 9.0; t += 0.7) {
    const geometry::SE3d pose = door.PoseAt(t);
    EXPECT_NEAR((pose * hinge_in_body - hinge).norm(), 0.0, 1e-12);
    // Another point of the axis, 2 m higher.
    const Eigen::Vector3d up = hinge - 2.0 * Eigen::Vector3d::UnitY();
    EXPECT_NEAR((pose * (closed.Inverse() * up) - up).norm(), 0.0, 1e-12);
  }
}

}  // namespace
}  // namespace twist::sim
