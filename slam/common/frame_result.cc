#include "slam/common/frame_result.h"

namespace twist {

const char* TrackingStateName(TrackingState s) {
  switch (s) {
    case TrackingState::kNotInitialized:
      return "not_initialized";
    case TrackingState::kOk:
      return "ok";
    case TrackingState::kLost:
      return "lost";
    case TrackingState::kRelocalized:
      return "relocalized";
  }
  return "unknown";
}

const char* ObjectStateName(ObjectState s) {
  switch (s) {
    case ObjectState::kNew:
      return "new";
    case ObjectState::kTracked:
      return "tracked";
    case ObjectState::kLost:
      return "lost";
  }
  return "unknown";
}

const char* ClusterEventTypeName(ClusterEventType t) {
  switch (t) {
    case ClusterEventType::kCreated:
      return "created";
    case ClusterEventType::kPlaneUpdated:
      return "plane_updated";
    case ClusterEventType::kLost:
      return "lost";
    case ClusterEventType::kRemoved:
      return "removed";
  }
  return "unknown";
}

}  // namespace twist
