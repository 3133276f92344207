#include "slam/sim/labels.h"

#include <gtest/gtest.h>

#include <cmath>
#include <map>

#include "slam/joints/joint.h"
#include "slam/sim/scenarios.h"
#include "slam/sim/writer.h"

namespace twist::sim {
namespace {

// KITTI box corners from a label (independent of SceneObject::BoxCorners).
std::vector<Eigen::Vector3d> LabelCorners(const FrameLabel& l) {
  const double c = std::cos(l.rotation_y), s = std::sin(l.rotation_y);
  Eigen::Matrix3d r;
  r << c, 0, s, 0, 1, 0, -s, 0, c;
  std::vector<Eigen::Vector3d> out;
  for (double x : {-0.5 * l.l, 0.5 * l.l})
    for (double y : {-l.h, 0.0})
      for (double z : {-0.5 * l.w, 0.5 * l.w})
        out.push_back(r * Eigen::Vector3d(x, y, z) + l.location);
  return out;
}

// The projected 3D ground-truth box of every labelled object contains every
// pixel of its mask instance, and the 2D box is the mask's bounding box.
TEST(Labels, ProjectedBoxesCoverTheirMaskInstances) {
  int checked_objects = 0;
  for (const char* name : {"driving", "intersection", "stationary_then_accelerating", "door"}) {
    absl::StatusOr<Scenario> sc = MakeScenario(name, 2, 100);
    ASSERT_TRUE(sc.ok());
    const Renderer renderer(sc->camera, RenderOptions());
    for (int frame : {5, 40, 75}) {
      const Exposure e;
      const StereoRender r =
          renderer.RenderStereo(sc->scene, sc->TimeOf(frame), sc->WorldFromCamera(frame), e, e);
      const std::vector<FrameLabel> labels = ComputeFrameLabels(*sc, renderer, frame, r.panoptic);
      for (const FrameLabel& label : labels) {
        const uint16_t id = PanopticId(label.class_id, label.track_id);
        double u0 = 1e18, u1 = -1e18, v0 = 1e18, v1 = -1e18;
        bool in_front = true;
        for (const Eigen::Vector3d& p : LabelCorners(label)) {
          if (p.z() < 0.1) in_front = false;
          const Eigen::Vector2d uv = sc->camera.Project(p);
          u0 = std::min(u0, uv.x());
          u1 = std::max(u1, uv.x());
          v0 = std::min(v0, uv.y());
          v1 = std::max(v1, uv.y());
        }
        int mx0 = INT32_MAX, mx1 = -1, my0 = INT32_MAX, my1 = -1;
        int64_t outside = 0, count = 0;
        for (int v = 0; v < r.panoptic.rows; ++v) {
          for (int u = 0; u < r.panoptic.cols; ++u) {
            if (r.panoptic.at<uint16_t>(v, u) != id) continue;
            ++count;
            mx0 = std::min(mx0, u);
            mx1 = std::max(mx1, u);
            my0 = std::min(my0, v);
            my1 = std::max(my1, v);
            if (u < u0 - 1e-6 || u > u1 + 1e-6 || v < v0 - 1e-6 || v > v1 + 1e-6) ++outside;
          }
        }
        EXPECT_EQ(count, label.visible_pixels);
        EXPECT_EQ(mx0, label.x1);
        EXPECT_EQ(mx1, label.x2);
        EXPECT_EQ(my0, label.y1);
        EXPECT_EQ(my1, label.y2);
        EXPECT_GE(label.full_pixels, label.visible_pixels);
        if (!in_front) continue;  // the box crosses the image plane: no 2D box
        EXPECT_EQ(outside, 0) << name << " frame " << frame << " track " << label.track_id;
        // objects_gt (box centre) and the label (bottom centre) agree.
        const Eigen::Vector3d centre_in_cam =
            sc->WorldFromCamera(frame).Inverse() * label.world_from_object.translation();
        EXPECT_NEAR(
            (centre_in_cam - (label.location - Eigen::Vector3d(0, 0.5 * label.h, 0))).norm(),
            0.0,
            1e-9);
        ++checked_objects;
      }
    }
  }
  EXPECT_GT(checked_objects, 50);
}

// Ground-truth poses obey their joints: the camera and every planar object
// keep their height and move only by yaw about the road normal; the door
// rotates about its hinge only. Checked on consecutive-frame twists with the
// joint projectors of slam/joints: Π ξ = ξ.
TEST(Labels, GroundTruthObeysTheJoints) {
  for (const ScenarioInfo& info : ListScenarios()) {
    absl::StatusOr<Scenario> sc = MakeScenario(info.name, 9, 100);
    ASSERT_TRUE(sc.ok());
    const Eigen::Vector3d up(0, -1, 0);
    double moving = 0.0;
    for (int i = 0; i + 1 < sc->num_frames; ++i) {
      const geometry::SE3d c0 = sc->WorldFromCamera(i), c1 = sc->WorldFromCamera(i + 1);
      EXPECT_NEAR(c1.translation().y(), 0.0, 1e-12);
      EXPECT_NEAR(c1.rotation()(1, 1), 1.0, 1e-12);
      const geometry::Vector6d xi_cam = (c1 * c0.Inverse()).Log();
      moving += xi_cam.norm();
      const joints::Joint cam_joint =
          joints::Joint::FromPlane(joints::JointType::kPlanar, up, c0.translation());
      EXPECT_NEAR((cam_joint.WorldProjector() * xi_cam - xi_cam).norm(), 0.0, 1e-9) << info.name;
      for (const SceneObject& object : sc->scene.objects) {
        const geometry::SE3d t0 = object.WorldFromObject(sc->TimeOf(i));
        const geometry::SE3d t1 = object.WorldFromObject(sc->TimeOf(i + 1));
        // World twist of the step: T1 = Exp(ξ) T0 (DESIGN.md §1.5 pose update).
        const geometry::Vector6d xi = (t1 * t0.Inverse()).Log();
        moving += xi.norm();
        joints::Joint joint;
        if (object.kind == MotionKind::kPlanar) {
          EXPECT_NEAR(t1.translation().y(), t0.translation().y(), 1e-12);
          EXPECT_NEAR(t1.rotation()(1, 1), 1.0, 1e-12);
          joint = joints::Joint::FromPlane(joints::JointType::kPlanar, up, t0.translation());
        } else {
          const Eigen::Vector3d hinge = object.revolute.hinge_point();
          joint = joints::Joint::FromAxis(
              joints::JointType::kRevolute, object.revolute.hinge_axis(), hinge);
          // Hinge points (box frame x = -l/2, z = 0) do not move.
          for (double y : {0.0, -1.0, -object.h}) {
            const Eigen::Vector3d p(-0.5 * object.l, y, 0.0);
            EXPECT_NEAR((t1 * p - t0 * p).norm(), 0.0, 1e-12);
          }
        }
        EXPECT_NEAR((joint.WorldProjector() * xi - xi).norm(), 0.0, 1e-9)
            << info.name << " object " << object.track_id << " frame " << i;
      }
    }
    EXPECT_GT(moving, 1.0) << info.name;  // the checks are not vacuous
  }
}

TEST(Labels, WrongJointIsDetected) {
  // A planar car step is not a revolute motion about a vertical axis through
  // an unrelated point: the projector check above can fail.
  absl::StatusOr<Scenario> sc = MakeScenario("driving", 1, 10);
  ASSERT_TRUE(sc.ok());
  const SceneObject& lead = sc->scene.objects.front();
  const geometry::Vector6d xi =
      (lead.WorldFromObject(0.1) * lead.WorldFromObject(0.0).Inverse()).Log();
  const joints::Joint wrong = joints::Joint::FromAxis(
      joints::JointType::kRevolute, Eigen::Vector3d(0, -1, 0), Eigen::Vector3d(50, 0, 0));
  EXPECT_GT((wrong.WorldProjector() * xi - xi).norm(), 0.1);
}

}  // namespace
}  // namespace twist::sim
