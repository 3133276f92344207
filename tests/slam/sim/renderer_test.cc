#include "slam/sim/renderer.h"

#include <gtest/gtest.h>

#include <algorithm>
#include <cmath>
#include <opencv2/features2d.hpp>
#include <opencv2/imgproc.hpp>
#include <vector>

#include "slam/sim/scenarios.h"
#include "slam/sim/writer.h"

namespace twist::sim {
namespace {

// Sub-pixel position where a row profile crosses `level` going up, searched
// in [u0, u1); nan if none.
double RisingCrossing(const cv::Mat& gray, int v, int u0, int u1, double level) {
  for (int u = u0; u < u1; ++u) {
    const double a = gray.at<uint8_t>(v, u), b = gray.at<uint8_t>(v, u + 1);
    if (a < level && b >= level) return u + (level - a) / (b - a);
  }
  return std::nan("");
}

// A known road point lands where the geometry says: the left edge of the
// solid lane line at x = 1.75 - 0.075 m (anti-aliased by an exact box filter,
// so its 50 % crossing is the true edge) appears at u = cx + fx·X/Z in the
// left image and fx·b/Z pixels further left in the right image, with Z the
// road depth of the row. The depth buffer equals the road-plane depth.
TEST(Renderer, RoadDisparityEqualsFxBOverZ) {
  absl::StatusOr<Scenario> sc = MakeScenario("static_street", 3, 1);
  ASSERT_TRUE(sc.ok());
  RenderOptions options;
  options.noise_sigma = 0.0;
  options.gray = true;
  const Renderer renderer(sc->camera, options);
  const Exposure same;
  const StereoRender r = renderer.RenderStereo(sc->scene, 0.0, sc->WorldFromCamera(0), same, same);
  const geometry::StereoCamera& cam = sc->camera;
  const uint16_t road = PanopticId(kClassRoad, 0);
  // Depth buffer on road pixels.
  int depth_checks = 0;
  for (int v = 200; v < cam.height; v += 5) {
    for (int u = 0; u < cam.width; u += 11) {
      if (r.panoptic.at<uint16_t>(v, u) != road) continue;
      const double z = kCameraHeight * cam.fy / (v - cam.cy);
      EXPECT_NEAR(r.depth.at<float>(v, u), z, 2e-6 * z) << u << "," << v;
      ++depth_checks;
    }
  }
  EXPECT_GT(depth_checks, 1000);
  // The lane line edge.
  const double edge_x = 1.75 - 0.075;
  int edge_checks = 0;
  std::vector<double> abs_errors;
  for (int v = 235; v < cam.height - 1; ++v) {
    const double z = kCameraHeight * cam.fy / (v - cam.cy);
    const double u_left = cam.cx + cam.fx * edge_x / z;
    const double disparity = cam.bf() / z;
    const double u_right = u_left - disparity;
    const int ul = static_cast<int>(std::floor(u_left)), ur = static_cast<int>(std::floor(u_right));
    if (ul + 6 >= cam.width || ur - 6 < 0) continue;
    // Road level 4 px outside, paint level 2 px inside the line (>= 4 px wide here).
    const double level_l = 0.5 * (r.left.at<uint8_t>(v, ul - 4) + r.left.at<uint8_t>(v, ul + 3));
    const double level_r = 0.5 * (r.right.at<uint8_t>(v, ur - 4) + r.right.at<uint8_t>(v, ur + 3));
    const double cl = RisingCrossing(r.left, v, ul - 3, ul + 3, level_l);
    const double cr = RisingCrossing(r.right, v, ur - 3, ur + 3, level_r);
    ASSERT_FALSE(std::isnan(cl) || std::isnan(cr)) << "row " << v;
    // Tolerances: the worn-paint and asphalt textures under the edge move the
    // 50 % crossing by up to ~0.35 px near the camera, identically in both
    // views (same world texture); the disparity only sees interpolation and
    // 8-bit quantisation (~0.1 px).
    EXPECT_NEAR(cl, u_left, 0.4) << "row " << v;
    EXPECT_NEAR(cr, u_right, 0.4) << "row " << v;
    EXPECT_NEAR(cl - cr, disparity, 0.12) << "row " << v;
    abs_errors.push_back(std::abs(cl - u_left));
    ++edge_checks;
  }
  EXPECT_GT(edge_checks, 100);
  std::sort(abs_errors.begin(), abs_errors.end());
  EXPECT_LT(abs_errors[abs_errors.size() / 2], 0.1);
}

// Every rasterised pixel back-projects onto the quad the buffer names.
TEST(Renderer, DepthBufferPointsLieOnTheirQuads) {
  absl::StatusOr<Scenario> sc = MakeScenario("intersection", 5, 80);
  ASSERT_TRUE(sc.ok());
  const Renderer renderer(sc->camera, RenderOptions());
  for (int frame : {0, 70}) {
    const double t = sc->TimeOf(frame);
    const std::vector<Quad> quads = Renderer::QuadsAt(sc->scene, t);
    const geometry::SE3d world_from_camera = sc->WorldFromCamera(frame);
    const ViewBuffers buffers = renderer.Rasterize(quads, world_from_camera);
    int checked = 0;
    for (int v = 0; v < sc->camera.height; v += 3) {
      for (int u = 0; u < sc->camera.width; u += 7) {
        const int32_t id = buffers.quad.at<int32_t>(v, u);
        const float z = buffers.depth.at<float>(v, u);
        if (id < 0) {
          EXPECT_TRUE(std::isinf(z));
          continue;
        }
        const Eigen::Vector3d p_cam = sc->camera.Backproject(Eigen::Vector2d(u, v), z);
        const Eigen::Vector3d p = world_from_camera * p_cam;
        const Quad& q = quads[id];
        const Eigen::Vector3d rel = p - q.origin;
        const double tol = 1e-6 * z + 1e-9;  // float depth storage
        EXPECT_NEAR(rel.dot(q.normal()), 0.0, tol);
        EXPECT_GE(rel.dot(q.axis_u), -tol);
        EXPECT_LE(rel.dot(q.axis_u), q.size_u + tol);
        EXPECT_GE(rel.dot(q.axis_v), -tol);
        EXPECT_LE(rel.dot(q.axis_v), q.size_v + tol);
        ++checked;
      }
    }
    EXPECT_GT(checked, 10000);
  }
}

// The textures give a feature extractor enough to work with in every
// scenario (first and a later frame).
TEST(Renderer, OrbFindsAtLeast1000KeypointsPerFrame) {
  for (const ScenarioInfo& info : ListScenarios()) {
    absl::StatusOr<Scenario> sc = MakeScenario(info.name, 1, 60);
    ASSERT_TRUE(sc.ok());
    RenderOptions options;
    options.gray = true;
    const Renderer renderer(sc->camera, options);
    for (int frame : {0, 45}) {
      Exposure left, right;
      FrameExposures(*sc, frame, &left, &right);
      const StereoRender r = renderer.RenderStereo(
          sc->scene, sc->TimeOf(frame), sc->WorldFromCamera(frame), left, right);
      cv::Ptr<cv::ORB> orb = cv::ORB::create(5000);
      std::vector<cv::KeyPoint> keypoints;
      orb->detect(r.left, keypoints);
      EXPECT_GE(keypoints.size(), 1000u) << info.name << " frame " << frame;
    }
  }
}

TEST(Renderer, RightCameraSitsAtPlusBaseline) {
  const geometry::SE3d world_from_left(
      Eigen::AngleAxisd(0.3, Eigen::Vector3d::UnitY()).toRotationMatrix(),
      Eigen::Vector3d(1, 2, 3));
  const geometry::SE3d world_from_right = RightFromLeftPose(world_from_left, 0.54);
  const Eigen::Vector3d p_world(4.0, 1.0, 20.0);
  const geometry::StereoCamera cam = KittiLikeCamera();
  const Eigen::Vector3d uvr =
      cam.ProjectStereo(Eigen::Vector3d(world_from_left.Inverse() * p_world));
  const Eigen::Vector2d right = cam.Project(Eigen::Vector3d(world_from_right.Inverse() * p_world));
  EXPECT_NEAR(right.x(), uvr.z(), 1e-9);
  EXPECT_NEAR(right.y(), uvr.y(), 1e-9);
}

}  // namespace
}  // namespace twist::sim
