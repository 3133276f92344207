#include "slam/tracking/pnp.h"

#include <gtest/gtest.h>

#include <algorithm>
#include <fstream>
#include <opencv2/calib3d.hpp>
#include <random>
#include <sstream>
#include <string>

#include "tests/slam/tracking/synthetic_features.h"

namespace twist::tracking {
namespace {

std::vector<int> All(size_t n) {
  std::vector<int> v(n);
  for (size_t i = 0; i < n; ++i) v[i] = static_cast<int>(i);
  return v;
}

TEST(Pnp, RecoversAPoseFromMatchesWithOutliers) {
  const geometry::StereoCamera cam = testing::TestCamera();
  std::mt19937 rng(3);
  std::uniform_real_distribution<double> ux(-15.0, 15.0), uy(-3.0, 2.0), uz(5.0, 60.0);
  const geometry::SE3d truth = geometry::SE3d::Exp(
      (geometry::SE3d::Vector6() << 0.3, -0.05, 1.2, 0.01, 0.04, -0.02).finished());
  std::vector<cv::Point3f> obj;
  std::vector<cv::Point2f> img;
  std::vector<bool> outlier;
  std::uniform_real_distribution<double> coin(0.0, 1.0), pix(0.0, 1200.0), row(0.0, 360.0);
  while (obj.size() < 200) {
    const Eigen::Vector3d pw(ux(rng), uy(rng), uz(rng));
    const Eigen::Vector3d pc = truth * pw;
    if (pc.z() < 1.0) continue;
    const Eigen::Vector2d uv = cam.Project(pc);
    if (uv.x() < 0 || uv.x() > cam.width || uv.y() < 0 || uv.y() > cam.height) continue;
    const bool bad = coin(rng) < 0.3;
    obj.emplace_back(
        static_cast<float>(pw.x()), static_cast<float>(pw.y()), static_cast<float>(pw.z()));
    img.emplace_back(static_cast<float>(bad ? pix(rng) : uv.x()),
                     static_cast<float>(bad ? row(rng) : uv.y()));
    outlier.push_back(bad);
  }
  geometry::SE3d pose;
  std::vector<int> inliers;
  ASSERT_TRUE(SolvePnpRansac(cam, obj, img, &pose, &inliers));
  EXPECT_LT((pose.translation() - truth.translation()).norm(), 1e-3);
  EXPECT_LT((pose.rotation() - truth.rotation()).norm(), 1e-4);
  for (int k : inliers) EXPECT_FALSE(outlier[k]) << k;
  int good = 0;
  for (bool b : outlier) good += !b;
  EXPECT_GE(static_cast<int>(inliers.size()), good - 2);
}

TEST(Pnp, PointsFarOutOfScaleAreLeftOut) {
  std::vector<cv::Point3f> obj;
  for (int i = 0; i < 20; ++i) obj.emplace_back(0.5f * i, 1.0f, 20.0f + i);
  obj.emplace_back(100.0f, 0.0f, 5.0e5f);  // index 20
  obj.emplace_back(0.0f, 0.0f, 300.0f);    // index 21: ~45x the median distance
  const std::vector<int> kept = PnpCandidates(obj, 100.0, 10);
  EXPECT_EQ(kept.size(), 21u);
  EXPECT_EQ(std::count(kept.begin(), kept.end(), 20), 0);
  EXPECT_EQ(std::count(kept.begin(), kept.end(), 21), 1);
  EXPECT_EQ(PnpCandidates(obj, 100.0, 22).size(), obj.size());  // too few would remain
  EXPECT_EQ(PnpCandidates(obj, 0.0, 10).size(), obj.size());    // off
}

// Real matches with 5 points 1-529 km away among 252 within 300 m. With
// them, OpenCV's PnP RANSAC found 218 inliers and returned a pose 263 m
// off that fitted 3. The pose returned must fit the matches it calls
// inliers.
TEST(Pnp, ThePoseReturnedFitsItsInliersAtTheStartOfATurn) {
  std::ifstream in(std::string(TWIST_SOURCE_DIR) +
                   "/tests/slam/tracking/testdata/pnp_turn_start.txt");
  ASSERT_TRUE(in.good());
  std::string line;
  geometry::StereoCamera cam;
  std::vector<cv::Point3f> obj;
  std::vector<cv::Point2f> img;
  bool have_camera = false;
  while (std::getline(in, line)) {
    if (line.empty() || line[0] == '#') continue;
    std::istringstream s(line);
    if (!have_camera) {
      s >> cam.fx >> cam.fy >> cam.cx >> cam.cy;
      cam.baseline = 0.54;
      cam.width = 1242;
      cam.height = 375;
      have_camera = true;
      continue;
    }
    float x, y, z, u, v;
    s >> x >> y >> z >> u >> v;
    obj.emplace_back(x, y, z);
    img.emplace_back(u, v);
  }
  ASSERT_EQ(obj.size(), 257u);
  geometry::SE3d pose;
  std::vector<int> inliers;
  ASSERT_TRUE(SolvePnpRansac(cam, obj, img, &pose, &inliers));
  EXPECT_GE(inliers.size(), 200u);
  const std::vector<int> fit = PnpConsistent(cam, obj, img, pose, inliers, 3.0);
  EXPECT_EQ(fit.size(), inliers.size());
  EXPECT_GE(PnpConsistent(cam, obj, img, pose, All(obj.size()), 3.0).size(), 200u);
}

}  // namespace
}  // namespace twist::tracking
