// Glue between the object tracker and the dynamic bundle adjustment: adds the
// tracked objects' recent poses, points and observations to a
// DynamicBaProblem over the engine's keyframes, and writes the refined poses
// and points back into the tracker.
#pragma once

#include <cstdint>
#include <map>
#include <vector>

#include "slam/objects/dynamic_ba.h"
#include "slam/objects/object_tracker.h"

namespace twist::objects {

// Which BA object came from which tracked object, frame by frame.
struct ObjectBaLink {
  int64_t object_id = 0;
  int problem_object = 0;              // index into DynamicBaProblem::objects
  std::vector<int64_t> frame_indices;  // per BaObjectFrame
  std::vector<int64_t> point_ids;      // per BaObject point
};

struct ObjectBaOptions {
  int min_frames = 3;  // objects seen in fewer window frames are skipped
  int min_observations_per_point = 2;
  double sigma_px = 1.0;  // per observation (MAD replaces it by default)
  // The step twist written back (the object's reported twist and the
  // tracker's next prediction) is the mean over the last twist_steps steps
  // of the refined poses, Log(P_i P_{i−k}⁻¹) / k. One step's difference
  // carries the poses' frame-to-frame noise twice: on the rendered scenes
  // the lead car's reported speed was off by ±2-4 km/h from frame to frame.
  // 2 steps: speed error 1.05 -> 0.93 km/h over 4 scenarios x 3 seeds, at
  // the cost of half a frame of lag (docs/objects.md §17); 3 steps lag the
  // braking cars (follow_braking 0.72 -> 0.84 km/h).
  int twist_steps = 2;
  // The newest frame, when the tracker coasted the object in it (a refused
  // step: the prediction stands, no observation kept), stays fixed: nothing
  // in it measures the object, so the motion priors alone would place it by
  // extrapolating its neighbours' noise. With the constant-acceleration
  // prior (DynamicBaOptions::const_acceleration_sqrt_weight) that
  // extrapolation is a quadratic (a crossing car jumped 0.2 m sideways on
  // intersection seed 4): turn this on with it. With the constant-velocity
  // prior alone it made no difference worth having on the rendered runs
  // (docs/objects.md section 29): off by default. Once later frames measure
  // the object the coasted frame is interpolated between them; fixing it
  // there too held them back.
  bool fix_coasted_newest_frame = false;
  // When the window has slid along an object's continuous track (the
  // history sample just before its first frame is the frame before), its
  // second frame is fixed too. With the first one only (the gauge of the
  // points), the constant-velocity prior pulls the second towards the chord
  // of its neighbours: back for a braking car, forward for an accelerating
  // one, by ~2 cm at 4 m/s². The next window fixes that frame where this one
  // left it, so the pull adds up frame after frame (a braking car 0.38 m
  // behind after 40 frames; follow_braking's lead car drifted 0.4 m). Two
  // fixed frames keep the velocity at the gauge, and every free frame but
  // the two newest has the pulls of its triplets cancel while the
  // acceleration is constant (docs/math.md section 13; follow_braking's lead
  // car 0.270 -> 0.144 m ATE, docs/objects.md section 29).
  bool keep_velocity_at_gauge = true;
  // A planar object may also move along its plane's normal in the BA, each
  // step by N(0, σ²) (σ in m per frame; 0: not at all). The camera's height
  // estimate drifts by 1-2 cm along a run while the road plane under a car
  // stays where it was fitted; held to that plane, the car can only match
  // its image height by moving in depth, ~10x the height error. On the
  // rendered runs 2 mm and 1 cm helped the lead car of follow_braking but
  // cost the others more (ATE 0.207 -> 0.224 / 0.256 m on 12 runs): off
  // (docs/objects.md section 30).
  double soft_normal_step_sigma_m = 0.0;
  // A point the window inherits from earlier windows (it has inlier
  // observations in frames older than the window) gets a Gaussian prior at
  // where those windows left it, with the information of those
  // observations: each one a stereo observation from the window's oldest
  // frame, with position noise inherited_point_sigma_px across the ray and
  // disparity noise inherited_point_disparity_sigma_px along it (the BA's
  // floor on its MAD scale, 0.5 px, and 0.3 of it). Solved again from the
  // window's frames alone, such a point follows the window's gauge, which is
  // itself the last window's estimate: as a car's points turn over (a car
  // coming closer or pulling away shows new corners), the whole structure
  // walks with the gauge. follow_braking seed 2's lead car, tracked under
  // the true camera poses (object_depth_bias): its motion's error along the
  // line of sight was 0.097 m RMS over 100 frames (up to 0.18 m, towards
  // the camera), 0.057 m with the prior. 24 rendered runs: moving ATE
  // 0.1046 -> 0.0965 m (docs/objects.md section 41). The prior stands for
  // what the dropped observations said about the point (a marginalisation
  // without their correlations with the poses).
  bool inherited_point_prior = true;
  double inherited_point_sigma_px = 0.5;
  double inherited_point_disparity_sigma_px = 0.15;
  // Hold such a point fixed instead when it has at least this many
  // observations before the window (0: never). Measured with 1, 4 and 7:
  // 4 gave ATE 0.0989 m on the 24 runs, with a larger rotation error
  // (RPE_R 0.162 against 0.155 °/m with the prior; section 41).
  int hold_points_seen_before_window = 0;
};

// For every tracked object (lost ones are left out), the history samples
// whose frame index is in `keyframe_of_frame` (frame index -> index into
// problem->keyframes; pass the temporal set) become BaObjectFrames (the
// oldest one fixed: the gauge of the object's points; also fixed: the frames
// in which the tracker held the object stationary and the frame each hold
// started from; with options.keep_velocity_at_gauge the second one when the
// window slid along the track; with options.fix_coasted_newest_frame the
// newest one if the object coasted in it), and their inlier observations
// become dynamic terms. Points seen in the window at least
// options.min_observations_per_point times enter the problem, with a prior
// when they were seen before it (options.inherited_point_prior) and held
// fixed when they were seen options.hold_points_seen_before_window times
// before it.
std::vector<ObjectBaLink> AddTrackedObjectsToBa(const ObjectTracker& tracker,
                                                const std::map<int64_t, int>& keyframe_of_frame,
                                                const ObjectBaOptions& options,
                                                DynamicBaProblem* problem);

// Writes the solved poses and points back: history poses, points in the
// object frame, the current pose when the newest frame was in the window, and
// the step twist Log(P_i P_{i−k}⁻¹) / k (k = options.twist_steps, or fewer
// when the older frames were not in the window or not consecutive).
void ApplyBaToTrackedObjects(const DynamicBaProblem& problem,
                             const std::vector<ObjectBaLink>& links,
                             const ObjectBaOptions& options,
                             ObjectTracker* tracker);

}  // namespace twist::objects
