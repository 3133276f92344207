#include "slam/objects/object_ba.h"

#include <glog/logging.h>

#include <algorithm>
#include <cmath>
#include <unordered_map>

#include "slam/joints/joint.h"

namespace twist::objects {

using geometry::SE3d;

namespace {

// Square root of the information that `observations` stereo observations
// from `object_from_camera`'s view give a point: across the ray the position
// noise (z σ / f), along it the disparity's (z² σ_d / (f b)); symmetric, in
// the object frame.
Eigen::Matrix3d InheritedPointSqrtInformation(const geometry::StereoCamera& camera,
                                              const SE3d& object_from_camera,
                                              const Eigen::Vector3d& point_in_object,
                                              int observations,
                                              const ObjectBaOptions& options) {
  const Eigen::Vector3d p_cam = object_from_camera.Inverse() * point_in_object;
  const double z = std::max(p_cam.z(), 0.5);  // a point behind that camera: as at 0.5 m
  const double across = z * options.inherited_point_sigma_px / camera.fx;
  const double along = z * z * options.inherited_point_disparity_sigma_px / camera.bf();
  const Eigen::Vector3d ray = object_from_camera.rotation() * p_cam.normalized();
  const Eigen::Matrix3d along_ray = ray * ray.transpose();
  return std::sqrt(static_cast<double>(observations)) *
         ((Eigen::Matrix3d::Identity() - along_ray) / across + along_ray / along);
}

}  // namespace

std::vector<ObjectBaLink> AddTrackedObjectsToBa(const ObjectTracker& tracker,
                                                const std::map<int64_t, int>& keyframe_of_frame,
                                                const ObjectBaOptions& options,
                                                DynamicBaProblem* problem) {
  CHECK(problem != nullptr);
  std::vector<ObjectBaLink> links;
  for (const auto& [id, object] : tracker.objects()) {
    // A lost object has no new observations: solving its window again under
    // a gauge that slides along its history only drifts its tail (on the
    // rendered scenes the last poses of lost cars ran off by metres).
    if (object.state == ObjectState::kLost) continue;
    std::vector<const ObjectPoseSample*> samples;
    const ObjectPoseSample* before_window = nullptr;  // the sample just before the first
    for (const ObjectPoseSample& s : object.history) {
      if (keyframe_of_frame.count(s.frame_index) > 0) {
        samples.push_back(&s);
      } else if (samples.empty()) {
        before_window = &s;
      }
    }
    if (static_cast<int>(samples.size()) < options.min_frames) continue;
    // The window slid along a continuous track: its first two frames were
    // refined in earlier windows, and fixing both keeps the velocity there.
    const bool slid = options.keep_velocity_at_gauge && before_window != nullptr &&
                      before_window->frame_index + 1 == samples[0]->frame_index;
    // Points observed often enough within the window.
    std::unordered_map<int64_t, int> count;
    for (const ObjectPoseSample* s : samples) {
      for (const ObjectPointObservation& o : s->observations) ++count[o.point_id];
    }
    std::unordered_map<int64_t, int> index_of_point;
    BaObject ba;
    ba.id = id;
    ba.world_projector = object.joint.WorldProjector();
    if (options.soft_normal_step_sigma_m > 0.0 &&
        object.joint.type() == joints::JointType::kPlanar) {
      // Π of the plane plus translation along its normal: the joint frame's
      // z, which a prismatic joint in the same frame allows.
      ba.world_projector +=
          joints::Joint(joints::JointType::kPrismatic, object.joint.world_from_joint())
              .WorldProjector();
      ba.soft_normal = object.joint.world_from_joint().rotation().col(2);
      ba.soft_normal_step_sigma_m = options.soft_normal_step_sigma_m;
    }
    ObjectBaLink link;
    link.object_id = id;
    // The window's oldest frame: the view the inherited points' priors take
    // their shape from.
    const SE3d gauge_object_from_camera =
        (problem->keyframes[static_cast<size_t>(keyframe_of_frame.at(samples[0]->frame_index))]
             .camera_from_world *
         samples[0]->world_from_object)
            .Inverse();
    for (const ObjectPoint& p : object.points) {
      auto it = count.find(p.id);
      if (it == count.end() || it->second < options.min_observations_per_point) continue;
      index_of_point[p.id] = static_cast<int>(ba.points_in_object.size());
      ba.points_in_object.push_back(p.point_in_object);
      const int before = p.num_observations - it->second;  // observations before the window
      ba.fixed_points.push_back(options.hold_points_seen_before_window > 0 &&
                                before >= options.hold_points_seen_before_window);
      ba.point_prior_sqrt_information.push_back(
          options.inherited_point_prior && before > 0
              ? InheritedPointSqrtInformation(
                    problem->camera, gauge_object_from_camera, p.point_in_object, before, options)
              : Eigen::Matrix3d::Zero());
      link.point_ids.push_back(p.id);
    }
    if (ba.points_in_object.empty()) continue;
    for (size_t k = 0; k < samples.size(); ++k) {
      const ObjectPoseSample* s = samples[k];
      BaObjectFrame f;
      f.keyframe = keyframe_of_frame.at(s->frame_index);
      f.world_from_object = s->world_from_object;
      // The first frame fixes the gauge of the points. A frame in which the
      // tracker held the object stationary repeats the previous pose: both
      // stay as they are, so that the refined trajectory does not move a
      // parked car.
      const bool held_next = k + 1 < samples.size() && samples[k + 1]->held &&
                             samples[k + 1]->frame_index == s->frame_index + 1;
      // After a gap (the object was lost) the poses start again from the
      // re-acquired or continued one, which is kept: no constant-velocity
      // term spans the gap, and a continued object (new points only) would
      // otherwise have no gauge there.
      f.follows_previous = k == 0 || s->frame_index == samples[k - 1]->frame_index + 1;
      f.fixed =
          k == 0 || (k == 1 && slid && f.follows_previous) || s->held || held_next ||
          !f.follows_previous ||
          (options.fix_coasted_newest_frame && k + 1 == samples.size() && s->observations.empty());
      ba.frames.push_back(f);
      link.frame_indices.push_back(s->frame_index);
      for (const ObjectPointObservation& o : s->observations) {
        auto it = index_of_point.find(o.point_id);
        if (it == index_of_point.end()) continue;
        BaObservation obs;
        obs.keyframe = f.keyframe;
        obs.point = it->second;
        obs.uv = o.uv;
        obs.u_right = o.u_right;
        obs.disparity_noise_ratio = o.disparity_noise_ratio;
        obs.sigma_px = options.sigma_px;
        ba.observations.push_back(obs);
      }
    }
    link.problem_object = static_cast<int>(problem->objects.size());
    problem->objects.push_back(std::move(ba));
    links.push_back(std::move(link));
  }
  return links;
}

void ApplyBaToTrackedObjects(const DynamicBaProblem& problem,
                             const std::vector<ObjectBaLink>& links,
                             const ObjectBaOptions& options,
                             ObjectTracker* tracker) {
  CHECK(tracker != nullptr);
  for (const ObjectBaLink& link : links) {
    TrackedObject* o = tracker->mutable_object(link.object_id);
    if (o == nullptr) continue;
    const BaObject& ba = problem.objects[static_cast<size_t>(link.problem_object)];
    std::unordered_map<int64_t, const SE3d*> pose_of_frame;
    for (size_t f = 0; f < ba.frames.size(); ++f) {
      pose_of_frame[link.frame_indices[f]] = &ba.frames[f].world_from_object;
    }
    for (ObjectPoseSample& s : o->history) {
      auto it = pose_of_frame.find(s.frame_index);
      if (it != pose_of_frame.end()) s.world_from_object = *it->second;
    }
    std::unordered_map<int64_t, size_t> point_index;
    for (size_t j = 0; j < link.point_ids.size(); ++j) point_index[link.point_ids[j]] = j;
    for (ObjectPoint& p : o->points) {
      auto it = point_index.find(p.id);
      if (it != point_index.end()) p.point_in_object = ba.points_in_object[it->second];
    }
    if (!o->history.empty() && pose_of_frame.count(o->history.back().frame_index) > 0 &&
        o->state != ObjectState::kLost) {
      o->world_from_object = o->history.back().world_from_object;
      // The mean step over the last twist_steps frames when they are all in
      // the window, else over fewer.
      for (int k = std::max(1, options.twist_steps); k >= 1; --k) {
        if (static_cast<int>(o->history.size()) <= k) continue;
        const ObjectPoseSample& first = o->history[o->history.size() - 1 - static_cast<size_t>(k)];
        if (pose_of_frame.count(first.frame_index) == 0 ||
            o->history.back().frame_index != first.frame_index + k)
          continue;
        o->twist_step = o->joint.WorldProjector() *
                        (o->world_from_object * first.world_from_object.Inverse()).Log() / k;
        o->history.back().twist_step = o->twist_step;
        break;
      }
    }
  }
}

}  // namespace twist::objects
