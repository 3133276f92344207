#include "server/session_manager.h"

#include <glog/logging.h>

#include <filesystem>
#include <utility>

#include "absl/strings/str_cat.h"
#include "absl/strings/str_format.h"

namespace twist::server {
namespace fs = std::filesystem;

namespace {

constexpr size_t kMaxRememberedClosed = 10000;

bool SameSecret(const std::string& a, const std::string& b) {
  if (a.size() != b.size()) return false;
  unsigned char diff = 0;
  for (size_t i = 0; i < a.size(); ++i) diff |= static_cast<unsigned char>(a[i] ^ b[i]);
  return diff == 0;
}

absl::Status NotFound(const std::string& id) {
  return absl::NotFoundError(absl::StrCat("session '", id, "' not found"));
}

// Ids become directory names: accept only what NewId produces.
bool WellFormedId(const std::string& id) {
  if (id.empty() || id.size() > 64) return false;
  for (char c : id) {
    if (!((c >= '0' && c <= '9') || (c >= 'a' && c <= 'z') || c == '-')) return false;
  }
  return true;
}

pb::SessionInfo StoredInfo(const SessionRecord& r) {
  pb::SessionInfo info;
  info.set_session_id(r.id);
  info.set_name(r.name);
  info.set_state(pb::SESSION_STATE_STORED);
  *info.mutable_calibration() = r.request.config().calibration();
  info.set_frames_processed(r.frames_processed);
  info.set_frames_dropped(r.frames_dropped);
  info.set_frames_rejected(r.frames_rejected);
  info.set_last_frame_index(r.last_frame_index);
  info.set_last_timestamp_ns(r.last_timestamp_ns);
  info.set_created_unix_ms(r.created_unix_ms);
  info.set_last_persisted_frames(r.frames_processed);
  *info.mutable_policy() = r.request.policy();
  *info.mutable_options() = r.request.config().options();  // as sent at creation
  return info;
}

}  // namespace

SessionManager::SessionManager(SessionManagerOptions options,
                               SlamSystemFactory factory,
                               Metrics* metrics)
    : options_(std::move(options)), factory_(std::move(factory)), metrics_(metrics) {
  std::random_device device;
  rng_.seed((static_cast<uint64_t>(device()) << 32) ^ device() ^
            static_cast<uint64_t>(absl::ToUnixNanos(absl::Now())));
  if (!options_.state_dir.empty()) {
    std::error_code ec;
    fs::create_directories(options_.state_dir, ec);
    if (ec)
      LOG(WARNING) << "cannot create state dir " << options_.state_dir << ": " << ec.message();
  }
  if (options_.housekeeping_period_s > 0) {
    housekeeping_ = std::thread([this] { HousekeepingLoop(); });
  }
}

SessionManager::~SessionManager() {
  stop_.Notify();
  if (housekeeping_.joinable()) housekeeping_.join();
  absl::MutexLock lock(&mu_);
  for (auto& [id, session] : sessions_) session->Close();
}

std::string SessionManager::NewId() {
  absl::MutexLock lock(&mu_);
  return absl::StrFormat("%016x%016x", rng_(), rng_());
}

absl::StatusOr<std::shared_ptr<Session>> SessionManager::Create(
    const pb::CreateSessionRequest& request, const std::string& owner) {
  if (!accepting_)
    return absl::UnavailableError("server is shutting down; not accepting new sessions");
  absl::StatusOr<SessionSetup> setup = BuildSessionSetup(request, options_.limits);
  if (!setup.ok()) return setup.status();
  const std::string id = NewId();
  const std::string token = NewId();
  {
    absl::MutexLock lock(&mu_);
    if (static_cast<int>(sessions_.size() + loading_.size()) >= options_.max_sessions) {
      return absl::ResourceExhaustedError(absl::StrCat("server has reached its limit of ",
                                                       options_.max_sessions,
                                                       " sessions; close one or try later"));
    }
    loading_.insert(id);
  }
  absl::StatusOr<std::unique_ptr<SlamSystem>> system = factory_.create(setup->config);
  if (!system.ok()) {
    absl::MutexLock lock(&mu_);
    loading_.erase(id);
    return system.status();
  }
  SessionRecord record;
  record.id = id;
  record.name = request.name();
  record.owner = owner;
  record.resume_token = token;
  record.created_unix_ms = absl::ToUnixMillis(absl::Now());
  record.request = request;
  auto session =
      std::make_shared<Session>(std::move(record), std::move(*setup), std::move(*system));
  {
    absl::MutexLock lock(&mu_);
    loading_.erase(id);
    sessions_[id] = session;
  }
  if (metrics_) metrics_->SessionCreated();
  LOG(INFO) << "session " << id << " created (name '" << request.name() << "', "
            << session->camera().width << "x" << session->camera().height << ")";
  return session;
}

absl::StatusOr<std::shared_ptr<Session>> SessionManager::Get(const std::string& id,
                                                             const std::string& owner) {
  if (id.empty()) return absl::InvalidArgumentError("session_id is empty");
  {
    absl::MutexLock lock(&mu_);
    auto it = sessions_.find(id);
    if (it != sessions_.end()) {
      if (it->second->owner() != owner) return NotFound(id);
      it->second->Touch();
      return it->second;
    }
    auto closed = closed_.find(id);
    if (closed != closed_.end() && closed->second == owner) {
      return absl::FailedPreconditionError(absl::StrCat("session '", id, "' is closed"));
    }
    if (loading_.count(id)) {
      return absl::UnavailableError(
          absl::StrCat("session '", id, "' is being loaded or saved; retry"));
    }
  }
  if (!options_.state_dir.empty() && WellFormedId(id)) {
    std::string engine_path;
    absl::StatusOr<SessionRecord> record = ReadSessionRecord(options_.state_dir, id, &engine_path);
    if (record.ok() && record->owner == owner) {
      return absl::FailedPreconditionError(
          absl::StrCat("session '", id, "' is stored but not loaded; call ResumeSession first"));
    }
  }
  return NotFound(id);
}

absl::StatusOr<std::shared_ptr<Session>> SessionManager::Resume(const std::string& id,
                                                                const std::string& resume_token,
                                                                const std::string& owner,
                                                                bool* loaded) {
  *loaded = false;
  if (!accepting_) return absl::UnavailableError("server is shutting down");
  if (id.empty()) return absl::InvalidArgumentError("session_id is empty");
  {
    absl::MutexLock lock(&mu_);
    auto it = sessions_.find(id);
    if (it != sessions_.end()) {
      if (it->second->owner() != owner) return NotFound(id);
      if (!SameSecret(it->second->resume_token(), resume_token)) {
        return absl::PermissionDeniedError(
            absl::StrCat("resume token does not match session '", id, "'"));
      }
      it->second->Touch();
      return it->second;
    }
  }
  if (options_.state_dir.empty()) {
    return absl::NotFoundError(
        absl::StrCat("session '", id, "' not found (the server has no --state-dir)"));
  }
  if (!WellFormedId(id)) return NotFound(id);
  std::string engine_path;
  absl::StatusOr<SessionRecord> record = ReadSessionRecord(options_.state_dir, id, &engine_path);
  if (!record.ok()) {
    if (absl::IsNotFound(record.status())) return NotFound(id);
    return record.status();
  }
  if (record->owner != owner) return NotFound(id);
  if (!SameSecret(record->resume_token, resume_token)) {
    return absl::PermissionDeniedError(
        absl::StrCat("resume token does not match session '", id, "'"));
  }
  {
    absl::MutexLock lock(&mu_);
    if (sessions_.count(id) || loading_.count(id)) {
      return absl::UnavailableError(absl::StrCat("session '", id, "' is being loaded; retry"));
    }
    if (static_cast<int>(sessions_.size() + loading_.size()) >= options_.max_sessions) {
      return absl::ResourceExhaustedError(absl::StrCat("server has reached its limit of ",
                                                       options_.max_sessions,
                                                       " sessions; close one or try later"));
    }
    loading_.insert(id);
  }
  auto fail = [this, &id](absl::Status s) {
    absl::MutexLock lock(&mu_);
    loading_.erase(id);
    return s;
  };
  absl::StatusOr<SessionSetup> setup = BuildSessionSetup(record->request, options_.limits);
  if (!setup.ok()) {
    return fail(absl::FailedPreconditionError(absl::StrCat(
        "stored session '", id, "' no longer fits this server: ", setup.status().message())));
  }
  absl::StatusOr<std::unique_ptr<SlamSystem>> system = factory_.load(engine_path);
  if (!system.ok()) {
    return fail(
        absl::Status(system.status().code(),
                     absl::StrCat("loading session '", id, "': ", system.status().message())));
  }
  if ((*system)->frames_processed() != record->frames_processed) {
    return fail(absl::DataLossError(absl::StrCat("stored session '",
                                                 id,
                                                 "': engine has ",
                                                 (*system)->frames_processed(),
                                                 " frames, record says ",
                                                 record->frames_processed)));
  }
  auto session =
      std::make_shared<Session>(std::move(*record), std::move(*setup), std::move(*system));
  session->MarkSaved();
  {
    absl::MutexLock lock(&mu_);
    loading_.erase(id);
    closed_.erase(id);
    sessions_[id] = session;
    last_save_[id] = absl::Now();
  }
  *loaded = true;
  LOG(INFO) << "session " << id << " resumed from " << options_.state_dir;
  return session;
}

absl::Status SessionManager::SaveLocked(Session* session) {
  if (options_.state_dir.empty())
    return absl::FailedPreconditionError("the server has no --state-dir");
  absl::StatusOr<SessionRecord> saved = session->SaveTo(options_.state_dir);
  if (!saved.ok()) {
    LOG(ERROR) << saved.status();
    return saved.status();
  }
  if (metrics_) metrics_->SessionPersisted();
  absl::MutexLock lock(&mu_);
  last_save_[session->id()] = absl::Now();
  return absl::OkStatus();
}

void SessionManager::RemoveStored(const std::string& id) {
  if (options_.state_dir.empty() || !WellFormedId(id)) return;
  std::error_code ec;
  fs::remove_all(fs::path(options_.state_dir) / id, ec);
}

absl::StatusOr<pb::SessionInfo> SessionManager::Close(const std::string& id,
                                                      const std::string& owner,
                                                      bool persist,
                                                      bool* persisted) {
  *persisted = false;
  absl::StatusOr<std::shared_ptr<Session>> session = Get(id, owner);
  if (!session.ok()) {
    // A session only on disk can be closed too (deleting it unless persist).
    if (absl::IsFailedPrecondition(session.status()) && !options_.state_dir.empty() &&
        WellFormedId(id)) {
      std::string engine_path;
      absl::StatusOr<SessionRecord> record =
          ReadSessionRecord(options_.state_dir, id, &engine_path);
      if (record.ok() && record->owner == owner) {
        pb::SessionInfo info = StoredInfo(*record);
        if (persist) {
          *persisted = true;
        } else {
          RemoveStored(id);
          info.set_state(pb::SESSION_STATE_CLOSED);
        }
        return info;
      }
    }
    return session.status();
  }
  if (persist && !options_.state_dir.empty()) {
    (*session)->CancelStream();
    (*session)->WaitUnbound(absl::Now() + absl::Seconds(10));
    if (absl::Status s = SaveLocked(session->get()); !s.ok()) return s;
    *persisted = true;
  }
  (*session)->Close();
  {
    absl::MutexLock lock(&mu_);
    sessions_.erase(id);
    // Remembered so that a late stream gets "closed" rather than "not found";
    // bounded so a long-running server does not grow.
    if (closed_.size() >= kMaxRememberedClosed) closed_.erase(closed_.begin());
    closed_[id] = owner;
    last_save_.erase(id);
  }
  if (!*persisted) RemoveStored(id);
  if (metrics_) metrics_->SessionClosed();
  LOG(INFO) << "session " << id << " closed" << (*persisted ? " (persisted)" : "");
  return (*session)->Info();
}

absl::StatusOr<SessionRecord> SessionManager::Persist(const std::string& id,
                                                      const std::string& owner) {
  absl::StatusOr<std::shared_ptr<Session>> session = Get(id, owner);
  if (!session.ok()) return session.status();
  if (options_.state_dir.empty()) {
    return absl::FailedPreconditionError(
        "cannot persist: the server was started without --state-dir");
  }
  if (absl::Status s = SaveLocked(session->get()); !s.ok()) return s;
  return (*session)->Record();
}

std::vector<pb::SessionInfo> SessionManager::List(const std::string& owner) {
  std::vector<pb::SessionInfo> out;
  std::set<std::string> skip;
  {
    absl::MutexLock lock(&mu_);
    for (const auto& [id, session] : sessions_) {
      skip.insert(id);
      if (session->owner() == owner) out.push_back(session->Info());
    }
    for (const auto& [id, o] : closed_) skip.insert(id);
    for (const std::string& id : loading_) skip.insert(id);
  }
  if (!options_.state_dir.empty()) {
    std::error_code ec;
    for (const fs::directory_entry& e : fs::directory_iterator(options_.state_dir, ec)) {
      const std::string id = e.path().filename().string();
      if (!e.is_directory() || skip.count(id) || !WellFormedId(id)) continue;
      std::string engine_path;
      absl::StatusOr<SessionRecord> record =
          ReadSessionRecord(options_.state_dir, id, &engine_path);
      if (record.ok() && record->owner == owner) out.push_back(StoredInfo(*record));
    }
  }
  return out;
}

int SessionManager::num_loaded() const {
  absl::MutexLock lock(&mu_);
  return static_cast<int>(sessions_.size());
}

MetricGauges SessionManager::Gauges() const {
  MetricGauges g;
  g.serving = accepting_;
  absl::MutexLock lock(&mu_);
  g.sessions_loaded = static_cast<int>(sessions_.size());
  for (const auto& [id, session] : sessions_) {
    const pb::SessionInfo info = session->Info();
    if (info.state() == pb::SESSION_STATE_STREAMING) ++g.sessions_streaming;
    g.queue_depth_total += info.queue_depth();
    g.queue_depth_max = std::max(g.queue_depth_max, info.queue_depth());
  }
  return g;
}

void SessionManager::StopAccepting() { accepting_ = false; }

void SessionManager::DrainStreams(absl::Time deadline) {
  std::vector<std::shared_ptr<Session>> sessions;
  {
    absl::MutexLock lock(&mu_);
    for (const auto& [id, session] : sessions_) sessions.push_back(session);
  }
  for (auto& s : sessions) s->BeginDrain();
  for (auto& s : sessions) s->WaitDrained(deadline);
  // Whatever still streams now is cancelled; its handler returns promptly.
  for (auto& s : sessions) s->CancelStream();
  const absl::Time unbind_deadline = std::max(deadline, absl::Now()) + absl::Seconds(2);
  for (auto& s : sessions) {
    if (!s->WaitUnbound(unbind_deadline))
      LOG(WARNING) << "session " << s->id() << ": stream did not end";
  }
}

void SessionManager::PersistAll() {
  if (options_.state_dir.empty()) return;
  std::vector<std::shared_ptr<Session>> sessions;
  {
    absl::MutexLock lock(&mu_);
    for (const auto& [id, session] : sessions_) sessions.push_back(session);
  }
  for (auto& s : sessions) {
    if (s->NeedsSave()) {
      if (SaveLocked(s.get()).ok()) LOG(INFO) << "session " << s->id() << " persisted";
    }
  }
}

void SessionManager::Housekeeping(absl::Time now) {
  std::vector<std::shared_ptr<Session>> sessions;
  {
    absl::MutexLock lock(&mu_);
    for (const auto& [id, session] : sessions_) sessions.push_back(session);
  }
  for (auto& s : sessions) {
    const double idle_s = absl::ToDoubleSeconds(now - s->last_activity());
    if (idle_s > s->policy().idle_timeout_s() && !s->streaming()) {
      // Mark it as being unloaded so that no lookup hands it out meanwhile.
      {
        absl::MutexLock lock(&mu_);
        if (!s->TryRetire()) continue;
        sessions_.erase(s->id());
        loading_.insert(s->id());
      }
      bool saved = false;
      if (!options_.state_dir.empty()) saved = SaveLocked(s.get()).ok();
      s->Close();
      {
        absl::MutexLock lock(&mu_);
        loading_.erase(s->id());
        if (!saved) {
          if (closed_.size() >= kMaxRememberedClosed) closed_.erase(closed_.begin());
          closed_[s->id()] = s->owner();
        }
      }
      if (metrics_) metrics_->SessionExpired();
      LOG(INFO) << "session " << s->id() << " idle for " << idle_s
                << " s: " << (saved ? "persisted and unloaded" : "closed");
      continue;
    }
    if (!options_.state_dir.empty() && options_.persist_interval_s > 0 && s->NeedsSave()) {
      absl::Time last;
      {
        absl::MutexLock lock(&mu_);
        auto it = last_save_.find(s->id());
        last = it == last_save_.end() ? absl::InfinitePast() : it->second;
        if (it == last_save_.end()) last_save_[s->id()] = now;  // first change: wait one interval
      }
      if (last != absl::InfinitePast() &&
          absl::ToDoubleSeconds(now - last) >= options_.persist_interval_s) {
        SaveLocked(s.get()).IgnoreError();
      }
    }
  }
}

void SessionManager::HousekeepingLoop() {
  const absl::Duration period = absl::Seconds(options_.housekeeping_period_s);
  while (!stop_.WaitForNotificationWithTimeout(period)) Housekeeping(absl::Now());
}

}  // namespace twist::server
