// Output of the engine for one frame: camera pose, objects, cluster events.
#pragma once

#include <cstdint>
#include <optional>
#include <string>
#include <vector>

#include <Eigen/Core>

#include "slam/geometry/se3.h"

namespace twist {

enum class TrackingState {
  kNotInitialized = 0,
  kOk = 1,
  kLost = 2,
  kRelocalized = 3,
};
const char* TrackingStateName(TrackingState s);

enum class ObjectState {
  kNew = 0,
  kTracked = 1,
  kLost = 2,
};
const char* ObjectStateName(ObjectState s);

struct ObjectResult {
  int64_t id = 0;  // stable object (cluster) id within the session
  int class_id = 0;
  int instance_id = 0;  // panoptic instance id last seen for this object
  ObjectState state = ObjectState::kNew;
  geometry::SE3d world_from_object;
  // Constrained twist of the last step, per second, in the world frame and in
  // the joint frame (v, ω).
  geometry::Vector6d twist_in_world = geometry::Vector6d::Zero();
  geometry::Vector6d twist_in_joint = geometry::Vector6d::Zero();
  double speed_mps = 0.0;  // |velocity of the object origin| in m/s
  std::string joint;       // joint type name, e.g. "planar"
  int num_points = 0;
  // The object's motion has been statistically insignificant for the last
  // frames (a parked car): its twist is reported as zero and its pose held.
  bool stationary = false;
};

enum class ClusterEventType {
  kCreated = 0,
  kPlaneUpdated = 1,
  kLost = 2,
  kRemoved = 3,
};
const char* ClusterEventTypeName(ClusterEventType t);

struct ClusterEvent {
  ClusterEventType type = ClusterEventType::kCreated;
  int64_t cluster_id = 0;
  int class_id = 0;
  int instance_id = 0;
  bool is_dynamic = false;
  std::optional<Eigen::Vector4d> plane;  // (a, b, c, d), |(a,b,c,d)| = 1, world frame
};

struct StageTiming {
  std::string stage;  // e.g. "orb", "stereo", "track", "objects", "ba"
  double ms = 0.0;
};

struct FrameResult {
  int64_t index = 0;
  int64_t timestamp_ns = 0;
  TrackingState state = TrackingState::kNotInitialized;
  geometry::SE3d world_from_camera;
  bool is_keyframe = false;
  int num_tracked_points = 0;  // static map points used by the camera tracker
  int num_map_points = 0;
  int num_keyframes = 0;
  std::vector<ObjectResult> objects;
  std::vector<ClusterEvent> cluster_events;
  std::vector<StageTiming> timings;
};

}  // namespace twist
