// Named synthetic scenarios (deterministic for a given seed).
//
//   static_street                 camera drives along a street lined with parked cars
//   driving                       leading and oncoming traffic, pedestrians
//   intersection                  the camera turns right at a crossing; crossing cars
//   stationary_then_accelerating  camera still, then accelerating; cars pass close
//   follow_braking                the leading car brakes to a stop and restarts; many parked cars
//   door                          a door on a revolute joint opens in a brick wall
#pragma once

#include <cstdint>
#include <string>
#include <vector>

#include "absl/status/statusor.h"
#include "slam/geometry/se3.h"
#include "slam/geometry/stereo_camera.h"
#include "slam/sim/motion.h"
#include "slam/sim/scene.h"

namespace twist::sim {

// Height of the left camera above the road (KITTI): the road is y = kCameraHeight.
inline constexpr double kCameraHeight = 1.65;
// Height of the sidewalk (curb) above the road.
inline constexpr double kCurbHeight = 0.15;

// KITTI-like rectified stereo rig: 1242x375, fx = fy = 721.5377,
// cx = 609.5593, cy = 172.854, baseline 0.54 m.
geometry::StereoCamera KittiLikeCamera();

struct Scenario {
  std::string name;
  uint32_t seed = 0;
  int num_frames = 100;
  double frame_period = 0.1;  // s (10 Hz)
  geometry::StereoCamera camera;
  Scene scene;
  PlanarMotion camera_motion;  // world_from_left-camera; identity at t = 0

  double TimeOf(int frame) const { return frame * frame_period; }
  geometry::SE3d WorldFromCamera(int frame) const {
    return camera_motion.PoseAt(TimeOf(frame), HeadingAxis::kZ);
  }
};

// One line per scenario: name and a short description.
struct ScenarioInfo {
  std::string name;
  std::string description;
};
std::vector<ScenarioInfo> ListScenarios();

// InvalidArgument for an unknown name or num_frames < 1.
absl::StatusOr<Scenario> MakeScenario(const std::string& name, uint32_t seed, int num_frames);

}  // namespace twist::sim
