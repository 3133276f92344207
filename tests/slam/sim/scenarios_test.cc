#include "slam/sim/scenarios.h"

#include <gtest/gtest.h>

#include <array>
#include <cmath>
#include <utility>
#include <vector>

#include "slam/sim/renderer.h"

namespace twist::sim {
namespace {

using Corners2 = std::array<Eigen::Vector2d, 4>;

// Footprint (x, z) of an oriented box on the ground, grown by `margin`.
Corners2 Footprint(const geometry::SE3d& world_from_body,
                   double half_x,
                   double half_z,
                   double margin) {
  const double hx = half_x + margin, hz = half_z + margin;
  const std::array<Eigen::Vector3d, 4> local = {Eigen::Vector3d(-hx, 0, -hz),
                                                Eigen::Vector3d(hx, 0, -hz),
                                                Eigen::Vector3d(hx, 0, hz),
                                                Eigen::Vector3d(-hx, 0, hz)};
  Corners2 c;
  for (int i = 0; i < 4; ++i) {
    const Eigen::Vector3d p = world_from_body * local[i];
    c[i] = Eigen::Vector2d(p.x(), p.z());
  }
  return c;
}

// Separating axis test of two convex quadrilaterals.
bool Overlap(const Corners2& a, const Corners2& b) {
  for (const Corners2* poly : {&a, &b}) {
    for (int i = 0; i < 4; ++i) {
      const Eigen::Vector2d e = (*poly)[(i + 1) % 4] - (*poly)[i];
      const Eigen::Vector2d n(-e.y(), e.x());
      double amin = 1e18, amax = -1e18, bmin = 1e18, bmax = -1e18;
      for (const auto& p : a) {
        amin = std::min(amin, n.dot(p));
        amax = std::max(amax, n.dot(p));
      }
      for (const auto& p : b) {
        bmin = std::min(bmin, n.dot(p));
        bmax = std::max(bmax, n.dot(p));
      }
      if (amax < bmin || bmax < amin) return false;
    }
  }
  return true;
}

TEST(Scenarios, ListAndErrors) {
  EXPECT_EQ(ListScenarios().size(), 7u);
  EXPECT_EQ(MakeScenario("nope", 1, 10).status().code(), absl::StatusCode::kInvalidArgument);
  EXPECT_EQ(MakeScenario("driving", 1, 0).status().code(), absl::StatusCode::kInvalidArgument);
  absl::StatusOr<Scenario> sc = MakeScenario("driving", 1, 10);
  ASSERT_TRUE(sc.ok());
  EXPECT_NEAR((sc->WorldFromCamera(0).matrix() - Eigen::Matrix4d::Identity()).norm(), 0.0, 1e-15);
  EXPECT_TRUE(sc->camera.Validate().ok());
}

// Objects never overlap each other or the ego car (a 1.9 m x 4.4 m box
// around the camera, 1.8 m of it ahead) over the default length for a few
// seeds, and over 60 s for one.
TEST(Scenarios, ObjectsDoNotCollide) {
  for (const ScenarioInfo& info : ListScenarios()) {
    for (const auto& [seed, frames] :
         std::vector<std::pair<uint32_t, int>>{{1, 100}, {2, 100}, {77, 100}, {5, 600}}) {
      absl::StatusOr<Scenario> sc = MakeScenario(info.name, seed, frames);
      ASSERT_TRUE(sc.ok());
      const auto& objects = sc->scene.objects;
      for (int i = 0; i < sc->num_frames; i += 2) {
        const double t = sc->TimeOf(i);
        // Ego: camera z axis forward; box from 2.6 m behind to 1.8 m ahead.
        const geometry::SE3d ego_centre =
            sc->WorldFromCamera(i) *
            geometry::SE3d(Eigen::Matrix3d::Identity(), Eigen::Vector3d(0, 0, -0.4));
        const Corners2 ego = Footprint(ego_centre, 0.95, 2.2, 0.0);
        std::vector<Corners2> boxes;
        for (const SceneObject& o : objects) {
          if (o.kind != MotionKind::kPlanar) {
            Corners2 none;
            none.fill(Eigen::Vector2d::Zero());
            boxes.push_back(none);
            continue;
          }
          boxes.push_back(Footprint(o.WorldFromObject(t), 0.5 * o.l, 0.5 * o.w, 0.05));
          EXPECT_FALSE(Overlap(ego, boxes.back()))
              << info.name << " seed " << seed << " frame " << i << " object " << o.track_id;
        }
        for (size_t a = 0; a < objects.size(); ++a) {
          if (objects[a].kind != MotionKind::kPlanar) continue;
          for (size_t b = a + 1; b < objects.size(); ++b) {
            if (objects[b].kind != MotionKind::kPlanar) continue;
            EXPECT_FALSE(Overlap(boxes[a], boxes[b]))
                << info.name << " seed " << seed << " frame " << i << " objects "
                << objects[a].track_id << " and " << objects[b].track_id;
          }
        }
      }
    }
  }
}

// Long sequences still look at a street: the world is sized to the distance
// the camera covers.
TEST(Scenarios, LongSequencesStayInsideTheStreet) {
  for (const ScenarioInfo& info : ListScenarios()) {
    absl::StatusOr<Scenario> sc = MakeScenario(info.name, 3, 600);
    ASSERT_TRUE(sc.ok());
    const Renderer renderer(sc->camera, RenderOptions());
    const int last = sc->num_frames - 1;
    const std::vector<Quad> quads = Renderer::QuadsAt(sc->scene, sc->TimeOf(last));
    const ViewBuffers view = renderer.Rasterize(quads, sc->WorldFromCamera(last));
    int64_t sky = 0, road = 0;
    for (int v = 0; v < view.quad.rows; ++v) {
      for (int u = 0; u < view.quad.cols; ++u) {
        const int32_t id = view.quad.at<int32_t>(v, u);
        if (id < 0) {
          ++sky;
        } else if (quads[id].panoptic == PanopticId(kClassRoad, 0)) {
          ++road;
        }
      }
    }
    const double n = static_cast<double>(view.quad.total());
    EXPECT_LT(sky / n, 0.4) << info.name;
    EXPECT_GT(road / n, 0.1) << info.name;
  }
}

}  // namespace
}  // namespace twist::sim
