// Rectification of an unrectified stereo rig (DESIGN.md §4): the server
// rectifies incoming frames so the engine always sees a rectified pinhole
// pair. Immutable after Create, so one instance serves a session's reader
// thread without locking.
#pragma once

#include <opencv2/core.hpp>
#include <vector>

#include "absl/status/statusor.h"
#include "slam/common/stereo_frame.h"
#include "slam/geometry/se3.h"
#include "slam/geometry/stereo_camera.h"

namespace twist::server {

struct RawCameraModel {
  double fx = 0, fy = 0, cx = 0, cy = 0;
  std::vector<double> distortion;  // OpenCV order; 0, 4, 5 or 8 values
};

struct RawStereoRig {
  RawCameraModel left;
  RawCameraModel right;
  geometry::SE3d right_from_left;  // OpenCV stereoRectify's (R, T)
  int width = 0;
  int height = 0;
};

class StereoRectifier {
 public:
  // Validates the rig and computes the zero-alpha rectification (every
  // rectified pixel is valid) with the principal points aligned.
  static absl::StatusOr<StereoRectifier> Create(const RawStereoRig& rig);

  // The rectified rig the engine works with (same image size as the input).
  const geometry::StereoCamera& rectified_camera() const { return rectified_; }

  // Remaps left/right (bilinear) and the panoptic mask (nearest), and maps the
  // boxes' corners; the frame must have the rig's size (FrameFromProto checked
  // it). Flow is not accepted for unrectified rigs.
  void Rectify(StereoFrame* frame) const;

 private:
  geometry::StereoCamera rectified_;
  cv::Mat left_map1_, left_map2_, right_map1_, right_map2_;
  cv::Mat mask_map_x_, mask_map_y_;
  cv::Matx33d k_left_, r_left_;
  cv::Matx34d p_left_;
  std::vector<double> dist_left_;
};

}  // namespace twist::server
