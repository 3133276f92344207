#include "slam/sim/labels.h"

#include <glog/logging.h>

#include <algorithm>
#include <cmath>
#include <map>

#include "absl/strings/str_format.h"

namespace twist::sim {

double WrapAngle(double a) {
  a = std::fmod(a + M_PI, 2.0 * M_PI);
  if (a < 0.0) a += 2.0 * M_PI;
  return a - M_PI;
}

std::vector<FrameLabel> ComputeFrameLabels(const Scenario& scenario,
                                           const Renderer& renderer,
                                           int frame,
                                           const cv::Mat& panoptic) {
  CHECK_EQ(panoptic.type(), CV_16UC1);
  struct Extent {
    int x0 = INT32_MAX, y0 = INT32_MAX, x1 = -1, y1 = -1;
    int64_t count = 0;
  };
  std::map<uint16_t, Extent> extents;
  for (const SceneObject& object : scenario.scene.objects) extents[object.panoptic()];
  for (int y = 0; y < panoptic.rows; ++y) {
    const uint16_t* row = panoptic.ptr<uint16_t>(y);
    for (int x = 0; x < panoptic.cols; ++x) {
      if (row[x] % 1000 == 0) continue;  // stuff
      auto it = extents.find(row[x]);
      if (it == extents.end()) continue;
      Extent& e = it->second;
      e.x0 = std::min(e.x0, x);
      e.y0 = std::min(e.y0, y);
      e.x1 = std::max(e.x1, x);
      e.y1 = std::max(e.y1, y);
      ++e.count;
    }
  }
  const double t = scenario.TimeOf(frame);
  const geometry::SE3d world_from_camera = scenario.WorldFromCamera(frame);
  const geometry::SE3d camera_from_world = world_from_camera.Inverse();
  const geometry::StereoCamera& cam = scenario.camera;
  std::vector<FrameLabel> labels;
  for (const SceneObject& object : scenario.scene.objects) {
    const Extent& e = extents[object.panoptic()];
    if (e.count == 0) continue;
    FrameLabel label;
    label.track_id = object.track_id;
    label.class_id = object.class_id;
    label.type = object.kitti_type;
    label.h = object.h;
    label.w = object.w;
    label.l = object.l;
    label.x1 = e.x0;
    label.y1 = e.y0;
    label.x2 = e.x1;
    label.y2 = e.y1;
    label.visible_pixels = e.count;
    const geometry::SE3d world_from_object = object.WorldFromObject(t);
    const geometry::SE3d camera_from_object = camera_from_world * world_from_object;
    label.location = camera_from_object.translation();
    const Eigen::Matrix3d r = camera_from_object.rotation();
    // Yaw-only by construction (planar camera, planar/vertical-hinge objects).
    CHECK(std::abs(r(1, 1) - 1.0) < 1e-9) << "object " << object.track_id << " is not yaw-only";
    label.rotation_y = std::atan2(r(0, 2), r(0, 0));
    label.alpha = WrapAngle(label.rotation_y - std::atan2(label.location.x(), label.location.z()));
    label.world_from_object =
        world_from_object *
        geometry::SE3d(Eigen::Matrix3d::Identity(), Eigen::Vector3d(0, -0.5 * object.h, 0));
    // Truncation from the projected 3D box.
    bool behind = false;
    double u0 = 1e18, v0 = 1e18, u1 = -1e18, v1 = -1e18;
    for (const Eigen::Vector3d& corner : object.BoxCorners()) {
      const Eigen::Vector3d p = camera_from_object * corner;
      if (p.z() < 0.1) {
        behind = true;
        break;
      }
      const Eigen::Vector2d uv = cam.Project(p);
      u0 = std::min(u0, uv.x());
      v0 = std::min(v0, uv.y());
      u1 = std::max(u1, uv.x());
      v1 = std::max(v1, uv.y());
    }
    if (behind) {
      label.truncated = 2;
    } else {
      const double area = std::max(1e-9, (u1 - u0) * (v1 - v0));
      const double iw = std::max(0.0, std::min(u1, cam.width - 1.0) - std::max(u0, 0.0));
      const double ih = std::max(0.0, std::min(v1, cam.height - 1.0) - std::max(v0, 0.0));
      const double outside = 1.0 - iw * ih / area;
      label.truncated = outside < 0.02 ? 0 : outside < 0.5 ? 1 : 2;
    }
    // Occlusion: visible mask pixels against the object drawn alone.
    std::vector<Quad> quads;
    for (const BoxPart& part : object.parts) {
      AppendBoxQuads(part, world_from_object, object.panoptic(), &quads);
    }
    label.full_pixels = renderer.CountCoverage(quads, world_from_camera);
    const double visible = static_cast<double>(label.visible_pixels) /
                           static_cast<double>(std::max<int64_t>(1, label.full_pixels));
    label.occluded = visible >= 0.95 ? 0 : visible >= 0.5 ? 1 : 2;
    labels.push_back(label);
  }
  std::sort(labels.begin(), labels.end(), [](const FrameLabel& a, const FrameLabel& b) {
    return a.track_id < b.track_id;
  });
  return labels;
}

std::string FormatKittiLabel(int frame, const FrameLabel& l) {
  return absl::StrFormat(
      "%d %d %s %d %d %.6f %.6f %.6f %.6f %.6f %.6f %.6f %.6f %.6f %.6f %.6f %.6f",
      frame,
      l.track_id,
      l.type,
      l.truncated,
      l.occluded,
      l.alpha,
      l.x1,
      l.y1,
      l.x2,
      l.y2,
      l.h,
      l.w,
      l.l,
      l.location.x(),
      l.location.y(),
      l.location.z(),
      l.rotation_y);
}

std::string FormatObjectGt(int frame, const FrameLabel& l) {
  const Eigen::Vector3d& t = l.world_from_object.translation();
  Eigen::Quaterniond q = l.world_from_object.unit_quaternion();
  if (q.w() < 0.0) q.coeffs() = -q.coeffs();
  return absl::StrFormat("%d %d %d %.9f %.9f %.9f %.9f %.9f %.9f %.9f",
                         frame,
                         l.track_id,
                         l.class_id,
                         t.x(),
                         t.y(),
                         t.z(),
                         q.x(),
                         q.y(),
                         q.z(),
                         q.w());
}

}  // namespace twist::sim
