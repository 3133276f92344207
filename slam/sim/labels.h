// Ground-truth labels of a rendered frame: KITTI tracking label_02 rows and
// world_from_object poses of every object visible in the left image.
#pragma once

#include <Eigen/Core>
#include <opencv2/core.hpp>
#include <string>
#include <vector>

#include "slam/geometry/se3.h"
#include "slam/sim/renderer.h"
#include "slam/sim/scenarios.h"

namespace twist::sim {

struct FrameLabel {
  int track_id = 0;  // == panoptic instance id
  int class_id = 0;
  std::string type;   // KITTI type: Car, Van, Pedestrian, Door
  int truncated = 0;  // KITTI tracking levels: 0 none, 1 partly, 2 heavily (box leaves the image)
  int occluded = 0;   // 0 fully visible (>= 95 %), 1 partly (>= 50 %), 2 largely
  double alpha = 0.0;
  double x1 = 0, y1 = 0, x2 = 0, y2 = 0;  // bounding box of the mask (pixel indices, inclusive)
  double h = 0, w = 0, l = 0;
  Eigen::Vector3d location = Eigen::Vector3d::Zero();  // bottom centre in the left camera frame
  double rotation_y = 0.0;
  int64_t visible_pixels = 0;  // mask pixels in the left image
  int64_t full_pixels = 0;     // pixels the object would cover without occluders
  // world_from_object with the origin at the 3D box centre (x along the
  // length, y down, z across), as in io::ObjectGtRow / KittiLabel::RefFromObject.
  geometry::SE3d world_from_object;
};

// Labels of the objects with at least one pixel in `panoptic` (the left mask
// of `frame`), ordered by track id.
std::vector<FrameLabel> ComputeFrameLabels(const Scenario& scenario,
                                           const Renderer& renderer,
                                           int frame,
                                           const cv::Mat& panoptic);

// "frame track_id type truncated occluded alpha x1 y1 x2 y2 h w l x y z rotation_y"
std::string FormatKittiLabel(int frame, const FrameLabel& label);
// "frame track_id class tx ty tz qx qy qz qw"
std::string FormatObjectGt(int frame, const FrameLabel& label);

// Wraps an angle to [-π, π).
double WrapAngle(double a);

}  // namespace twist::sim
