// Camera tracking against the static map (ORB-SLAM2-style, without a
// vocabulary):
//  1. constant-velocity prediction + projection search of the previous frame's
//     points (map points and temporary stereo points);
//  2. fallback: projection search of the reference keyframe's points from the
//     last pose with wide windows;
//  3. local map: keyframes sharing points with the frame plus their best
//     covisible neighbours; projection search of their points;
//  4. robust pose-only optimisation after each search;
//  5. when lost: relocalisation by descriptor matching against recent
//     keyframes, PnP RANSAC (OpenCV, deterministic) and refinement.
// Only keypoints flagged `is_static` take part (dynamic classes are masked
// out by the caller).
#pragma once

#include <cstdint>
#include <optional>
#include <vector>

#include "slam/common/frame_result.h"
#include "slam/map/map.h"
#include "slam/tracking/pose_optimizer.h"

namespace twist::tracking {

struct TrackerOptions {
  double close_depth_baselines = 40.0;  // "close" stereo points (ThDepth)
  int min_init_stereo_points = 100;     // to initialise from one stereo frame
  int motion_search_radius = 7;         // px at level 0, scaled by level
  int reference_search_radius = 20;     // px, fallback search
  int min_motion_inliers = 10;
  // A motion-model pose with fewer map-point inliers than this is checked
  // against descriptor tracking of the reference keyframe (PnP RANSAC), and
  // the one with more inliers wins: a sudden turn moves every keypoint out
  // of the search windows around the constant-velocity prediction, and the
  // few matches left there can be wrong ones on repetitive texture, which a
  // pose-only optimisation fits without complaint (intersection seed 2: 13-21
  // inliers for five frames, 0.2-0.8 m error per frame).
  int confident_motion_inliers = 50;
  int min_local_map_inliers = 30;
  int min_relocalized_inliers = 50;
  int recent_relocalization_frames = 10;  // frames that need the higher bar
  // A frame that neither the motion model nor the reference keyframe tracks
  // is relocalized at once (descriptor matching against the recent keyframes
  // and PnP RANSAC) rather than reported lost: at the start of a sharp turn
  // (intersection seed 4, frame 65) the next frame's relocalization succeeded,
  // so the failed frame lost nothing but its own pose.
  bool relocalize_on_failure = true;
  int max_local_keyframes = 80;
  int relocalization_keyframes = 40;  // most recent keyframes tried
  int max_temporary_points = 100;     // extra VO points kept from last frame
  // A frame whose local-map search keeps fewer inliers than this share of
  // the last frame's map points searches the local map a second time from
  // its optimised pose, and is optimised again (0: never). At the end of a
  // sharp turn the constant-velocity prediction overshoots (intersection
  // frame 90: 3.6 -> 2.3 -> 0 deg per frame, 1.3 deg off), the first search
  // finds half the points and the pose fitted to them is biased; the second
  // search, from a pose much closer to the truth, finds the rest. The second
  // search is kept only if it reaches this share of the last frame's inliers.
  double research_inlier_ratio = 0.6;
  // A motion-model frame that stays under research_inlier_ratio of the last
  // frame's inliers after the second search is tracked again from the
  // reference keyframe by descriptor (PnP RANSAC, no pose prior) and its
  // local map; the pass with more local-map inliers is kept. When the
  // prediction is off at the end of a turn, the first pass can settle on a
  // biased pose that the second search cannot leave (intersection seed 1,
  // frame 90 with another map: 263 then 377 inliers against 739, 0.39 m off).
  bool retry_weak_frames_from_reference = true;
  PoseOptimizerOptions pose;
};

enum class TrackingPath { kNone = 0, kMotionModel, kReferenceKeyFrame, kRelocalization };

// Statistics the keyframe policy needs (and diagnostics).
struct TrackingStats {
  TrackingPath path = TrackingPath::kNone;  // how the first pose was found
  int num_inliers = 0;                      // matched map points that are inliers
  int num_tracked_close = 0;                // close stereo keypoints with an inlier map point
  int num_untracked_close = 0;              // close stereo keypoints without
};

class CameraTracker {
 public:
  CameraTracker(const geometry::StereoCamera& camera,
                const features::ScalePyramid& pyramid,
                const TrackerOptions& options);

  // Tracks `frame` (features filled, matches reset) against `map`, locking
  // the map's mutex. Sets frame->camera_from_world and the matches. Returns
  // kNotInitialized until Initialize() has been called.
  TrackingState Track(map::Frame* frame, map::Map* map);

  // True when `frame` can start the map (enough close stereo points).
  bool CanInitialize(const map::Frame& frame) const;
  // Called with the first keyframe (made from `frame`) after initialisation.
  void Initialize(const map::Frame& frame, const map::KeyFrame& kf);
  // Called after a new keyframe was made from the last tracked frame.
  void OnKeyFrameCreated(const map::Frame& frame, const map::KeyFrame& kf);

  // Forces the lost state (tests, operator command): the next frame
  // relocalises.
  void ForceLost() { state_ = TrackingState::kLost; }

  TrackingState state() const { return state_; }
  const TrackingStats& stats() const { return stats_; }
  int64_t reference_kf_id() const { return reference_kf_id_; }
  int64_t last_keyframe_frame_id() const { return last_kf_frame_id_; }
  int64_t last_relocalization_frame_id() const { return last_reloc_frame_id_; }
  const map::Frame& last_frame() const { return last_frame_; }
  const std::optional<geometry::SE3d>& velocity() const { return velocity_; }
  const TrackerOptions& options() const { return options_; }

  // Full internal state for save/load (exact resume).
  struct State {
    TrackingState state = TrackingState::kNotInitialized;
    map::Frame last_frame;
    bool last_frame_is_keyframe = false;
    std::optional<geometry::SE3d> velocity;
    geometry::SE3d last_from_reference;  // last frame pose relative to its reference kf
    int64_t reference_kf_id = -1;
    int64_t last_kf_frame_id = -1;
    int64_t last_reloc_frame_id = -1000000;
    int last_inliers = 0;  // the last frame's map-point inliers
  };
  State GetState() const;
  void SetState(State s);

 private:
  // Returns the number of map-point inliers (0 when it failed).
  int TrackWithMotionModel(map::Frame* frame, map::Map* map);
  // Returns the number of map-point inliers (0 when it failed).
  int TrackReferenceKeyFrame(map::Frame* frame, map::Map* map);
  bool TrackLocalMap(map::Frame* frame, map::Map* map, bool just_relocalized);
  bool Relocalize(map::Frame* frame, map::Map* map);
  void UpdateLastFrame(map::Map* map);

  // Matches the points of `source` keypoints (positions, descriptors) into
  // `frame` by projection; returns the number of new matches.
  int SearchLastFrame(map::Frame* frame, const map::Frame& last, float radius) const;
  int SearchKeyFramePoints(map::Frame* frame,
                           const map::KeyFrame& kf,
                           const map::Map& map,
                           float radius,
                           int max_distance) const;
  // Projection search of `local_points` into `frame`; skips the points
  // already matched in this frame (MapPoint::last_local_map_frame). Counts
  // each point as visible when `count_visible`.
  int SearchLocalPoints(map::Frame* frame,
                        map::Map* map,
                        const std::vector<int64_t>& local_points,
                        bool count_visible);
  int Optimize(map::Frame* frame);
  // Matched map points that are not outliers.
  static int CountMapInliers(const map::Frame& frame);
  void ComputeStats(const map::Frame& frame);

  geometry::StereoCamera camera_;
  features::ScalePyramid pyramid_;
  TrackerOptions options_;
  TrackingState state_ = TrackingState::kNotInitialized;
  map::Frame last_frame_;
  bool last_frame_is_keyframe_ = false;
  std::optional<geometry::SE3d> velocity_;
  geometry::SE3d last_from_reference_;
  int64_t reference_kf_id_ = -1;
  int64_t last_kf_frame_id_ = -1;
  int64_t last_reloc_frame_id_ = -1000000;
  int last_inliers_ = 0;  // the last tracked frame's map-point inliers
  TrackingStats stats_;
};

}  // namespace twist::tracking
