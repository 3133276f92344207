// The dynamic-object stage of one session (TwistSLAM §IV), run by
// SlamSystem::Process after the camera has been tracked on static points:
//
//  1. panoptic segments -> detections: instances of dynamic classes (with
//     their masks) and the "stuff" segments of plane classes (road, wall...);
//  2. ClusterAssociator: detections -> stable clusters (robust to instance-id
//     swaps), created / lost / removed events;
//  3. one ClusterPlane per plane class, refitted by RANSAC on the world
//     positions of that class's stereo keypoints as they accumulate
//     ("plane updated" events carry the plane);
//  4. each dynamic cluster's joint from its class (ClassTable) and its
//     parent's plane: planar joints lie in the parent plane as the current
//     camera sees it (ObjectStageOptions::camera_plane_frames); axis joints (a
//     door's hinge) get a vertical axis in the parent plane at the cluster's
//     edge nearest to the camera when first seen (a heuristic: the hinge is
//     not observable before the door moves), fixed for the cluster's life;
//  5. ObjectTracker: object poses and constrained twists;
//  6. optionally a dynamic bundle adjustment of the objects' poses and points
//     over the last frames (camera poses fixed, from static tracking).
//
// Per-session state only (no globals); deterministic for a given input
// sequence (RANSAC draws from a generator seeded with SlamOptions::seed).
// Persisted by SlamSystem::Save (state format >= 4, Write/Read below): a
// resumed session continues the object tracks exactly as an uninterrupted one.
#pragma once

#include <cstdint>
#include <deque>
#include <map>
#include <opencv2/core.hpp>
#include <optional>
#include <random>
#include <tuple>
#include <utility>
#include <vector>

#include "absl/status/statusor.h"
#include "slam/common/frame_result.h"
#include "slam/geometry/se3.h"
#include "slam/joints/joint.h"
#include "slam/map/map.h"
#include "slam/objects/object_tracker.h"
#include "slam/semantic/cluster_association.h"
#include "slam/semantic/plane_fitting.h"
#include "slam/system/slam_options.h"

namespace twist {

struct MapSnapshot;

namespace system_io {
class BinaryWriter;
class BinaryReader;
}  // namespace system_io

struct ObjectStageOptions {
  int min_segment_pixels = 400;     // smaller instance segments are ignored
  // The object tracker's threads (ObjectTrackerOptions::num_threads: the
  // objects' steps side by side; the same results for any value).
  int tracker_threads = 2;
  double max_plane_depth_m = 30.0;  // plane points further away are not used
  int max_plane_points = 4000;      // per plane class (oldest dropped)
  double plane_inlier_m = 0.05;     // RANSAC inlier distance
  // Disparity noise of a plane point on pyramid level 0 (times 1.2^level on
  // coarser levels): with the viewing ray it weights the point in the plane's
  // refinement (semantic::StereoPlanePoint, RefinePlaneWeighted).
  double plane_disparity_sigma_px = 0.5;
  // A plane point's disparity is measured again on level 0 with the block
  // restricted to its class's mask (objects::MaskedDisparity, as the object
  // points are), around the engine matcher's value; a point whose masked
  // measurement fails is not used for the plane. Needs the right image
  // (ObjectStageInput::right); without it the matcher's disparity is used.
  // The matcher's disparities on the rendered road are too large by a
  // median 0.09 px (most in the blocks that straddle a car), the masked ones
  // by 0.003 px; with them the plane follows the camera's own height drift
  // closely enough for the planar cars to follow their plane
  // (ObjectTrackerOptions::follow_parent_plane; docs/objects.md §37). Costs
  // ~5 ms per frame on the generated street scenes (objects_bench).
  bool masked_plane_stereo = true;
  double plane_stereo_half_px = 5.5;  // the masked block's half size (level-0 pixels)
  // Plane points within this many pixels of a dynamic segment are not used:
  // the road beside a car may be hidden behind it in the right image, and
  // the engine measures the stereo of static keypoints next to a segment
  // again for the camera (docs/objects.md §48). 0: all used. SlamSystem sets
  // it to 24 with SlamOptions::extra_camera_keypoints (measured there; with
  // the budget as it is, 8 px was neutral: docs/objects.md §47).
  int plane_dynamic_margin_px = 0;
  // Dynamic BA over the last frames (0: off). The window is also bounded by
  // SlamOptions::temporal_window_s. SlamSystem sets it from
  // SlamOptions::object_ba_window_frames (10 by default; the solve is
  // bit-deterministic, see dynamic_ba.cc); 0 here for a stage built alone.
  int ba_window_frames = 0;
  int ba_iterations = 3;
  // Planar joints take their parent plane as the current camera sees it:
  // refined (RefinePlaneWeighted) on the plane points of the last
  // camera_plane_frames frames, each kept in the camera frame it was measured
  // in, and carried into the world with this frame's camera pose. A car is
  // measured from the current camera, so its plane then shares that pose's
  // error (the world fit, on ~57 frames of points placed by their own poses,
  // moved by up to 1.2 cm within four frames in the current camera's frame
  // on `intersection` seed 1). Assumes the camera's pose on the road changes
  // little over the window. 24 runs: moving ATE 0.123 -> 0.105 m, coverage
  // 0.901 -> 0.903 (5 / 15 / 30 frames: ATE 0.118 / 0.108 / 0.118;
  // docs/objects.md §38). <= 0: the world fit (ClusterPlane::reported_plane).
  int camera_plane_frames = 10;
};

struct ObjectStageInput {
  int64_t frame_index = 0;
  int64_t timestamp_ns = 0;
  cv::Mat left;                                  // CV_8UC1
  cv::Mat right;                                 // optional CV_8UC1 (object depths from the mask)
  cv::Mat panoptic;                              // CV_16UC1 / CV_32SC1, class * 1000 + instance
  cv::Mat flow;                                  // optional CV_32FC2, previous left -> this left
  // Optional CV_8UC1: FavourMask(panoptic) >= 128 (the dynamic segments),
  // when the caller has it already; empty: built from `panoptic` when needed.
  cv::Mat dynamic;
  const map::FrameFeatures* features = nullptr;  // the frame's stereo keypoints
  geometry::SE3d camera_from_world;              // from static tracking
};

struct ObjectStageOutput {
  std::vector<ObjectResult> objects;
  std::vector<ClusterEvent> cluster_events;
  double ba_ms = 0.0;
  // Sub-stages: "objects_segments" (segments, association, planes, joints)
  // and "objects_track" (ObjectTracker).
  std::vector<StageTiming> timings;
};

class ObjectStage {
 public:
  explicit ObjectStage(const SessionConfig& config,
                       const ObjectStageOptions& options = ObjectStageOptions());

  absl::StatusOr<ObjectStageOutput> Process(const ObjectStageInput& input);

  // Region mask for the ORB extractor (orb_extractor.h convention): 1 on
  // static pixels, 200 (favoured) on pixels of dynamic classes, so that
  // objects keep enough keypoints. Empty when the panoptic image is empty.
  static cv::Mat FavourMask(const cv::Mat& panoptic, const joints::ClassTable& classes);

  const objects::ObjectTracker& tracker() const { return tracker_; }

  // Adds the stage's clusters to a map snapshot (SlamSystem::Snapshot):
  // every cluster the associator keeps (class, last instance id, dynamic
  // flag); a plane class's cluster with its fitted plane; a dynamic cluster
  // with the pose history of the object that holds it, oldest first, as the
  // dynamic BA left it (bounded by ObjectTrackerOptions::max_history). Static
  // points of a plane class are labelled with that class's cluster. Adds the
  // whole trajectory of every object, removed ones included
  // (ObjectTracker::Trajectories).
  void AddToSnapshot(MapSnapshot* snapshot) const;

  // Persistence (SlamSystem::Save/Load): everything that evolves from frame
  // to frame (clusters, planes and their points, tracked objects, axis joints,
  // the RANSAC generator, the BA window); the configuration is the caller's.
  // Read() expects a stage freshly built from the same configuration and
  // returns DataLoss (never crashes) on truncated or inconsistent data.
  // `version` is the state file's format version (>= 4).
  void Write(system_io::BinaryWriter* w) const;
  absl::Status Read(system_io::BinaryReader* r, uint32_t version);

 private:
  struct PlaneState {
    semantic::ClusterPlane plane;
    std::deque<semantic::StereoPlanePoint> points;
    int64_t cluster_id = -1;
    // The points of the last ObjectStageOptions::camera_plane_frames frames
    // in the camera frame each was measured in (with that frame's index),
    // and the plane refined on them, in the current camera's frame.
    std::deque<std::pair<int64_t, semantic::StereoPlanePoint>> camera_points;
    std::optional<Eigen::Vector4d> camera_plane;
  };
  joints::Joint JointFor(const objects::ObjectDetectionInput& det,
                         const geometry::SE3d& world_from_camera,
                         const std::vector<Eigen::Vector3d>& points_in_world);
  void RunDynamicBa(std::vector<ObjectResult>* results);
  // Drops the camera points older than camera_plane_frames and refines the
  // plane in this frame's camera frame on the rest (none without a world fit
  // or with too few points).
  void UpdateCameraPlane(int64_t frame_index,
                         const geometry::SE3d& world_from_camera,
                         PlaneState* ps) const;
  static constexpr int kMinCameraPlanePoints = 30;

  SessionConfig config_;
  ObjectStageOptions options_;
  semantic::ClusterAssociator associator_;
  std::map<int, PlaneState> planes_;  // by plane class id
  objects::ObjectTracker tracker_;
  std::map<int64_t, joints::Joint> axis_joints_;  // by cluster id
  std::mt19937_64 rng_;
  // (frame index, timestamp, camera_from_world) of the BA window.
  std::deque<std::tuple<int64_t, int64_t, geometry::SE3d>> window_;
};

}  // namespace twist
