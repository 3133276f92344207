#include "slam/semantic/plane_fitting.h"

#include <gtest/gtest.h>

#include <Eigen/Geometry>
#include <algorithm>
#include <cmath>

namespace twist::semantic {
namespace {

// Points on the plane n·x + d = 0 with Gaussian noise along n, plus a share
// of gross outliers spread in a box around it.
std::vector<Eigen::Vector3d> MakePlanePoints(const Eigen::Vector3d& n,
                                             double d,
                                             int num,
                                             double outlier_ratio,
                                             double noise,
                                             std::mt19937_64* rng) {
  const Eigen::Vector3d normal = n.normalized();
  Eigen::Vector3d u = normal.unitOrthogonal();
  Eigen::Vector3d v = normal.cross(u);
  const Eigen::Vector3d origin = -d * normal;
  std::uniform_real_distribution<double> span(-10.0, 10.0);
  std::normal_distribution<double> gauss(0.0, noise);
  std::vector<Eigen::Vector3d> pts;
  const int num_out = static_cast<int>(std::round(outlier_ratio * num));
  for (int k = 0; k < num - num_out; ++k) {
    pts.push_back(origin + span(*rng) * u + span(*rng) * v + gauss(*rng) * normal);
  }
  std::uniform_real_distribution<double> off(0.3, 5.0);
  std::bernoulli_distribution side(0.5);
  for (int k = 0; k < num_out; ++k) {
    const double h = side(*rng) ? off(*rng) : -off(*rng);
    pts.push_back(origin + span(*rng) * u + span(*rng) * v + h * normal);
  }
  std::shuffle(pts.begin(), pts.end(), *rng);
  return pts;
}

double NormalAngleDeg(const Eigen::Vector4d& a, const Eigen::Vector4d& b) {
  const double c = std::abs(PlaneNormal(a).dot(PlaneNormal(b)));
  return std::acos(std::min(1.0, c)) * 180.0 / M_PI;
}

TEST(PlaneFitting, NormalisationAndDistance) {
  const Eigen::Vector4d p = NormalizePlane(Eigen::Vector4d(0, -2, 0, -3));  // y = -1.5
  EXPECT_NEAR(p.norm(), 1.0, 1e-12);
  EXPECT_GE(p(3), 0.0);
  EXPECT_NEAR(PointPlaneDistance(p, Eigen::Vector3d(4, 0.5, 2)), 2.0, 1e-12);
}

TEST(PlaneFitting, LeastSquaresIsExactOnNoiseFreePoints) {
  std::mt19937_64 rng(1);
  const auto pts = MakePlanePoints({0.1, -1.0, 0.05}, 1.6, 50, 0.0, 0.0, &rng);
  const auto plane = FitPlaneLeastSquares(pts);
  ASSERT_TRUE(plane.ok());
  const Eigen::Vector4d truth = NormalizePlane(
      Eigen::Vector4d(0.1, -1.0, 0.05, 1.6 * Eigen::Vector3d(0.1, -1.0, 0.05).norm()));
  EXPECT_LT((*plane - truth).norm(), 1e-9);
  EXPECT_FALSE(FitPlaneLeastSquares({{0, 0, 0}, {1, 1, 1}, {2, 2, 2}}).ok());
  EXPECT_FALSE(FitPlaneLeastSquares({{0, 0, 0}, {1, 1, 1}}).ok());
}

class PlaneRansacOutliers : public ::testing::TestWithParam<double> {};

TEST_P(PlaneRansacOutliers, RecoversThePlane) {
  const double outlier_ratio = GetParam();
  const Eigen::Vector3d n(0.02, -1.0, 0.03);  // a road seen from a camera 1.65 m above
  const double d = 1.65;
  const Eigen::Vector4d truth = NormalizePlane(Eigen::Vector4d(n.x(), n.y(), n.z(), d * n.norm()));
  for (uint64_t seed = 1; seed <= 5; ++seed) {
    std::mt19937_64 rng(seed);
    const auto pts = MakePlanePoints(n, d, 400, outlier_ratio, 0.01, &rng);
    PlaneRansacOptions options;
    options.inlier_threshold_m = 0.05;
    std::mt19937_64 ransac_rng(seed + 100);
    const auto fit = FitPlaneRansac(pts, options, &ransac_rng);
    ASSERT_TRUE(fit.ok()) << fit.status();
    EXPECT_LT(NormalAngleDeg(fit->plane, truth), 0.5) << "seed " << seed;
    // Offset of the plane along the normal.
    EXPECT_NEAR(fit->plane(3) / fit->plane.head<3>().norm(), d, 0.01);
    const int expected_inliers = static_cast<int>(std::round(400 * (1.0 - outlier_ratio)));
    EXPECT_GE(static_cast<int>(fit->inliers.size()), expected_inliers - 5);
    EXPECT_LE(static_cast<int>(fit->inliers.size()), expected_inliers + 5);
    EXPECT_LT(fit->rms_distance_m, 0.02);
  }
}

INSTANTIATE_TEST_SUITE_P(OutlierShares, PlaneRansacOutliers, ::testing::Values(0.3, 0.4, 0.5));

TEST(PlaneFitting, RansacIsReproducibleWithTheSameSeed) {
  std::mt19937_64 rng(7);
  const auto pts = MakePlanePoints({0, 1, 0}, 2.0, 200, 0.4, 0.02, &rng);
  std::mt19937_64 a(3), b(3);
  const auto fa = FitPlaneRansac(pts, {}, &a);
  const auto fb = FitPlaneRansac(pts, {}, &b);
  ASSERT_TRUE(fa.ok() && fb.ok());
  EXPECT_EQ(fa->plane, fb->plane);
  EXPECT_EQ(fa->inliers, fb->inliers);
}

TEST(PlaneFitting, RansacFailsWithoutAPlane) {
  std::mt19937_64 rng(5);
  std::uniform_real_distribution<double> u(-5, 5);
  std::vector<Eigen::Vector3d> cloud;
  for (int k = 0; k < 200; ++k) cloud.push_back({u(rng), u(rng), u(rng)});
  PlaneRansacOptions options;
  options.inlier_threshold_m = 0.01;
  EXPECT_EQ(FitPlaneRansac(cloud, options, &rng).status().code(), absl::StatusCode::kNotFound);
}

TEST(PlaneFitting, ClusterPlaneRefitsAsTheClusterGrows) {
  std::mt19937_64 rng(11);
  const auto pts = MakePlanePoints({0, -1, 0}, 1.5, 300, 0.3, 0.01, &rng);
  ClusterPlane::Options options;
  options.min_points = 50;
  options.refit_growth = 1.5;
  ClusterPlane plane(options);
  std::vector<Eigen::Vector3d> growing(pts.begin(), pts.begin() + 40);
  EXPECT_FALSE(plane.Update(growing, &rng));  // too few points
  growing.assign(pts.begin(), pts.begin() + 100);
  EXPECT_TRUE(plane.Update(growing, &rng));
  EXPECT_TRUE(plane.has_plane());
  growing.assign(pts.begin(), pts.begin() + 140);
  EXPECT_FALSE(plane.Update(growing, &rng));  // grew by < 50 %
  EXPECT_EQ(plane.num_points_at_fit(), 100);
  growing.assign(pts.begin(), pts.end());
  plane.Update(growing, &rng);
  EXPECT_EQ(plane.num_points_at_fit(), 300);
  EXPECT_NEAR(std::abs(PlaneNormal(plane.plane()).y()), 1.0, 1e-3);
}

}  // namespace
}  // namespace twist::semantic
