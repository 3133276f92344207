#include "slam/semantic/plane_fitting.h"

#include <gtest/gtest.h>

#include <Eigen/Geometry>
#include <algorithm>
#include <cmath>
#include <cstdio>
#include <string>

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

TEST(PlaneFitting, TransformPlaneMovesWithItsPoints) {
  // The road 1.65 m below a camera, carried into a world in which that
  // camera is turned and displaced: the plane's points stay on it, and the
  // sign follows NormalizePlane in the new frame.
  std::mt19937_64 rng(3);
  const Eigen::Vector3d n = Eigen::Vector3d(0.002, -1.0, 0.004).normalized();
  const auto in_camera = MakePlanePoints(n, 1.65, 20, 0.0, 0.0, &rng);
  const Eigen::Vector4d road = NormalizePlane(Eigen::Vector4d(n.x(), n.y(), n.z(), 1.65));
  const Eigen::Matrix3d r =
      Eigen::AngleAxisd(0.7, Eigen::Vector3d(0.1, 1.0, -0.2).normalized()).toRotationMatrix();
  const Eigen::Vector3d t(12.0, -3.0, 40.0);
  const Eigen::Vector4d in_world = TransformPlane(r, t, road);
  EXPECT_NEAR(in_world.norm(), 1.0, 1e-12);
  EXPECT_GE(in_world(3), 0.0);
  for (const Eigen::Vector3d& p : in_camera) {
    ASSERT_NEAR(PointPlaneDistance(road, p), 0.0, 1e-9);
    EXPECT_NEAR(PointPlaneDistance(in_world, r * p + t), 0.0, 1e-9);
  }
  // Distances are kept: the camera's height above the road.
  EXPECT_NEAR(std::abs(PointPlaneDistance(in_world, t)),
              PointPlaneDistance(road, Eigen::Vector3d::Zero()),
              1e-9);
  // And back.
  const Eigen::Vector4d back = TransformPlane(r.transpose(), -(r.transpose() * t), in_world);
  EXPECT_LT((back - road).norm(), 1e-12);
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

// A road (y = 1.65 below a camera at the origin looking along +z) seen by a
// KITTI-like stereo rig (f b = 388 px m): every point's depth error lies along
// its ray, σ_z = z² σ_d / (f b). The points 18–30 m ahead whose stereo
// block straddled an occluder are `biased` too close by `bias` of their
// depth, which lifts them 2–4 cm: within RANSAC's 5 cm.
std::vector<StereoPlanePoint> MakeStereoRoad(int num,
                                             double biased,
                                             double bias,
                                             std::mt19937_64* rng) {
  const double fb = 388.0, sigma_d = 0.5, height = 1.65;
  std::uniform_real_distribution<double> x(-4.0, 4.0), z(4.0, 30.0);
  std::uniform_real_distribution<double> unit(0.0, 1.0);
  std::normal_distribution<double> gauss(0.0, 1.0);
  std::vector<StereoPlanePoint> pts;
  for (int k = 0; k < num; ++k) {
    const Eigen::Vector3d truth(x(*rng), height, z(*rng));
    const double sigma_z = truth.z() * truth.z() * sigma_d / fb;
    double depth = truth.z() + sigma_z * gauss(*rng);
    if (truth.z() > 18.0 && unit(*rng) < biased) depth -= bias * truth.z();
    StereoPlanePoint p;
    p.ray = truth.normalized();
    p.point = truth * (depth / truth.z());
    p.sigma_along_m = sigma_z * truth.norm() / truth.z();
    pts.push_back(p);
  }
  return pts;
}

// Pitch of a plane against y = const (degrees).
double PitchDeg(const Eigen::Vector4d& plane) {
  const Eigen::Vector3d n = PlaneNormal(plane);
  return std::atan2(std::abs(n.z()), std::abs(n.y())) * 180.0 / M_PI;
}

TEST(PlaneFitting, DistanceNoiseFollowsTheViewingRay) {
  PlaneRefineOptions options;
  StereoPlanePoint p;
  p.sigma_along_m = 0.5;
  p.ray = Eigen::Vector3d(0.0, 1.65, 20.0).normalized();  // road point 20 m ahead
  EXPECT_NEAR(PlaneDistanceSigma(p, Eigen::Vector3d(0, -1, 0), options),
              0.5 * 1.65 / std::hypot(1.65, 20.0),
              1e-12);
  p.ray = Eigen::Vector3d(0.0, 0.0, 1.0);  // a wall seen head-on
  EXPECT_NEAR(PlaneDistanceSigma(p, Eigen::Vector3d(0, 0, -1), options), 0.5, 1e-12);
  EXPECT_EQ(PlaneDistanceSigma(p, Eigen::Vector3d(0, -1, 0), options), options.min_sigma_m);
  p.sigma_along_m = 0.0;  // not known
  EXPECT_EQ(PlaneDistanceSigma(p, Eigen::Vector3d(0, -1, 0), options), options.unknown_sigma_m);
}

TEST(PlaneFitting, WeightedRefinementIsExactOnNoiseFreePoints) {
  std::mt19937_64 rng(3);
  std::vector<StereoPlanePoint> pts = MakeStereoRoad(200, 0.0, 0.0, &rng);
  for (StereoPlanePoint& p : pts) p.point *= 1.65 / p.point.y();  // onto the plane
  const Eigen::Vector4d truth = NormalizePlane(Eigen::Vector4d(0, -1, 0, 1.65));
  const Eigen::Vector4d start = NormalizePlane(Eigen::Vector4d(0.01, -1, 0.02, 1.6));
  const auto refined = RefinePlaneWeighted(pts, start, PlaneRefineOptions{});
  ASSERT_TRUE(refined.ok()) << refined.status();
  EXPECT_LT((*refined - truth).norm(), 1e-9);
  PlaneRefineOptions bad;
  bad.tukey_c = 0.0;
  EXPECT_EQ(RefinePlaneWeighted(pts, start, bad).status().code(),
            absl::StatusCode::kInvalidArgument);
  EXPECT_EQ(RefinePlaneWeighted(pts, Eigen::Vector4d::Zero(), PlaneRefineOptions{}).status().code(),
            absl::StatusCode::kInvalidArgument);
}

// The stereo road of MakeStereoRoad with a fifth of its far points lifted by
// occluders: the RANSAC refit, which weighs every inlier alike, tilts towards
// them; weighting each point by its noise along the ray does not.
TEST(PlaneFitting, StereoNoiseWeightsKeepTheRoadLevel) {
  double ransac_pitch = 0.0, weighted_pitch = 0.0, ransac_height = 0.0, weighted_height = 0.0;
  const int runs = 10;
  for (int run = 0; run < runs; ++run) {
    std::mt19937_64 rng(100 + run);
    const std::vector<StereoPlanePoint> pts = MakeStereoRoad(600, 0.2, 0.02, &rng);
    std::vector<Eigen::Vector3d> positions;
    for (const StereoPlanePoint& p : pts) positions.push_back(p.point);
    std::mt19937_64 rng_a(7), rng_b(7);
    ClusterPlane ransac_only(ClusterPlane::Options{});
    ClusterPlane weighted(ClusterPlane::Options{});
    ASSERT_TRUE(ransac_only.Update(positions, &rng_a));
    ASSERT_TRUE(weighted.Update(pts, &rng_b));
    ransac_pitch += PitchDeg(ransac_only.plane()) / runs;
    weighted_pitch += PitchDeg(weighted.plane()) / runs;
    // Height error of the road under a car 30 m ahead.
    const Eigen::Vector3d car(0.0, 1.65, 30.0);
    ransac_height += std::abs(PointPlaneDistance(ransac_only.plane(), car)) / runs;
    weighted_height += std::abs(PointPlaneDistance(weighted.plane(), car)) / runs;
  }
  EXPECT_GT(ransac_pitch, 0.03);
  EXPECT_LT(weighted_pitch, 0.5 * ransac_pitch);
  EXPECT_LT(weighted_height, 0.5 * ransac_height);
  RecordProperty("ransac_pitch_deg", std::to_string(ransac_pitch));
  RecordProperty("weighted_pitch_deg", std::to_string(weighted_pitch));
  std::printf(
      "mean |pitch|: RANSAC refit %.3f deg, weighted %.3f deg; height at 30 m %.3f / %.3f m\n",
      ransac_pitch,
      weighted_pitch,
      ransac_height,
      weighted_height);
}

// Once its buffer is full, a stereo plane is no longer refitted by RANSAC (the
// buffer does not grow), but it is refined on the current points at every
// update: the road a drifting camera sees moves with it.
TEST(PlaneFitting, AFullStereoPlaneFollowsItsNewestPoints) {
  std::mt19937_64 rng(5);
  std::vector<StereoPlanePoint> pts = MakeStereoRoad(400, 0.0, 0.0, &rng);
  ClusterPlane plane(ClusterPlane::Options{});
  ASSERT_TRUE(plane.Update(pts, &rng));
  EXPECT_EQ(plane.num_points_at_fit(), 400);
  auto offset = [](const Eigen::Vector4d& p) { return p(3) / p.head<3>().norm(); };
  const double first = offset(plane.plane());
  // The same number of points, 1 cm lower: no RANSAC refit is due.
  for (StereoPlanePoint& p : pts) p.point.y() += 0.01;
  EXPECT_TRUE(plane.Update(pts, &rng));
  EXPECT_EQ(plane.num_points_at_fit(), 400);
  EXPECT_NEAR(offset(plane.plane()) - first, 0.01, 0.001);
  // Nothing new: no change reported.
  EXPECT_FALSE(plane.Update(pts, &rng));
  ClusterPlane::Options frozen;
  frozen.refine_every_update = false;
  ClusterPlane fixed(frozen);
  for (StereoPlanePoint& p : pts) p.point.y() -= 0.01;
  ASSERT_TRUE(fixed.Update(pts, &rng));
  const Eigen::Vector4d before = fixed.plane();
  for (StereoPlanePoint& p : pts) p.point.y() += 0.01;
  EXPECT_FALSE(fixed.Update(pts, &rng));
  EXPECT_EQ(fixed.plane(), before);
}

}  // namespace
}  // namespace twist::semantic
