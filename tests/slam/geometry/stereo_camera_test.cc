#include "slam/geometry/stereo_camera.h"

#include <gtest/gtest.h>

#include <Eigen/Core>
#include <cmath>
#include <limits>
#include <random>

#include "slam/geometry/se3.h"

namespace twist::geometry {
namespace {

StereoCamera Camera() {
  StereoCamera c;
  c.fx = 718.856;
  c.fy = 707.5;
  c.cx = 607.19;
  c.cy = 185.22;
  c.baseline = 0.537;
  c.width = 1241;
  c.height = 376;
  return c;
}

class Random {
 public:
  explicit Random(unsigned seed) : rng_(seed) {}
  double Uniform(double lo, double hi) {
    return std::uniform_real_distribution<double>(lo, hi)(rng_);
  }
  Eigen::Vector3d PointInFront() {
    const double z = Uniform(0.5, 80.0);
    return Eigen::Vector3d(Uniform(-0.8, 0.8) * z, Uniform(-0.3, 0.3) * z, z);
  }

 private:
  std::mt19937 rng_;
};

TEST(StereoCameraTest, ValidateAcceptsAGoodCameraAndNamesEachProblem) {
  EXPECT_TRUE(Camera().Validate().ok());
  auto expect_invalid = [](StereoCamera c, const std::string& fragment) {
    const absl::Status status = c.Validate();
    ASSERT_FALSE(status.ok()) << fragment;
    EXPECT_EQ(status.code(), absl::StatusCode::kInvalidArgument);
    EXPECT_NE(std::string(status.message()).find(fragment), std::string::npos) << status;
  };
  StereoCamera c = Camera();
  c.fx = 0.0;
  expect_invalid(c, "focal");
  c = Camera();
  c.fy = std::numeric_limits<double>::quiet_NaN();
  expect_invalid(c, "focal");
  c = Camera();
  c.baseline = -0.5;
  expect_invalid(c, "baseline");
  c = Camera();
  c.baseline = std::numeric_limits<double>::infinity();
  expect_invalid(c, "baseline");
  c = Camera();
  c.width = 0;
  expect_invalid(c, "size");
  c = Camera();
  c.cx = 2000.0;
  expect_invalid(c, "principal point");
  c = Camera();
  c.cy = -1.0;
  expect_invalid(c, "principal point");
}

TEST(StereoCameraTest, ProjectionJacobiansMatchCentralDifferences) {
  const StereoCamera camera = Camera();
  Random random(1);
  const double h = 1e-6;
  for (int i = 0; i < 200; ++i) {
    const Eigen::Vector3d p = random.PointInFront();
    Eigen::Vector2d uv;
    Eigen::Matrix<double, 2, 3> j2;
    ASSERT_TRUE(camera.ProjectChecked(p, &uv, &j2));
    Eigen::Vector3d uvr;
    Eigen::Matrix3d j3;
    ASSERT_TRUE(camera.ProjectStereoChecked(p, &uvr, &j3));
    EXPECT_LT((uv - camera.Project(p)).norm(), 1e-12);
    EXPECT_LT((uvr - camera.ProjectStereo(p)).norm(), 1e-12);
    for (int k = 0; k < 3; ++k) {
      Eigen::Vector3d d = Eigen::Vector3d::Zero();
      d[k] = h;
      const Eigen::Vector2d n2 =
          (camera.Project(Eigen::Vector3d(p + d)) - camera.Project(Eigen::Vector3d(p - d))) /
          (2 * h);
      const Eigen::Vector3d n3 = (camera.ProjectStereo(Eigen::Vector3d(p + d)) -
                                  camera.ProjectStereo(Eigen::Vector3d(p - d))) /
                                 (2 * h);
      EXPECT_LT((j2.col(k) - n2).norm(), 1e-6 * std::max(1.0, n2.norm()));
      EXPECT_LT((j3.col(k) - n3).norm(), 1e-6 * std::max(1.0, n3.norm()));
    }
  }
}

TEST(StereoCameraTest, RightImageIsLeftShiftedByDisparity) {
  const StereoCamera camera = Camera();
  Random random(2);
  for (int i = 0; i < 100; ++i) {
    const Eigen::Vector3d p = random.PointInFront();
    const Eigen::Vector3d uvr = camera.ProjectStereo(p);
    EXPECT_NEAR(uvr[0] - uvr[2], camera.DepthToDisparity(p.z()), 1e-9);
    // The right camera sits at +baseline along x.
    const Eigen::Vector3d in_right = p - Eigen::Vector3d(camera.baseline, 0, 0);
    EXPECT_NEAR(uvr[2], camera.Project(in_right).x(), 1e-9);
    // Projection matrices agree with the projections.
    const Eigen::Vector3d l = camera.LeftProjectionMatrix() * p.homogeneous();
    const Eigen::Vector3d r = camera.RightProjectionMatrix() * p.homogeneous();
    EXPECT_LT((l.hnormalized() - uvr.head<2>()).norm(), 1e-9);
    EXPECT_NEAR(r.hnormalized().x(), uvr[2], 1e-9);
    EXPECT_NEAR(r.hnormalized().y(), uvr[1], 1e-9);
  }
}

TEST(StereoCameraTest, RejectsPointsBehindTheCamera) {
  const StereoCamera camera = Camera();
  Eigen::Vector2d uv;
  Eigen::Vector3d uvr;
  EXPECT_FALSE(camera.ProjectChecked(Eigen::Vector3d(0, 0, -1), &uv));
  EXPECT_FALSE(camera.ProjectChecked(Eigen::Vector3d(0, 0, 0), &uv));
  EXPECT_FALSE(camera.ProjectStereoChecked(Eigen::Vector3d(1, 0, 1e-7), &uvr));
  EXPECT_FALSE(camera.ProjectChecked(Eigen::Vector3d(0, 0, 0.5), &uv, nullptr, 1.0));
  EXPECT_TRUE(camera.ProjectChecked(Eigen::Vector3d(0, 0, 2.0), &uv, nullptr, 1.0));
}

TEST(StereoCameraTest, BackprojectInvertsProjectAndBearingIsTheRay) {
  const StereoCamera camera = Camera();
  Random random(3);
  for (int i = 0; i < 200; ++i) {
    const Eigen::Vector3d p = random.PointInFront();
    const Eigen::Vector2d uv = camera.Project(p);
    EXPECT_LT((camera.Backproject(uv, p.z()) - p).norm(), 1e-9 * p.norm());
    const Eigen::Vector3d bearing = camera.Bearing(uv);
    EXPECT_NEAR(bearing.norm(), 1.0, 1e-12);
    EXPECT_LT((bearing - p.normalized()).norm(), 1e-12);
  }
}

TEST(StereoCameraTest, DisparityDepthRoundTrip) {
  const StereoCamera camera = Camera();
  for (double depth : {0.3, 1.0, 7.5, 42.0, 300.0}) {
    const double disparity = camera.DepthToDisparity(depth);
    EXPECT_NEAR(disparity, camera.fx * camera.baseline / depth, 1e-12);
    EXPECT_NEAR(camera.DisparityToDepth(disparity), depth, 1e-9 * depth);
  }
  EXPECT_DOUBLE_EQ(camera.bf(), camera.fx * camera.baseline);
}

TEST(StereoCameraTest, TriangulateStereoIsExactOnSyntheticMatches) {
  const StereoCamera camera = Camera();
  Random random(4);
  for (int i = 0; i < 200; ++i) {
    const Eigen::Vector3d p = random.PointInFront();
    const Eigen::Vector3d uvr = camera.ProjectStereo(p);
    const std::optional<Eigen::Vector3d> x = camera.TriangulateStereo(uvr[0], uvr[1], uvr[2]);
    ASSERT_TRUE(x.has_value());
    EXPECT_LT((*x - p).norm(), 1e-9 * p.norm());
  }
  EXPECT_FALSE(camera.TriangulateStereo(500.0, 100.0, 500.0).has_value());  // zero disparity
  EXPECT_FALSE(camera.TriangulateStereo(500.0, 100.0, 510.0).has_value());  // negative
  const double far_disparity = camera.DepthToDisparity(200.0);
  EXPECT_FALSE(camera.TriangulateStereo(600.0, 100.0, 600.0 - far_disparity, 100.0).has_value());
  EXPECT_TRUE(camera.TriangulateStereo(600.0, 100.0, 600.0 - far_disparity, 300.0).has_value());
}

TEST(StereoCameraTest, InImageHonoursBorders) {
  const StereoCamera camera = Camera();
  EXPECT_TRUE(camera.InImage(Eigen::Vector2d(0.0, 0.0)));
  EXPECT_FALSE(camera.InImage(Eigen::Vector2d(-0.1, 10.0)));
  EXPECT_FALSE(camera.InImage(Eigen::Vector2d(1241.0, 10.0)));
  EXPECT_TRUE(camera.InImage(Eigen::Vector2d(1240.5, 375.5)));
  EXPECT_FALSE(camera.InImage(Eigen::Vector2d(5.0, 100.0), 10.0));
  EXPECT_TRUE(camera.InImage(Eigen::Vector2d(15.0, 100.0), 10.0));
}

TEST(TriangulateTwoViewTest, ExactOnSyntheticPoints) {
  std::mt19937 rng(5);
  std::uniform_real_distribution<double> u(-1.0, 1.0);
  for (int i = 0; i < 200; ++i) {
    const Eigen::Vector3d p(5.0 * u(rng), 2.0 * u(rng), 10.0 + 5.0 * u(rng));
    Vector6d xi1, xi2;
    for (int k = 0; k < 6; ++k) {
      xi1[k] = 0.2 * u(rng);
      xi2[k] = 0.2 * u(rng);
    }
    xi2[0] += 1.0;  // baseline of about a metre
    const SE3d cam1_from_world = SE3d::Exp(xi1), cam2_from_world = SE3d::Exp(xi2);
    const Eigen::Vector3d p1 = cam1_from_world * p, p2 = cam2_from_world * p;
    const std::optional<Eigen::Vector3d> x = TriangulateTwoView(cam1_from_world.matrix3x4(),
                                                                cam2_from_world.matrix3x4(),
                                                                p1.hnormalized(),
                                                                p2.hnormalized());
    ASSERT_TRUE(x.has_value());
    EXPECT_LT((*x - p).norm(), 1e-8);
  }
}

TEST(TriangulateTwoViewTest, ParallelRaysAreDegenerate) {
  // Pure sideways translation, both cameras see the point straight ahead:
  // the rays are parallel and meet only at infinity.
  const SE3d cam1_from_world;
  const SE3d cam2_from_world(Eigen::Matrix3d::Identity(), Eigen::Vector3d(-1.0, 0.0, 0.0));
  EXPECT_FALSE(TriangulateTwoView(cam1_from_world.matrix3x4(),
                                  cam2_from_world.matrix3x4(),
                                  Eigen::Vector2d(0.1, -0.05),
                                  Eigen::Vector2d(0.1, -0.05))
                   .has_value());
}

}  // namespace
}  // namespace twist::geometry
