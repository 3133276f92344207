// Per-session tracker of dynamic objects (paper §IV-D/E).
//
// Every frame, for each object:
//  1. its points seen in the previous frame are followed by optical flow
//     (the client's dense field when the frame carries one, else pyramidal LK
//     seeded with the constant-velocity prediction);
//  2. the constrained twist is estimated (twist_estimator.h) from those 2D
//     (or stereo, when a stereo keypoint sits under the flow position)
//     observations;
//  3. the object's other points are projected with the estimated twist and
//     matched by descriptor (frame keypoints) or patch NCC, and the twist is
//     re-estimated with all matches;
//  4. world_from_object_i = Exp(Π ξ) · world_from_object_{i−1}; new stereo
//     keypoints inside the object's mask become new object points.
// Detections without an object first try to re-identify a recently lost
// object of the same class (predicted pose + appearance), otherwise a new
// structure is triangulated from stereo. It continues a recently lost object
// whose predicted body holds it (the object keeps its id and motion, its
// points are replaced), or else makes a new object, with its frame at the
// points' centroid projected onto the joint plane and its axes aligned with
// the joint frame. Objects are new -> tracked -> lost -> removed.
//
// Plain-data in, plain-data out: the engine passes the camera pose of the
// frame (from static tracking), the gray left image, the frame's stereo
// keypoints, optional dense flow, and one entry per dynamic cluster detected
// in the frame with its resolved joint.
#pragma once

#include <Eigen/Core>
#include <cstdint>
#include <deque>
#include <map>
#include <opencv2/core.hpp>
#include <optional>
#include <vector>

#include "absl/status/status.h"
#include "absl/status/statusor.h"
#include "slam/common/frame_result.h"
#include "slam/geometry/se3.h"
#include "slam/geometry/stereo_camera.h"
#include "slam/joints/joint.h"
#include "slam/objects/flow_association.h"
#include "slam/objects/masked_stereo.h"
#include "slam/objects/projection_search.h"
#include "slam/objects/twist_estimator.h"

namespace twist::objects {

struct ObjectPoint {
  int64_t id = 0;  // unique within its object
  Eigen::Vector3d point_in_object = Eigen::Vector3d::Zero();
  // Its stereo depth noise (one σ) along the ray it was triangulated on, in
  // the object frame (TwistObservation::point_sigma_in_object).
  Eigen::Vector3d sigma_in_object = Eigen::Vector3d::Zero();
  cv::Mat descriptor;                                 // CV_8U row (may be empty)
  cv::Mat patch;                                      // CV_32F reference patch (may be empty)
  Eigen::Vector2d last_uv = Eigen::Vector2d::Zero();  // in the last frame it was seen
  bool seen_last_frame = false;
  int num_observations = 0;
  // Unit direction from the point to the camera when `patch` was taken, in
  // the object frame (ObjectTrackerOptions::patch_refresh_view_change_deg).
  Eigen::Vector3d patch_view_in_object = Eigen::Vector3d::Zero();
};

// A point of an object observed in one frame (an inlier of the estimate).
struct ObjectPointObservation {
  int64_t point_id = 0;
  Eigen::Vector2d uv = Eigen::Vector2d::Zero();
  double u_right = -1.0;  // < 0: mono
  // The disparity's noise as a multiple of the position's, as the step's
  // estimate weighed it (TwistObservation::disparity_noise_ratio); the
  // dynamic BA weighs the observation the same way. 0: not known (the rows
  // independent); unused for mono.
  double disparity_noise_ratio = 0.0;
};

struct ObjectPoseSample {
  int64_t frame_index = 0;
  int64_t timestamp_ns = 0;
  geometry::SE3d world_from_object;
  geometry::Vector6d twist_step = geometry::Vector6d::Zero();  // into this frame, world, per frame
  // The object was held stationary in this frame (its pose is the previous
  // frame's; the dynamic BA keeps such poses fixed).
  bool held = false;
  // The object's points observed in this frame (for the dynamic BA).
  std::vector<ObjectPointObservation> observations;
};

// One pose of an object's trajectory (ObjectTrajectory).
struct TimedObjectPose {
  int64_t frame_index = 0;
  int64_t timestamp_ns = 0;
  geometry::SE3d world_from_object;
};

// The whole trajectory of one object, as the dynamic BA last left it: the
// poses that fell out of its bounded `history`, then the history
// (ObjectTracker::Trajectories).
struct ObjectTrajectory {
  int64_t object_id = 0;
  int class_id = 0;
  int instance_id = 0;  // the last one seen
  int64_t cluster_id = 0;
  std::vector<TimedObjectPose> poses;  // oldest first
};

// TrackedObject::cluster_id of a lost object whose cluster was taken over by
// another object (cluster ids are >= 1).
inline constexpr int64_t kNoCluster = -1;

struct TrackedObject {
  int64_t id = 0;          // stable object id (own counter per tracker)
  int64_t cluster_id = 0;  // cluster currently associated (changes on re-identification)
  int class_id = 0;
  int instance_id = 0;
  ObjectState state = ObjectState::kNew;
  joints::Joint joint;
  geometry::SE3d world_from_object;
  // Constrained twist of the last step (world frame, one frame step) and its
  // duration in seconds (0 before the first step).
  geometry::Vector6d twist_step = geometry::Vector6d::Zero();
  double step_seconds = 0.0;
  // Covariance of twist_step after the last tracked step or re-acquisition
  // (the constant-velocity filter's state,
  // ObjectTrackerOptions::acceleration_sigma_mps2); invalid after creation,
  // while stationary, and after a re-acquisition without
  // gate_after_reacquisition.
  geometry::Matrix6d twist_covariance = geometry::Matrix6d::Zero();
  bool twist_covariance_valid = false;
  std::vector<ObjectPoint> points;
  int frames_lost = 0;
  int64_t last_seen_frame = 0;
  cv::Rect2d last_box;
  std::deque<ObjectPoseSample> history;  // most recent last, bounded
  // The poses that left `history` (oldest first), so that the object's whole
  // trajectory survives; bounded by ObjectTrackerOptions::max_trajectory_poses.
  std::deque<TimedObjectPose> settled_poses;
  int64_t next_point_id = 1;
  // Observations of the current frame, moved into the history by RecordPose.
  std::vector<ObjectPointObservation> pending_observations;
  // Consecutive steps whose twist was statistically insignificant, and
  // whether the object is currently held stationary (see
  // ObjectTrackerOptions::stationary_after_frames).
  int insignificant_steps = 0;
  bool stationary = false;
  // Diagnostics of the last estimate.
  int last_num_inliers = 0;
  double last_sigma_px = 0.0;
};

// One dynamic cluster detected in the current frame.
struct ObjectDetectionInput {
  int64_t cluster_id = 0;
  int class_id = 0;
  int instance_id = 0;
  cv::Rect2d box;
  cv::Mat mask;  // optional CV_8UC1 full-image mask (non-zero inside)
  // The cluster's joint resolved from its parent (joint_frames.h); a free
  // joint when unknown. Ignored (free) when the tracker runs unconstrained.
  joints::Joint joint;
};

struct ObjectFrameInput {
  int64_t frame_index = 0;
  int64_t timestamp_ns = 0;
  geometry::SE3d camera_from_world;
  cv::Mat left;              // CV_8UC1
  cv::Mat right;             // optional CV_8UC1 rectified right image (masked object stereo)
  cv::Mat flow;              // optional CV_32FC2 previous-left -> this-left
  FrameKeypoints keypoints;  // stereo keypoints of the left image (u_right < 0: mono)
  std::vector<ObjectDetectionInput> detections;
};

struct ObjectTrackerOptions {
  TwistEstimatorOptions estimator;
  SparseFlowOptions flow;
  ProjectionSearchOptions search;
  // A point's reference patch (the template of the patch search) is taken
  // again once the view of the point has turned by more than this angle
  // since it was taken (the direction from the point to the camera, in the
  // object frame), centred where the step's estimate projects the point, if
  // that is within patch_refresh_max_offset_px of where it was found (else
  // the point or the match is off, and the old patch stays). 0: the patch
  // of the point's creation stays (the default). Taken once, the patch of a
  // turning car's point is matched on a view that turns away from it: at 5°
  // the rendered turning cars' rotation error per step went from 0.464 to
  // 0.376° (true camera poses) and their online RPE_R from 0.481 to 0.450
  // °/m, but the 24 rendered runs' ATE from 0.0965 to 0.1000 m, and at 10°
  // to 0.1103 m: a refreshed patch kept cars tracked through frames where
  // they went wrong (docs/objects.md §43). Centred on the match instead of
  // the estimate, refreshed at every match: ATE 0.1231 m (a drift).
  double patch_refresh_view_change_deg = 0.0;
  double patch_refresh_max_offset_px = 1.0;
  // Reference patches keep only the pixels on the object's mask (the others
  // NaN), and the patch search correlates only the pixels on the object in
  // both views (MaskedPatchSearch): a patch near the car's outline otherwise
  // follows the still background and the sliding silhouette. A patch with
  // less than search.min_masked_patch_share of its pixels on the mask stays
  // whole and is searched plainly. 24 runs: ATE 0.096 → 0.088 m
  // (`follow_braking` 0.104 → 0.086), RPE_R 0.151 → 0.165 °/m,
  // `stationary_then_accelerating` 0.093 → 0.108 m (docs/objects.md §44,
  // §46). Off: the plain patches.
  bool masked_patches = true;
  bool constrained = true;  // false: every object is a free 6-DoF body
  // A planar object is created with its origin on its parent plane, and its
  // steps keep it there. When the parent plane is refitted, a moving object
  // follows it: before the step, its origin is moved along the new normal
  // onto the new plane (its orientation is kept: turning it with every refit
  // of the normal adds rotation noise). Its height above the road then stays
  // what the stereo measured at creation, relative to the plane the camera
  // sees now, and the depth that the planar joint reads from a car's image
  // height does not drift with the camera's height estimate. A held
  // (stationary) object is not moved. On by default since the object stage
  // measures the plane points' disparities on the plane's own mask
  // (ObjectStageOptions::masked_plane_stereo): the camera's height estimate
  // drifts by ~1 cm along a run, and the plane then follows it closely
  // enough for the cars to gain (24 runs: moving ATE 0.137 -> 0.128 m,
  // `follow_braking` 0.162 -> 0.127 m; docs/objects.md §37). Off, or on
  // with the matcher's disparities, the plane's refit-to-refit noise moved
  // the cars more than the drift did (§26).
  bool follow_parent_plane = true;
  int min_points_to_create = 8;
  int min_points_to_track = 5;
  // A tracked step with fewer inliers is refused (the object coasts on its
  // prediction): on intersection seeds 2 and 6 far crossing cars stepped on
  // 4-5 of 13-20 observations and ran off by 5 m (docs/objects.md §26).
  int min_step_inliers = 8;
  int max_points_per_object = 300;
  // When an object holds max_points_per_object points, the points it has not
  // observed in its last evict_unseen_frames frames make room for new ones
  // (0: never). Without it a long-tracked car stops taking points once full,
  // and loses track when the camera comes to see other faces of it
  // (docs/objects.md §23).
  int evict_unseen_frames = 5;
  double max_depth_m = 60.0;        // triangulated points further away are dropped
  double max_depth_spread_m = 4.0;  // around the object's median depth
  // An object is created only once its stereo structure is usable: the depth
  // noise at its median depth, z² σ_d / (f b), must not exceed
  // max_create_depth_sigma_m (σ_d = disparity_sigma_px). One stereo frame of
  // a car 40 m away gives ±1.3 m along the rays (measured on the synthetic
  // scenes, σ_d ≈ 0.3 px), and a structure that poor biases every later step.
  // 0.8 m (about 32 m on KITTI's rig) keeps the coverage of the frames where
  // a car shows >= 2000 mask pixels (`driving`: 0.881; 0.5 m: 0.837 for
  // somewhat better accuracy). <= 0: no limit.
  double max_create_depth_sigma_m = 0.8;
  // An object is tracked only while the depth noise at its origin,
  // z² σ_d / (f b) for level-0 stereo, is at most this: 0.8 m, the creation
  // bound, is ≈ 32 m on KITTI's rig. Beyond, a car's steps are not
  // measured well enough to follow it: on the rendered scenes a car receding
  // from 35 to 45 m drifted by 4 m along the rays (docs/objects.md §14), in
  // frames that show under 2000 mask pixels. The object is lost instead, and
  // re-identified or created again if it comes closer. (1.2 m, ≈ 40 m, until
  // the stationary_then_accelerating runs of seeds 2 and 3 showed the same
  // drift from 36 to 40 m: moving ATE over 12 runs 0.380 -> 0.276 m, other
  // figures level; §17. 1.0 m, ≈ 36 m, until the far cars of
  // stationary_then_accelerating seeds 2, 4 and 6 were found to add 0.02-0.06
  // m of ATE to their runs beyond 32 m: moving ATE over the 24 runs 0.137 ->
  // 0.133 m, coverage 0.9025 -> 0.9023; §37.) 0: no limit.
  double max_track_depth_sigma_m = 0.8;
  double disparity_sigma_px = 0.3;  // on level 0
  // The depth noise above is the median over the points of z² σ_d s / (f b),
  // with s the scale of each keypoint's pyramid level: the stereo matcher
  // refines on that level, and the depth spread of car keypoints grows with
  // it (25-33 m: MAD 1.7 % on level 0, 3.7-5 % on levels 4-7; docs/objects.md
  // §11). s = FrameKeypoints::stereo_support_px / stereo_level0_half_px (the
  // matcher's level-0 block half-size); 1 when the keypoints carry no support.
  // Against the flat σ_d, over 3 seeds x 4 scenarios: moving ATE −4 %, speed
  // error −7 %, RPE_R and parked speed level, coverage −1 point (§11).
  double stereo_level0_half_px = 5.5;
  double min_point_spacing_px = 3.0;
  double mask_erosion_px = 2.0;  // new points at least this far inside the mask
  // Object depths from the mask only (masked_stereo.h): when the frame
  // carries the right image, every stereo depth the tracker uses for an
  // object (creation, new points, stereo observations) is measured again on
  // level 0 with the block restricted to the detection's mask, of the
  // half-size of the matcher's block (FrameKeypoints::stereo_support_px, else
  // masked_stereo_default_half_px). The engine's matcher blocks straddle the
  // car and the background for most keypoints of a car 20-30 m away, which
  // biases their disparity (docs/objects.md §11). A keypoint whose masked
  // measurement fails is used as mono (no point created from it).
  // The masked depths are 3-4x more accurate against the renderer
  // (objects_masked_stereo_test). On by default since the manoeuvre gate
  // (docs/objects.md §32): the object rotation errors that kept it off
  // (§11, §31) were turns whose onset the filter refused.
  bool masked_stereo = true;
  // When the masked measurement fails (too few mask pixels in the window,
  // no texture, weak correlation): true keeps the matcher's depth, false
  // uses the keypoint as mono.
  bool masked_stereo_keep_unmeasured = false;
  double masked_stereo_default_half_px = 5.5;
  MaskedStereoOptions masked_stereo_options;
  double stereo_lookup_px = 1.5;  // flow position -> stereo keypoint
  // A point measured at a position with no stereo keypoint near it (flow,
  // patch search) gets its disparity measured on the images there
  // (MaskedDisparity on the detection's mask, needs masked_stereo and the
  // right image), searched around the disparity its predicted depth gives,
  // ± max(masked_stereo_options.search_px, tracked_stereo_search_fraction of
  // it). Without it most of a step's observations were mono (16-42 % had
  // stereo on the generated scenes), so a step's depth rested on the image
  // size of a structure whose points are replaced as the car recedes, and it
  // drifted: an overtaking car was 4 % too far or too near after 30 m
  // (docs/objects.md §33).
  bool measure_tracked_stereo = true;
  double tracked_stereo_search_fraction = 0.05;
  // A step's stereo observation carries its disparity's own noise:
  // disparity_sigma_px × the scale of the level it was measured on (1 for a
  // disparity measured at a tracked point), relative to the estimator's
  // floor on a position's noise (estimator.min_sigma_px), as
  // TwistObservation::disparity_noise_ratio; the twist estimator whitens
  // u_right = u − d under that correlation. Without it, u_right counted as
  // an independent measurement with the position's noise (0.7-1 px), so the
  // depth of a step rested mostly on the image size of the structure. Over
  // the 24 generated runs: moving ATE 0.182 -> 0.168 m, RPE_R 0.194 -> 0.174
  // °/m, speed error 0.586 -> 0.554 km/h, coverage 0.900 -> 0.902
  // (docs/objects.md §34).
  bool step_disparity_noise = true;
  // In a step that brings the object nearer to the camera, each disparity's
  // noise ratio above is scaled by 1 / (1 + approaching_growth_time_s · g),
  // g the rate at which the object's image grows (its closing speed over its
  // range, from the camera's previous pose to its predicted pose from the
  // current one; 1 / the time to contact), and by no less than
  // approaching_disparity_noise_scale: the disparities weigh more against
  // the image positions. The positions of a car whose image grows from frame
  // to frame read it nearer than it is: under the true camera poses, cars
  // first seen 20-30 m away and coming closer were 1 cm per frame too near
  // over their first frames, however exact their creation depth, and
  // weighting the disparity less made it worse (docs/objects.md §53). Not
  // for a receding car: there the same weight made the cars driving away
  // from a still camera drift further. A rate rather than a switch on the
  // sign of the closing speed: a car followed at a range that holds would
  // flip its step's weights on noise. 0: off, the default: on the rendered
  // streets 1.25 brings the cars' ATE from 0.092 to 0.087 m, but where the
  // disparities carry exactly the model's noise (the synthetic cars) the
  // weight is too much and the filter's gate refuses steps and loses cars;
  // the visible coverage drops a little on the rendered streets too
  // (docs/objects.md §54).
  double approaching_growth_time_s = 0.0;
  double approaching_disparity_noise_scale = 0.5;
  int max_frames_lost = 10;  // re-identification window, then removed
  double reid_min_score = 0.3;
  // Whether an object tracked up to the last frame whose cluster has no
  // detection in this one may re-acquire an unmatched detection in the same
  // frame (as a lost object may), before a new object is created on it.
  // (On 4 scenarios x 3 seeds: visible coverage 0.860 -> 0.871; without it
  // such a car was lost and a duplicate created on the same frame, e.g. one
  // oncoming car of `driving` seed 2 split over 4 tracks.)
  bool reidentify_undetected = true;
  // The constant-velocity filter across a re-acquisition (docs/objects.md
  // §16). gate_reacquisition: the motion over the gap must pass the filter's
  // gate against n steps of the last twist (covariance n² P plus the random
  // acceleration over the gap, n³ q); a refused re-acquisition leaves the
  // object lost and the detection to the other lost objects and creation.
  // gate_after_reacquisition: the mean step over the gap and its covariance
  // seed the filter, so the next tracked step is fused and gated too (it was
  // taken as measured).
  bool gate_reacquisition = true;
  bool gate_after_reacquisition = true;
  double reid_radius_scale = 4.0;  // search radius multiplier after a loss
  // Continuation (docs/objects.md §24): a detection that no object
  // re-acquires, and on which a new object would be created, continues a lost
  // object instead when the new structure lies on that object's predicted
  // body: at least continuation_min_inside of the new points fall inside the
  // box of its points (in its frame, at the pose predicted over the gap),
  // grown by continuation_margin_m. The object then keeps its id and motion;
  // its points are replaced by the new ones, placed with the predicted pose.
  // Only objects lost for at most max_continuation_gap_frames frames (0:
  // never), with continuation_min_history recorded poses (a motion to predict
  // from), and whose last recorded step was measured (not coasted: an object
  // lost on steps its filter refused has a motion that is not to be trusted)
  // qualify. Re-acquisition fails where the old points cannot be
  // matched: another face of the car, or a part of it that an occluder left.
  int max_continuation_gap_frames = 5;
  int continuation_min_history = 3;
  double continuation_margin_m = 0.5;
  double continuation_min_inside = 0.8;
  // The first step of a new object has no motion to predict from: it is
  // predicted as no motion, and when that finds nothing to measure (too few
  // flow tracks and matches for an estimate), it is tried again predicted
  // from its detection: the shift of the detection box's centre since the
  // object was created, beyond the shift the camera's own motion gives its
  // points, as a translation across the view at the points' median depth
  // (projected onto the joint). A car crossing the view 20-25 m away
  // (25-30 px per frame) was otherwise found by neither the flow nor the
  // projection search, and on `intersection` such cars were created and
  // lost again frame after frame (docs/objects.md §28). Not the first try:
  // the box of a car cut by the image border or an occluder moves without
  // it (seeding every first step raised the parked cars' speed error).
  bool seed_first_step_from_box = true;
  bool refine_by_projection = true;
  // With refine_by_projection: the observations of the final estimate are the
  // keypoint (descriptor) and patch matches of all the object's points, found
  // around their projection with the flow estimate; flow only predicts. Flow
  // chained from frame to frame drifts, and on a surface seen more and more
  // obliquely it drifts the same way for all points: on the synthetic
  // `driving` scene, parked cars then "moved" at 1-3 km/h and approaching cars
  // turned by 10-30°. false: flow positions are kept and only the points flow
  // lost are searched. The flow estimate is the fallback when too few
  // matches are found.
  bool measure_by_matching = true;
  // The matched estimate is kept only if at least this share of the flow
  // inliers lies within flow_agreement_px of its projections.
  double flow_agreement_px = 4.0;
  double flow_agreement_ratio = 0.5;
  int max_history = 300;
  // The trajectories kept for Trajectories(): at most this many poses per
  // object (oldest dropped; 18000 = 30 min at 10 Hz), and the trajectories of
  // at most this many removed objects (oldest removal dropped).
  int max_trajectory_poses = 18000;
  int max_removed_trajectories = 500;
  // Threads the steps of a frame's objects run on (each object's step
  // touches that object only; the results are the same for any value, the
  // steps merged in the detections' order). 2: the tracking thread and one
  // more, on the second core of the 2-core machines the service runs on,
  // where the other work there is the background mapper at low priority.
  int num_threads = 2;
  // Stationarity (parked cars). A step is "still" when the zero twist
  // explains the inlier observations about as well as the estimate,
  //   Σ ‖r_j(0)/σ‖² − Σ ‖r_j(ξ*)/σ‖² < χ²_k(stationary_confidence),
  // k = rank(Π) (likelihood-ratio test, σ the estimate's MAD scale), or when
  // the speed of the step is below stationary_enter_speed_mps (the tracker's
  // bias floor: a parked car 20-40 m away otherwise "moves" at 1-3 km/h on
  // the synthetic scenes). After stationary_after_frames still steps in a
  // row the object is stationary: its twist is zero and its pose is held.
  // It moves again at the first step that is significant and faster than
  // stationary_leave_speed_mps; steps are then measured from the held pose,
  // so a slow start accumulates until it is detected. 0 frames: off.
  // (2 frames / 0.8 m/s: parked speed error 1.2 / 0.7 / 0.4 / 0.5 km/h on
  // driving / follow_braking / intersection / stationary_then_accelerating,
  // against 1.4 / 0.9 / 0.7 / 0.7 with 3 frames / 0.6 m/s.)
  int stationary_after_frames = 2;
  // Constant-velocity filter on the twist (docs/objects.md §13). Each
  // tracked step's estimate (with its Gauss–Newton covariance) is fused with
  // the prediction, the previous step's twist whose covariance grows by the
  // process noise of a random acceleration at the object's origin:
  // acceleration_sigma_mps2 (linear) and angular_acceleration_sigma_radps2.
  // A step whose innovation fails the χ² test at filter_gate_confidence, or
  // whose residual scale (MAD) exceeds max_step_sigma_px, is a failed
  // measurement (occlusion, flow on the occluder, too few points), not a
  // car's motion: the object coasts on its prediction for that frame (no
  // observation kept; the next frame searches its points from the
  // prediction), at most max_coast_frames frames in a row, then it is lost
  // and re-acquired. Not applied to stationary objects (their start has its
  // own test, below). acceleration_sigma_mps2 = 0: off.
  double acceleration_sigma_mps2 = 4.0;
  double angular_acceleration_sigma_radps2 = 0.5;
  // A car entering a turn (docs/objects.md §32). Its rate of turn jumps
  // within a frame or two (the generator's turning cars: 0 -> 0.7 rad/s, an
  // angular acceleration of ~4 rad/s^2, 7 sigma of the process noise above),
  // so its first turning steps failed the gate and coasted straight, and the
  // track kept the missed ~10 deg of heading for good. A step that fails the
  // gate is tested again against the prediction whose rate of turn may also
  // change by this angular acceleration (added to the process noise, about
  // the object's origin: it moves no point of the car sideways); it is a
  // manoeuvre and is fused with that covariance when it passes. A step that
  // shifts the car sideways or along its way still coasts. 0: off.
  double manoeuvre_angular_acceleration_sigma_radps2 = 4.0;
  // A car's rate of turn changes about its rear axle, and the tracker's origin
  // (its first points' centre, on the road) lies ahead of or behind the axle: at
  // the origin the end of a turn is also a sideways change of velocity, rate
  // change x offset (0.07 rad x 2 m per frame), which the noise above, about the
  // origin, does not hold. A car of `turning_traffic` seed 4 turning at 4.5° per
  // frame had its straight steps after the turn refused (χ² 16.7 against 16.3)
  // and coasted on with the turn until it was lost (docs/objects.md §66). A step
  // that eases the turn (turning less than the prediction, which turns faster
  // than manoeuvre_lever_arm_min_turn_radps) is tested with sideways noise of
  // this arm added to the manoeuvre's. A step that tightens or starts a turn gets
  // none (on the young, poorly seen car of `turning_traffic` seed 5 that let
  // wrong steps through), nor one under the young car's zero-turn prior, which
  // reads less turn than the car makes. 0: off.
  double manoeuvre_lever_arm_m = 2.0;
  double manoeuvre_lever_arm_min_turn_radps = 0.175;
  // A step that reverses the turn, turning one way at more than this rate
  // (rad/s, about the joint's normal) when the prediction turns the other
  // way at more than it too, is not a manoeuvre: no car swings from a left
  // turn into a right one within a frame. With masked_patches, a car of
  // `turning_traffic` seed 3 turning at +4.9° per frame was measured at
  // −2.1°, passed as a manoeuvre, and kept 0.4 m aside (docs/objects.md
  // §46). 0: off.
  double manoeuvre_max_reversal_turn_radps = 0.175;
  // A filtered step of a planar object whose turn would take more lateral
  // acceleration than this (the rate of turn about the joint's normal times
  // the speed of the object's origin, m/s²) coasts: no tyre holds a car in
  // a turn beyond about 1 g, and the generator's tightest turns take 5.5
  // m/s² (turning_traffic, 0.78 rad/s at 7 m/s). A car crossing 43 m ahead
  // at 9 m/s (`intersection` 3, background mapping) was followed into a
  // spin of 10° per frame, 16 m/s², that the gate took for a manoeuvre and
  // the next steps for its continuation (docs/objects.md §61). Not applied
  // to the step after a coasted frame (it also corrects the prediction that
  // stood; restart_filter_after_refusals). 0: off.
  double max_lateral_acceleration_mps2 = 10.0;
  // The twist of an object with its points' own stereo errors (errors in
  // variables, TwistObservation::point_sigma_in_object; docs/objects.md §27):
  // each point's depth along its creation ray is estimated with the twist.
  // A crossing car then no longer turns with its bearing (24 straight-driving
  // runs: RPE_R 0.306 -> 0.217 °/m with turn_rate_sigma_radps 0.1), but the
  // cars of `turning_traffic` (the generator's only turning ones) are
  // tracked far worse (coverage 0.87 -> 0.54, RPE_R 1.4 -> 3.1 °/m): off
  // until that is understood.
  bool model_point_noise = false;
  // A zero-mean prior on a planar object's rate of turn about its joint's
  // axis, fused with every tracked step as a residual of the solve (σ in
  // rad/s). Cars mostly drive straight, and with model_point_noise the data
  // alone let a few short fragments spin at 30° per frame. It lags real
  // turns: a car turning at 0.2 rad/s is followed with 0.47 m of error over
  // 20 frames instead of 0.15 m. <= 0: no prior (default).
  double turn_rate_sigma_radps = 0.0;
  // The same prior, with this sigma, on the steps of a young object (fewer
  // than young_turn_prior_poses poses), and none after that unless
  // turn_rate_sigma_radps is set (docs/objects.md §32). A new car seen from
  // behind barely shows its yaw, and its first free steps could spin it by
  // ~30 deg; the constant-velocity filter then predicted the spin. 0: off.
  double young_turn_rate_sigma_radps = 0.1;
  int young_turn_prior_poses = 3;
  // A young object's step (by age, young_turn_prior_poses) is estimated
  // without that prior too, and the free estimate is taken when it shows a
  // turn clearly: its rate of turn about the joint's axis exceeds
  // young_turn_release_sigmas of its own standard deviations, it rests on
  // at least young_turn_release_min_inliers inliers (its covariance holds no
  // structure noise and is over-confident on a few points), and it turns no
  // tighter than young_turn_release_max_curvature_per_m (rate of turn <=
  // curvature · the origin's speed + 0.01 rad per frame). A car first seen
  // in a turn was otherwise held back to a third of its turn, or none of
  // it, in its first step (docs/objects.md §56). A car pulling away from a
  // stop keeps its prior (starting_turn_prior_poses): seen from behind, its
  // free steps passed this test on noise. 0 sigmas: off.
  double young_turn_release_sigmas = 6.0;
  int young_turn_release_min_inliers = 20;
  double young_turn_release_max_curvature_per_m = 0.3;
  // The young prior also holds for the first starting_turn_prior_poses
  // poses of an object that moves again after the tracker held it
  // stationary: a car pulling away from a stop, seen from behind, barely
  // shows its yaw either, and its steps start from rest. The lead car of
  // `stationary_then_accelerating` seed 5 turned by 7-9° per frame four
  // frames after it started and was lost 10 frames later (docs/objects.md
  // section 40). 0: off.
  int starting_turn_prior_poses = 15;
  // The young prior also holds for the reacquiring step and the next
  // unseen_turn_prior_poses poses of an object that went unseen (a coasted
  // frame, or lost and reacquired): seen again, it is often partly
  // occluded and its few points show its yaw as poorly as a new car's. A
  // car crossing 46 m ahead (`intersection` 1), seen again after the car
  // crossing in front of it, turned by 2° per frame on a straight road
  // (docs/objects.md §64). 0: off.
  int unseen_turn_prior_poses = 3;
  double filter_gate_confidence = 0.999;
  double max_step_sigma_px = 4.0;
  int max_coast_frames = 3;
  // When the constant-velocity filter has refused the steps of the last
  // restart_filter_after_refusals frames (the object coasted) and refuses this
  // one too, although it rests on min_step_inliers or more inliers, the step
  // is taken as measured and the filter starts again from it (its covariance
  // is dropped) instead of the object coasting on towards being lost. 0:
  // never (default). The lead car of `stationary_then_accelerating` seed 6
  // accelerated at 2 m/s² while an overtaking car hid most of it (10 inliers
  // of 73 points); the filter's prediction fell 0.5 m behind, the steps
  // measured once the car showed again were refused, and the car was lost and
  // created again. With 2 it keeps its track, but on the 24 generated runs
  // the catch-up step and a young crossing car that took an 18-inlier step
  // after two refused 40- and 31-inlier ones cost more than the coverage
  // gained (measured with the camera-frame road plane on 15 frames):
  // coverage 0.900 -> 0.908, moving ATE 0.108 -> 0.115 m, RPE_R 0.162 ->
  // 0.178 °/m (docs/objects.md §38).
  int restart_filter_after_refusals = 0;
  double stationary_confidence = 0.99;
  double stationary_enter_speed_mps = 0.8;
  double stationary_leave_speed_mps = 1.2;
  // A step that the likelihood-ratio test finds insignificant but that is
  // faster than stationary_enter_speed_mps counts as still only when its
  // residual scale (MAD) is at most this: on a noisier step "insignificant"
  // says that the matches show nothing, not that the object stands, and
  // such a step leaves the count of still steps as it was. A car emerging
  // at 7 m/s from behind a building with a pedestrian in front of it
  // (`turning_traffic` seed 5) was measured at 0.9-1.2 m/s on steps of
  // 1.9 and 2.8 px, held stationary, and its filter then refused its true
  // speed until it had drifted 6 m behind (docs/objects.md §65). Slower
  // steps are still by their speed whatever their scale. 0: off (every
  // insignificant step is still).
  double stationary_max_still_sigma_px = 1.5;
  // A stationary object's step faster than this is a failed measurement, not
  // a start (a car at 4 m/s² reaches 1.2 m/s, the leave speed, within
  // 0.3 s): it coasts like a step refused by the filter's gate. On the
  // rendered scenes such steps came from parked cars leaving the image or
  // covered by passing ones, at 8-30 km/h. 0: no bound.
  double stationary_max_leave_speed_mps = 4.0;
  // A stationary object's step that would start it must rest on at least
  // this share of the inliers of its last accepted step; on fewer it is a
  // failed measurement and coasts (held). On the rendered scenes a
  // pedestrian crossing in front of a car stopped at a light left 8 of 29
  // inliers, on the occluder's edge, that "moved" the car sideways at
  // 1.7 m/s; it was then lost and tracked again as a new object. 0: off.
  double stationary_min_leave_support = 0.5;
  // A stationary object's step that would start it may turn by at most
  // stationary_max_leave_curvature_per_m × the distance it moves plus
  // stationary_leave_turn_slack_rad; one that turns more is a failed
  // measurement and coasts (held). No car turns 7° while it pulls away by
  // 0.13 m (a radius of 1 m); the lead car of
  // `stationary_then_accelerating` seed 4, 9 m ahead and seen from behind on
  // 10-20 inliers, was started by a step that turned it by −4.4° (7.2°
  // with an early version of masked_patches; docs/objects.md §45). The
  // bound (a radius of 3.3 m) holds for the cars; a pedestrian turning on
  // the spot as it starts stays held for the frame. 0: off.
  double stationary_max_leave_curvature_per_m = 0.3;
  double stationary_leave_turn_slack_rad = 0.01;

  absl::Status Validate() const;
};

struct ObjectTrackerStats {
  int tracked = 0;
  int created = 0;
  int reidentified = 0;
  int continued = 0;  // lost objects continued on a new structure
  int lost = 0;
  int removed = 0;
  int rejected = 0;         // steps that failed the filter's gate (coasted or lost)
  int manoeuvres = 0;       // steps that passed the gate only as a change of the rate of turn
  // Young steps' estimates taken free of the turn prior (a step is
  // estimated once or twice; young_turn_release_sigmas).
  int young_turns_released = 0;
  int filter_restarts = 0;  // refused steps taken as measured (restart_filter_after_refusals)
  int beyond_grip = 0;      // steps refused for their lateral acceleration

  ObjectTrackerStats& operator+=(const ObjectTrackerStats& o) {
    tracked += o.tracked;
    created += o.created;
    reidentified += o.reidentified;
    continued += o.continued;
    lost += o.lost;
    removed += o.removed;
    rejected += o.rejected;
    manoeuvres += o.manoeuvres;
    young_turns_released += o.young_turns_released;
    filter_restarts += o.filter_restarts;
    beyond_grip += o.beyond_grip;
    return *this;
  }
};

class ObjectTracker {
 public:
  ObjectTracker(const geometry::StereoCamera& camera, const ObjectTrackerOptions& options);

  // Processes one frame. InvalidArgument for malformed input (image type or
  // size, flow type); object tracking failures are states in the results.
  absl::StatusOr<std::vector<ObjectResult>> Process(const ObjectFrameInput& frame);

  const std::map<int64_t, TrackedObject>& objects() const { return objects_; }
  // The trajectory of every object, the removed ones (see
  // max_removed_trajectories) and the current ones, ordered by object id.
  std::vector<ObjectTrajectory> Trajectories() const;
  const ObjectTrackerStats& last_stats() const { return stats_; }
  // Lets the dynamic bundle adjustment write back refined poses and points.
  TrackedObject* mutable_object(int64_t id);

  // Everything that evolves from frame to frame (the camera and options come
  // from the configuration); SlamSystem::Save/Load persist it.
  struct State {
    std::map<int64_t, TrackedObject> objects;
    int64_t next_object_id = 1;
    cv::Mat prev_left;
    int64_t prev_timestamp_ns = 0;
    bool has_prev = false;
    // The camera's pose in the previous frame (approaching_growth_time_s);
    // none: taken as the current one's.
    std::optional<geometry::SE3d> prev_camera_from_world;
    ObjectTrackerStats stats;
    std::deque<ObjectTrajectory> removed_trajectories;  // oldest removal first
  };
  State GetState() const;
  void SetState(State state);

  // Converts a tracked object to the engine's per-frame result.
  static ObjectResult ToResult(const TrackedObject& object);
  // The object's whole trajectory (settled_poses, then history).
  static ObjectTrajectory TrajectoryOf(const TrackedObject& object);

 private:
  struct FrameContext;
  // The sparse flow's pyramids of the previous and this frame's left image
  // into ctx (SparseFlow builds them on first use); PrepareSparseFlow
  // builds them ahead of steps that run side by side, false if it cannot.
  absl::Status BuildFlowPyramids(const FrameContext& ctx) const;
  bool PrepareSparseFlow(const FrameContext& ctx) const;
  // Sparse flow of the points `prev_uv` of the previous left image into this
  // frame's, seeded at `predicted_uv` (TrackSparseFlow on the frame's shared
  // pyramids).
  absl::StatusOr<std::vector<std::optional<Eigen::Vector2d>>> SparseFlow(
      const FrameContext& ctx,
      const std::vector<Eigen::Vector2d>& prev_uv,
      const std::vector<Eigen::Vector2d>& predicted_uv) const;
  // What an object's step (Track, Reacquire) reports besides the object
  // itself: kept apart from the tracker, so that the steps of a frame's
  // objects can run side by side (ObjectTrackerOptions::num_threads), and
  // merged in the detections' order.
  struct StepReport {
    ObjectTrackerStats stats;  // the step's counts (added to stats_)
    // Objects whose re-acquisition the filter's gate refused
    // (FrameContext::gate_refused).
    std::vector<int64_t> gate_refused;
  };
  // Adds `report` to the frame's statistics and context.
  void Merge(const StepReport& report, const FrameContext& ctx);
  // A tracked step; a new object's first step (no motion yet) is predicted
  // as no motion, or with seed_from_detection from its detection
  // (FirstStepSeed).
  bool Track(const FrameContext& ctx,
             const ObjectDetectionInput& det,
             TrackedObject* object,
             bool seed_from_detection,
             StepReport* report) const;
  // Whether a young object's step estimated without the turn prior shows a
  // turn clearly (ObjectTrackerOptions::young_turn_release_sigmas).
  bool ShowsAYoungTurn(const TrackedObject& object, const TwistEstimate& free) const;
  // The lateral acceleration (m/s²) of a planar object's step `twist` (in
  // the world frame, over `seconds`): its rate of turn about the joint's
  // normal times the speed of its origin. 0 for other joints.
  double LateralAcceleration(const TrackedObject& object,
                             const geometry::Vector6d& twist,
                             double seconds) const;
  // The predicted first step of a new object (seed_first_step_from_box).
  geometry::Vector6d FirstStepSeed(const FrameContext& ctx,
                                   const ObjectDetectionInput& det,
                                   const TrackedObject& object) const;
  // The constant-velocity filter's update of a tracked step (see
  // acceleration_sigma_mps2): fuses `estimate` with the prediction
  // `predicted` in place and returns true, or returns false when the step
  // fails the gate. Both live in the subspace of `joint`'s projector: the
  // detection's joint, which at a re-acquisition is not yet the object's.
  bool FilterStep(const TrackedObject& object,
                  const joints::Joint& joint,
                  const geometry::Vector6d& predicted,
                  const geometry::Matrix6d& predicted_covariance,
                  TwistEstimate* estimate) const;
  // The zero-turn prior (turn_rate_sigma_radps, or sigma_radps) of a planar
  // object's motion over `seconds`; empty for other joints or a sigma <= 0.
  TwistPrior TurnPrior(const joints::Joint& joint, double seconds) const;
  TwistPrior TurnPrior(const joints::Joint& joint, double seconds, double sigma_radps) const;
  // The filter's process noise over one step of `dt` seconds: a random
  // acceleration (acceleration_sigma_mps2, angular_acceleration_sigma_radps2,
  // or the given sigmas) at the object's origin, as a change of its per-step
  // world twist projected onto its joint.
  geometry::Matrix6d ProcessNoise(const TrackedObject& object, double dt) const;
  geometry::Matrix6d ProcessNoise(const TrackedObject& object,
                                  double dt,
                                  double acceleration_sigma_mps2,
                                  double angular_acceleration_sigma_radps2) const;
  // The manoeuvre's extra process noise over a step of `dt` seconds
  // (manoeuvre_angular_acceleration_sigma_radps2, about the object's origin;
  // with `lever_arm`, also sideways by manoeuvre_lever_arm_m) for the
  // prediction `predicted`.
  geometry::Matrix6d ManoeuvreNoise(const TrackedObject& object,
                                    const geometry::Vector6d& predicted,
                                    double dt,
                                    bool lever_arm) const;
  // Whether the `measured` step of a planar object turns less than the
  // `predicted` one, which turns faster than
  // manoeuvre_lever_arm_min_turn_radps.
  bool EasesTheTurn(const TrackedObject& object,
                    const geometry::Vector6d& predicted,
                    const geometry::Vector6d& measured,
                    double dt) const;
  // Stereo depth noise z² σ_d s / (f b) of a point at `depth`, s the scale of
  // its keypoint's pyramid level (1: level 0).
  double DepthNoise(double depth, double level_scale) const;
  // The pyramid-level scale s of keypoint k's stereo match (DepthNoise).
  double StereoLevelScale(const FrameKeypoints& keypoints, size_t k) const;
  // TwistObservation::disparity_noise_ratio of a disparity measured on a
  // level of scale s (step_disparity_noise; 0 when off).
  double StepDisparityNoiseRatio(double level_scale) const;
  // The factor on StepDisparityNoiseRatio in a step of `object` to
  // `camera_from_predicted` (approaching_growth_time_s: below 1 when the
  // object comes nearer to the camera, else 1).
  double ApproachDisparityScale(const FrameContext& ctx,
                                const TrackedObject& object,
                                const geometry::SE3d& camera_from_predicted) const;
  // One σ of a stereo point p_c (camera frame) from keypoint k: its depth
  // noise along its ray, in the camera frame.
  Eigen::Vector3d StereoPointSigma(const FrameKeypoints& keypoints,
                                   size_t k,
                                   const Eigen::Vector3d& p_c) const;
  // Whether an object at `camera_from_object` is too far to track
  // (max_track_depth_sigma_m).
  bool BeyondTrackingRange(const geometry::SE3d& camera_from_object) const;
  // Covariance of the constant-velocity prediction of `object`'s next step.
  geometry::Matrix6d PredictedCovariance(const FrameContext& ctx,
                                         const TrackedObject& object) const;
  bool Reacquire(const FrameContext& ctx,
                 const ObjectDetectionInput& det,
                 TrackedObject* object,
                 double* score,
                 StepReport* report) const;
  bool Create(const FrameContext& ctx, const ObjectDetectionInput& det, TrackedObject* object);
  // The share of `created`'s points (just created) inside the predicted body
  // of `lost` (ObjectTrackerOptions::continuation_*), and the predicted pose;
  // -1 when `lost` does not qualify.
  double ContinuationFit(const FrameContext& ctx,
                         const TrackedObject& lost,
                         const TrackedObject& created,
                         geometry::SE3d* predicted) const;
  // Moves `created`'s points into `lost` at `predicted` (see above).
  void Continue(const geometry::SE3d& predicted, TrackedObject* created, TrackedObject* lost) const;
  // Removes the points of a full object (max_points_per_object) that no
  // observation of its last evict_unseen_frames frames saw.
  void EvictUnseenPoints(const FrameContext& ctx, TrackedObject* o) const;
  // A point's reference patch at uv of this frame's left image (empty on
  // untextured areas); with masked_patches, its pixels off det's mask NaN.
  cv::Mat PointPatch(const FrameContext& ctx,
                     const ObjectDetectionInput& det,
                     const Eigen::Vector2d& uv) const;
  // Whether the step `measured` turns the object (about its joint's normal)
  // against the turn of the prediction `predicted`, both faster than
  // manoeuvre_max_reversal_turn_radps over `dt` seconds.
  bool ReversesTurn(const TrackedObject& o,
                    const geometry::Vector6d& predicted,
                    const geometry::Vector6d& measured,
                    double dt) const;
  // Takes the point's reference patch again when the view of it has turned
  // (patch_refresh_view_change_deg > 0); the step's pose is
  // `camera_from_object` (the camera's centre `camera_in_object`), `found`
  // is where this frame found the point.
  void RefreshPatch(const FrameContext& ctx,
                    const ObjectDetectionInput& det,
                    const geometry::SE3d& camera_from_object,
                    const Eigen::Vector3d& camera_in_object,
                    const Eigen::Vector2d& found,
                    ObjectPoint* point) const;
  // After a step (tracked or re-acquired) with estimate `est` on
  // observations `obs` of the points `obs_point`: the inliers become the
  // points' observations of this frame (pending for the pose history), and
  // new points are added where none was seen.
  void RecordInliers(const FrameContext& ctx,
                     const ObjectDetectionInput& det,
                     const TwistEstimate& est,
                     const std::vector<TwistObservation>& obs,
                     const std::vector<size_t>& obs_point,
                     TrackedObject* object) const;
  void AddNewPoints(const FrameContext& ctx,
                    const ObjectDetectionInput& det,
                    TrackedObject* object,
                    const std::vector<Eigen::Vector2d>& occupied) const;
  void RecordPose(const FrameContext& ctx, TrackedObject* object);
  joints::Joint EffectiveJoint(const joints::Joint& joint) const;
  // Sets the object's joint for this frame (see follow_parent_plane).
  void UpdateJoint(const joints::Joint& joint, TrackedObject* o) const;
  // u_right of keypoint k for the object of `det` (ObjectTrackerOptions::
  // masked_stereo); < 0: no usable stereo depth.
  double ObjectStereo(const FrameContext& ctx, const ObjectDetectionInput& det, size_t k) const;
  // u_right measured on the images at uv, a point of the object of `det`
  // expected at predicted_depth (ObjectTrackerOptions::
  // measure_tracked_stereo); < 0: not measured.
  double TrackedPointStereo(const FrameContext& ctx,
                            const ObjectDetectionInput& det,
                            const Eigen::Vector2d& uv,
                            double predicted_depth) const;

  geometry::StereoCamera camera_;
  ObjectTrackerOptions options_;
  std::map<int64_t, TrackedObject> objects_;
  int64_t next_object_id_ = 1;
  cv::Mat prev_left_;
  // The sparse flow's pyramid of prev_left_ when the previous frame built
  // one (the next frame's "previous" pyramid, not built twice); empty
  // otherwise, and after SetState.
  std::vector<cv::Mat> prev_left_pyramid_;
  int64_t prev_timestamp_ns_ = 0;
  bool has_prev_ = false;
  std::optional<geometry::SE3d> prev_camera_from_world_;
  ObjectTrackerStats stats_;
  std::deque<ObjectTrajectory> removed_trajectories_;
};

}  // namespace twist::objects
