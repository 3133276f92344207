// KITTI tracking `label_02/SSSS.txt`:
//   frame track_id type truncated occluded alpha x1 y1 x2 y2 h w l x y z rotation_y [score]
// (x, y, z) is the bottom centre of the 3D box in the rectified reference
// camera frame of that frame (camera 0; add KittiTrackingCalib::
// left_from_ref_translation for the left colour camera). rotation_y is the yaw
// about the camera y axis. DontCare entries have track_id -1 and dummy 3D
// values (-1000 / -10).
#pragma once

#include <Eigen/Core>
#include <array>
#include <cstdint>
#include <string>
#include <vector>

#include "absl/status/statusor.h"
#include "slam/geometry/se3.h"

namespace twist::io {

struct KittiLabel {
  int64_t frame = 0;
  int64_t track_id = -1;
  std::string type;  // Car, Van, Truck, Pedestrian, Person_sitting, Cyclist, Tram, Misc, DontCare
  double truncated = 0;                                // 0..1 (tracking: 0, 1, 2 levels)
  int occluded = 0;                                    // 0 visible, 1 partly, 2 largely, 3 unknown
  double alpha = 0;                                    // observation angle
  double x1 = 0, y1 = 0, x2 = 0, y2 = 0;               // 2D box in the left colour image (px)
  double height = 0, width = 0, length = 0;            // 3D box size (m)
  Eigen::Vector3d location = Eigen::Vector3d::Zero();  // bottom centre, reference camera (m)
  double rotation_y = 0;
  double score = 0;  // optional 18th column (results files)

  bool is_dont_care() const { return type == "DontCare"; }
  // ref_camera_from_object with the origin at the 3D box centre (object x
  // along its length, y down, z across, as KITTI's devkit builds corners).
  geometry::SE3d RefFromObject() const;
  // The 8 corners of the 3D box in the reference camera frame.
  std::array<Eigen::Vector3d, 8> Corners() const;
};

absl::StatusOr<std::vector<KittiLabel>> ReadKittiLabels(const std::string& path);

// Cityscapes class id for a KITTI object type (Car/Van 26, Truck 27,
// Pedestrian/Person_sitting 24, Cyclist 25 (rider), Tram 31); 0 for Misc,
// DontCare and unknown types.
int KittiTypeToClassId(const std::string& type);

}  // namespace twist::io
