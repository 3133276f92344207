// KITTI calibration files.
//
// Odometry (`sequences/SS/calib.txt`): lines `P0: ...` .. `P3: ...` (3x4
// row-major) and `Tr: ...`. The stereo pair is P0 (left gray) / P1 (right).
//
// Tracking (`calib/SSSS.txt`): P0..P3, `R_rect`/`R0_rect` (3x3),
// `Tr_velo_cam`/`Tr_velo_to_cam` (3x4), `Tr_imu_velo`/`Tr_imu_to_velo` (3x4);
// both spellings are accepted. The stereo pair is P2 (left colour) / P3.
//
// For a rectified pair (P_left, P_right) sharing K:
//   fx = P_left(0,0), fy = P_left(1,1), cx = P_left(0,2), cy = P_left(1,2),
//   baseline = (P_left(0,3) - P_right(0,3)) / fx   (= -P1(0,3)/fx for P0/P1).
#pragma once

#include <Eigen/Core>
#include <map>
#include <optional>
#include <string>

#include "absl/status/statusor.h"
#include "slam/geometry/stereo_camera.h"

namespace twist::io {

using Matrix34d = Eigen::Matrix<double, 3, 4>;

// All `KEY: numbers` entries of a KITTI calibration file. Keys are stored as
// written (without the colon). Fails on a line without "KEY:" or with a
// non-numeric field, naming the file and line.
absl::StatusOr<std::map<std::string, std::vector<double>>> ReadKittiCalibEntries(
    const std::string& path);

// Builds the stereo camera of a rectified pair (width/height left 0: the
// caller sets them from the images). Fails when the pair does not share the
// intrinsics, the baseline is not positive or fx is not positive.
absl::StatusOr<geometry::StereoCamera> StereoFromProjections(const Matrix34d& p_left,
                                                             const Matrix34d& p_right,
                                                             const std::string& what);

struct KittiOdometryCalib {
  Matrix34d p0 = Matrix34d::Zero();
  Matrix34d p1 = Matrix34d::Zero();
  geometry::StereoCamera camera;  // width/height 0 until images are seen
};
absl::StatusOr<KittiOdometryCalib> ReadKittiOdometryCalib(const std::string& path);

struct KittiTrackingCalib {
  Matrix34d p2 = Matrix34d::Zero();
  Matrix34d p3 = Matrix34d::Zero();
  std::optional<Eigen::Matrix3d> r_rect;  // R_rect / R0_rect
  std::optional<Matrix34d> tr_velo_cam;   // Tr_velo_cam / Tr_velo_to_cam
  std::optional<Matrix34d> tr_imu_velo;   // Tr_imu_velo / Tr_imu_to_velo
  geometry::StereoCamera camera;          // left = camera 2, right = camera 3
  // KITTI labels are given in the rectified reference camera 0 frame; a point
  // there maps to the left (camera 2) frame by adding this translation:
  // p_in_left = p_in_ref + left_from_ref_translation = K⁻¹ P2(:,3).
  Eigen::Vector3d left_from_ref_translation = Eigen::Vector3d::Zero();
};
absl::StatusOr<KittiTrackingCalib> ReadKittiTrackingCalib(const std::string& path);

}  // namespace twist::io
