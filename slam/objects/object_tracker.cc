#include "slam/objects/object_tracker.h"

#include <glog/logging.h>

#include <Eigen/Geometry>
#include <algorithm>
#include <atomic>
#include <cmath>
#include <functional>
#include <iterator>
#include <optional>
#include <string>
#include <thread>
#include <unordered_map>
#include <unordered_set>

namespace twist::objects {

using geometry::Matrix6d;
using geometry::SE3d;
using geometry::Vector6d;

namespace {

// How far the object's origin moves in the world-frame step `twist`:
// v + ω × t, t its position.
double OriginStepLength(const TrackedObject& o, const Vector6d& twist) {
  return (twist.head<3>() + twist.tail<3>().cross(o.world_from_object.translation())).norm();
}

// Frames in a row, up to the last one, in which the object coasted (a
// refused step: no observation kept).
int CoastedFrames(const TrackedObject& o) {
  int coasted = 0;
  for (auto it = o.history.rbegin(); it != o.history.rend() && it->observations.empty(); ++it)
    ++coasted;
  return coasted;
}

// Whether `pred(sample, before)` holds for one of the object's last `poses`
// pose samples (looks at those only: the history holds up to max_history);
// `before` is the sample recorded before it, or nullptr for the oldest.
template <typename Pred>
bool AnyOfLastPoses(const TrackedObject& o, int poses, Pred&& pred) {
  int k = 0;
  for (auto it = o.history.rbegin(); it != o.history.rend() && k < poses; ++it, ++k) {
    const auto before = std::next(it);
    if (pred(*it, before == o.history.rend() ? nullptr : &*before)) return true;
  }
  return false;
}

// Whether the tracker held the object stationary in one of its last `poses`
// poses.
bool HeldWithin(const TrackedObject& o, int poses) {
  return AnyOfLastPoses(
      o, poses, [](const ObjectPoseSample& s, const ObjectPoseSample*) { return s.held; });
}

// Whether the object went unseen within its last `poses` poses: one of them
// coasted (no observation kept, the object not held stationary), or a frame
// is missing between two of them (it was lost and reacquired).
bool UnseenWithin(const TrackedObject& o, int poses) {
  return AnyOfLastPoses(o, poses, [](const ObjectPoseSample& s, const ObjectPoseSample* before) {
    return (s.observations.empty() && !s.held) ||
           (before != nullptr && s.frame_index - before->frame_index > 1);
  });
}

// Buckets keypoints on a coarse grid for radius look-ups.
class KeypointGrid {
 public:
  KeypointGrid(const FrameKeypoints& kps, double cell) : kps_(kps), cell_(cell) {
    for (size_t k = 0; k < kps.uv.size(); ++k)
      cells_[Key(kps.uv[k])].push_back(static_cast<int>(k));
  }
  // Nearest keypoint within radius satisfying pred, or -1.
  template <typename Pred>
  int Nearest(const Eigen::Vector2d& uv, double radius, Pred&& pred) const {
    const int cx = static_cast<int>(std::floor(uv.x() / cell_));
    const int cy = static_cast<int>(std::floor(uv.y() / cell_));
    const int r = static_cast<int>(std::ceil(radius / cell_));
    int best = -1;
    double best_d2 = radius * radius;
    for (int dy = -r; dy <= r; ++dy) {
      for (int dx = -r; dx <= r; ++dx) {
        auto it = cells_.find(Pack(cx + dx, cy + dy));
        if (it == cells_.end()) continue;
        for (int k : it->second) {
          const double d2 = (kps_.uv[static_cast<size_t>(k)] - uv).squaredNorm();
          if (d2 <= best_d2 && pred(k)) {
            best_d2 = d2;
            best = k;
          }
        }
      }
    }
    return best;
  }

 private:
  static int64_t Pack(int x, int y) {
    return (static_cast<int64_t>(x) << 32) ^ static_cast<int64_t>(static_cast<uint32_t>(y));
  }
  int64_t Key(const Eigen::Vector2d& uv) const {
    return Pack(static_cast<int>(std::floor(uv.x() / cell_)),
                static_cast<int>(std::floor(uv.y() / cell_)));
  }
  const FrameKeypoints& kps_;
  double cell_;
  std::unordered_map<int64_t, std::vector<int>> cells_;
};

bool InsideDetection(const ObjectDetectionInput& det,
                     const Eigen::Vector2d& uv,
                     double margin = 0.0) {
  if (!det.mask.empty()) {
    const int x = static_cast<int>(std::lround(uv.x()));
    const int y = static_cast<int>(std::lround(uv.y()));
    if (x < 0 || y < 0 || x >= det.mask.cols || y >= det.mask.rows) return false;
    return det.mask.at<uint8_t>(y, x) != 0;
  }
  return uv.x() >= det.box.x - margin && uv.y() >= det.box.y - margin &&
         uv.x() <= det.box.x + det.box.width + margin &&
         uv.y() <= det.box.y + det.box.height + margin;
}

// Reference patch for the NCC search; none on untextured areas, where the
// correlation is meaningless. With a mask, the pixels off it are NaN
// (ExtractMaskedPatch), and the texture is that of the others.
cv::Mat TexturedPatch(const cv::Mat& image,
                      const Eigen::Vector2d& uv,
                      int half_size,
                      const cv::Mat& mask = cv::Mat(),
                      double min_share = 0.5) {
  cv::Mat patch = mask.empty() ? ExtractPatch(image, uv, half_size)
                               : ExtractMaskedPatch(image, mask, uv, half_size, min_share);
  if (patch.empty()) return patch;
  double n = 0.0, sum = 0.0, sum_sq = 0.0;
  for (auto it = patch.begin<float>(); it != patch.end<float>(); ++it) {
    if (std::isnan(*it)) continue;
    n += 1.0;
    sum += *it;
    sum_sq += static_cast<double>(*it) * *it;
  }
  const double mean = sum / n;
  return std::sqrt(std::max(0.0, sum_sq / n - mean * mean)) >= 2.0 ? patch : cv::Mat();
}

// Whether a reference patch was taken with pixels off the object's mask
// (NaN; TexturedPatch).
bool HasMaskedPixels(const cv::Mat& patch) {
  return std::any_of(
      patch.begin<float>(), patch.end<float>(), [](float v) { return std::isnan(v); });
}

// New points must sit well inside the mask: keypoints on the boundary
// describe the background as much as the object.
bool DeepInsideDetection(const ObjectDetectionInput& det,
                         const Eigen::Vector2d& uv,
                         double erosion) {
  if (!InsideDetection(det, uv)) return false;
  if (det.mask.empty() || erosion <= 0.0) return true;
  for (const Eigen::Vector2d& d : {Eigen::Vector2d(erosion, 0),
                                   Eigen::Vector2d(-erosion, 0),
                                   Eigen::Vector2d(0, erosion),
                                   Eigen::Vector2d(0, -erosion)}) {
    if (!InsideDetection(det, uv + d)) return false;
  }
  return true;
}

// Steps elapsed since `o` was last seen, in units of its last step (frames
// when its step has no duration); at least 1.
double StepsSinceSeen(const ObjectFrameInput& f, const TrackedObject& o) {
  double steps = static_cast<double>(std::max<int64_t>(1, f.frame_index - o.last_seen_frame));
  if (o.step_seconds > 0.0 && !o.history.empty() &&
      f.timestamp_ns > o.history.back().timestamp_ns) {
    steps = (f.timestamp_ns - o.history.back().timestamp_ns) * 1e-9 / o.step_seconds;
  }
  return steps;
}

// Velocity of the point p (world frame) under the world twist ξ = (v, ω)
// (per unit of the twist's time): v + ω × p.
Eigen::Vector3d PointVelocity(const Vector6d& twist, const Eigen::Vector3d& p) {
  return twist.head<3>() + twist.tail<3>().cross(p);
}

double Median(std::vector<double> v) {
  if (v.empty()) return 0.0;
  std::nth_element(v.begin(), v.begin() + static_cast<long>(v.size() / 2), v.end());
  return v[v.size() / 2];
}

// fn(0) ... fn(n - 1) on up to `threads` threads (this one and threads - 1
// started for the call), each index taken once, in no set order.
void ParallelFor(size_t n, int threads, const std::function<void(size_t)>& fn) {
  if (n == 0) return;
  std::atomic<size_t> next{0};
  auto work = [&] {
    for (size_t i = next.fetch_add(1); i < n; i = next.fetch_add(1)) fn(i);
  };
  std::vector<std::thread> helpers;
  const size_t extra = std::min(n, static_cast<size_t>(std::max(threads, 1))) - 1;
  for (size_t t = 0; t < extra; ++t) helpers.emplace_back(work);
  work();
  for (std::thread& t : helpers) t.join();
}

}  // namespace

struct ObjectTracker::FrameContext {
  const ObjectFrameInput& frame;
  SE3d world_from_camera;
  double dt = 0.0;  // seconds since the previous frame (0 on the first)
  KeypointGrid grid;
  // Stereo u_right of (cluster id, keypoint) as ObjectStereo measured it.
  mutable std::unordered_map<int64_t, std::unordered_map<size_t, double>> stereo_cache;
  // Objects whose re-acquisition the filter's gate refused in this frame: a
  // measurement that disagrees with their motion; not continued either.
  mutable std::unordered_set<int64_t> gate_refused;
  // The sparse flow's pyramids of the previous and this frame's left image,
  // built on first use and shared by the frame's objects.
  mutable std::vector<cv::Mat> prev_pyramid, pyramid;
  FrameContext(const ObjectFrameInput& f, double dt_s)
      : frame(f),
        world_from_camera(f.camera_from_world.Inverse()),
        dt(dt_s),
        grid(f.keypoints, 8.0) {}
};

absl::Status ObjectTrackerOptions::Validate() const {
  if (absl::Status s = estimator.Validate(); !s.ok()) return s;
  if (absl::Status s = flow.Validate(); !s.ok()) return s;
  if (min_points_to_track < 3 || min_points_to_create < min_points_to_track) {
    return absl::InvalidArgumentError(
        "object tracker needs 3 <= min_points_to_track <= min_points_to_create");
  }
  if (max_points_per_object < min_points_to_create) {
    return absl::InvalidArgumentError(
        "object tracker max_points_per_object < min_points_to_create");
  }
  if (evict_unseen_frames < 0) {
    return absl::InvalidArgumentError("object tracker evict_unseen_frames < 0");
  }
  if (num_threads < 1 || num_threads > 64) {
    return absl::InvalidArgumentError("object tracker num_threads must be in [1, 64]");
  }
  if (max_continuation_gap_frames < 0 || continuation_min_history < 2 ||
      !(continuation_margin_m >= 0.0) ||
      !(continuation_min_inside > 0.0 && continuation_min_inside <= 1.0)) {
    return absl::InvalidArgumentError(
        "object tracker needs max_continuation_gap_frames >= 0, continuation_min_history >= 2, "
        "continuation_margin_m >= 0 and continuation_min_inside in (0, 1]");
  }
  if (!(stereo_level0_half_px > 0.0)) {
    return absl::InvalidArgumentError("object tracker needs stereo_level0_half_px > 0");
  }
  if (!(max_depth_m > 0.0) || !(max_depth_spread_m > 0.0) || max_frames_lost < 0) {
    return absl::InvalidArgumentError(
        "object tracker needs max_depth_m > 0, max_depth_spread_m > 0, max_frames_lost >= 0");
  }
  if (!(max_track_depth_sigma_m >= 0.0)) {
    return absl::InvalidArgumentError("object tracker needs max_track_depth_sigma_m >= 0");
  }
  if (!(stationary_max_leave_speed_mps >= 0.0) || !(stationary_max_still_sigma_px >= 0.0)) {
    return absl::InvalidArgumentError(
        "object tracker needs stationary_max_leave_speed_mps >= 0 and "
        "stationary_max_still_sigma_px >= 0");
  }
  if (!(stationary_max_leave_curvature_per_m >= 0.0) || !(stationary_leave_turn_slack_rad >= 0.0)) {
    return absl::InvalidArgumentError(
        "object tracker needs stationary_max_leave_curvature_per_m >= 0 and "
        "stationary_leave_turn_slack_rad >= 0");
  }
  if (!(stationary_min_leave_support >= 0.0 && stationary_min_leave_support <= 1.0)) {
    return absl::InvalidArgumentError(
        "object tracker needs stationary_min_leave_support in [0, 1]");
  }
  if (!(acceleration_sigma_mps2 >= 0.0) || !(angular_acceleration_sigma_radps2 > 0.0) ||
      !(max_step_sigma_px > 0.0) || !(filter_gate_confidence > 0.0) ||
      !(filter_gate_confidence < 1.0) || max_coast_frames < 0 ||
      restart_filter_after_refusals < 0) {
    return absl::InvalidArgumentError(
        "object tracker needs acceleration_sigma_mps2 >= 0, angular_acceleration_sigma_radps2 > 0, "
        "max_step_sigma_px > 0, 0 < filter_gate_confidence < 1, max_coast_frames >= 0 and "
        "restart_filter_after_refusals >= 0");
  }
  if (!(young_turn_rate_sigma_radps >= 0.0) || young_turn_prior_poses < 0 ||
      starting_turn_prior_poses < 0 || unseen_turn_prior_poses < 0) {
    return absl::InvalidArgumentError(
        "object tracker needs young_turn_rate_sigma_radps >= 0, young_turn_prior_poses >= 0, "
        "starting_turn_prior_poses >= 0 and unseen_turn_prior_poses >= 0");
  }
  if (!(young_turn_release_sigmas >= 0.0) || young_turn_release_min_inliers < 0 ||
      !(young_turn_release_max_curvature_per_m > 0.0)) {
    return absl::InvalidArgumentError(
        "object tracker needs young_turn_release_sigmas >= 0, young_turn_release_min_inliers >= 0 "
        "and young_turn_release_max_curvature_per_m > 0");
  }
  if (!(approaching_disparity_noise_scale > 0.0 && approaching_disparity_noise_scale <= 1.0) ||
      !(approaching_growth_time_s >= 0.0)) {
    return absl::InvalidArgumentError(
        "object tracker needs approaching_disparity_noise_scale in (0, 1] and "
        "approaching_growth_time_s >= 0");
  }
  if (!(tracked_stereo_search_fraction >= 0.0 && tracked_stereo_search_fraction <= 1.0)) {
    return absl::InvalidArgumentError(
        "object tracker needs tracked_stereo_search_fraction in [0, 1]");
  }
  if (!(max_lateral_acceleration_mps2 >= 0.0)) {
    return absl::InvalidArgumentError("object tracker needs max_lateral_acceleration_mps2 >= 0");
  }
  if (!(manoeuvre_angular_acceleration_sigma_radps2 >= 0.0) ||
      !(manoeuvre_max_reversal_turn_radps >= 0.0) || !(manoeuvre_lever_arm_m >= 0.0) ||
      !(manoeuvre_lever_arm_min_turn_radps >= 0.0)) {
    return absl::InvalidArgumentError(
        "object tracker needs manoeuvre_angular_acceleration_sigma_radps2, "
        "manoeuvre_max_reversal_turn_radps, manoeuvre_lever_arm_m and "
        "manoeuvre_lever_arm_min_turn_radps >= 0");
  }
  if (std::isnan(turn_rate_sigma_radps)) {
    return absl::InvalidArgumentError("object tracker turn_rate_sigma_radps must be a number");
  }
  if (!(search.min_masked_patch_share > 0.0 && search.min_masked_patch_share <= 1.0) ||
      search.patch_gauss_newton_iterations < 0) {
    return absl::InvalidArgumentError(
        "object tracker needs search.min_masked_patch_share in (0, 1] and "
        "search.patch_gauss_newton_iterations >= 0");
  }
  if (!(patch_refresh_view_change_deg >= 0.0 && patch_refresh_view_change_deg <= 180.0) ||
      !(patch_refresh_max_offset_px >= 0.0)) {
    return absl::InvalidArgumentError(
        "object tracker needs patch_refresh_view_change_deg in [0, 180] and "
        "patch_refresh_max_offset_px >= 0");
  }
  return absl::OkStatus();
}

ObjectTracker::ObjectTracker(const geometry::StereoCamera& camera,
                             const ObjectTrackerOptions& options)
    : camera_(camera), options_(options) {
  CHECK(camera_.Validate().ok()) << camera_.Validate().message();
  CHECK(options_.Validate().ok()) << options_.Validate().message();
}

double ObjectTracker::ObjectStereo(const FrameContext& ctx,
                                   const ObjectDetectionInput& det,
                                   size_t k) const {
  const FrameKeypoints& kps = ctx.frame.keypoints;
  const double u_right = kps.u_right[k];
  if (u_right < 0.0 || !options_.masked_stereo || ctx.frame.right.empty() || det.mask.empty())
    return u_right;
  // The cluster's entry exists when the steps run side by side (Process
  // makes them): then only found, never inserted.
  auto entry = ctx.stereo_cache.find(det.cluster_id);
  if (entry == ctx.stereo_cache.end()) entry = ctx.stereo_cache.try_emplace(det.cluster_id).first;
  auto& cache = entry->second;
  if (auto it = cache.find(k); it != cache.end()) return it->second;
  const double half = kps.stereo_support_px.empty() ? options_.masked_stereo_default_half_px
                                                    : kps.stereo_support_px[k];
  const std::optional<double> d = MaskedDisparity(ctx.frame.left,
                                                  ctx.frame.right,
                                                  det.mask,
                                                  kps.uv[k],
                                                  kps.uv[k].x() - u_right,
                                                  half,
                                                  options_.masked_stereo_options);
  const double result = d && *d > 0.0                            ? kps.uv[k].x() - *d
                        : options_.masked_stereo_keep_unmeasured ? u_right
                                                                 : -1.0;
  cache.emplace(k, result);
  return result;
}

double ObjectTracker::TrackedPointStereo(const FrameContext& ctx,
                                         const ObjectDetectionInput& det,
                                         const Eigen::Vector2d& uv,
                                         double predicted_depth) const {
  if (!options_.measure_tracked_stereo || !options_.masked_stereo || ctx.frame.right.empty() ||
      det.mask.empty() || !(predicted_depth > 0.1)) {
    return -1.0;
  }
  const double predicted = camera_.bf() / predicted_depth;
  MaskedStereoOptions search = options_.masked_stereo_options;
  search.search_px =
      std::max(search.search_px,
               static_cast<int>(std::ceil(options_.tracked_stereo_search_fraction * predicted)));
  const std::optional<double> d = MaskedDisparity(ctx.frame.left,
                                                  ctx.frame.right,
                                                  det.mask,
                                                  uv,
                                                  predicted,
                                                  options_.masked_stereo_default_half_px,
                                                  search);
  return d && *d > 0.0 ? uv.x() - *d : -1.0;
}

TrackedObject* ObjectTracker::mutable_object(int64_t id) {
  auto it = objects_.find(id);
  return it == objects_.end() ? nullptr : &it->second;
}

namespace {

// Gives `o` the joint `joint`: its last step and the step's covariance are
// projected onto the new joint's twists. A refitted road plane turns the
// joint a little from frame to frame, and a step kept from the old joint
// (the prediction of a step that then fails, a continued object's step) would
// be reported with out-of-plane components.
void AdoptJoint(const joints::Joint& joint, TrackedObject* o) {
  const Matrix6d projector = joint.WorldProjector();
  o->joint = joint;
  o->twist_step = projector * o->twist_step;
  if (o->twist_covariance_valid) {
    o->twist_covariance = projector * o->twist_covariance * projector.transpose();
  }
}

}  // namespace

joints::Joint ObjectTracker::EffectiveJoint(const joints::Joint& joint) const {
  if (options_.constrained) return joint;
  return joints::Joint(joints::JointType::kFree, joint.world_from_joint());
}

void ObjectTracker::UpdateJoint(const joints::Joint& joint, TrackedObject* o) const {
  joints::Joint next = EffectiveJoint(joint);
  if (next.type() == o->joint.type() &&
      (next.type() == joints::JointType::kPlanar || next.type() == joints::JointType::kFree)) {
    // A joint frame built from a plane has arbitrary in-plane axes (picked
    // from the normal alone: they swap when the normal's smallest component
    // changes from x to z). Keep the object's: its last frame turned by the
    // smallest rotation onto the new normal, at the new origin. The joint's
    // constraint is the same; the twist reported in the joint frame keeps its
    // axes from frame to frame.
    const Eigen::Matrix3d last = o->joint.world_from_joint().rotation();
    const Eigen::Matrix3d turn =
        Eigen::Quaterniond::FromTwoVectors(last.col(2), next.world_from_joint().rotation().col(2))
            .toRotationMatrix();
    next = joints::Joint(next.type(), SE3d(turn * last, next.world_from_joint().translation()));
  }
  if (options_.follow_parent_plane && !o->stationary && next.type() == joints::JointType::kPlanar &&
      o->joint.type() == joints::JointType::kPlanar) {
    const Eigen::Vector3d n = next.world_from_joint().rotation().col(2);
    const Eigen::Vector3d on_plane = next.world_from_joint().translation();
    const Eigen::Vector3d t = o->world_from_object.translation();
    o->world_from_object.translation() = t - (t - on_plane).dot(n) * n;
  }
  AdoptJoint(next, o);
}

ObjectTracker::State ObjectTracker::GetState() const {
  State s;
  s.objects = objects_;
  s.next_object_id = next_object_id_;
  s.prev_left = prev_left_;
  s.prev_timestamp_ns = prev_timestamp_ns_;
  s.has_prev = has_prev_;
  s.prev_camera_from_world = prev_camera_from_world_;
  s.stats = stats_;
  s.removed_trajectories = removed_trajectories_;
  return s;
}

void ObjectTracker::SetState(State state) {
  objects_ = std::move(state.objects);
  next_object_id_ = state.next_object_id;
  prev_left_ = std::move(state.prev_left);
  prev_left_pyramid_.clear();
  prev_timestamp_ns_ = state.prev_timestamp_ns;
  has_prev_ = state.has_prev;
  prev_camera_from_world_ = state.prev_camera_from_world;
  stats_ = state.stats;
  removed_trajectories_ = std::move(state.removed_trajectories);
}

ObjectTrajectory ObjectTracker::TrajectoryOf(const TrackedObject& o) {
  ObjectTrajectory t;
  t.object_id = o.id;
  t.class_id = o.class_id;
  t.instance_id = o.instance_id;
  t.cluster_id = o.cluster_id;
  t.poses.reserve(o.settled_poses.size() + o.history.size());
  t.poses.insert(t.poses.end(), o.settled_poses.begin(), o.settled_poses.end());
  for (const ObjectPoseSample& s : o.history) {
    t.poses.push_back({s.frame_index, s.timestamp_ns, s.world_from_object});
  }
  return t;
}

std::vector<ObjectTrajectory> ObjectTracker::Trajectories() const {
  std::vector<ObjectTrajectory> out(removed_trajectories_.begin(), removed_trajectories_.end());
  for (const auto& [id, o] : objects_) out.push_back(TrajectoryOf(o));
  std::sort(out.begin(), out.end(), [](const ObjectTrajectory& a, const ObjectTrajectory& b) {
    return a.object_id < b.object_id;
  });
  return out;
}

ObjectResult ObjectTracker::ToResult(const TrackedObject& o) {
  ObjectResult r;
  r.id = o.id;
  r.class_id = o.class_id;
  r.instance_id = o.instance_id;
  r.state = o.state;
  r.world_from_object = o.world_from_object;
  // A stationary object's twist is zero by decision, whatever a later
  // refinement (the dynamic BA) made of its held poses.
  if (o.step_seconds > 0.0 && !o.stationary) r.twist_in_world = o.twist_step / o.step_seconds;
  r.twist_in_joint = o.joint.WorldToJoint(r.twist_in_world);
  r.speed_mps = PointVelocity(r.twist_in_world, o.world_from_object.translation()).norm();
  r.joint = joints::JointTypeName(o.joint.type());
  r.num_points = static_cast<int>(o.points.size());
  r.stationary = o.stationary;
  return r;
}

void ObjectTracker::RecordPose(const FrameContext& ctx, TrackedObject* o) {
  ObjectPoseSample s;
  s.frame_index = ctx.frame.frame_index;
  s.timestamp_ns = ctx.frame.timestamp_ns;
  s.world_from_object = o->world_from_object;
  s.twist_step = o->twist_step;
  s.held = o->stationary;
  s.observations = std::move(o->pending_observations);
  o->pending_observations.clear();
  o->history.push_back(std::move(s));
  while (static_cast<int>(o->history.size()) > options_.max_history) {
    const ObjectPoseSample& oldest = o->history.front();
    o->settled_poses.push_back({oldest.frame_index, oldest.timestamp_ns, oldest.world_from_object});
    o->history.pop_front();
  }
  while (!o->settled_poses.empty() &&
         static_cast<int>(o->settled_poses.size() + o->history.size()) >
             options_.max_trajectory_poses) {
    o->settled_poses.pop_front();
  }
}

void ObjectTracker::EvictUnseenPoints(const FrameContext& ctx, TrackedObject* o) const {
  if (options_.evict_unseen_frames <= 0 ||
      static_cast<int>(o->points.size()) < options_.max_points_per_object)
    return;
  // Seen: observed in this frame (pending) or in a recorded frame of the
  // last evict_unseen_frames.
  std::unordered_set<int64_t> seen;
  for (const ObjectPointObservation& obs : o->pending_observations) seen.insert(obs.point_id);
  const int64_t oldest = ctx.frame.frame_index - options_.evict_unseen_frames;
  for (auto it = o->history.rbegin(); it != o->history.rend() && it->frame_index > oldest; ++it) {
    for (const ObjectPointObservation& obs : it->observations) seen.insert(obs.point_id);
  }
  o->points.erase(std::remove_if(o->points.begin(),
                                 o->points.end(),
                                 [&](const ObjectPoint& p) { return seen.count(p.id) == 0; }),
                  o->points.end());
}

cv::Mat ObjectTracker::PointPatch(const FrameContext& ctx,
                                  const ObjectDetectionInput& det,
                                  const Eigen::Vector2d& uv) const {
  return TexturedPatch(ctx.frame.left,
                       uv,
                       options_.search.patch_half_size,
                       options_.masked_patches ? det.mask : cv::Mat(),
                       options_.search.min_masked_patch_share);
}

void ObjectTracker::RefreshPatch(const FrameContext& ctx,
                                 const ObjectDetectionInput& det,
                                 const SE3d& camera_from_object,
                                 const Eigen::Vector3d& camera_in_object,
                                 const Eigen::Vector2d& found,
                                 ObjectPoint* point) const {
  if (point->patch.empty()) return;
  const Eigen::Vector3d view = (camera_in_object - point->point_in_object).normalized();
  if (std::acos(std::clamp(view.dot(point->patch_view_in_object), -1.0, 1.0)) <=
      options_.patch_refresh_view_change_deg * M_PI / 180.0) {
    return;
  }
  Eigen::Vector2d uv;
  if (!camera_.ProjectChecked(camera_from_object * point->point_in_object, &uv, nullptr, 0.1) ||
      (uv - found).norm() > options_.patch_refresh_max_offset_px) {
    return;
  }
  cv::Mat patch = PointPatch(ctx, det, uv);
  if (patch.empty()) return;
  point->patch = std::move(patch);
  point->patch_view_in_object = view;
}

void ObjectTracker::RecordInliers(const FrameContext& ctx,
                                  const ObjectDetectionInput& det,
                                  const TwistEstimate& est,
                                  const std::vector<TwistObservation>& obs,
                                  const std::vector<size_t>& obs_point,
                                  TrackedObject* o) const {
  o->last_num_inliers = est.num_inliers;
  o->last_sigma_px = est.sigma_px;
  for (ObjectPoint& p : o->points) p.seen_last_frame = false;
  // The step's pose, for the patch refresh (once per step, not per point).
  const bool refresh = options_.patch_refresh_view_change_deg > 0.0;
  const SE3d camera_from_object = ctx.frame.camera_from_world * o->world_from_object;
  const Eigen::Vector3d camera_in_object = camera_from_object.Inverse().translation();
  std::vector<Eigen::Vector2d> occupied;
  for (size_t j = 0; j < obs.size(); ++j) {
    if (!est.inliers[j]) continue;
    ObjectPoint& p = o->points[obs_point[j]];
    if (refresh) RefreshPatch(ctx, det, camera_from_object, camera_in_object, obs[j].uv, &p);
    p.last_uv = obs[j].uv;
    p.seen_last_frame = true;
    ++p.num_observations;
    o->pending_observations.push_back(
        {p.id, obs[j].uv, obs[j].u_right, obs[j].disparity_noise_ratio});
    occupied.push_back(obs[j].uv);
  }
  AddNewPoints(ctx, det, o, occupied);
}

void ObjectTracker::AddNewPoints(const FrameContext& ctx,
                                 const ObjectDetectionInput& det,
                                 TrackedObject* o,
                                 const std::vector<Eigen::Vector2d>& occupied) const {
  EvictUnseenPoints(ctx, o);
  const FrameKeypoints& kps = ctx.frame.keypoints;
  const SE3d camera_from_object = ctx.frame.camera_from_world * o->world_from_object;
  const SE3d object_from_camera = camera_from_object.Inverse();
  std::vector<double> depths;
  for (const ObjectPoint& p : o->points)
    depths.push_back((camera_from_object * p.point_in_object).z());
  const double median_depth = Median(depths);
  std::vector<Eigen::Vector2d> taken = occupied;
  const double spacing2 = options_.min_point_spacing_px * options_.min_point_spacing_px;
  for (size_t k = 0; k < kps.uv.size(); ++k) {
    if (static_cast<int>(o->points.size()) >= options_.max_points_per_object) break;
    if (kps.u_right[k] < 0.0 || !DeepInsideDetection(det, kps.uv[k], options_.mask_erosion_px))
      continue;
    bool close = false;
    for (const auto& t : taken) {
      if ((t - kps.uv[k]).squaredNorm() < spacing2) {
        close = true;
        break;
      }
    }
    if (close) continue;
    const double u_right = ObjectStereo(ctx, det, k);
    if (u_right < 0.0) continue;
    const auto p_c =
        camera_.TriangulateStereo(kps.uv[k].x(), kps.uv[k].y(), u_right, options_.max_depth_m);
    if (!p_c) continue;
    if (!depths.empty() && std::abs(p_c->z() - median_depth) > options_.max_depth_spread_m)
      continue;
    ObjectPoint p;
    p.id = o->next_point_id++;
    p.point_in_object = object_from_camera * *p_c;
    p.sigma_in_object = object_from_camera.rotation() * StereoPointSigma(kps, k, *p_c);
    if (!kps.descriptors.empty()) p.descriptor = kps.descriptors.row(static_cast<int>(k)).clone();
    p.patch = PointPatch(ctx, det, kps.uv[k]);
    p.patch_view_in_object = (object_from_camera.translation() - p.point_in_object).normalized();
    p.last_uv = kps.uv[k];
    p.seen_last_frame = true;
    p.num_observations = 1;
    o->pending_observations.push_back(
        {p.id, kps.uv[k], u_right, StepDisparityNoiseRatio(StereoLevelScale(kps, k))});
    o->points.push_back(std::move(p));
    taken.push_back(kps.uv[k]);
  }
}

bool ObjectTracker::Create(const FrameContext& ctx,
                           const ObjectDetectionInput& det,
                           TrackedObject* o) {
  const FrameKeypoints& kps = ctx.frame.keypoints;
  std::vector<size_t> idx;
  std::vector<double> u_rights;
  std::vector<Eigen::Vector3d> p_cam;
  for (size_t k = 0; k < kps.uv.size(); ++k) {
    if (kps.u_right[k] < 0.0 || !DeepInsideDetection(det, kps.uv[k], options_.mask_erosion_px))
      continue;
    const double u_right = ObjectStereo(ctx, det, k);
    if (u_right < 0.0) continue;
    const auto p_c =
        camera_.TriangulateStereo(kps.uv[k].x(), kps.uv[k].y(), u_right, options_.max_depth_m);
    if (!p_c) continue;
    u_rights.push_back(u_right);
    idx.push_back(k);
    p_cam.push_back(*p_c);
  }
  if (static_cast<int>(idx.size()) < options_.min_points_to_create) return false;
  // Mask edges leak background: keep the points near the median depth.
  std::vector<double> depths;
  for (const auto& p : p_cam) depths.push_back(p.z());
  const double median_depth = Median(depths);
  // Depth noise of the structure: the median over the points of
  // z² σ_d s / (f b), s the scale of the keypoint's pyramid level (its stereo
  // block relative to level 0's): the matcher refines on that level.
  std::vector<double> sigmas;
  for (size_t j = 0; j < idx.size(); ++j) {
    sigmas.push_back(DepthNoise(p_cam[j].z(), StereoLevelScale(kps, idx[j])));
  }
  if (options_.max_create_depth_sigma_m > 0.0 && Median(sigmas) > options_.max_create_depth_sigma_m)
    return false;
  std::vector<Eigen::Vector3d> p_world;
  std::vector<size_t> kept;
  for (size_t j = 0; j < idx.size(); ++j) {
    if (std::abs(p_cam[j].z() - median_depth) > options_.max_depth_spread_m) continue;
    p_world.push_back(ctx.world_from_camera * p_cam[j]);
    kept.push_back(j);
  }
  if (static_cast<int>(kept.size()) < options_.min_points_to_create) return false;
  Eigen::Vector3d centroid = Eigen::Vector3d::Zero();
  for (const auto& p : p_world) centroid += p;
  centroid /= static_cast<double>(p_world.size());
  o->joint = EffectiveJoint(det.joint);
  const SE3d& world_from_joint = o->joint.world_from_joint();
  const Eigen::Vector3d z = world_from_joint.rotation().col(2);
  const Eigen::Vector3d origin = centroid - (centroid - world_from_joint.translation()).dot(z) * z;
  o->world_from_object = SE3d(world_from_joint.so3(), origin);
  const SE3d object_from_world = o->world_from_object.Inverse();
  o->points.clear();
  for (size_t m = 0;
       m < kept.size() && static_cast<int>(o->points.size()) < options_.max_points_per_object;
       ++m) {
    const size_t k = idx[kept[m]];
    ObjectPoint p;
    p.id = o->next_point_id++;
    p.point_in_object = object_from_world * p_world[m];
    p.sigma_in_object = (object_from_world * ctx.world_from_camera).rotation() *
                        StereoPointSigma(kps, k, p_cam[kept[m]]);
    if (!kps.descriptors.empty()) p.descriptor = kps.descriptors.row(static_cast<int>(k)).clone();
    p.patch = PointPatch(ctx, det, kps.uv[k]);
    p.patch_view_in_object =
        ((object_from_world * ctx.world_from_camera).translation() - p.point_in_object)
            .normalized();
    p.last_uv = kps.uv[k];
    p.seen_last_frame = true;
    p.num_observations = 1;
    o->pending_observations.push_back(
        {p.id, kps.uv[k], u_rights[kept[m]], StepDisparityNoiseRatio(StereoLevelScale(kps, k))});
    o->points.push_back(std::move(p));
  }
  o->cluster_id = det.cluster_id;
  o->class_id = det.class_id;
  o->instance_id = det.instance_id;
  o->state = ObjectState::kNew;
  o->twist_step.setZero();
  o->step_seconds = 0.0;
  o->frames_lost = 0;
  o->last_seen_frame = ctx.frame.frame_index;
  o->last_box = det.box;
  return true;
}

double ObjectTracker::DepthNoise(double depth, double level_scale) const {
  return depth * depth * options_.disparity_sigma_px * level_scale / camera_.bf();
}

double ObjectTracker::ApproachDisparityScale(const FrameContext& ctx,
                                             const TrackedObject& o,
                                             const SE3d& camera_from_predicted) const {
  if (!(options_.approaching_growth_time_s > 0.0)) return 1.0;  // off
  const SE3d& camera_from_world_before =
      prev_camera_from_world_ ? *prev_camera_from_world_ : ctx.frame.camera_from_world;
  const double range_before = (camera_from_world_before * o.world_from_object).translation().norm();
  const double range_now = camera_from_predicted.translation().norm();
  if (!(ctx.dt > 0.0) || !(range_now < range_before)) return 1.0;
  // The image's rate of growth (1 / the time to contact), 1/s.
  const double growth = (range_before - range_now) / (range_now * ctx.dt);
  return std::max(options_.approaching_disparity_noise_scale,
                  1.0 / (1.0 + options_.approaching_growth_time_s * growth));
}

double ObjectTracker::StepDisparityNoiseRatio(double level_scale) const {
  return options_.step_disparity_noise
             ? options_.disparity_sigma_px * level_scale / options_.estimator.min_sigma_px
             : 0.0;
}

double ObjectTracker::StereoLevelScale(const FrameKeypoints& kps, size_t k) const {
  return kps.stereo_support_px.empty() ? 1.0
                                       : kps.stereo_support_px[k] / options_.stereo_level0_half_px;
}

Eigen::Vector3d ObjectTracker::StereoPointSigma(const FrameKeypoints& kps,
                                                size_t k,
                                                const Eigen::Vector3d& p_c) const {
  return DepthNoise(p_c.z(), StereoLevelScale(kps, k)) / p_c.z() * p_c;
}

bool ObjectTracker::BeyondTrackingRange(const SE3d& camera_from_object) const {
  return options_.max_track_depth_sigma_m > 0.0 &&
         DepthNoise(camera_from_object.translation().z(), 1.0) > options_.max_track_depth_sigma_m;
}

Matrix6d ObjectTracker::ProcessNoise(const TrackedObject& o, double dt) const {
  return ProcessNoise(
      o, dt, options_.acceleration_sigma_mps2, options_.angular_acceleration_sigma_radps2);
}

Matrix6d ObjectTracker::ProcessNoise(const TrackedObject& o,
                                     double dt,
                                     double acceleration_sigma_mps2,
                                     double angular_acceleration_sigma_radps2) const {
  // Random acceleration over a step of dt, as a change of the per-step twist
  // at the object's origin c: δv = a·dt², δω = α·dt²; moved to the world
  // origin by v = v_c + c × ω and projected onto the joint's twists.
  const double dt2 = dt * dt;
  const double qv = std::pow(acceleration_sigma_mps2 * dt2, 2);
  const double qw = std::pow(angular_acceleration_sigma_radps2 * dt2, 2);
  Matrix6d q = Matrix6d::Zero();
  q.topLeftCorner<3, 3>() = qv * Eigen::Matrix3d::Identity();
  q.bottomRightCorner<3, 3>() = qw * Eigen::Matrix3d::Identity();
  Matrix6d to_world = Matrix6d::Identity();
  to_world.topRightCorner<3, 3>() = geometry::SO3d::Hat(o.world_from_object.translation());
  const Matrix6d projector = o.joint.WorldProjector();
  return projector * to_world * q * to_world.transpose() * projector.transpose();
}

Matrix6d ObjectTracker::ManoeuvreNoise(const TrackedObject& o,
                                       const Vector6d& predicted,
                                       double dt,
                                       bool lever_arm) const {
  const Matrix6d q = ProcessNoise(o, dt, 0.0, options_.manoeuvre_angular_acceleration_sigma_radps2);
  if (!lever_arm || !(options_.manoeuvre_lever_arm_m > 0.0) ||
      o.joint.type() != joints::JointType::kPlanar) {
    return q;
  }
  // Sideways: across the predicted velocity of the origin, in the plane (a
  // change of the world twist's linear part moves the origin by as much).
  const Eigen::Vector3d axis = o.joint.world_from_joint().rotation().col(2);
  const Eigen::Vector3d c = o.world_from_object.translation();
  const Eigen::Vector3d side = axis.cross(predicted.head<3>() + predicted.tail<3>().cross(c));
  if (!(side.norm() > 1e-6)) return q;
  const Eigen::Vector3d l = side.normalized();
  // The rate's change over the step times the arm.
  const double sigma = options_.manoeuvre_angular_acceleration_sigma_radps2 * dt * dt *
                       options_.manoeuvre_lever_arm_m;
  Matrix6d lateral = Matrix6d::Zero();
  lateral.topLeftCorner<3, 3>() = sigma * sigma * l * l.transpose();
  const Matrix6d projector = o.joint.WorldProjector();
  return q + projector * lateral * projector.transpose();
}

bool ObjectTracker::EasesTheTurn(const TrackedObject& o,
                                 const Vector6d& predicted,
                                 const Vector6d& measured,
                                 double dt) const {
  if (o.joint.type() != joints::JointType::kPlanar) return false;
  const Eigen::Vector3d axis = o.joint.world_from_joint().rotation().col(2);
  const double turn_predicted = std::abs(axis.dot(predicted.tail<3>()));
  return turn_predicted > options_.manoeuvre_lever_arm_min_turn_radps * dt &&
         std::abs(axis.dot(measured.tail<3>())) < turn_predicted;
}

Matrix6d ObjectTracker::PredictedCovariance(const FrameContext& ctx, const TrackedObject& o) const {
  const double r = o.step_seconds > 0.0 ? ctx.dt / o.step_seconds : 1.0;
  const Matrix6d projector = o.joint.WorldProjector();
  return projector * (r * r * o.twist_covariance) * projector.transpose() + ProcessNoise(o, ctx.dt);
}

bool ObjectTracker::FilterStep(const TrackedObject& o,
                               const joints::Joint& joint,
                               const Vector6d& predicted,
                               const Matrix6d& predicted_covariance,
                               TwistEstimate* est) const {
  if (est->sigma_px > options_.max_step_sigma_px) return false;
  if (!o.twist_covariance_valid || !est->covariance_valid) return true;  // nothing to fuse
  const Eigen::Matrix<double, 6, Eigen::Dynamic> basis =
      ProjectorRangeBasis(joint.WorldProjector());
  const Eigen::Index k = basis.cols();
  if (k == 0) return true;
  const Eigen::MatrixXd p = basis.transpose() * predicted_covariance * basis;
  const Eigen::MatrixXd m = basis.transpose() * est->covariance * basis;
  const Eigen::MatrixXd s = p + m;
  const Eigen::VectorXd d = basis.transpose() * (est->twist - predicted);
  const Eigen::LDLT<Eigen::MatrixXd> ldlt(s);
  if (ldlt.info() != Eigen::Success || !ldlt.isPositive()) return true;
  const double chi2 = d.dot(ldlt.solve(d));
  if (chi2 > ChiSquareQuantile(static_cast<int>(k), options_.filter_gate_confidence)) return false;
  // Kalman update: x = x_pred + K d, P⁺ = (I − K) P with K = P S⁻¹.
  const Eigen::MatrixXd gain = ldlt.solve(p).transpose();  // P S⁻¹ (P, S symmetric)
  const Eigen::VectorXd x = basis.transpose() * predicted + gain * d;
  Eigen::MatrixXd post = (Eigen::MatrixXd::Identity(k, k) - gain) * p;
  post = 0.5 * (post + post.transpose());
  est->twist = basis * x;
  est->world_from_object = SE3d::Exp(est->twist) * o.world_from_object;
  est->covariance = basis * post * basis.transpose();
  return true;
}

TwistPrior ObjectTracker::TurnPrior(const joints::Joint& joint, double seconds) const {
  return TurnPrior(joint, seconds, options_.turn_rate_sigma_radps);
}

TwistPrior ObjectTracker::TurnPrior(const joints::Joint& joint,
                                    double seconds,
                                    double sigma) const {
  TwistPrior prior;
  if (!(sigma > 0.0) || !(seconds > 0.0) || joint.type() != joints::JointType::kPlanar) {
    return prior;
  }
  prior.sqrt_information = Eigen::Matrix<double, 1, 6>::Zero();
  prior.sqrt_information.rightCols<3>() =
      joint.world_from_joint().rotation().col(2).transpose() / (sigma * seconds);
  return prior;
}

double ObjectTracker::LateralAcceleration(const TrackedObject& o,
                                          const Vector6d& twist,
                                          double seconds) const {
  if (o.joint.type() != joints::JointType::kPlanar || !(seconds > 0.0)) return 0.0;
  const Eigen::Vector3d axis = o.joint.world_from_joint().rotation().col(2);
  return std::abs(axis.dot(twist.tail<3>())) * OriginStepLength(o, twist) / (seconds * seconds);
}

bool ObjectTracker::ShowsAYoungTurn(const TrackedObject& o, const TwistEstimate& free) const {
  if (!free.success || !free.covariance_valid ||
      free.num_inliers < options_.young_turn_release_min_inliers ||
      o.joint.type() != joints::JointType::kPlanar) {
    return false;
  }
  const Eigen::Vector3d axis = o.joint.world_from_joint().rotation().col(2);
  const Eigen::Vector3d omega = free.twist.tail<3>();
  const double rate = axis.dot(omega);  // rad per frame
  const double variance = axis.dot(free.covariance.bottomRightCorner<3, 3>() * axis);
  if (!(variance > 0.0) ||
      std::abs(rate) <= options_.young_turn_release_sigmas * std::sqrt(variance)) {
    return false;
  }
  const double speed = OriginStepLength(o, free.twist);  // m per frame
  constexpr double kTurnSlackRad = 0.01;
  return std::abs(rate) <= options_.young_turn_release_max_curvature_per_m * speed + kTurnSlackRad;
}

Vector6d ObjectTracker::FirstStepSeed(const FrameContext& ctx,
                                      const ObjectDetectionInput& det,
                                      const TrackedObject& o) const {
  Vector6d seed = Vector6d::Zero();
  if (o.last_box.area() <= 0.0 || det.box.area() <= 0.0) return seed;
  // Where the points seen in the last frame were, and where the camera's own
  // motion alone takes them (the object held still).
  const SE3d camera_from_object = ctx.frame.camera_from_world * o.world_from_object;
  Eigen::Vector2d was = Eigen::Vector2d::Zero(), held = Eigen::Vector2d::Zero();
  std::vector<double> depths;
  for (const ObjectPoint& p : o.points) {
    if (!p.seen_last_frame) continue;
    const Eigen::Vector3d p_c = camera_from_object * p.point_in_object;
    Eigen::Vector2d uv;
    if (!camera_.ProjectChecked(p_c, &uv, nullptr, 0.1)) continue;
    was += p.last_uv;
    held += uv;
    depths.push_back(p_c.z());
  }
  if (depths.empty()) return seed;
  const double n = static_cast<double>(depths.size());
  was /= n;
  held /= n;
  auto centre = [](const cv::Rect2d& r) {
    return Eigen::Vector2d(r.x + 0.5 * r.width, r.y + 0.5 * r.height);
  };
  // The detection's shift beyond the camera's motion, as a translation
  // across the view at the points' depth.
  const Eigen::Vector2d shift = (centre(det.box) - centre(o.last_box)) - (held - was);
  const double z = Median(depths);
  const Eigen::Vector3d across(shift.x() * z / camera_.fx, shift.y() * z / camera_.fy, 0.0);
  seed.head<3>() = ctx.world_from_camera.so3() * across;
  return o.joint.WorldProjector() * seed;
}

absl::Status ObjectTracker::BuildFlowPyramids(const FrameContext& ctx) const {
  if (prev_left_pyramid_.empty()) {
    absl::StatusOr<std::vector<cv::Mat>> prev = SparseFlowPyramid(prev_left_, options_.flow);
    if (!prev.ok()) return prev.status();
    ctx.prev_pyramid = *std::move(prev);
  } else {
    ctx.prev_pyramid = prev_left_pyramid_;  // shares the buffers
  }
  absl::StatusOr<std::vector<cv::Mat>> next = SparseFlowPyramid(ctx.frame.left, options_.flow);
  if (!next.ok()) {
    ctx.prev_pyramid.clear();
    return next.status();
  }
  ctx.pyramid = *std::move(next);
  return absl::OkStatus();
}

bool ObjectTracker::PrepareSparseFlow(const FrameContext& ctx) const {
  return !ctx.pyramid.empty() || BuildFlowPyramids(ctx).ok();
}

void ObjectTracker::Merge(const StepReport& report, const FrameContext& ctx) {
  stats_ += report.stats;
  ctx.gate_refused.insert(report.gate_refused.begin(), report.gate_refused.end());
}

absl::StatusOr<std::vector<std::optional<Eigen::Vector2d>>> ObjectTracker::SparseFlow(
    const FrameContext& ctx,
    const std::vector<Eigen::Vector2d>& prev_uv,
    const std::vector<Eigen::Vector2d>& predicted_uv) const {
  if (ctx.pyramid.empty()) {
    if (absl::Status st = BuildFlowPyramids(ctx); !st.ok()) return st;
  }
  return TrackSparseFlow(ctx.prev_pyramid, ctx.pyramid, prev_uv, options_.flow, &predicted_uv);
}

bool ObjectTracker::ReversesTurn(const TrackedObject& o,
                                 const Vector6d& predicted,
                                 const Vector6d& measured,
                                 double dt) const {
  const double bound = options_.manoeuvre_max_reversal_turn_radps * dt;
  if (!(bound > 0.0)) return false;
  const Eigen::Vector3d normal = o.joint.world_from_joint().rotation().col(2);
  const double turn_predicted = predicted.tail<3>().dot(normal);
  const double turn_measured = measured.tail<3>().dot(normal);
  return turn_predicted * turn_measured < 0.0 && std::abs(turn_predicted) > bound &&
         std::abs(turn_measured) > bound;
}

bool ObjectTracker::Track(const FrameContext& ctx,
                          const ObjectDetectionInput& det,
                          TrackedObject* o,
                          bool seed_from_detection,
                          StepReport* report) const {
  const ObjectFrameInput& f = ctx.frame;
  // Constant-velocity prediction, scaled to this frame's duration. A new
  // object has no step yet: no motion, or its detection's image motion.
  Vector6d initial = o->twist_step;
  if (o->step_seconds > 0.0 && ctx.dt > 0.0) {
    initial *= ctx.dt / o->step_seconds;
  } else if (seed_from_detection) {
    initial = FirstStepSeed(ctx, det, *o);
  }
  const SE3d predicted = SE3d::Exp(o->joint.WorldProjector() * initial) * o->world_from_object;
  const SE3d camera_from_predicted = f.camera_from_world * predicted;
  if (BeyondTrackingRange(camera_from_predicted)) return false;
  const double approach_scale = ApproachDisparityScale(ctx, *o, camera_from_predicted);

  std::vector<size_t> flow_idx;
  std::vector<Eigen::Vector2d> prev_uv, pred_uv;
  for (size_t k = 0; k < o->points.size(); ++k) {
    if (!o->points[k].seen_last_frame) continue;
    flow_idx.push_back(k);
    prev_uv.push_back(o->points[k].last_uv);
    Eigen::Vector2d uv;
    if (!camera_.ProjectChecked(
            camera_from_predicted * o->points[k].point_in_object, &uv, nullptr, 0.1) ||
        !camera_.InImage(uv)) {
      uv = o->points[k].last_uv;
    }
    pred_uv.push_back(uv);
  }
  absl::StatusOr<std::vector<std::optional<Eigen::Vector2d>>> flowed =
      !f.flow.empty() ? TrackDenseFlow(f.flow, prev_uv, options_.flow.border_px)
                      : SparseFlow(ctx, prev_uv, pred_uv);
  if (!flowed.ok()) return false;

  std::vector<TwistObservation> obs;
  std::vector<size_t> obs_point;
  // `level_scale`: of the level the disparity was measured on (DepthNoise).
  auto add_obs = [&](size_t point, const Eigen::Vector2d& uv, double u_right, double level_scale) {
    TwistObservation t;
    t.point_in_object = o->points[point].point_in_object;
    if (options_.model_point_noise) t.point_sigma_in_object = o->points[point].sigma_in_object;
    t.uv = uv;
    t.u_right = u_right;
    t.disparity_noise_ratio = StepDisparityNoiseRatio(level_scale) * approach_scale;
    obs.push_back(t);
    obs_point.push_back(point);
  };
  // Right-image u of the stereo keypoint under a flow position (descriptor
  // checked when both sides have one), shifted by the sub-pixel offset;
  // without one, measured on the images (measure_tracked_stereo). Sets
  // `*level_scale` to the scale of the level it was measured on.
  auto stereo_at = [&](const Eigen::Vector2d& uv, size_t point, double* level_scale) {
    const cv::Mat& desc = o->points[point].descriptor;
    const int kp = ctx.grid.Nearest(uv, options_.stereo_lookup_px, [&](int i) {
      if (f.keypoints.u_right[static_cast<size_t>(i)] < 0.0) return false;
      if (desc.empty() || f.keypoints.descriptors.empty()) return true;
      return HammingDistance(desc, f.keypoints.descriptors.row(i)) <= options_.search.max_hamming;
    });
    const double u_right = kp < 0 ? -1.0 : ObjectStereo(ctx, det, static_cast<size_t>(kp));
    if (u_right >= 0.0) {
      *level_scale = StereoLevelScale(f.keypoints, static_cast<size_t>(kp));
      return u_right + (uv.x() - f.keypoints.uv[static_cast<size_t>(kp)].x());
    }
    *level_scale = 1.0;  // masked_stereo_default_half_px, the level-0 block
    return TrackedPointStereo(
        ctx, det, uv, (camera_from_predicted * o->points[point].point_in_object).z());
  };
  for (size_t j = 0; j < flow_idx.size(); ++j) {
    const auto& q = (*flowed)[j];
    if (!q || !InsideDetection(det, *q, 2.0)) continue;
    double level_scale = 1.0;
    const double u_right = stereo_at(*q, flow_idx[j], &level_scale);
    add_obs(flow_idx[j], *q, u_right, level_scale);
  }
  const Matrix6d projector = o->joint.WorldProjector();
  // The young object's turn prior, also for one pulling away from a stop
  // and for one just seen again: it is seen as poorly as a new one.
  const bool young_by_age = static_cast<int>(o->history.size()) < options_.young_turn_prior_poses;
  const bool young = young_by_age ||
                     (!o->stationary && HeldWithin(*o, options_.starting_turn_prior_poses)) ||
                     UnseenWithin(*o, options_.unseen_turn_prior_poses);
  const TwistPrior turn_prior =
      young ? TurnPrior(o->joint, ctx.dt, options_.young_turn_rate_sigma_radps)
            : TurnPrior(o->joint, ctx.dt);
  const bool may_release = young_by_age && turn_prior.sqrt_information.rows() > 0 &&
                           options_.young_turn_release_sigmas > 0.0;
  auto solve = [&](const Vector6d& start, const TwistPrior& prior) {
    return EstimateObjectTwist(camera_,
                               f.camera_from_world,
                               o->world_from_object,
                               projector,
                               obs,
                               start,
                               options_.estimator,
                               prior);
  };
  // The constrained twist from the current observations, when there are
  // enough of them and the solver converged; a young object's step free of
  // its turn prior when that shows a turn clearly.
  auto estimate = [&](const Vector6d& start) -> std::optional<TwistEstimate> {
    if (static_cast<int>(obs.size()) < options_.min_points_to_track) return std::nullopt;
    absl::StatusOr<TwistEstimate> e = solve(start, turn_prior);
    if (!e.ok() || !e->success) return std::nullopt;
    // (Fewer observations than the release needs inliers: no free solve.)
    if (may_release && static_cast<int>(obs.size()) >= options_.young_turn_release_min_inliers) {
      absl::StatusOr<TwistEstimate> free = solve(start, TwistPrior());
      if (free.ok() && ShowsAYoungTurn(*o, *free)) {
        ++report->stats.young_turns_released;
        return *std::move(free);
      }
    }
    return *std::move(e);
  };
  std::optional<TwistEstimate> est = estimate(initial);

  if (options_.refine_by_projection) {
    // Project the points with the current estimate (or the prediction) and
    // look for them by descriptor among the frame's keypoints, then by patch
    // (NCC against the reference patch taken when the point was created).
    // Both are drift-free: flow chained from frame to frame is not (below).
    const SE3d current = est ? est->world_from_object : predicted;
    const SE3d camera_from_object = f.camera_from_world * current;
    std::vector<TwistObservation> flow_obs;  // inliers of the first estimate
    std::vector<size_t> flow_point;
    if (est) {
      for (size_t j = 0; j < obs.size(); ++j) {
        if (!est->inliers[j]) continue;
        flow_obs.push_back(obs[j]);
        flow_point.push_back(obs_point[j]);
      }
    }
    std::vector<bool> skip(o->points.size(), false);
    if (!options_.measure_by_matching) {
      // Flow-tracked points keep their flow positions; only the others are searched.
      for (size_t j = 0; j < obs.size(); ++j) {
        if (!est || est->inliers[j]) skip[obs_point[j]] = true;
      }
      obs = flow_obs;
      obs_point = flow_point;
    } else {
      obs.clear();
      obs_point.clear();
    }
    std::vector<Eigen::Vector3d> pts;
    std::vector<cv::Mat> descs;
    for (const ObjectPoint& p : o->points) {
      pts.push_back(p.point_in_object);
      descs.push_back(p.descriptor);
    }
    ProjectionSearchOptions search = options_.search;
    if (!est) search.radius_px *= 2.0;  // only the prediction to go by
    const std::vector<int> match =
        SearchByProjection(camera_, camera_from_object, pts, descs, skip, f.keypoints, search);
    const size_t before = obs.size();
    for (size_t k = 0; k < o->points.size(); ++k) {
      if (skip[k]) continue;
      if (match[k] >= 0) {
        const size_t kp = static_cast<size_t>(match[k]);
        if (!InsideDetection(det, f.keypoints.uv[kp], 2.0)) continue;
        add_obs(
            k, f.keypoints.uv[kp], ObjectStereo(ctx, det, kp), StereoLevelScale(f.keypoints, kp));
        continue;
      }
      if (o->points[k].patch.empty()) continue;
      Eigen::Vector2d uv;
      if (!camera_.ProjectChecked(camera_from_object * pts[k], &uv, nullptr, 0.1) ||
          !camera_.InImage(uv, 8))
        continue;
      const cv::Mat& patch = o->points[k].patch;
      // (A masked patch is searched as one with the option off too: a
      // state saved with it on.)
      const auto found = HasMaskedPixels(patch)
                             ? MaskedPatchSearch(f.left,
                                                 patch,
                                                 options_.masked_patches ? det.mask : cv::Mat(),
                                                 uv,
                                                 options_.search)
                             : PatchSearch(f.left, patch, uv, options_.search);
      if (!found || !InsideDetection(det, *found, 2.0)) continue;
      double level_scale = 1.0;
      const double u_right = stereo_at(*found, k, &level_scale);
      add_obs(k, *found, u_right, level_scale);
    }
    // Falls back to the first (flow) estimate and its inliers.
    auto use_flow_estimate = [&]() {
      obs = flow_obs;
      obs_point = flow_point;
      est->inliers.assign(obs.size(), true);
    };
    if (obs.size() > before || !est) {
      std::optional<TwistEstimate> refined = estimate(est ? est->twist : initial);
      // Matches around a wrong projection can agree on a wrong pose
      // (repetitive texture): the refined estimate must explain most of the
      // flow inliers.
      if (refined && est && options_.measure_by_matching && !flow_obs.empty()) {
        int agree = 0;
        for (const TwistObservation& t : flow_obs) {
          const auto r =
              TwistResidual(camera_, f.camera_from_world, o->world_from_object, refined->twist, t);
          agree += r && r->head<2>().norm() <= options_.flow_agreement_px ? 1 : 0;
        }
        if (agree < options_.flow_agreement_ratio * static_cast<double>(flow_obs.size())) {
          refined.reset();
        }
      }
      if (refined) {
        est = std::move(refined);
      } else if (!est) {
        return false;
      } else {
        use_flow_estimate();
      }
    } else if (est && options_.measure_by_matching) {
      use_flow_estimate();  // nothing matched
    } else if (est) {
      est->inliers.assign(obs.size(), true);  // the flow inliers kept above
    }
  }
  if (!est) return false;
  const bool filtered = options_.acceleration_sigma_mps2 > 0.0 && !o->stationary && ctx.dt > 0.0;
  Matrix6d predicted_covariance = Matrix6d::Zero();
  // A refused step: the prediction stands for this frame, no observation is
  // kept, and the next frame searches the points from the prediction; after
  // max_coast_frames refused steps in a row the object is lost (and
  // re-acquired later).
  auto coast = [&]() {
    ++report->stats.rejected;
    if (CoastedFrames(*o) >= options_.max_coast_frames) return false;
    o->world_from_object = predicted;
    o->twist_step = initial;
    o->step_seconds = ctx.dt;
    o->twist_covariance = predicted_covariance;
    for (ObjectPoint& p : o->points) p.seen_last_frame = false;
    return true;
  };
  // A step resting on a handful of inliers is not a measurement (a far car
  // whose matches went to its surroundings): the prediction stands.
  if (est->num_inliers < options_.min_step_inliers) return coast();
  if (filtered) {
    if (o->twist_covariance_valid) predicted_covariance = PredictedCovariance(ctx, *o);
    const Vector6d measured = est->twist;
    // A turn no tyre would hold is not the car's motion. (After a coasted
    // frame the step also corrects the prediction that stood: not a rate,
    // and the filter's restart, below, deals with it.)
    if (options_.max_lateral_acceleration_mps2 > 0.0 && CoastedFrames(*o) == 0 &&
        LateralAcceleration(*o, measured, ctx.dt) > options_.max_lateral_acceleration_mps2) {
      ++report->stats.beyond_grip;
      return coast();
    }
    if (!FilterStep(*o, o->joint, initial, predicted_covariance, &*est)) {
      // A turn's onset (manoeuvre_angular_acceleration_sigma_radps2). A step
      // that fails this gate too coasts with the wider covariance, so that
      // the next step is gated as a possible turn as well.
      const double manoeuvre = options_.manoeuvre_angular_acceleration_sigma_radps2;
      bool passed = false;
      if (manoeuvre > 0.0 && o->twist_covariance_valid &&
          !ReversesTurn(*o, initial, measured, ctx.dt)) {
        // (A step under the young car's zero-turn prior reads less turn
        // than the car makes: it shows no end of a turn.)
        predicted_covariance += ManoeuvreNoise(
            *o, initial, ctx.dt, !young && EasesTheTurn(*o, initial, measured, ctx.dt));
        passed = FilterStep(*o, o->joint, initial, predicted_covariance, &*est);
        if (passed) ++report->stats.manoeuvres;
      }
      if (!passed) {
        if (options_.restart_filter_after_refusals <= 0 ||
            est->sigma_px > options_.max_step_sigma_px ||
            CoastedFrames(*o) < options_.restart_filter_after_refusals) {
          return coast();
        }
        // The filter lags: the step stands as measured, and the filter
        // starts again from it.
        o->twist_covariance_valid = false;
        est->covariance_valid = false;
        ++report->stats.filter_restarts;
      }
    }
  }

  if (options_.stationary_after_frames > 0 && ctx.dt > 0.0) {
    const int dof = static_cast<int>(ProjectorRangeBasis(projector).cols());
    const bool significant =
        dof > 0 &&
        TwistSignificance(camera_, f.camera_from_world, o->world_from_object, *est, obs) >=
            ChiSquareQuantile(dof, options_.stationary_confidence);
    const double speed =
        PointVelocity(est->twist, o->world_from_object.translation()).norm() / ctx.dt;
    if (o->stationary && significant && options_.stationary_max_leave_speed_mps > 0.0 &&
        speed > options_.stationary_max_leave_speed_mps) {
      return coast();  // no car starts that fast: a failed measurement
    }
    // A held object's step that would start it.
    const bool starts =
        o->stationary && significant && speed >= options_.stationary_leave_speed_mps;
    if (starts && est->num_inliers < options_.stationary_min_leave_support * o->last_num_inliers) {
      return coast();  // a start seen by a few points only: an occlusion
    }
    if (starts && options_.stationary_max_leave_curvature_per_m > 0.0 &&
        est->twist.tail<3>().norm() >
            options_.stationary_max_leave_curvature_per_m * speed * ctx.dt +
                options_.stationary_leave_turn_slack_rad) {
      return coast();  // no car turns that sharply as it pulls away
    }
    if (o->stationary) {
      o->stationary = !starts;
      o->insignificant_steps = o->stationary ? o->insignificant_steps + 1 : 0;
    } else {
      // Still: slow, or insignificant on good matches. Moving: significant
      // and not slow. Otherwise (insignificant on poor matches) the step
      // shows nothing and the count stands.
      const bool slow = speed < options_.stationary_enter_speed_mps;
      const bool good_matches = options_.stationary_max_still_sigma_px <= 0.0 ||
                                est->sigma_px <= options_.stationary_max_still_sigma_px;
      if (slow || (!significant && good_matches)) {
        ++o->insignificant_steps;
      } else if (significant) {
        o->insignificant_steps = 0;
      }
      o->stationary = o->insignificant_steps >= options_.stationary_after_frames;
    }
    if (o->stationary) {
      est->twist.setZero();
      est->world_from_object = o->world_from_object;
    }
  }

  o->world_from_object = est->world_from_object;
  o->twist_step = est->twist;
  o->step_seconds = ctx.dt;
  o->twist_covariance_valid = filtered && !o->stationary && est->covariance_valid;
  o->twist_covariance = o->twist_covariance_valid ? est->covariance : Matrix6d::Zero();
  RecordInliers(ctx, det, *est, obs, obs_point, o);
  return true;
}

bool ObjectTracker::Reacquire(const FrameContext& ctx,
                              const ObjectDetectionInput& det,
                              TrackedObject* o,
                              double* score,
                              StepReport* report) const {
  const ObjectFrameInput& f = ctx.frame;
  const double steps = StepsSinceSeen(f, *o);
  const joints::Joint joint = EffectiveJoint(det.joint);
  const Matrix6d projector = joint.WorldProjector();
  const Vector6d initial = projector * (steps * o->twist_step);
  const SE3d predicted = SE3d::Exp(initial) * o->world_from_object;
  const SE3d camera_from_object = f.camera_from_world * predicted;
  if (BeyondTrackingRange(camera_from_object)) return false;
  // Predicted box from the projected points.
  double x0 = 1e18, y0 = 1e18, x1 = -1e18, y1 = -1e18;
  int in_front = 0;
  std::vector<Eigen::Vector3d> pts;
  std::vector<cv::Mat> descs;
  for (const ObjectPoint& p : o->points) {
    pts.push_back(p.point_in_object);
    descs.push_back(p.descriptor);
    Eigen::Vector2d uv;
    if (!camera_.ProjectChecked(camera_from_object * p.point_in_object, &uv, nullptr, 0.1))
      continue;
    ++in_front;
    x0 = std::min(x0, uv.x());
    y0 = std::min(y0, uv.y());
    x1 = std::max(x1, uv.x());
    y1 = std::max(y1, uv.y());
  }
  if (in_front == 0) return false;
  const cv::Rect2d box(x0, y0, x1 - x0, y1 - y0);
  const double inter = (box & det.box).area();
  const double iou = inter > 0 ? inter / (box.area() + det.box.area() - inter) : 0.0;
  ProjectionSearchOptions search = options_.search;
  search.radius_px *= options_.reid_radius_scale;
  const std::vector<int> match = SearchByProjection(camera_,
                                                    camera_from_object,
                                                    pts,
                                                    descs,
                                                    std::vector<bool>(pts.size(), false),
                                                    f.keypoints,
                                                    search);
  std::vector<TwistObservation> obs;
  std::vector<size_t> obs_point;
  int with_descriptor = 0;
  for (size_t k = 0; k < pts.size(); ++k) {
    with_descriptor += descs[k].empty() ? 0 : 1;
    if (match[k] < 0) continue;
    const size_t kp = static_cast<size_t>(match[k]);
    if (!InsideDetection(det, f.keypoints.uv[kp], 2.0)) continue;
    TwistObservation t;
    t.point_in_object = pts[k];
    if (options_.model_point_noise) t.point_sigma_in_object = o->points[k].sigma_in_object;
    t.uv = f.keypoints.uv[kp];
    t.u_right = ObjectStereo(ctx, det, kp);
    t.disparity_noise_ratio = StepDisparityNoiseRatio(StereoLevelScale(f.keypoints, kp));
    obs.push_back(t);
    obs_point.push_back(k);
  }
  const double appearance =
      with_descriptor > 0 ? static_cast<double>(obs.size()) / with_descriptor : 0.0;
  *score = 0.5 * iou + 0.5 * appearance;
  if (*score < options_.reid_min_score ||
      static_cast<int>(obs.size()) < options_.min_points_to_track) {
    return false;
  }
  absl::StatusOr<TwistEstimate> est = EstimateObjectTwist(
      camera_,
      f.camera_from_world,
      o->world_from_object,
      projector,
      obs,
      initial,
      options_.estimator,
      // Seen again, it has the young prior (unseen_turn_prior_poses).
      TurnPrior(joint,
                std::max(1.0, steps) * ctx.dt,
                options_.unseen_turn_prior_poses > 0 ? options_.young_turn_rate_sigma_radps
                                                     : options_.turn_rate_sigma_radps));
  // A residual scale no tracked step may have (max_step_sigma_px): the
  // matches do not agree on a motion.
  if (!est.ok() || !est->success || est->sigma_px > options_.max_step_sigma_px) return false;
  const double n = std::max(1.0, steps);
  if (options_.gate_reacquisition && options_.acceleration_sigma_mps2 > 0.0 &&
      o->twist_covariance_valid && !o->stationary && o->step_seconds > 0.0) {
    // The motion over the gap is predicted as n steps of the last one: its
    // covariance n² P, plus a random acceleration held over the gap (n³ q).
    const Matrix6d predicted_covariance =
        projector * (n * n * o->twist_covariance) * projector.transpose() +
        n * n * n * ProcessNoise(*o, o->step_seconds);
    if (!FilterStep(*o, joint, initial, predicted_covariance, &*est)) {
      report->gate_refused.push_back(o->id);
      return false;
    }
  }
  o->joint = joint;
  o->world_from_object = est->world_from_object;
  o->twist_step = est->twist / n;
  // The mean step over the gap, with its covariance: the next tracked step is
  // fused with it and gated (a re-acquisition's next step is as likely to
  // lock onto an occluder as any).
  o->twist_covariance_valid =
      options_.gate_after_reacquisition && est->covariance_valid && !o->stationary;
  o->twist_covariance =
      o->twist_covariance_valid ? Matrix6d(est->covariance / (n * n)) : Matrix6d::Zero();
  o->step_seconds = ctx.dt;
  RecordInliers(ctx, det, *est, obs, obs_point, o);
  return true;
}

double ObjectTracker::ContinuationFit(const FrameContext& ctx,
                                      const TrackedObject& lost,
                                      const TrackedObject& created,
                                      SE3d* predicted) const {
  const int64_t gap = ctx.frame.frame_index - lost.last_seen_frame;
  if (options_.max_continuation_gap_frames <= 0 || gap < 1 ||
      gap > options_.max_continuation_gap_frames || lost.class_id != created.class_id ||
      static_cast<int>(lost.history.size()) < options_.continuation_min_history ||
      lost.points.empty() || created.points.empty() || lost.history.back().observations.empty()) {
    return -1.0;
  }
  // The pose predicted over the gap, as for a re-acquisition.
  const Vector6d motion = lost.stationary
                              ? Vector6d::Zero()
                              : Vector6d(lost.joint.WorldProjector() *
                                         (StepsSinceSeen(ctx.frame, lost) * lost.twist_step));
  *predicted = SE3d::Exp(motion) * lost.world_from_object;
  // The box of the lost object's points, from the 5th to the 95th
  // percentile on each axis (a creation can leak a few background points).
  Eigen::Vector3d lo, hi;
  std::vector<double> axis(lost.points.size());
  const size_t n = axis.size();
  const size_t low = n / 20, high = n - 1 - n / 20;
  for (int a = 0; a < 3; ++a) {
    for (size_t k = 0; k < n; ++k) axis[k] = lost.points[k].point_in_object[a];
    std::nth_element(axis.begin(), axis.begin() + static_cast<std::ptrdiff_t>(low), axis.end());
    lo[a] = axis[low] - options_.continuation_margin_m;
    std::nth_element(axis.begin(), axis.begin() + static_cast<std::ptrdiff_t>(high), axis.end());
    hi[a] = axis[high] + options_.continuation_margin_m;
  }
  const SE3d lost_from_created = predicted->Inverse() * created.world_from_object;
  int inside = 0;
  for (const ObjectPoint& p : created.points) {
    const Eigen::Vector3d q = lost_from_created * p.point_in_object;
    inside += (q.array() >= lo.array()).all() && (q.array() <= hi.array()).all() ? 1 : 0;
  }
  return static_cast<double>(inside) / static_cast<double>(created.points.size());
}

void ObjectTracker::Continue(const SE3d& predicted,
                             TrackedObject* created,
                             TrackedObject* lost) const {
  const SE3d lost_from_created = predicted.Inverse() * created->world_from_object;
  std::unordered_map<int64_t, int64_t> new_id;
  lost->points.clear();
  for (ObjectPoint& p : created->points) {
    new_id[p.id] = lost->next_point_id;
    p.id = lost->next_point_id++;
    p.point_in_object = lost_from_created * p.point_in_object;
    p.sigma_in_object = lost_from_created.rotation() * p.sigma_in_object;
    p.patch_view_in_object = lost_from_created.rotation() * p.patch_view_in_object;
    lost->points.push_back(std::move(p));
  }
  lost->pending_observations.clear();
  for (ObjectPointObservation obs : created->pending_observations) {
    obs.point_id = new_id.at(obs.point_id);
    lost->pending_observations.push_back(obs);
  }
  // The motion over the gap is the prediction: the step and its covariance
  // stand, widened by the random acceleration of one step.
  lost->world_from_object = predicted;
  AdoptJoint(created->joint, lost);
  if (lost->twist_covariance_valid && lost->step_seconds > 0.0) {
    lost->twist_covariance += ProcessNoise(*lost, lost->step_seconds);
  }
  lost->class_id = created->class_id;
  lost->last_num_inliers = static_cast<int>(lost->points.size());
}

absl::StatusOr<std::vector<ObjectResult>> ObjectTracker::Process(const ObjectFrameInput& frame) {
  if (frame.left.empty() || frame.left.type() != CV_8UC1) {
    return absl::InvalidArgumentError("object tracker needs a CV_8UC1 left image");
  }
  if (frame.left.cols != camera_.width || frame.left.rows != camera_.height) {
    return absl::InvalidArgumentError(
        "left image is " + std::to_string(frame.left.cols) + "x" + std::to_string(frame.left.rows) +
        ", camera is " + std::to_string(camera_.width) + "x" + std::to_string(camera_.height));
  }
  if (!frame.right.empty() &&
      (frame.right.type() != CV_8UC1 || frame.right.size() != frame.left.size())) {
    return absl::InvalidArgumentError("the right image must be CV_8UC1 of the left image's size");
  }
  if (!frame.flow.empty() &&
      (frame.flow.type() != CV_32FC2 || frame.flow.size() != frame.left.size())) {
    return absl::InvalidArgumentError("flow must be CV_32FC2 with the size of the left image");
  }
  const FrameKeypoints& kps = frame.keypoints;
  if (kps.u_right.size() != kps.uv.size() ||
      (!kps.descriptors.empty() && (kps.descriptors.rows != static_cast<int>(kps.uv.size()) ||
                                    kps.descriptors.type() != CV_8UC1))) {
    return absl::InvalidArgumentError(
        "keypoints need one u_right per keypoint and one CV_8UC1 descriptor row per keypoint");
  }
  if (!kps.stereo_support_px.empty() && kps.stereo_support_px.size() != kps.uv.size()) {
    return absl::InvalidArgumentError(
        "keypoints' stereo_support_px must be empty or have one entry per keypoint");
  }
  if (has_prev_ && frame.timestamp_ns <= prev_timestamp_ns_) {
    return absl::InvalidArgumentError("object tracker timestamps must increase");
  }
  const double dt = has_prev_ ? (frame.timestamp_ns - prev_timestamp_ns_) * 1e-9 : 0.0;
  FrameContext ctx(frame, dt);
  stats_ = ObjectTrackerStats{};
  for (auto& [id, obj] : objects_) obj.pending_observations.clear();

  std::unordered_set<int64_t> handled;
  std::vector<const ObjectDetectionInput*> unmatched;
  // A cluster taken over by a re-identified or new object no longer leads
  // to the lost object that held it (it can still be re-identified).
  auto release_cluster = [&](int64_t cluster_id) {
    for (auto& [id, obj] : objects_) {
      if (obj.cluster_id == cluster_id) obj.cluster_id = kNoCluster;
    }
  };
  // An object seen on a detection in this frame.
  auto mark_seen = [&](const ObjectDetectionInput& det, TrackedObject* obj) {
    obj->instance_id = det.instance_id;
    obj->state = ObjectState::kTracked;
    obj->frames_lost = 0;
    obj->last_seen_frame = frame.frame_index;
    obj->last_box = det.box;
  };
  // Each detection whose cluster has an object steps that object (tracked
  // since the last frame: Track; else Reacquire).
  struct Step {
    const ObjectDetectionInput* det = nullptr;
    TrackedObject* o = nullptr;
    bool reacquiring = false;
    bool ok = false;
    StepReport report;
  };
  auto run_step = [&](Step* st) {
    TrackedObject* o = st->o;
    const ObjectDetectionInput& det = *st->det;
    if (!st->reacquiring) {
      UpdateJoint(det.joint, o);
      st->ok = Track(ctx, det, o, /*seed_from_detection=*/false, &st->report);
      // A new object's first step, predicted as no motion, found nothing
      // to measure: predicted from its detection's image motion instead.
      if (!st->ok && o->step_seconds == 0.0 && options_.seed_first_step_from_box) {
        st->ok = Track(ctx, det, o, /*seed_from_detection=*/true, &st->report);
      }
    } else {
      double score = 0.0;
      st->ok = Reacquire(ctx, det, o, &score, &st->report);
    }
  };
  auto finish_step = [&](const Step& st) {
    Merge(st.report, ctx);
    TrackedObject* o = st.o;
    if (st.ok) {
      o->class_id = st.det->class_id;
      mark_seen(*st.det, o);
      ++stats_.tracked;
      RecordPose(ctx, o);
    } else {
      handled.erase(o->id);  // aged below like an undetected object
      // A lost object that does not re-acquire the detection of its cluster
      // leaves it to the other lost objects and to creation: cluster ids
      // follow the segmentation's association, which can hand an object's
      // cluster to another instance after an occlusion.
      if (st.reacquiring) unmatched.push_back(st.det);
    }
  };
  // The step of the cluster's object not stepped yet (handled from now
  // on); none when the cluster has no such object.
  auto step_of = [&](const ObjectDetectionInput& det) -> std::optional<Step> {
    TrackedObject* o = nullptr;
    for (auto& [id, obj] : objects_) {
      if (obj.cluster_id == det.cluster_id && handled.count(id) == 0) o = &obj;
    }
    if (o == nullptr) return std::nullopt;
    handled.insert(o->id);
    return Step{&det, o, !(o->frames_lost == 0 && has_prev_), false, {}};
  };
  // The steps touch their own object only (and the frame's caches, made
  // ready below), so they may run side by side, and the results are the
  // same in any order; merged in the detections' order. That needs one
  // detection per cluster (a failed step hands its object back to the
  // detections after it), which the association gives.
  std::unordered_set<int64_t> clusters;
  bool parallel = options_.num_threads > 1 && frame.detections.size() > 1;
  for (const ObjectDetectionInput& det : frame.detections) {
    parallel = parallel && clusters.insert(det.cluster_id).second;
  }
  if (parallel && frame.flow.empty() && has_prev_) parallel = PrepareSparseFlow(ctx);
  if (!parallel) {
    for (const ObjectDetectionInput& det : frame.detections) {
      std::optional<Step> st = step_of(det);
      if (!st) {
        unmatched.push_back(&det);
        continue;
      }
      run_step(&*st);
      finish_step(*st);
    }
  } else {
    std::vector<Step> steps;
    std::vector<int> step_of_detection;
    for (const ObjectDetectionInput& det : frame.detections) {
      std::optional<Step> st = step_of(det);
      step_of_detection.push_back(st ? static_cast<int>(steps.size()) : -1);
      if (!st) continue;
      steps.push_back(*std::move(st));
      ctx.stereo_cache[det.cluster_id];  // each step's entry, made here
    }
    ParallelFor(steps.size(), options_.num_threads, [&](size_t i) { run_step(&steps[i]); });
    for (size_t d = 0; d < frame.detections.size(); ++d) {
      if (step_of_detection[d] < 0) {
        unmatched.push_back(&frame.detections[d]);
      } else {
        finish_step(steps[static_cast<size_t>(step_of_detection[d])]);
      }
    }
  }
  // Objects tracked up to the last frame whose cluster has no detection in
  // this one: the cluster association can give a car a new cluster (fast
  // image motion, a changed mask). They are offered the unmatched detections
  // like lost objects, before a new object is created on one.
  std::unordered_set<int64_t> detected_clusters;
  for (const ObjectDetectionInput& det : frame.detections) detected_clusters.insert(det.cluster_id);
  auto may_take = [&](const TrackedObject& obj) {
    return obj.state == ObjectState::kLost ||
           (options_.reidentify_undetected && detected_clusters.count(obj.cluster_id) == 0);
  };
  // A lost (or undetected) object takes an unmatched detection over.
  auto take_detection = [&](const ObjectDetectionInput& det, TrackedObject* obj) {
    release_cluster(det.cluster_id);
    obj->cluster_id = det.cluster_id;
    mark_seen(det, obj);
    handled.insert(obj->id);
    RecordPose(ctx, obj);
  };
  for (const ObjectDetectionInput* det : unmatched) {
    // Re-identification of a recently lost object of the same class.
    TrackedObject* best = nullptr;
    for (auto& [id, obj] : objects_) {
      if (handled.count(id) > 0 || obj.class_id != det->class_id || !may_take(obj) ||
          obj.cluster_id == det->cluster_id)
        continue;  // (the cluster's own object was tried above)
      double score = 0.0;
      StepReport report;
      const bool ok = Reacquire(ctx, *det, &obj, &score, &report);
      Merge(report, ctx);
      if (ok) {
        best = &obj;
        break;
      }
    }
    if (best != nullptr) {
      take_detection(*det, best);
      ++stats_.reidentified;
      continue;
    }
    TrackedObject o;
    o.id = next_object_id_;
    if (!Create(ctx, *det, &o)) continue;
    // A lost object whose predicted body holds the new structure continues
    // on it.
    TrackedObject* continued = nullptr;
    SE3d continued_pose;
    double best_fit = options_.continuation_min_inside;
    for (auto& [id, obj] : objects_) {
      if (handled.count(id) > 0 || !may_take(obj) || ctx.gate_refused.count(id) > 0) continue;
      SE3d predicted;
      const double fit = ContinuationFit(ctx, obj, o, &predicted);
      if (fit >= best_fit) {
        best_fit = fit;
        continued = &obj;
        continued_pose = predicted;
      }
    }
    if (continued != nullptr) {
      Continue(continued_pose, &o, continued);
      take_detection(*det, continued);
      ++stats_.continued;
      continue;
    }
    release_cluster(det->cluster_id);
    ++next_object_id_;
    handled.insert(o.id);
    ++stats_.created;
    RecordPose(ctx, &o);
    objects_.emplace(o.id, std::move(o));
  }
  for (auto it = objects_.begin(); it != objects_.end();) {
    TrackedObject& o = it->second;
    if (handled.count(o.id) > 0) {
      ++it;
      continue;
    }
    ++o.frames_lost;
    for (ObjectPoint& p : o.points) p.seen_last_frame = false;
    if (o.state != ObjectState::kLost) {
      o.state = ObjectState::kLost;
      ++stats_.lost;
    }
    if (o.frames_lost > options_.max_frames_lost) {
      ++stats_.removed;
      if (options_.max_removed_trajectories > 0) {
        removed_trajectories_.push_back(TrajectoryOf(o));
        while (static_cast<int>(removed_trajectories_.size()) > options_.max_removed_trajectories) {
          removed_trajectories_.pop_front();
        }
      }
      it = objects_.erase(it);
      continue;
    }
    ++it;
  }

  std::vector<ObjectResult> results;
  for (const auto& [id, o] : objects_) results.push_back(ToResult(o));
  prev_left_ = frame.left.clone();
  prev_left_pyramid_ = std::move(ctx.pyramid);  // empty when no object needed flow
  prev_timestamp_ns_ = frame.timestamp_ns;
  has_prev_ = true;
  prev_camera_from_world_ = frame.camera_from_world;
  return results;
}

}  // namespace twist::objects
