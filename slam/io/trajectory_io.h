// Trajectory and object-track text formats (DESIGN.md §5, §6; docs/formats.md).
//
//  KITTI poses : one line per frame, 12 numbers, row-major 3x4 [R|t] of
//                world_from_camera. Rotations are re-orthonormalised on read
//                (nearest rotation by SVD): KITTI's are not exactly orthonormal.
//  times       : one line per frame, seconds (read into int64 nanoseconds).
//  TUM         : `t tx ty tz qx qy qz qw` (t in seconds), world_from_camera.
//  objects.txt : `frame track_id class tx ty tz qx qy qz qw vx vy vz wx wy wz
//                [instance_id]` — world_from_object and the constrained twist
//                in the world frame (per second, (v, ω)); the optional 17th
//                column is the panoptic instance id the engine last saw for
//                the object (used to associate it with ground truth).
//  objects_gt  : `frame track_id class tx ty tz qx qy qz qw`, world_from_object
//                with the origin at the 3D box centre; track_id = the mask
//                instance id of the object.
#pragma once

#include <cstdint>
#include <string>
#include <vector>

#include "absl/status/status.h"
#include "absl/status/statusor.h"
#include "slam/geometry/se3.h"

namespace twist::io {

// Nearest rotation matrix (SVD, det +1) to `m`.
Eigen::Matrix3d NearestRotation(const Eigen::Matrix3d& m);

// --- KITTI 3x4 poses -------------------------------------------------------
absl::StatusOr<std::vector<geometry::SE3d>> ReadKittiPoses(const std::string& path);
std::string FormatKittiPoses(const std::vector<geometry::SE3d>& world_from_camera);
absl::Status WriteKittiPoses(const std::string& path,
                             const std::vector<geometry::SE3d>& world_from_camera);

// --- times.txt (seconds per line) ------------------------------------------
// Fails unless the times are finite, non-negative and strictly increasing.
absl::StatusOr<std::vector<int64_t>> ReadTimes(const std::string& path);
std::string FormatTimes(const std::vector<int64_t>& timestamps_ns);
int64_t SecondsToNs(double seconds);
double NsToSeconds(int64_t ns);

// --- TUM -------------------------------------------------------------------
struct StampedPose {
  int64_t timestamp_ns = 0;
  geometry::SE3d world_from_camera;
};
absl::StatusOr<std::vector<StampedPose>> ReadTumTrajectory(const std::string& path);
std::string FormatTumTrajectory(const std::vector<StampedPose>& poses);
absl::Status WriteTumTrajectory(const std::string& path, const std::vector<StampedPose>& poses);

// --- objects.txt (estimated object tracks) -----------------------------------
struct ObjectTrackRow {
  int64_t frame = 0;
  int64_t track_id = 0;
  int class_id = 0;
  geometry::SE3d world_from_object;
  geometry::Vector6d twist_in_world = geometry::Vector6d::Zero();  // (v, ω) per second
  int64_t instance_id = -1;                                        // -1: not written / unknown
};
absl::StatusOr<std::vector<ObjectTrackRow>> ReadObjectTracks(const std::string& path);
std::string FormatObjectTracks(const std::vector<ObjectTrackRow>& rows);
absl::Status WriteObjectTracks(const std::string& path, const std::vector<ObjectTrackRow>& rows);

// --- objects_gt/SSSS.txt (ground-truth object poses) -------------------------
struct ObjectGtRow {
  int64_t frame = 0;
  int64_t track_id = 0;  // = mask instance id
  int class_id = 0;
  geometry::SE3d world_from_object;  // origin at the 3D box centre
};
absl::StatusOr<std::vector<ObjectGtRow>> ReadObjectsGt(const std::string& path);
std::string FormatObjectsGt(const std::vector<ObjectGtRow>& rows);
absl::Status WriteObjectsGt(const std::string& path, const std::vector<ObjectGtRow>& rows);

}  // namespace twist::io
