// All sessions of a server: creation with limits, lookup with ownership,
// close, list, persistence to the state directory (on request, on close,
// periodically, on shutdown), resume after a restart, idle expiry.
#pragma once

#include <atomic>
#include <map>
#include <memory>
#include <random>
#include <set>
#include <string>
#include <thread>
#include <vector>

#include "absl/base/thread_annotations.h"
#include "absl/status/statusor.h"
#include "absl/synchronization/mutex.h"
#include "absl/synchronization/notification.h"
#include "absl/time/time.h"
#include "server/metrics.h"
#include "server/session.h"

namespace twist::server {

struct SessionManagerOptions {
  SetupLimits limits;
  int max_sessions = 16;               // loaded sessions at once
  std::string state_dir;               // empty: no persistence
  double persist_interval_s = 60;      // periodic save of changed sessions; <= 0 off
  double housekeeping_period_s = 1.0;  // how often expiry/persistence run
  absl::Duration takeover_wait = absl::Seconds(10);
};

struct CreatedSession {
  std::shared_ptr<Session> session;
};

class SessionManager {
 public:
  SessionManager(SessionManagerOptions options, SlamSystemFactory factory, Metrics* metrics);
  ~SessionManager();

  const SessionManagerOptions& options() const { return options_; }

  absl::StatusOr<std::shared_ptr<Session>> Create(const pb::CreateSessionRequest& request,
                                                  const std::string& owner);
  // A loaded session of `owner`. NOT_FOUND for unknown ids and other owners'
  // sessions; FAILED_PRECONDITION for a closed session or one only stored on
  // disk (ResumeSession loads it).
  absl::StatusOr<std::shared_ptr<Session>> Get(const std::string& id, const std::string& owner);
  // Loads a stored session (or returns the loaded one) after checking the
  // resume token. *loaded tells whether it came from disk.
  absl::StatusOr<std::shared_ptr<Session>> Resume(const std::string& id,
                                                  const std::string& resume_token,
                                                  const std::string& owner,
                                                  bool* loaded);
  // Closes a session (optionally persisting it first; without persist any
  // stored copy is deleted). Returns its final info and whether it was saved.
  absl::StatusOr<pb::SessionInfo> Close(const std::string& id,
                                        const std::string& owner,
                                        bool persist,
                                        bool* persisted);
  absl::StatusOr<SessionRecord> Persist(const std::string& id, const std::string& owner);
  // Loaded and stored sessions of `owner`.
  std::vector<pb::SessionInfo> List(const std::string& owner);

  bool accepting() const { return accepting_; }
  int num_loaded() const;
  MetricGauges Gauges() const;

  // Graceful shutdown, step by step (TwistServer::Shutdown drives it):
  // refuse new sessions/streams; let bound streams drain their queues (until
  // `deadline`), then cancel them; wait for their handlers; save every
  // session that changed.
  void StopAccepting();
  void DrainStreams(absl::Time deadline);
  void PersistAll();

  // One housekeeping pass (normally run by the background thread; public for
  // tests): expires idle sessions and saves changed ones periodically.
  void Housekeeping(absl::Time now);

 private:
  std::string NewId();
  absl::Status SaveLocked(Session* session);
  void RemoveStored(const std::string& id);
  void HousekeepingLoop();

  const SessionManagerOptions options_;
  const SlamSystemFactory factory_;
  Metrics* const metrics_;
  std::atomic<bool> accepting_{true};

  mutable absl::Mutex mu_;
  std::map<std::string, std::shared_ptr<Session>> sessions_ ABSL_GUARDED_BY(mu_);
  std::map<std::string, std::string> closed_ ABSL_GUARDED_BY(mu_);  // id -> owner
  std::set<std::string> loading_ ABSL_GUARDED_BY(mu_);              // ids being created/loaded
  std::mt19937_64 rng_ ABSL_GUARDED_BY(mu_);
  std::map<std::string, absl::Time> last_save_ ABSL_GUARDED_BY(mu_);

  absl::Notification stop_;
  std::thread housekeeping_;
};

}  // namespace twist::server
