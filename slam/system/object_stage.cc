#include "slam/system/object_stage.h"

#include <glog/logging.h>

#include <algorithm>
#include <cmath>
#include <optional>
#include <tuple>
#include <unordered_set>

#include "slam/common/timer.h"
#include "slam/objects/dynamic_ba.h"
#include "slam/objects/joint_frames.h"
#include "slam/objects/object_ba.h"
#include "slam/semantic/panoptic.h"

namespace twist {
namespace {

using geometry::SE3d;

objects::ObjectTrackerOptions TrackerOptionsFrom(const SlamOptions& o) {
  objects::ObjectTrackerOptions t;
  t.constrained = o.constrain_objects;
  return t;
}

semantic::ClusterPlane::Options PlaneOptionsFrom(const ObjectStageOptions& o) {
  semantic::ClusterPlane::Options p;
  p.ransac.inlier_threshold_m = o.plane_inlier_m;
  return p;
}

bool IsAxisJoint(joints::JointType t) {
  return t == joints::JointType::kRevolute || t == joints::JointType::kPrismatic ||
         t == joints::JointType::kCylindrical || t == joints::JointType::kHelical ||
         t == joints::JointType::kSphereCylinder;
}

}  // namespace

ObjectStage::ObjectStage(const SessionConfig& config, const ObjectStageOptions& options)
    : config_(config),
      options_(options),
      associator_(semantic::ClusterAssociationOptions{}),
      tracker_(config.camera, TrackerOptionsFrom(config.options)),
      rng_(config.options.seed) {
  std::unordered_set<int> dynamic;
  for (const joints::ClassInfo& c : config_.classes.classes()) {
    if (c.is_dynamic) dynamic.insert(c.id);
    if (!c.is_dynamic && c.fit_plane) {
      planes_.emplace(c.id, PlaneState{semantic::ClusterPlane(PlaneOptionsFrom(options_)), {}, -1});
    }
  }
  associator_.set_dynamic_classes(std::move(dynamic));
}

cv::Mat ObjectStage::FavourMask(const cv::Mat& panoptic, const joints::ClassTable& classes) {
  if (panoptic.empty()) return cv::Mat();
  cv::Mat favour(panoptic.size(), CV_8UC1, cv::Scalar(1));
  for (int y = 0; y < panoptic.rows; ++y) {
    uint8_t* out = favour.ptr<uint8_t>(y);
    int last_class = -1;
    bool last_dynamic = false;
    for (int x = 0; x < panoptic.cols; ++x) {
      const int64_t id = semantic::PanopticIdAt(panoptic, x, y);
      if (id < 0) continue;
      const int c = semantic::ClassOf(id);
      if (c != last_class) {
        last_class = c;
        last_dynamic = classes.IsDynamic(c);
      }
      if (last_dynamic) out[x] = 200;
    }
  }
  return favour;
}

joints::Joint ObjectStage::JointFor(const objects::ObjectDetectionInput& det,
                                    const SE3d& world_from_camera,
                                    const std::vector<Eigen::Vector3d>& points_in_world) {
  const joints::ClassInfo* info = config_.classes.Find(det.class_id);
  objects::JointSpec spec;
  spec.anchor = world_from_camera.translation();
  if (!points_in_world.empty()) {
    Eigen::Vector3d c = Eigen::Vector3d::Zero();
    for (const auto& p : points_in_world) c += p;
    spec.anchor = c / static_cast<double>(points_in_world.size());
  }
  if (info == nullptr) return objects::ResolveJointOrFree(spec);
  spec.type = info->joint;
  spec.pitch = info->pitch;
  const auto parent = planes_.find(info->parent_id);
  if (parent != planes_.end() && parent->second.plane.has_plane()) {
    spec.parent_plane = parent->second.plane.plane();
  }
  if (!IsAxisJoint(spec.type)) return objects::ResolveJointOrFree(spec);

  // Axis joints: fixed per cluster once resolved.
  if (auto it = axis_joints_.find(det.cluster_id); it != axis_joints_.end()) return it->second;
  if (!spec.parent_plane || points_in_world.size() < 5) {
    spec.type = joints::JointType::kFree;
    return objects::ResolveJointOrFree(spec);
  }
  // The axis is the "up" direction within the parent plane (a hinge in a
  // wall): up = the normal of a horizontal plane class when one is fitted,
  // else the camera's up.
  const Eigen::Vector3d n = spec.parent_plane->head<3>().normalized();
  Eigen::Vector3d up = world_from_camera.so3() * Eigen::Vector3d(0.0, -1.0, 0.0);
  for (const auto& [cls, ps] : planes_) {
    if (cls == info->parent_id || !ps.plane.has_plane()) continue;
    const Eigen::Vector3d m = ps.plane.plane().head<3>().normalized();
    if (std::abs(m.dot(up)) > 0.9) {
      up = m.dot(up) > 0 ? m : Eigen::Vector3d(-m);
      break;
    }
  }
  Eigen::Vector3d axis = up - up.dot(n) * n;
  if (axis.norm() < 0.3) {
    spec.type = joints::JointType::kFree;
    return objects::ResolveJointOrFree(spec);
  }
  axis.normalize();
  const Eigen::Vector3d h = axis.cross(n);
  std::vector<double> s;
  s.reserve(points_in_world.size());
  for (const auto& p : points_in_world) s.push_back(h.dot(p));
  std::sort(s.begin(), s.end());
  const double lo = s[s.size() / 10];
  const double hi = s[s.size() - 1 - s.size() / 10];
  const Eigen::Vector3d centre =
      spec.anchor -
      (n.dot(spec.anchor) + spec.parent_plane->w() / spec.parent_plane->head<3>().norm()) * n;
  const Eigen::Vector3d edge_lo = centre + (lo - h.dot(centre)) * h;
  const Eigen::Vector3d edge_hi = centre + (hi - h.dot(centre)) * h;
  const Eigen::Vector3d cam = world_from_camera.translation();
  spec.axis_direction = axis;
  spec.axis_point = (edge_lo - cam).norm() <= (edge_hi - cam).norm() ? edge_lo : edge_hi;
  const joints::Joint joint = objects::ResolveJointOrFree(spec);
  axis_joints_.emplace(det.cluster_id, joint);
  return joint;
}

absl::StatusOr<ObjectStageOutput> ObjectStage::Process(const ObjectStageInput& in) {
  if (in.features == nullptr) return absl::InvalidArgumentError("object stage needs features");
  if (absl::Status s = semantic::ValidatePanopticMask(in.panoptic, in.left.size()); !s.ok()) {
    return s;
  }
  ObjectStageOutput out;
  Stopwatch sw;
  const geometry::StereoCamera& cam = config_.camera;
  const SE3d world_from_camera = in.camera_from_world.Inverse();
  const map::FrameFeatures& f = *in.features;
  const int n = f.size();

  // Stereo keypoints in the world, and plane points per plane class.
  std::vector<std::optional<Eigen::Vector3d>> p_world(n);
  for (int i = 0; i < n; ++i) {
    if (f.u_right[i] < 0.0f) continue;
    const auto p = cam.TriangulateStereo(
        f.keypoints[i].pt.x, f.keypoints[i].pt.y, f.u_right[i], options_.max_plane_depth_m);
    if (!p) continue;
    p_world[i] = world_from_camera * *p;
    const int cls = semantic::ClassOf(f.labels[i]);
    auto it = planes_.find(cls);
    if (it == planes_.end() || !f.is_static[i]) continue;
    it->second.points.push_back(*p_world[i]);
    if (static_cast<int>(it->second.points.size()) > options_.max_plane_points) {
      it->second.points.pop_front();
    }
  }

  // Detections: dynamic instances (masks) and plane-class stuff (boxes).
  const std::vector<semantic::Segment> segments = semantic::ExtractSegments(in.panoptic, 1, false);
  std::vector<semantic::Detection> dets;
  for (const semantic::Segment& s : segments) {
    const int c = s.label.class_id;
    if (config_.classes.IsDynamic(c)) {
      if (s.label.instance_id == 0 || s.num_pixels < options_.min_segment_pixels) continue;
      semantic::Detection d;
      d.label = s.label;
      d.box = cv::Rect2d(s.box);
      d.mask = semantic::SegmentMask(in.panoptic, s.label);
      dets.push_back(std::move(d));
    } else if (planes_.count(c) > 0 && s.label.instance_id == 0 &&
               s.num_pixels >= options_.min_segment_pixels) {
      semantic::Detection d;
      d.label = s.label;
      d.box = cv::Rect2d(s.box);
      dets.push_back(std::move(d));
    }
  }
  const semantic::AssociationResult assoc = associator_.Associate(dets);
  out.cluster_events = assoc.events;
  for (int64_t removed : assoc.removed) axis_joints_.erase(removed);

  // Planes.
  for (size_t d = 0; d < dets.size(); ++d) {
    auto it = planes_.find(dets[d].label.class_id);
    if (it != planes_.end() && dets[d].label.instance_id == 0) {
      it->second.cluster_id = assoc.cluster_of_detection[d];
    }
  }
  for (auto& [cls, ps] : planes_) {
    if (ps.cluster_id < 0) continue;
    const std::vector<Eigen::Vector3d> pts(ps.points.begin(), ps.points.end());
    if (ps.plane.Update(pts, &rng_)) {
      ClusterEvent e;
      e.type = ClusterEventType::kPlaneUpdated;
      e.cluster_id = ps.cluster_id;
      e.class_id = cls;
      e.is_dynamic = false;
      e.plane = ps.plane.plane();
      out.cluster_events.push_back(e);
    }
  }

  // Object tracking.
  objects::ObjectFrameInput of;
  of.frame_index = in.frame_index;
  of.timestamp_ns = in.timestamp_ns;
  of.camera_from_world = in.camera_from_world;
  of.left = in.left;
  of.flow = in.flow;
  of.keypoints.descriptors = f.descriptors;
  of.keypoints.uv.reserve(n);
  of.keypoints.u_right.reserve(n);
  for (int i = 0; i < n; ++i) {
    of.keypoints.uv.emplace_back(f.keypoints[i].pt.x, f.keypoints[i].pt.y);
    of.keypoints.u_right.push_back(f.u_right[i]);
  }
  for (size_t d = 0; d < dets.size(); ++d) {
    if (dets[d].label.instance_id == 0) continue;
    objects::ObjectDetectionInput det;
    det.cluster_id = assoc.cluster_of_detection[d];
    det.class_id = dets[d].label.class_id;
    det.instance_id = dets[d].label.instance_id;
    det.box = dets[d].box;
    det.mask = dets[d].mask;
    std::vector<Eigen::Vector3d> inside;
    for (int i = 0; i < n; ++i) {
      if (!p_world[i]) continue;
      const int x = std::clamp(cvRound(f.keypoints[i].pt.x), 0, det.mask.cols - 1);
      const int y = std::clamp(cvRound(f.keypoints[i].pt.y), 0, det.mask.rows - 1);
      if (det.mask.at<uint8_t>(y, x) != 0) inside.push_back(*p_world[i]);
    }
    det.joint = JointFor(det, world_from_camera, inside);
    of.detections.push_back(std::move(det));
  }
  out.timings.push_back({"objects_segments", sw.ElapsedMs()});
  sw.Restart();
  absl::StatusOr<std::vector<ObjectResult>> results = tracker_.Process(of);
  out.timings.push_back({"objects_track", sw.ElapsedMs()});
  if (!results.ok()) return results.status();
  out.objects = *std::move(results);

  // Dynamic BA over the window (camera poses fixed).
  if (options_.ba_window_frames > 0) {
    window_.emplace_back(in.frame_index, in.timestamp_ns, in.camera_from_world);
    const int64_t span_ns = static_cast<int64_t>(config_.options.temporal_window_s * 1e9);
    while (static_cast<int>(window_.size()) > options_.ba_window_frames ||
           (!window_.empty() && in.timestamp_ns - std::get<1>(window_.front()) > span_ns)) {
      window_.pop_front();
    }
    sw.Restart();
    RunDynamicBa(&out.objects);
    out.ba_ms = sw.ElapsedMs();
  }
  return out;
}

void ObjectStage::RunDynamicBa(std::vector<ObjectResult>* results) {
  if (window_.size() < 3 || results->empty()) return;
  objects::DynamicBaProblem problem;
  problem.camera = config_.camera;
  std::map<int64_t, int> keyframe_of_frame;
  for (const auto& [index, ts, pose] : window_) {
    objects::BaKeyframe kf;
    kf.id = index;
    kf.timestamp_ns = ts;
    kf.camera_from_world = pose;
    kf.fixed = true;
    keyframe_of_frame[index] = static_cast<int>(problem.keyframes.size());
    problem.keyframes.push_back(kf);
  }
  const auto links = objects::AddTrackedObjectsToBa(
      tracker_, keyframe_of_frame, objects::ObjectBaOptions{}, &problem);
  if (links.empty()) return;
  objects::DynamicBaOptions ba;
  ba.max_iterations = options_.ba_iterations;
  ba.constrained = config_.options.constrain_objects;
  const auto summary = objects::SolveDynamicBa(&problem, ba);
  if (!summary.ok() || !summary->usable) return;
  objects::ApplyBaToTrackedObjects(problem, links, &tracker_);
  for (ObjectResult& o : *results) {
    auto it = tracker_.objects().find(o.id);
    if (it != tracker_.objects().end()) o = objects::ObjectTracker::ToResult(it->second);
  }
}

}  // namespace twist
