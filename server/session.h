// One SLAM session of the server: its engine (one SlamSystem), its immutable
// setup (calibration, frame format, rectifier, policy), its counters, and the
// stream currently bound to it (at most one).
#pragma once

#include <grpcpp/server_context.h>

#include <atomic>
#include <cstdint>
#include <deque>
#include <functional>
#include <memory>
#include <optional>
#include <string>

#include "absl/base/thread_annotations.h"
#include "absl/status/status.h"
#include "absl/status/statusor.h"
#include "absl/synchronization/mutex.h"
#include "absl/time/time.h"
#include "server/convert.h"
#include "server/frame_queue.h"
#include "server/rectifier.h"
#include "slam/system/slam_system.h"
#include "twistslam/v1/slam_service.pb.h"

namespace twist::server {

// How the server makes engines; tests substitute fakes, the product binary
// uses SlamSystem::Create / SlamSystem::Load.
struct SlamSystemFactory {
  std::function<absl::StatusOr<std::unique_ptr<SlamSystem>>(const SessionConfig&)> create;
  std::function<absl::StatusOr<std::unique_ptr<SlamSystem>>(const std::string& path)> load;
};

// Everything derived from a CreateSessionRequest (validated).
struct SessionSetup {
  SessionConfig config;                      // what the engine is created with
  FrameFormat format;                        // what incoming frames must look like
  std::optional<StereoRectifier> rectifier;  // unrectified rigs only
  pb::SessionPolicy policy;                  // effective (defaults applied, capped)
};

// The stream bound to a session (owned by the Stream handler).
struct StreamHandle {
  grpc::ServerContext* context = nullptr;
  FrameQueue* queue = nullptr;
  std::atomic<bool> taken_over{false};  // a newer stream bound the session
  std::atomic<bool> shutdown{false};    // the server is draining
};

// Identity and counters, persisted with the engine state.
struct SessionRecord {
  std::string id;
  std::string name;
  std::string owner;  // principal ("" without authentication)
  std::string resume_token;
  int64_t created_unix_ms = 0;
  pb::CreateSessionRequest request;  // as sent (rebuilds the setup on load)
  int64_t frames_processed = 0;
  int64_t frames_dropped = 0;
  int64_t frames_rejected = 0;
  int64_t last_frame_index = -1;
  int64_t last_timestamp_ns = 0;
};

class Session {
 public:
  Session(SessionRecord record, SessionSetup setup, std::unique_ptr<SlamSystem> system);
  ~Session();

  const std::string& id() const { return id_; }
  const std::string& owner() const { return owner_; }
  const std::string& resume_token() const { return resume_token_; }
  const FrameFormat& format() const { return setup_.format; }
  const StereoRectifier* rectifier() const {
    return setup_.rectifier ? &*setup_.rectifier : nullptr;
  }
  const pb::SessionPolicy& policy() const { return setup_.policy; }
  const geometry::StereoCamera& camera() const { return setup_.config.camera; }

  // Runs the engine on one decoded frame. FailedPrecondition when closed,
  // InvalidArgument for a timestamp not after the last processed frame's, or
  // the engine's own error; the session is unchanged on error.
  absl::StatusOr<FrameResult> Process(const StereoFrame& frame, double* engine_ms);

  // A consistent copy of the map and the frame count it corresponds to.
  absl::StatusOr<MapSnapshot> Snapshot(int64_t* frames_processed);

  // Saves engine + record under <state_dir>/<id>/ (a new version directory,
  // then an atomic switch of CURRENT). Returns the record saved.
  absl::StatusOr<SessionRecord> SaveTo(const std::string& state_dir);
  // True when never saved or frames were processed since the last save.
  bool NeedsSave() const;
  // Records that the current state is on disk (after loading it).
  void MarkSaved();

  // Binds `handle`; a stream already bound is taken over (cancelled) and
  // waited for up to `wait`.
  absl::Status Bind(StreamHandle* handle, absl::Duration wait);
  void Unbind(StreamHandle* handle);
  bool streaming() const;
  // Asks the bound stream (if any) to stop reading and drain its queue.
  void BeginDrain();
  // Polls until no stream is bound or its queue is empty and no frame is in
  // the engine, or `deadline` passes.
  void WaitDrained(absl::Time deadline);
  // Polls until no stream is bound or `deadline` passes; true if unbound.
  bool WaitUnbound(absl::Time deadline);
  // Atomically: if no stream is bound, refuses any further Bind/Process (the
  // session is being unloaded) and returns true.
  bool TryRetire();
  // Cancels the bound stream (if any).
  void CancelStream();

  // Last updates, for replay to a reconnecting stream (BindStream.replay).
  static constexpr size_t kReplayCapacity = 256;
  void RememberUpdate(const pb::FrameUpdate& update);
  std::vector<pb::FrameUpdate> UpdatesAfter(int64_t timestamp_ns) const;

  void Touch();
  absl::Time last_activity() const;
  void RecordDropped(int64_t n);
  void RecordRejected();

  pb::SessionInfo Info() const;
  SessionRecord Record() const;
  // Marks the session closed, ends the bound stream, stops the engine.
  void Close();
  bool closed() const;

 private:
  const std::string id_;
  const std::string owner_;
  const std::string resume_token_;
  const SessionSetup setup_;

  // Held while the engine runs, saves or snapshots (lock order: engine_mu_
  // before mu_).
  mutable absl::Mutex engine_mu_;
  std::unique_ptr<SlamSystem> system_ ABSL_GUARDED_BY(engine_mu_);

  mutable absl::Mutex mu_;
  SessionRecord record_ ABSL_GUARDED_BY(mu_);
  int64_t saved_frames_ ABSL_GUARDED_BY(mu_) = -1;
  absl::Time last_activity_ ABSL_GUARDED_BY(mu_);
  bool closed_ ABSL_GUARDED_BY(mu_) = false;
  bool processing_ ABSL_GUARDED_BY(mu_) = false;
  bool engine_stopped_ ABSL_GUARDED_BY(engine_mu_) = false;
  StreamHandle* bound_ ABSL_GUARDED_BY(mu_) = nullptr;
  int num_map_points_ ABSL_GUARDED_BY(mu_) = 0;
  int num_keyframes_ ABSL_GUARDED_BY(mu_) = 0;
  std::deque<pb::FrameUpdate> recent_updates_ ABSL_GUARDED_BY(mu_);
};

// SlamOptions' defaults except mapping_mode = background.
inline SlamOptions ServiceDefaultOptions() {
  SlamOptions o;
  o.mapping_mode = MappingMode::kBackground;
  return o;
}

// Builds and validates a session's setup from its creation request, on top
// of the server's defaults.
struct SetupLimits {
  // The engine's defaults, with mapping in the session's own thread: a
  // service must keep up with its stream (synchronous mapping, the engine's
  // deterministic default for tests, runs a KITTI-size stream at ~3 frames/s
  // on 2 cores against ~10 in the background; docs/server.md).
  SlamOptions default_options = ServiceDefaultOptions();
  int default_queue_capacity = 4;
  int max_queue_capacity = 64;
  double default_idle_timeout_s = 600;
  double max_idle_timeout_s = 7 * 24 * 3600;
  int max_image_width = 8192;
  int max_image_height = 8192;
};
absl::StatusOr<SessionSetup> BuildSessionSetup(const pb::CreateSessionRequest& request,
                                               const SetupLimits& limits);

// Reads a session saved by Session::SaveTo: its record and the path of the
// engine state to give SlamSystemFactory::load.
absl::StatusOr<SessionRecord> ReadSessionRecord(const std::string& state_dir,
                                                const std::string& id,
                                                std::string* engine_path);

}  // namespace twist::server
