// Writer of the per-run outputs of DESIGN.md §6 into an output directory:
//   camera.txt      KITTI 3x4 world_from_left-camera, one line per frame
//   camera_tum.txt  TUM `t tx ty tz qx qy qz qw`
//   objects.txt     `frame track_id class tx ty tz qx qy qz qw vx vy vz wx wy wz instance_id`
//                   (objects in state new/tracked only)
//   objects_refined.txt  the same columns from the objects' whole trajectories
//                   as the dynamic BA left them (SetRefinedObjects; only when set)
//   camera_refined.txt  camera.txt corrected by the final map's keyframe poses
//                   (SetRefinedKeyFrames; only when set; RefineCameraWithKeyFrames)
//   summary.json    run description, tracking-state counts, timings, caller's extras
// Every file is written to a temporary name and renamed, summary.json last, so
// a directory with summary.json holds a complete run.
//
//   RunOutputWriter out;
//   for (...) out.Add(result);                 // FrameResult per frame, in order
//   RunInfo info; info.dataset = ...;
//   absl::Status s = out.Write("/tmp/run", info);
#pragma once

#include <optional>
#include <string>
#include <utility>
#include <vector>

#include "absl/status/status.h"
#include "slam/common/frame_result.h"
#include "slam/io/trajectory_io.h"

namespace twist::io {

struct RunInfo {
  std::string dataset;  // dataset directory
  std::string format;   // kitti-odometry | kitti-tracking
  std::string sequence;
  std::string mode;  // e.g. "embedded", "server 127.0.0.1:50051"
  double wall_time_s = 0;
  // Extra scalar fields added to summary.json at the top level.
  std::vector<std::pair<std::string, double>> numbers;
  std::vector<std::pair<std::string, std::string>> strings;
};

// One object's trajectory at the end of a run (MapSnapshot::Object).
struct TimedObjectTrajectory {
  int64_t track_id = 0;
  int class_id = 0;
  int64_t instance_id = -1;
  std::vector<std::pair<int64_t, geometry::SE3d>> poses;  // (timestamp_ns, world_from_object)
};

// The trajectory as the final map has it: each frame's online pose corrected
// by what the local BA did to the keyframes around it. A keyframe's correction
// is C_k = refined_k · online_k^-1 (on the world side); a frame between the
// keyframes a and b gets C_a · Exp(s · Log(C_a^-1 · C_b)), s its share of the
// time from a to b, so a change of reference keyframe is no jump; frames
// before the first (after the last) keyframe take its correction. Keyframes
// are matched to frames by timestamp; those of no frame are ignored. With no
// keyframe the online poses are returned. (ORB-SLAM2 writes the frames
// relative to their reference keyframe, which on KITTI 06 f0-50 made RPE_t
// 0.0129 -> 0.0166 m/frame with our keyframes: docs/math.md section 11.)
std::vector<geometry::SE3d> RefineCameraWithKeyFrames(
    const std::vector<std::pair<int64_t, geometry::SE3d>>& frames,      // (t_ns, world_from_camera)
    const std::vector<std::pair<int64_t, geometry::SE3d>>& keyframes);  // (t_ns, world_from_camera)

class RunOutputWriter {
 public:
  void Add(const FrameResult& result);
  // The refined trajectories (written as objects_refined.txt). Each pose is
  // placed at the added frame with its timestamp (poses of other times are
  // dropped); the twist of a row is the central difference of the poses
  // two rows either side, the world twist per second
  // Log(T_{i+2} T_{i-2}^-1) / (t_{i+2} - t_{i-2}) (the window is cut at the
  // track's ends; zero for a single row). Over ±1 row the pose noise made
  // the speed error 17 % larger (docs/objects.md §21).
  void SetRefinedObjects(std::vector<TimedObjectTrajectory> trajectories);
  // The final map's keyframes (timestamp_ns, world_from_camera): camera.txt
  // corrected by them is written as camera_refined.txt.
  void SetRefinedKeyFrames(std::vector<std::pair<int64_t, geometry::SE3d>> keyframes);
  std::vector<geometry::SE3d> RefinedCameraPoses() const;
  int64_t num_frames() const { return static_cast<int64_t>(frames_.size()); }

  std::vector<geometry::SE3d> CameraPoses() const;
  std::vector<StampedPose> CameraTum() const;
  std::vector<ObjectTrackRow> ObjectRows() const;
  std::vector<ObjectTrackRow> RefinedObjectRows() const;
  std::string SummaryJson(const RunInfo& info) const;

  // Creates `dir` if needed and writes the files.
  absl::Status Write(const std::string& dir, const RunInfo& info) const;

 private:
  struct FrameRecord {
    int64_t index = 0;
    int64_t timestamp_ns = 0;
    TrackingState state = TrackingState::kNotInitialized;
    geometry::SE3d world_from_camera;
    bool is_keyframe = false;
    int num_map_points = 0;
    int num_keyframes = 0;
    std::vector<StageTiming> timings;
  };
  std::vector<FrameRecord> frames_;
  std::vector<ObjectTrackRow> objects_;
  std::optional<std::vector<TimedObjectTrajectory>> refined_;
  std::optional<std::vector<std::pair<int64_t, geometry::SE3d>>> refined_keyframes_;
};

}  // namespace twist::io
