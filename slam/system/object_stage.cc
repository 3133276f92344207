#include "slam/system/object_stage.h"

#include <glog/logging.h>

#include <algorithm>
#include <cmath>
#include <opencv2/imgproc.hpp>
#include <optional>
#include <sstream>
#include <tuple>
#include <unordered_set>

#include "slam/common/timer.h"
#include "slam/features/orb_extractor.h"
#include "slam/features/stereo_matcher.h"
#include "slam/objects/dynamic_ba.h"
#include "slam/objects/joint_frames.h"
#include "slam/objects/masked_stereo.h"
#include "slam/objects/object_ba.h"
#include "slam/semantic/panoptic.h"
#include "slam/system/binary_io.h"
#include "slam/system/slam_system.h"

namespace twist {
namespace {

using geometry::SE3d;

// Masked stereo with the rig's disparity correction.
objects::MaskedStereoOptions MaskedStereoOptionsFrom(const SlamOptions& o) {
  objects::MaskedStereoOptions m;
  m.disparity_offset_px = o.disparity_offset_px;
  return m;
}

objects::ObjectTrackerOptions TrackerOptionsFrom(const SlamOptions& o,
                                                const ObjectStageOptions& stage) {
  objects::ObjectTrackerOptions t;
  t.num_threads = stage.tracker_threads;
  t.constrained = o.constrain_objects;
  t.masked_stereo_options = MaskedStereoOptionsFrom(o);
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

// The keypoints the object stage reads: `f` without the camera's extra
// keypoints (OrbExtractor::kExtraKeypoint, docs/objects.md §48), which are
// written to `*storage` when there are any.
const map::FrameFeatures& WithoutExtraKeypoints(const map::FrameFeatures& f,
                                                map::FrameFeatures* storage) {
  std::vector<int> keep;
  keep.reserve(f.keypoints.size());
  for (int i = 0; i < f.size(); ++i) {
    if (f.keypoints[i].class_id != features::OrbExtractor::kExtraKeypoint) keep.push_back(i);
  }
  if (static_cast<int>(keep.size()) == f.size()) return f;
  storage->descriptors.create(
      static_cast<int>(keep.size()), f.descriptors.cols, f.descriptors.type());
  for (size_t j = 0; j < keep.size(); ++j) {
    const int i = keep[j];
    storage->keypoints.push_back(f.keypoints[i]);
    f.descriptors.row(i).copyTo(storage->descriptors.row(static_cast<int>(j)));
    storage->u_right.push_back(f.u_right[i]);
    storage->depth.push_back(f.depth[i]);
    storage->labels.push_back(f.labels[i]);
    storage->is_static.push_back(f.is_static[i]);
  }
  storage->disparity_offset = f.disparity_offset;
  return *storage;
}

}  // namespace

ObjectStage::ObjectStage(const SessionConfig& config, const ObjectStageOptions& options)
    : config_(config),
      options_(options),
      associator_(semantic::ClusterAssociationOptions{}),
      tracker_(config.camera, TrackerOptionsFrom(config.options, options)),
      rng_(config.options.seed) {
  std::unordered_set<int> dynamic;
  for (const joints::ClassInfo& c : config_.classes.classes()) {
    if (c.is_dynamic) dynamic.insert(c.id);
    if (!c.is_dynamic && c.fit_plane) {
      planes_.emplace(
          c.id,
          PlaneState{semantic::ClusterPlane(PlaneOptionsFrom(options_)), {}, -1, {}, std::nullopt});
    }
  }
  associator_.set_dynamic_classes(std::move(dynamic));
}

cv::Mat ObjectStage::FavourMask(const cv::Mat& panoptic, const joints::ClassTable& classes) {
  if (panoptic.empty()) return cv::Mat();
  CHECK(panoptic.type() == CV_16UC1 || panoptic.type() == CV_32SC1)
      << "panoptic mask must be CV_16UC1 or CV_32SC1";
  // 200 on the pixels of dynamic classes, 1 elsewhere (and on void pixels).
  cv::Mat favour(panoptic.size(), CV_8UC1, cv::Scalar(1));
  semantic::ForEachLabelRun(panoptic, [&](int x_first, int x_last, int y, int64_t id) {
    if (!classes.IsDynamic(semantic::ClassOf(id))) return;
    uint8_t* out = favour.ptr<uint8_t>(y);
    std::fill(out + x_first, out + x_last + 1, uint8_t{200});
  });
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
    spec.parent_plane = parent->second.plane.reported_plane();
    if (!IsAxisJoint(spec.type) && parent->second.camera_plane) {
      spec.parent_plane = semantic::TransformPlane(world_from_camera.rotation(),
                                                   world_from_camera.translation(),
                                                   *parent->second.camera_plane);
    }
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
    const Eigen::Vector3d m = ps.plane.reported_plane().head<3>().normalized();
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

void ObjectStage::UpdateCameraPlane(int64_t frame_index,
                                    const SE3d& world_from_camera,
                                    PlaneState* ps) const {
  if (options_.camera_plane_frames <= 0) return;
  while (!ps->camera_points.empty() &&
         ps->camera_points.front().first <= frame_index - options_.camera_plane_frames) {
    ps->camera_points.pop_front();
  }
  if (!ps->plane.has_plane() ||
      static_cast<int>(ps->camera_points.size()) < kMinCameraPlanePoints) {
    ps->camera_plane.reset();
    return;
  }
  std::vector<semantic::StereoPlanePoint> points;
  points.reserve(ps->camera_points.size());
  for (const auto& [frame, p] : ps->camera_points) points.push_back(p);
  // The refinement is local (its Tukey weights keep the points near the
  // initial plane): from the last camera plane, else from the world fit as
  // this camera sees it.
  Eigen::Vector4d initial;
  if (ps->camera_plane) {
    initial = *ps->camera_plane;
  } else {
    const SE3d camera_from_world = world_from_camera.Inverse();
    initial = semantic::TransformPlane(
        camera_from_world.rotation(), camera_from_world.translation(), ps->plane.plane());
  }
  absl::StatusOr<Eigen::Vector4d> refined =
      semantic::RefinePlaneWeighted(points, initial, semantic::PlaneRefineOptions());
  ps->camera_plane.reset();
  if (refined.ok()) ps->camera_plane = *refined;
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
  map::FrameFeatures storage;
  const map::FrameFeatures& f = WithoutExtraKeypoints(*in.features, &storage);
  const int n = f.size();

  // Stereo keypoints in the world, and plane points per plane class.
  std::vector<std::optional<Eigen::Vector3d>> p_world(n);
  const bool masked_planes =
      options_.masked_plane_stereo && !in.right.empty() && !in.panoptic.empty();
  const objects::MaskedStereoOptions plane_stereo = MaskedStereoOptionsFrom(config_.options);
  std::map<int, cv::Mat> class_masks;  // plane class -> its mask, built on first use
  cv::Mat near_dynamic;  // within plane_dynamic_margin_px of a dynamic segment, on first use
  for (int i = 0; i < n; ++i) {
    if (f.u_right[i] < 0.0f) continue;
    auto p = cam.TriangulateStereo(
        f.keypoints[i].pt.x, f.keypoints[i].pt.y, f.u_right[i], options_.max_plane_depth_m);
    if (!p) continue;
    p_world[i] = world_from_camera * *p;
    const int cls = semantic::ClassOf(f.labels[i]);
    auto it = planes_.find(cls);
    if (it == planes_.end() || !f.is_static[i]) continue;
    if (options_.plane_dynamic_margin_px > 0 && !in.panoptic.empty()) {
      if (near_dynamic.empty()) {
        const int side = 2 * options_.plane_dynamic_margin_px + 1;
        cv::dilate(
            in.dynamic.empty() ? FavourMask(in.panoptic, config_.classes) >= 128 : in.dynamic,
            near_dynamic,
            cv::getStructuringElement(cv::MORPH_RECT, cv::Size(side, side)));
      }
      const int x = std::clamp(cvRound(f.keypoints[i].pt.x), 0, near_dynamic.cols - 1);
      const int y = std::clamp(cvRound(f.keypoints[i].pt.y), 0, near_dynamic.rows - 1);
      if (near_dynamic.at<uint8_t>(y, x) != 0) continue;
    }
    if (masked_planes) {
      auto mask = class_masks.find(cls);
      if (mask == class_masks.end())
        mask = class_masks.emplace(cls, semantic::ClassMask(in.panoptic, cls)).first;
      const Eigen::Vector2d uv(f.keypoints[i].pt.x, f.keypoints[i].pt.y);
      const std::optional<double> d = objects::MaskedDisparity(in.left,
                                                               in.right,
                                                               mask->second,
                                                               uv,
                                                               uv.x() - f.u_right[i],
                                                               options_.plane_stereo_half_px,
                                                               plane_stereo);
      if (!d || !(*d > 0.0)) continue;
      p = cam.TriangulateStereo(uv.x(), uv.y(), uv.x() - *d, options_.max_plane_depth_m);
      if (!p) continue;
    }
    const Eigen::Vector3d p_plane = world_from_camera * *p;
    // Depth noise z² σ_d s / (f b) along the ray, s = the level's scale.
    const double sigma_z = p->z() * p->z() * options_.plane_disparity_sigma_px *
                           std::pow(config_.options.scale_factor, f.keypoints[i].octave) /
                           (cam.fx * cam.baseline);
    semantic::StereoPlanePoint sp;
    sp.point = p_plane;
    sp.ray = world_from_camera.so3() * p->normalized();
    sp.sigma_along_m = sigma_z * p->norm() / p->z();
    it->second.points.push_back(sp);
    if (static_cast<int>(it->second.points.size()) > options_.max_plane_points) {
      it->second.points.pop_front();
    }
    if (options_.camera_plane_frames > 0) {
      semantic::StereoPlanePoint in_camera = sp;
      in_camera.point = *p;
      in_camera.ray = p->normalized();
      it->second.camera_points.emplace_back(in.frame_index, in_camera);
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
      d.mask = semantic::SegmentMask(in.panoptic, s.label, s.box);  // scans the box only
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
    if (ps.cluster_id >= 0) {
      const std::vector<semantic::StereoPlanePoint> pts(ps.points.begin(), ps.points.end());
      if (ps.plane.Update(pts, &rng_)) {
        ClusterEvent e;
        e.type = ClusterEventType::kPlaneUpdated;
        e.cluster_id = ps.cluster_id;
        e.class_id = cls;
        e.is_dynamic = false;
        e.plane = ps.plane.reported_plane();
        out.cluster_events.push_back(e);
      }
    }
    // Every class, so that the camera points of a class without a cluster
    // (and so without a plane) are dropped too.
    UpdateCameraPlane(in.frame_index, world_from_camera, &ps);
  }

  // Object tracking.
  objects::ObjectFrameInput of;
  of.frame_index = in.frame_index;
  of.timestamp_ns = in.timestamp_ns;
  of.camera_from_world = in.camera_from_world;
  of.left = in.left;
  of.right = in.right;
  of.flow = in.flow;
  of.keypoints.descriptors = f.descriptors;
  of.keypoints.uv.reserve(n);
  of.keypoints.u_right.reserve(n);
  // The stereo matcher's block on each keypoint's pyramid level, in level-0
  // pixels: the tracker trusts a depth only when the block lies on the object.
  of.keypoints.stereo_support_px.reserve(n);
  for (int i = 0; i < n; ++i) {
    of.keypoints.uv.emplace_back(f.keypoints[i].pt.x, f.keypoints[i].pt.y);
    of.keypoints.u_right.push_back(f.u_right[i]);
    of.keypoints.stereo_support_px.push_back(
        features::StereoBlockHalfPx(std::pow(config_.options.scale_factor, f.keypoints[i].octave)));
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
  const objects::ObjectBaOptions ba_options;
  const auto links =
      objects::AddTrackedObjectsToBa(tracker_, keyframe_of_frame, ba_options, &problem);
  if (links.empty()) return;
  objects::DynamicBaOptions ba;
  ba.max_iterations = options_.ba_iterations;
  ba.constrained = config_.options.constrain_objects;
  const auto summary = objects::SolveDynamicBa(&problem, ba);
  if (!summary.ok() || !summary->usable) return;
  objects::ApplyBaToTrackedObjects(problem, links, ba_options, &tracker_);
  for (ObjectResult& o : *results) {
    auto it = tracker_.objects().find(o.id);
    if (it != tracker_.objects().end()) o = objects::ObjectTracker::ToResult(it->second);
  }
}

}  // namespace twist

// ------------------------------------------------------------- persistence
namespace twist {
namespace {

using system_io::BinaryReader;
using system_io::BinaryWriter;

template <typename Derived>
void WriteVec(const Eigen::MatrixBase<Derived>& v, BinaryWriter* w) {
  for (Eigen::Index i = 0; i < v.size(); ++i) w->Pod<double>(v[i]);
}
template <typename Vec>
Vec ReadVec(BinaryReader* r) {
  Vec v;
  for (Eigen::Index i = 0; i < v.size(); ++i) v[i] = r->Pod<double>();
  return v;
}

// A plane point: position, viewing ray and noise along it (56 bytes).
void WritePlanePoint(const semantic::StereoPlanePoint& p, BinaryWriter* w) {
  WriteVec(p.point, w);
  WriteVec(p.ray, w);
  w->Pod(p.sigma_along_m);
}
// `with_noise` false: the position alone (formats before 7; noise unknown).
// False on non-finite values.
bool ReadPlanePoint(BinaryReader* r, bool with_noise, semantic::StereoPlanePoint* p) {
  p->point = ReadVec<Eigen::Vector3d>(r);
  if (with_noise) {
    p->ray = ReadVec<Eigen::Vector3d>(r);
    p->sigma_along_m = r->Pod<double>();
  }
  return p->point.allFinite() && p->ray.allFinite() && std::isfinite(p->sigma_along_m);
}

void WriteRect(const cv::Rect2d& b, BinaryWriter* w) {
  w->Pod(b.x);
  w->Pod(b.y);
  w->Pod(b.width);
  w->Pod(b.height);
}
cv::Rect2d ReadRect(BinaryReader* r) {
  cv::Rect2d b;
  b.x = r->Pod<double>();
  b.y = r->Pod<double>();
  b.width = r->Pod<double>();
  b.height = r->Pod<double>();
  return b;
}

void WriteJoint(const joints::Joint& j, BinaryWriter* w) {
  w->Pod<int32_t>(static_cast<int32_t>(j.type()));
  w->Pod(j.pitch());
  w->Pose(j.world_from_joint());
}
joints::Joint ReadJoint(BinaryReader* r) {
  const int32_t type = r->Pod<int32_t>();
  const double pitch = r->Pod<double>();
  const SE3d pose = r->Pose();
  if (!r->ok() || type < 0 || type >= joints::kNumJointTypes || !std::isfinite(pitch)) {
    r->Fail();
    return joints::Joint();
  }
  return joints::Joint(static_cast<joints::JointType>(type), pose, pitch);
}

void WriteObservations(const std::vector<objects::ObjectPointObservation>& obs, BinaryWriter* w) {
  w->Pod<uint64_t>(obs.size());
  for (const auto& o : obs) {
    w->Pod(o.point_id);
    WriteVec(o.uv, w);
    w->Pod(o.u_right);
    w->Pod(o.disparity_noise_ratio);
  }
}
std::vector<objects::ObjectPointObservation> ReadObservations(BinaryReader* r, uint32_t version) {
  std::vector<objects::ObjectPointObservation> obs(r->Count(version >= 11 ? 40 : 32));
  for (auto& o : obs) {
    o.point_id = r->Pod<int64_t>();
    o.uv = ReadVec<Eigen::Vector2d>(r);
    o.u_right = r->Pod<double>();
    if (version >= 11) o.disparity_noise_ratio = r->Pod<double>();
    if (!std::isfinite(o.disparity_noise_ratio) || o.disparity_noise_ratio < 0.0) r->Fail();
  }
  return obs;
}

template <typename Enum>
Enum ReadEnum(BinaryReader* r, int32_t max_value) {
  const int32_t v = r->Pod<int32_t>();
  if (v < 0 || v > max_value) {
    r->Fail();
    return static_cast<Enum>(0);
  }
  return static_cast<Enum>(v);
}

template <typename Container>
void WriteTimedPoses(const Container& poses, BinaryWriter* w) {
  w->Pod<uint64_t>(poses.size());
  for (const objects::TimedObjectPose& p : poses) {
    w->Pod(p.frame_index);
    w->Pod(p.timestamp_ns);
    w->Pose(p.world_from_object);
  }
}
std::vector<objects::TimedObjectPose> ReadTimedPoses(BinaryReader* r) {
  std::vector<objects::TimedObjectPose> poses(r->Count(72));
  for (objects::TimedObjectPose& p : poses) {
    p.frame_index = r->Pod<int64_t>();
    p.timestamp_ns = r->Pod<int64_t>();
    p.world_from_object = r->Pose();
  }
  return poses;
}

void WriteTrackedObject(const objects::TrackedObject& o, BinaryWriter* w) {
  w->Pod(o.id);
  w->Pod(o.cluster_id);
  w->Pod<int32_t>(o.class_id);
  w->Pod<int32_t>(o.instance_id);
  w->Pod<int32_t>(static_cast<int32_t>(o.state));
  WriteJoint(o.joint, w);
  w->Pose(o.world_from_object);
  WriteVec(o.twist_step, w);
  w->Pod(o.step_seconds);
  w->Pod<uint64_t>(o.points.size());
  for (const objects::ObjectPoint& p : o.points) {
    w->Pod(p.id);
    WriteVec(p.point_in_object, w);
    w->Mat(p.descriptor);
    w->Mat(p.patch);
    WriteVec(p.last_uv, w);
    w->Pod<uint8_t>(p.seen_last_frame);
    w->Pod<int32_t>(p.num_observations);
    WriteVec(p.sigma_in_object, w);       // format 8
    WriteVec(p.patch_view_in_object, w);  // format 13
  }
  w->Pod<int32_t>(o.frames_lost);
  w->Pod(o.last_seen_frame);
  WriteRect(o.last_box, w);
  w->Pod<uint64_t>(o.history.size());
  for (const objects::ObjectPoseSample& s : o.history) {
    w->Pod(s.frame_index);
    w->Pod(s.timestamp_ns);
    w->Pose(s.world_from_object);
    WriteVec(s.twist_step, w);
    WriteObservations(s.observations, w);
    w->Pod<uint8_t>(s.held);  // format 6
  }
  w->Pod(o.next_point_id);
  WriteObservations(o.pending_observations, w);
  w->Pod<int32_t>(o.insignificant_steps);
  w->Pod<uint8_t>(o.stationary);
  w->Pod<int32_t>(o.last_num_inliers);
  w->Pod(o.last_sigma_px);
  w->Pod<uint8_t>(o.twist_covariance_valid);  // format 5
  for (int i = 0; i < 36; ++i) w->Pod<double>(o.twist_covariance.data()[i]);
  WriteTimedPoses(o.settled_poses, w);  // format 6
}

objects::TrackedObject ReadTrackedObject(BinaryReader* r, uint32_t version) {
  objects::TrackedObject o;
  o.id = r->Pod<int64_t>();
  o.cluster_id = r->Pod<int64_t>();
  o.class_id = r->Pod<int32_t>();
  o.instance_id = r->Pod<int32_t>();
  o.state = ReadEnum<ObjectState>(r, static_cast<int32_t>(ObjectState::kLost));
  o.joint = ReadJoint(r);
  o.world_from_object = r->Pose();
  o.twist_step = ReadVec<geometry::Vector6d>(r);
  o.step_seconds = r->Pod<double>();
  // The smallest point (empty images).
  const uint64_t np = r->Count(version >= 13 ? 125 : version >= 8 ? 101 : 77);
  o.points.reserve(np);
  for (uint64_t k = 0; k < np && r->ok(); ++k) {
    objects::ObjectPoint p;
    p.id = r->Pod<int64_t>();
    p.point_in_object = ReadVec<Eigen::Vector3d>(r);
    p.descriptor = r->Mat();
    p.patch = r->Mat();
    p.last_uv = ReadVec<Eigen::Vector2d>(r);
    p.seen_last_frame = r->Pod<uint8_t>() != 0;
    p.num_observations = r->Pod<int32_t>();
    // Before format 8 the points' own noise was not kept: they count as exact.
    if (version >= 8) p.sigma_in_object = ReadVec<Eigen::Vector3d>(r);
    // Before format 13 the view of a point's patch was not kept: with
    // patch_refresh_view_change_deg on, the patch is taken again at its next
    // match.
    if (version >= 13) p.patch_view_in_object = ReadVec<Eigen::Vector3d>(r);
    o.points.push_back(std::move(p));
  }
  o.frames_lost = r->Pod<int32_t>();
  o.last_seen_frame = r->Pod<int64_t>();
  o.last_box = ReadRect(r);
  const uint64_t nh = r->Count(128);
  for (uint64_t k = 0; k < nh && r->ok(); ++k) {
    objects::ObjectPoseSample s;
    s.frame_index = r->Pod<int64_t>();
    s.timestamp_ns = r->Pod<int64_t>();
    s.world_from_object = r->Pose();
    s.twist_step = ReadVec<geometry::Vector6d>(r);
    s.observations = ReadObservations(r, version);
    if (version >= 6) s.held = r->Pod<uint8_t>() != 0;
    o.history.push_back(std::move(s));
  }
  o.next_point_id = r->Pod<int64_t>();
  o.pending_observations = ReadObservations(r, version);
  o.insignificant_steps = r->Pod<int32_t>();
  o.stationary = r->Pod<uint8_t>() != 0;
  o.last_num_inliers = r->Pod<int32_t>();
  o.last_sigma_px = r->Pod<double>();
  if (version >= 5) {
    o.twist_covariance_valid = r->Pod<uint8_t>() != 0;
    for (int i = 0; i < 36; ++i) o.twist_covariance.data()[i] = r->Pod<double>();
    if (!o.twist_covariance.allFinite()) r->Fail();
  }
  if (version >= 6) {
    const std::vector<objects::TimedObjectPose> settled = ReadTimedPoses(r);
    o.settled_poses.assign(settled.begin(), settled.end());
  }
  return o;
}

// Full-image CV_8UC1 masks are mostly zero: only the bounding box of their
// non-zero pixels is stored (the rest is restored as zeros, bit-exactly).
void WriteMask(const cv::Mat& m, BinaryWriter* w) {
  const bool compact = !m.empty() && m.type() == CV_8UC1;
  w->Pod<uint8_t>(compact);
  if (!compact) {
    w->Mat(m);
    return;
  }
  const cv::Rect roi = cv::boundingRect(m);
  w->Pod<int32_t>(m.rows);
  w->Pod<int32_t>(m.cols);
  w->Pod<int32_t>(roi.x);
  w->Pod<int32_t>(roi.y);
  w->Mat(m(roi));
}
cv::Mat ReadMask(BinaryReader* r, const cv::Size& image_size) {
  if (r->Pod<uint8_t>() == 0) return r->Mat();
  const int rows = r->Pod<int32_t>();
  const int cols = r->Pod<int32_t>();
  const int x = r->Pod<int32_t>();
  const int y = r->Pod<int32_t>();
  const cv::Mat crop = r->Mat();
  // Only image-sized masks are valid (checked by the caller); refuse other
  // sizes before allocating.
  if (!r->ok() || rows != image_size.height || cols != image_size.width || x < 0 || y < 0 ||
      (!crop.empty() && crop.type() != CV_8UC1) || crop.cols > cols - x || crop.rows > rows - y) {
    r->Fail();
    return cv::Mat();
  }
  cv::Mat m(rows, cols, CV_8UC1, cv::Scalar(0));
  if (!crop.empty()) crop.copyTo(m(cv::Rect(x, y, crop.cols, crop.rows)));
  return m;
}

void WriteCluster(const semantic::ClusterTrack& c, BinaryWriter* w) {
  w->Pod(c.id);
  w->Pod<int32_t>(c.class_id);
  w->Pod<int32_t>(c.instance_id);
  w->Pod<uint8_t>(c.is_stuff);
  w->Pod<int32_t>(static_cast<int32_t>(c.state));
  WriteRect(c.last_box, w);
  WriteMask(c.last_mask, w);
  w->Pod<uint8_t>(c.predicted_box.has_value());
  WriteRect(c.predicted_box.value_or(cv::Rect2d()), w);
  WriteMask(c.predicted_mask, w);
  std::vector<int64_t> ids(c.point_ids.begin(), c.point_ids.end());
  std::sort(ids.begin(), ids.end());
  w->PodVector(ids);
  w->Pod<int32_t>(c.frames_since_seen);
  w->Pod<int32_t>(c.num_frames_seen);
}

semantic::ClusterTrack ReadCluster(BinaryReader* r, const cv::Size& image_size) {
  semantic::ClusterTrack c;
  c.id = r->Pod<int64_t>();
  c.class_id = r->Pod<int32_t>();
  c.instance_id = r->Pod<int32_t>();
  c.is_stuff = r->Pod<uint8_t>() != 0;
  c.state =
      ReadEnum<semantic::ClusterState>(r, static_cast<int32_t>(semantic::ClusterState::kLost));
  c.last_box = ReadRect(r);
  c.last_mask = ReadMask(r, image_size);
  const bool has_prediction = r->Pod<uint8_t>() != 0;
  const cv::Rect2d predicted = ReadRect(r);
  if (has_prediction) c.predicted_box = predicted;
  c.predicted_mask = ReadMask(r, image_size);
  const std::vector<int64_t> ids = r->PodVector<int64_t>();
  c.point_ids.insert(ids.begin(), ids.end());
  c.frames_since_seen = r->Pod<int32_t>();
  c.num_frames_seen = r->Pod<int32_t>();
  return c;
}

}  // namespace

void ObjectStage::Write(BinaryWriter* w) const {
  // Clusters.
  w->Pod<uint64_t>(associator_.clusters().size());
  for (const auto& [id, c] : associator_.clusters()) WriteCluster(c, w);
  w->Pod(associator_.next_id());
  // Planes (one per plane class of the configuration).
  w->Pod<uint64_t>(planes_.size());
  for (const auto& [cls, ps] : planes_) {
    w->Pod<int32_t>(cls);
    w->Pod<uint8_t>(ps.plane.has_plane());
    WriteVec(ps.plane.plane(), w);
    WriteVec(ps.plane.reported_plane(), w);  // format 7
    w->Pod<int32_t>(ps.plane.num_points_at_fit());
    w->Pod<int32_t>(ps.plane.num_inliers());
    w->Pod<uint64_t>(ps.points.size());
    for (const semantic::StereoPlanePoint& p : ps.points) WritePlanePoint(p, w);  // ray: format 7
    w->Pod(ps.cluster_id);
    w->Pod<uint64_t>(ps.camera_points.size());  // format 12
    for (const auto& [frame, p] : ps.camera_points) {
      w->Pod(frame);
      WritePlanePoint(p, w);
    }
    w->Pod<uint8_t>(ps.camera_plane.has_value());
    WriteVec(ps.camera_plane.value_or(Eigen::Vector4d::Zero()), w);
  }
  // Tracked objects.
  const objects::ObjectTracker::State ts = tracker_.GetState();
  w->Pod<uint64_t>(ts.objects.size());
  for (const auto& [id, o] : ts.objects) WriteTrackedObject(o, w);
  w->Pod(ts.next_object_id);
  w->Mat(ts.prev_left);
  w->Pod(ts.prev_timestamp_ns);
  w->Pod<uint8_t>(ts.has_prev);
  w->Pod<int32_t>(ts.stats.tracked);
  w->Pod<int32_t>(ts.stats.created);
  w->Pod<int32_t>(ts.stats.reidentified);
  w->Pod<int32_t>(ts.stats.lost);
  w->Pod<int32_t>(ts.stats.removed);
  w->Pod<uint64_t>(ts.removed_trajectories.size());  // format 6
  for (const objects::ObjectTrajectory& t : ts.removed_trajectories) {
    w->Pod(t.object_id);
    w->Pod<int32_t>(t.class_id);
    w->Pod<int32_t>(t.instance_id);
    w->Pod(t.cluster_id);
    WriteTimedPoses(t.poses, w);
  }
  // Axis joints, the RANSAC generator, the BA window.
  w->Pod<uint64_t>(axis_joints_.size());
  for (const auto& [cluster, joint] : axis_joints_) {
    w->Pod(cluster);
    WriteJoint(joint, w);
  }
  std::ostringstream rng;
  rng << rng_;
  w->String(rng.str());
  w->Pod<uint64_t>(window_.size());
  for (const auto& [index, ts_ns, pose] : window_) {
    w->Pod(index);
    w->Pod(ts_ns);
    w->Pose(pose);
  }
  // The tracker's previous camera pose (format 16).
  w->Pod<uint8_t>(ts.prev_camera_from_world.has_value());
  if (ts.prev_camera_from_world) w->Pose(*ts.prev_camera_from_world);
}

absl::Status ObjectStage::Read(BinaryReader* r, uint32_t version) {
  auto corrupt = [](const std::string& what) {
    return absl::DataLossError("state file has corrupt object state: " + what);
  };
  const cv::Size image_size(config_.camera.width, config_.camera.height);
  std::map<int64_t, semantic::ClusterTrack> clusters;
  const uint64_t nc = r->Count(100);
  for (uint64_t k = 0; k < nc && r->ok(); ++k) {
    semantic::ClusterTrack c = ReadCluster(r, image_size);
    if (!r->ok() || !clusters.emplace(c.id, std::move(c)).second) return corrupt("clusters");
  }
  auto bad_mask = [&](const cv::Mat& m) {
    return !m.empty() && (m.type() != CV_8UC1 || m.size() != image_size);
  };
  for (const auto& [id, c] : clusters) {
    if (bad_mask(c.last_mask) || bad_mask(c.predicted_mask)) return corrupt("cluster mask");
  }
  const int64_t next_cluster_id = r->Pod<int64_t>();
  if (!r->ok() || (!clusters.empty() && next_cluster_id <= clusters.rbegin()->first)) {
    return corrupt("clusters");
  }

  std::map<int, PlaneState> planes = planes_;
  const uint64_t npl = r->Count(30);
  if (!r->ok() || npl != planes.size()) return corrupt("planes (configuration mismatch)");
  for (uint64_t k = 0; k < npl && r->ok(); ++k) {
    auto it = planes.find(r->Pod<int32_t>());
    if (it == planes.end()) return corrupt("plane class not in the configuration");
    const bool has_plane = r->Pod<uint8_t>() != 0;
    const Eigen::Vector4d plane = ReadVec<Eigen::Vector4d>(r);
    const Eigen::Vector4d reported = version >= 7 ? ReadVec<Eigen::Vector4d>(r) : plane;
    const int at_fit = r->Pod<int32_t>();
    const int inliers = r->Pod<int32_t>();
    if (!reported.allFinite() || (has_plane && reported.head<3>().norm() < 1e-9)) {
      return corrupt("plane");
    }
    it->second.plane.RestoreState(has_plane, plane, reported, at_fit, inliers);
    const uint64_t np = r->Count(version >= 7 ? 56 : 24);
    it->second.points.clear();
    for (uint64_t i = 0; i < np && r->ok(); ++i) {
      semantic::StereoPlanePoint p;
      if (!ReadPlanePoint(r, version >= 7, &p)) return corrupt("plane point");
      it->second.points.push_back(p);
    }
    it->second.cluster_id = r->Pod<int64_t>();
    if (!r->ok() || !plane.allFinite() || (has_plane && plane.head<3>().norm() < 1e-9)) {
      return corrupt("plane");
    }
    it->second.camera_points.clear();
    it->second.camera_plane.reset();
    if (version >= 12) {  // before: no camera points (the plane is refitted on new ones)
      const uint64_t nc = r->Count(64);
      for (uint64_t i = 0; i < nc && r->ok(); ++i) {
        const int64_t frame = r->Pod<int64_t>();
        semantic::StereoPlanePoint p;
        if (!ReadPlanePoint(r, true, &p)) return corrupt("camera plane point");
        it->second.camera_points.emplace_back(frame, p);
      }
      const bool has_camera_plane = r->Pod<uint8_t>() != 0;
      const Eigen::Vector4d camera_plane = ReadVec<Eigen::Vector4d>(r);
      if (!r->ok() || !camera_plane.allFinite() ||
          (has_camera_plane && camera_plane.head<3>().norm() < 1e-9)) {
        return corrupt("camera plane");
      }
      if (has_camera_plane) it->second.camera_plane = camera_plane;
    }
  }

  objects::ObjectTracker::State ts;
  const uint64_t no = r->Count(200);
  for (uint64_t k = 0; k < no && r->ok(); ++k) {
    objects::TrackedObject o = ReadTrackedObject(r, version);
    if (!r->ok() || !ts.objects.emplace(o.id, std::move(o)).second) return corrupt("objects");
  }
  ts.next_object_id = r->Pod<int64_t>();
  ts.prev_left = r->Mat();
  ts.prev_timestamp_ns = r->Pod<int64_t>();
  ts.has_prev = r->Pod<uint8_t>() != 0;
  ts.stats.tracked = r->Pod<int32_t>();
  ts.stats.created = r->Pod<int32_t>();
  ts.stats.reidentified = r->Pod<int32_t>();
  ts.stats.lost = r->Pod<int32_t>();
  ts.stats.removed = r->Pod<int32_t>();
  if (version >= 6) {
    const uint64_t nt = r->Count(32);
    for (uint64_t k = 0; k < nt && r->ok(); ++k) {
      objects::ObjectTrajectory t;
      t.object_id = r->Pod<int64_t>();
      t.class_id = r->Pod<int32_t>();
      t.instance_id = r->Pod<int32_t>();
      t.cluster_id = r->Pod<int64_t>();
      t.poses = ReadTimedPoses(r);
      ts.removed_trajectories.push_back(std::move(t));
    }
  }
  if (!r->ok() || (!ts.objects.empty() && ts.next_object_id <= ts.objects.rbegin()->first)) {
    return corrupt("objects");
  }
  if (!ts.prev_left.empty() &&
      (ts.prev_left.type() != CV_8UC1 || ts.prev_left.cols != config_.camera.width ||
       ts.prev_left.rows != config_.camera.height)) {
    return corrupt("previous image");
  }
  const int patch_side = 2 * objects::ObjectTrackerOptions().search.patch_half_size + 1;
  for (const auto& [id, o] : ts.objects) {
    if (!o.twist_step.allFinite() || !std::isfinite(o.step_seconds) ||
        !std::isfinite(o.last_sigma_px)) {
      return corrupt("object twist");
    }
    for (const objects::ObjectPoseSample& h : o.history) {
      if (!h.twist_step.allFinite()) return corrupt("object history");
    }
    for (const objects::ObjectPoint& p : o.points) {
      if (!p.point_in_object.allFinite() || !p.sigma_in_object.allFinite() ||
          !p.patch_view_in_object.allFinite() || !p.last_uv.allFinite())
        return corrupt("object point");
      // ORB descriptors (32 bytes) and square patches of the tracker's size.
      if (!p.descriptor.empty() &&
          (p.descriptor.type() != CV_8UC1 || p.descriptor.rows != 1 || p.descriptor.cols != 32)) {
        return corrupt("point descriptor");
      }
      if (!p.patch.empty() && (p.patch.type() != CV_32FC1 || p.patch.rows != patch_side ||
                               p.patch.cols != patch_side)) {
        return corrupt("point patch");
      }
    }
  }

  std::map<int64_t, joints::Joint> axis_joints;
  const uint64_t nj = r->Count(68);
  for (uint64_t k = 0; k < nj && r->ok(); ++k) {
    const int64_t cluster = r->Pod<int64_t>();
    axis_joints[cluster] = ReadJoint(r);
  }
  std::mt19937_64 rng;
  {
    std::istringstream in(r->String());
    in >> rng;
    if (!r->ok() || in.fail()) return corrupt("random generator");
  }
  std::deque<std::tuple<int64_t, int64_t, SE3d>> window;
  const uint64_t nw = r->Count(72);
  for (uint64_t k = 0; k < nw && r->ok(); ++k) {
    const int64_t index = r->Pod<int64_t>();
    const int64_t ts_ns = r->Pod<int64_t>();
    window.emplace_back(index, ts_ns, r->Pose());
  }
  if (!r->ok()) return corrupt("axis joints or BA window");
  // Before format 16 the tracker's previous camera pose was not kept: its
  // next frame takes the current one's (ObjectTracker::State).
  if (version >= 16 && r->Pod<uint8_t>() != 0) ts.prev_camera_from_world = r->Pose();
  if (!r->ok()) return corrupt("previous camera pose");

  associator_.RestoreState(std::move(clusters), next_cluster_id);
  planes_ = std::move(planes);
  tracker_.SetState(std::move(ts));
  axis_joints_ = std::move(axis_joints);
  rng_ = rng;
  window_ = std::move(window);
  return absl::OkStatus();
}

void ObjectStage::AddToSnapshot(MapSnapshot* snapshot) const {
  std::map<int64_t, const PlaneState*> plane_of_cluster;
  for (const auto& [cls, ps] : planes_) {
    if (ps.cluster_id >= 0) plane_of_cluster[ps.cluster_id] = &ps;
  }
  std::map<int64_t, const objects::TrackedObject*> object_of_cluster;
  for (const auto& [id, o] : tracker_.objects()) {
    if (o.cluster_id != objects::kNoCluster) object_of_cluster[o.cluster_id] = &o;
  }
  for (const auto& [id, c] : associator_.clusters()) {
    MapSnapshot::Cluster out;
    out.id = id;
    out.class_id = c.class_id;
    out.instance_id = c.instance_id;
    out.is_dynamic = config_.classes.IsDynamic(c.class_id);
    if (auto p = plane_of_cluster.find(id);
        p != plane_of_cluster.end() && p->second->plane.has_plane()) {
      out.plane = p->second->plane.reported_plane();
    }
    if (auto o = object_of_cluster.find(id); o != object_of_cluster.end()) {
      out.trajectory.reserve(o->second->history.size());
      for (const objects::ObjectPoseSample& s : o->second->history) {
        out.trajectory.emplace_back(s.timestamp_ns, s.world_from_object);
      }
    }
    snapshot->clusters.push_back(std::move(out));
  }
  for (const objects::ObjectTrajectory& t : tracker_.Trajectories()) {
    MapSnapshot::Object out;
    out.id = t.object_id;
    out.class_id = t.class_id;
    out.instance_id = t.instance_id;
    out.cluster_id = t.cluster_id;
    out.trajectory.reserve(t.poses.size());
    for (const objects::TimedObjectPose& p : t.poses) {
      out.trajectory.emplace_back(p.timestamp_ns, p.world_from_object);
    }
    snapshot->objects.push_back(std::move(out));
  }
  for (MapSnapshot::Point& p : snapshot->points) {
    if (auto it = planes_.find(p.class_id); it != planes_.end() && it->second.cluster_id >= 0) {
      p.cluster_id = it->second.cluster_id;
    }
  }
}

}  // namespace twist
