// SlamSystem: the engine facade one session owns. Single-threaded and
// deterministic when Options::mapping_mode == kSynchronous; with kBackground
// the session's local mapping runs in its own thread.
//
// Contract used by server/ and client/ (do not break it lightly):
//   auto sys = SlamSystem::Create(config);          // validates everything
//   absl::StatusOr<FrameResult> r = sys->Process(frame);
//     - bad input (sizes, types, non-increasing timestamps) -> InvalidArgument,
//       and the session is left exactly as it was;
//     - "tracking lost" is r->state, not an error.
//   sys->Save(path) / SlamSystem::Load(path) round-trip the whole state,
//     object stage included (state format 4): a resumed session continues
//     bit for bit like an uninterrupted one. Files of formats 1-3 still load
//     (their objects restart); corrupt files give DataLoss.
#pragma once

#include <memory>
#include <string>
#include <vector>

#include "absl/status/status.h"
#include "absl/status/statusor.h"
#include "slam/common/frame_result.h"
#include "slam/common/stereo_frame.h"
#include "slam/geometry/stereo_camera.h"
#include "slam/system/slam_options.h"

namespace twist {

// A read-only copy of the map for clients (map fetch, plots, PLY export).
struct MapSnapshot {
  // (timestamp_ns, world_from_object), oldest first.
  using TimedPoses = std::vector<std::pair<int64_t, geometry::SE3d>>;
  struct Point {
    Eigen::Vector3d p_in_world;
    int class_id = 0;
    int64_t cluster_id = -1;  // -1: not in a cluster
  };
  struct KeyFrame {
    int64_t id = 0;
    int64_t timestamp_ns = 0;
    geometry::SE3d world_from_camera;
  };
  struct Cluster {
    int64_t id = 0;
    int class_id = 0;
    int instance_id = 0;
    bool is_dynamic = false;
    std::optional<Eigen::Vector4d> plane;
    TimedPoses trajectory;
  };
  // The whole trajectory of a tracked object (also of one removed since), as
  // the dynamic BA left it: its refined counterpart of the per-frame
  // ObjectResult poses, with the same object id.
  struct Object {
    int64_t id = 0;
    int class_id = 0;
    int instance_id = 0;     // the last one seen
    int64_t cluster_id = 0;  // the last one held (-1: none)
    TimedPoses trajectory;
  };
  std::vector<Point> points;
  std::vector<KeyFrame> keyframes;
  std::vector<Cluster> clusters;
  std::vector<Object> objects;  // ordered by id
};

class SlamSystem {
 public:
  static absl::StatusOr<std::unique_ptr<SlamSystem>> Create(const SessionConfig& config);
  // Restores a system written by Save().
  static absl::StatusOr<std::unique_ptr<SlamSystem>> Load(const std::string& path);

  virtual ~SlamSystem() = default;

  virtual absl::StatusOr<FrameResult> Process(const StereoFrame& frame) = 0;
  virtual MapSnapshot Snapshot() const = 0;
  // Writes the whole state (config, map, camera tracker, mapper, parked
  // instances, object stage, last timestamps) atomically (temp file + rename).
  virtual absl::Status Save(const std::string& path) const = 0;
  virtual const SessionConfig& config() const = 0;
  virtual int64_t frames_processed() const = 0;
  // Stops background threads (idempotent). Process() after Shutdown() fails
  // with FailedPrecondition.
  virtual void Shutdown() = 0;
};

}  // namespace twist
