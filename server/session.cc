#include "server/session.h"

#include <glog/logging.h>

#include <filesystem>
#include <fstream>
#include <sstream>
#include <utility>

#include "absl/strings/ascii.h"
#include "absl/strings/escaping.h"
#include "absl/strings/numbers.h"
#include "absl/strings/str_cat.h"
#include "absl/strings/str_split.h"
#include "slam/common/timer.h"

namespace twist::server {
namespace fs = std::filesystem;

namespace {

constexpr char kCurrentFile[] = "CURRENT";
constexpr char kEngineFile[] = "engine.state";
constexpr char kRequestFile[] = "request.pb";
constexpr char kRecordFile[] = "record.txt";

absl::Status WriteFile(const fs::path& path, const std::string& contents) {
  const fs::path tmp = path.string() + ".tmp";
  {
    std::ofstream out(tmp, std::ios::binary | std::ios::trunc);
    if (!out) return absl::InternalError(absl::StrCat("cannot write ", tmp.string()));
    out.write(contents.data(), static_cast<std::streamsize>(contents.size()));
    out.flush();
    if (!out) return absl::InternalError(absl::StrCat("cannot write ", tmp.string()));
  }
  std::error_code ec;
  fs::rename(tmp, path, ec);
  if (ec)
    return absl::InternalError(absl::StrCat("cannot rename ", tmp.string(), ": ", ec.message()));
  return absl::OkStatus();
}

absl::StatusOr<std::string> ReadFile(const fs::path& path) {
  std::ifstream in(path, std::ios::binary);
  if (!in) return absl::NotFoundError(absl::StrCat("cannot read ", path.string()));
  std::stringstream ss;
  ss << in.rdbuf();
  return ss.str();
}

std::string RecordText(const SessionRecord& r) {
  std::string out;
  auto kv = [&out](const char* k, const std::string& v) {
    absl::StrAppend(&out, k, "=", absl::CEscape(v), "\n");
  };
  kv("id", r.id);
  kv("name", r.name);
  kv("owner", r.owner);
  kv("resume_token", r.resume_token);
  kv("created_unix_ms", absl::StrCat(r.created_unix_ms));
  kv("frames_processed", absl::StrCat(r.frames_processed));
  kv("frames_dropped", absl::StrCat(r.frames_dropped));
  kv("frames_rejected", absl::StrCat(r.frames_rejected));
  kv("last_frame_index", absl::StrCat(r.last_frame_index));
  kv("last_timestamp_ns", absl::StrCat(r.last_timestamp_ns));
  return out;
}

absl::Status ParseRecordText(const std::string& text, SessionRecord* r) {
  std::map<std::string, std::string> kv;
  for (absl::string_view line : absl::StrSplit(text, '\n', absl::SkipEmpty())) {
    const size_t eq = line.find('=');
    if (eq == absl::string_view::npos) return absl::DataLossError("session record: malformed line");
    std::string value;
    if (!absl::CUnescape(line.substr(eq + 1), &value))
      return absl::DataLossError("session record: bad escape");
    kv[std::string(line.substr(0, eq))] = value;
  }
  auto int_field = [&kv](const char* k, int64_t* v) {
    auto it = kv.find(k);
    return it != kv.end() && absl::SimpleAtoi(it->second, v);
  };
  r->id = kv["id"];
  r->name = kv["name"];
  r->owner = kv["owner"];
  r->resume_token = kv["resume_token"];
  if (r->id.empty() || r->resume_token.empty() ||
      !int_field("created_unix_ms", &r->created_unix_ms) ||
      !int_field("frames_processed", &r->frames_processed) ||
      !int_field("frames_dropped", &r->frames_dropped) ||
      !int_field("frames_rejected", &r->frames_rejected) ||
      !int_field("last_frame_index", &r->last_frame_index) ||
      !int_field("last_timestamp_ns", &r->last_timestamp_ns)) {
    return absl::DataLossError("session record: missing fields");
  }
  return absl::OkStatus();
}

}  // namespace

// ---------------------------------------------------------------------------

absl::StatusOr<SessionSetup> BuildSessionSetup(const pb::CreateSessionRequest& request,
                                               const SetupLimits& limits) {
  if (request.name().size() > 128) {
    return absl::InvalidArgumentError(
        absl::StrCat("name is ", request.name().size(), " bytes; at most 128"));
  }
  if (!request.has_config() || !request.config().has_calibration()) {
    return absl::InvalidArgumentError("config.calibration is required");
  }
  const pb::StereoCalibration& calib = request.config().calibration();
  if (calib.width() > limits.max_image_width || calib.height() > limits.max_image_height) {
    return absl::InvalidArgumentError(absl::StrCat("calibration: image size ",
                                                   calib.width(),
                                                   "x",
                                                   calib.height(),
                                                   " exceeds the server limit ",
                                                   limits.max_image_width,
                                                   "x",
                                                   limits.max_image_height));
  }
  SessionSetup setup;
  if (calib.has_unrectified()) {
    const pb::UnrectifiedRig& u = calib.unrectified();
    RawStereoRig rig;
    auto camera_model = [](const pb::CameraIntrinsics& c) {
      RawCameraModel m;
      m.fx = c.fx();
      m.fy = c.fy();
      m.cx = c.cx();
      m.cy = c.cy();
      m.distortion.assign(c.distortion().begin(), c.distortion().end());
      return m;
    };
    rig.left = camera_model(u.left());
    rig.right = camera_model(u.right());
    absl::StatusOr<geometry::SE3d> right_from_left = FromProto(u.right_from_left());
    if (!right_from_left.ok()) {
      return absl::InvalidArgumentError(
          absl::StrCat("unrectified rig right_from_left: ", right_from_left.status().message()));
    }
    rig.right_from_left = *right_from_left;
    rig.width = calib.width();
    rig.height = calib.height();
    absl::StatusOr<StereoRectifier> rectifier = StereoRectifier::Create(rig);
    if (!rectifier.ok()) return rectifier.status();
    setup.config.camera = rectifier->rectified_camera();
    setup.rectifier = std::move(*rectifier);
    setup.format.allow_flow = false;
  } else {
    absl::StatusOr<geometry::StereoCamera> camera = RectifiedCameraFromProto(calib);
    if (!camera.ok()) return camera.status();
    setup.config.camera = *camera;
  }
  setup.format.width = calib.width();
  setup.format.height = calib.height();

  absl::StatusOr<joints::ClassTable> classes = ClassTableFromProto(request.config().class_table());
  if (!classes.ok()) return classes.status();
  setup.config.classes = std::move(*classes);
  setup.config.options = limits.default_options;
  if (absl::Status s = ApplyOptions(request.config().options(), &setup.config.options); !s.ok())
    return s;

  const pb::SessionPolicy& p = request.policy();
  if (p.queue_capacity() < 0) {
    return absl::InvalidArgumentError(
        absl::StrCat("policy.queue_capacity ", p.queue_capacity(), " is negative"));
  }
  if (!(p.idle_timeout_s() >= 0)) {
    return absl::InvalidArgumentError("policy.idle_timeout_s must be >= 0");
  }
  if (p.overflow() != pb::OVERFLOW_POLICY_UNSPECIFIED &&
      p.overflow() != pb::OVERFLOW_POLICY_BLOCK &&
      p.overflow() != pb::OVERFLOW_POLICY_DROP_OLDEST) {
    return absl::InvalidArgumentError(
        absl::StrCat("policy.overflow ", p.overflow(), " is unknown"));
  }
  setup.policy.set_queue_capacity(p.queue_capacity() == 0
                                      ? limits.default_queue_capacity
                                      : std::min(p.queue_capacity(), limits.max_queue_capacity));
  setup.policy.set_overflow(p.overflow() == pb::OVERFLOW_POLICY_DROP_OLDEST
                                ? pb::OVERFLOW_POLICY_DROP_OLDEST
                                : pb::OVERFLOW_POLICY_BLOCK);
  setup.policy.set_idle_timeout_s(p.idle_timeout_s() == 0
                                      ? limits.default_idle_timeout_s
                                      : std::min(p.idle_timeout_s(), limits.max_idle_timeout_s));
  return setup;
}

absl::StatusOr<SessionRecord> ReadSessionRecord(const std::string& state_dir,
                                                const std::string& id,
                                                std::string* engine_path) {
  const fs::path dir = fs::path(state_dir) / id;
  absl::StatusOr<std::string> current = ReadFile(dir / kCurrentFile);
  if (!current.ok()) return absl::NotFoundError(absl::StrCat("session ", id, " is not stored"));
  const fs::path version = dir / std::string(absl::StripAsciiWhitespace(*current));
  SessionRecord record;
  absl::StatusOr<std::string> text = ReadFile(version / kRecordFile);
  if (!text.ok())
    return absl::DataLossError(absl::StrCat("session ", id, ": ", text.status().message()));
  if (absl::Status s = ParseRecordText(*text, &record); !s.ok()) {
    return absl::DataLossError(absl::StrCat("session ", id, ": ", s.message()));
  }
  absl::StatusOr<std::string> request = ReadFile(version / kRequestFile);
  if (!request.ok() || !record.request.ParseFromString(*request)) {
    return absl::DataLossError(absl::StrCat("session ", id, ": cannot read its creation request"));
  }
  if (record.id != id)
    return absl::DataLossError(absl::StrCat("session ", id, ": record names another id"));
  *engine_path = (version / kEngineFile).string();
  return record;
}

// ---------------------------------------------------------------------------

Session::Session(SessionRecord record, SessionSetup setup, std::unique_ptr<SlamSystem> system)
    : id_(record.id),
      owner_(record.owner),
      resume_token_(record.resume_token),
      setup_(std::move(setup)),
      system_(std::move(system)),
      record_(std::move(record)),
      last_activity_(absl::Now()) {}

Session::~Session() { Close(); }

absl::StatusOr<FrameResult> Session::Process(const StereoFrame& frame, double* engine_ms) {
  absl::MutexLock engine_lock(&engine_mu_);
  int64_t last_ts = 0;
  bool have_last = false;
  {
    absl::MutexLock lock(&mu_);
    if (closed_) return absl::FailedPreconditionError(absl::StrCat("session ", id_, " is closed"));
    have_last = record_.frames_processed > 0;
    last_ts = record_.last_timestamp_ns;
    processing_ = true;
  }
  if (have_last && frame.timestamp_ns <= last_ts) {
    absl::MutexLock lock(&mu_);
    processing_ = false;
    ++record_.frames_rejected;
    return absl::InvalidArgumentError(absl::StrCat(
        "timestamp_ns ", frame.timestamp_ns, " is not after the previous frame's ", last_ts));
  }
  Stopwatch watch;
  absl::StatusOr<FrameResult> result = system_->Process(frame);
  *engine_ms = watch.ElapsedMs();
  absl::MutexLock lock(&mu_);
  processing_ = false;
  last_activity_ = absl::Now();
  if (result.ok()) {
    ++record_.frames_processed;
    record_.last_frame_index = frame.index;
    record_.last_timestamp_ns = frame.timestamp_ns;
    num_map_points_ = result->num_map_points;
    num_keyframes_ = result->num_keyframes;
  } else {
    ++record_.frames_rejected;
  }
  return result;
}

absl::StatusOr<MapSnapshot> Session::Snapshot(int64_t* frames_processed) {
  absl::MutexLock engine_lock(&engine_mu_);
  {
    absl::MutexLock lock(&mu_);
    if (closed_) return absl::FailedPreconditionError(absl::StrCat("session ", id_, " is closed"));
    *frames_processed = record_.frames_processed;
    last_activity_ = absl::Now();
  }
  return system_->Snapshot();
}

absl::StatusOr<SessionRecord> Session::SaveTo(const std::string& state_dir) {
  absl::MutexLock engine_lock(&engine_mu_);
  SessionRecord record;
  {
    absl::MutexLock lock(&mu_);
    record = record_;
  }
  const fs::path dir = fs::path(state_dir) / id_;
  std::error_code ec;
  fs::create_directories(dir, ec);
  if (ec)
    return absl::InternalError(absl::StrCat("cannot create ", dir.string(), ": ", ec.message()));
  // A fresh version directory; CURRENT switches to it only when complete.
  const std::string version =
      absl::StrCat("v", record.frames_processed, "-", absl::ToUnixNanos(absl::Now()));
  const fs::path vdir = dir / version;
  fs::create_directories(vdir, ec);
  if (ec)
    return absl::InternalError(absl::StrCat("cannot create ", vdir.string(), ": ", ec.message()));
  absl::Status s = system_->Save((vdir / kEngineFile).string());
  if (s.ok()) s = WriteFile(vdir / kRequestFile, record.request.SerializeAsString());
  if (s.ok()) s = WriteFile(vdir / kRecordFile, RecordText(record));
  if (s.ok()) s = WriteFile(dir / kCurrentFile, version + "\n");
  if (!s.ok()) {
    fs::remove_all(vdir, ec);
    return absl::Status(s.code(), absl::StrCat("saving session ", id_, ": ", s.message()));
  }
  // Older versions are garbage now.
  for (const fs::directory_entry& e : fs::directory_iterator(dir, ec)) {
    if (e.is_directory() && e.path().filename() != version) fs::remove_all(e.path(), ec);
  }
  absl::MutexLock lock(&mu_);
  saved_frames_ = record.frames_processed;
  return record;
}

bool Session::NeedsSave() const {
  absl::MutexLock lock(&mu_);
  return saved_frames_ < 0 || saved_frames_ != record_.frames_processed;
}

void Session::MarkSaved() {
  absl::MutexLock lock(&mu_);
  saved_frames_ = record_.frames_processed;
}

absl::Status Session::Bind(StreamHandle* handle, absl::Duration wait) {
  absl::MutexLock lock(&mu_);
  if (closed_) return absl::FailedPreconditionError(absl::StrCat("session ", id_, " is closed"));
  if (bound_ != nullptr) {
    LOG(INFO) << "session " << id_ << ": a new stream takes over from the bound one";
    // The old stream's worker stops, tells its client and ends the call; if
    // it is stuck writing to a client that does not read, cancel the call.
    bound_->taken_over = true;
    bound_->queue->Abort();
    auto released = [this]()
                        ABSL_SHARED_LOCKS_REQUIRED(mu_) { return bound_ == nullptr || closed_; };
    if (!mu_.AwaitWithTimeout(absl::Condition(&released), absl::Seconds(2))) {
      bound_->context->TryCancel();
      if (!mu_.AwaitWithTimeout(absl::Condition(&released), wait)) {
        return absl::UnavailableError(
            absl::StrCat("session ", id_, " is busy: the previous stream did not end"));
      }
    }
    if (closed_) return absl::FailedPreconditionError(absl::StrCat("session ", id_, " is closed"));
  }
  bound_ = handle;
  last_activity_ = absl::Now();
  return absl::OkStatus();
}

void Session::Unbind(StreamHandle* handle) {
  absl::MutexLock lock(&mu_);
  if (bound_ == handle) bound_ = nullptr;
  last_activity_ = absl::Now();
}

bool Session::streaming() const {
  absl::MutexLock lock(&mu_);
  return bound_ != nullptr;
}

void Session::BeginDrain() {
  absl::MutexLock lock(&mu_);
  if (bound_ == nullptr) return;
  bound_->shutdown = true;
  bound_->queue->CloseInput();
}

void Session::WaitDrained(absl::Time deadline) {
  while (absl::Now() < deadline) {
    {
      absl::MutexLock lock(&mu_);
      if (bound_ == nullptr || (bound_->queue->size() == 0 && !processing_)) return;
    }
    absl::SleepFor(absl::Milliseconds(5));
  }
}

bool Session::WaitUnbound(absl::Time deadline) {
  absl::MutexLock lock(&mu_);
  auto unbound = [this]() ABSL_SHARED_LOCKS_REQUIRED(mu_) { return bound_ == nullptr; };
  return mu_.AwaitWithDeadline(absl::Condition(&unbound), deadline);
}

bool Session::TryRetire() {
  absl::MutexLock lock(&mu_);
  if (bound_ != nullptr || closed_) return false;
  closed_ = true;
  return true;
}

void Session::CancelStream() {
  absl::MutexLock lock(&mu_);
  if (bound_ == nullptr) return;
  bound_->queue->Abort();
  bound_->context->TryCancel();
}

void Session::RememberUpdate(const pb::FrameUpdate& update) {
  absl::MutexLock lock(&mu_);
  recent_updates_.push_back(update);
  if (recent_updates_.size() > kReplayCapacity) recent_updates_.pop_front();
}

std::vector<pb::FrameUpdate> Session::UpdatesAfter(int64_t timestamp_ns) const {
  absl::MutexLock lock(&mu_);
  std::vector<pb::FrameUpdate> out;
  for (const pb::FrameUpdate& u : recent_updates_) {
    if (u.timestamp_ns() > timestamp_ns) out.push_back(u);
  }
  return out;
}

void Session::Touch() {
  absl::MutexLock lock(&mu_);
  last_activity_ = absl::Now();
}

absl::Time Session::last_activity() const {
  absl::MutexLock lock(&mu_);
  return last_activity_;
}

void Session::RecordDropped(int64_t n) {
  absl::MutexLock lock(&mu_);
  record_.frames_dropped += n;
}

void Session::RecordRejected() {
  absl::MutexLock lock(&mu_);
  ++record_.frames_rejected;
}

pb::SessionInfo Session::Info() const {
  absl::MutexLock lock(&mu_);
  pb::SessionInfo info;
  info.set_session_id(id_);
  info.set_name(record_.name);
  info.set_state(closed_
                     ? pb::SESSION_STATE_CLOSED
                     : (bound_ != nullptr ? pb::SESSION_STATE_STREAMING : pb::SESSION_STATE_IDLE));
  ToProto(setup_.config.camera, info.mutable_calibration());
  info.set_frames_processed(record_.frames_processed);
  info.set_frames_dropped(record_.frames_dropped);
  info.set_frames_rejected(record_.frames_rejected);
  info.set_last_frame_index(record_.last_frame_index);
  info.set_last_timestamp_ns(record_.last_timestamp_ns);
  info.set_created_unix_ms(record_.created_unix_ms);
  info.set_last_activity_unix_ms(absl::ToUnixMillis(last_activity_));
  info.set_last_persisted_frames(saved_frames_);
  info.set_queue_depth(bound_ != nullptr ? bound_->queue->size() : 0);
  *info.mutable_policy() = setup_.policy;
  ToProto(setup_.config.options, info.mutable_options());
  info.set_num_map_points(num_map_points_);
  info.set_num_keyframes(num_keyframes_);
  return info;
}

SessionRecord Session::Record() const {
  absl::MutexLock lock(&mu_);
  return record_;
}

void Session::Close() {
  {
    absl::MutexLock lock(&mu_);
    closed_ = true;
    if (bound_ != nullptr) {
      bound_->queue->Abort();
      bound_->context->TryCancel();
    }
  }
  absl::MutexLock engine_lock(&engine_mu_);
  if (system_ && !engine_stopped_) system_->Shutdown();
  engine_stopped_ = true;
}

bool Session::closed() const {
  absl::MutexLock lock(&mu_);
  return closed_;
}

}  // namespace twist::server
