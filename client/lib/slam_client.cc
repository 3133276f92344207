#include "client/lib/slam_client.h"

#include <algorithm>
#include <chrono>
#include <fstream>
#include <limits>
#include <sstream>

#include "absl/strings/str_cat.h"

namespace twist::client {
namespace {

constexpr int64_t kNoTimestamp = std::numeric_limits<int64_t>::min();

}  // namespace

absl::Status ToAbslStatus(const grpc::Status& status) {
  if (status.ok()) return absl::OkStatus();
  const int code = static_cast<int>(status.error_code());
  return absl::Status(
      code >= 0 && code <= 16 ? static_cast<absl::StatusCode>(code) : absl::StatusCode::kUnknown,
      status.error_message());
}

absl::StatusOr<std::unique_ptr<SlamClient>> SlamClient::Connect(const ClientOptions& options) {
  if (options.address.empty()) return absl::InvalidArgumentError("no server address (HOST:PORT)");
  std::unique_ptr<SlamClient> client(new SlamClient(options));
  std::shared_ptr<grpc::ChannelCredentials> credentials = grpc::InsecureChannelCredentials();
  grpc::ChannelArguments args;
  args.SetMaxReceiveMessageSize(static_cast<int>(options.max_message_bytes));
  args.SetMaxSendMessageSize(static_cast<int>(options.max_message_bytes));
  args.SetInt(GRPC_ARG_KEEPALIVE_TIME_MS, 30000);
  args.SetInt(GRPC_ARG_KEEPALIVE_TIMEOUT_MS, 10000);
  // Reconnect quickly after a server restart (tests restart on loopback).
  args.SetInt(GRPC_ARG_INITIAL_RECONNECT_BACKOFF_MS, 100);
  args.SetInt(GRPC_ARG_MIN_RECONNECT_BACKOFF_MS, 100);
  args.SetInt(GRPC_ARG_MAX_RECONNECT_BACKOFF_MS, 1000);
  if (!options.tls_ca_file.empty()) {
    std::ifstream in(options.tls_ca_file);
    if (!in)
      return absl::NotFoundError(absl::StrCat("cannot read TLS CA file ", options.tls_ca_file));
    std::stringstream roots;
    roots << in.rdbuf();
    grpc::SslCredentialsOptions ssl;
    ssl.pem_root_certs = roots.str();
    credentials = grpc::SslCredentials(ssl);
    if (!options.tls_server_name.empty()) args.SetSslTargetNameOverride(options.tls_server_name);
  }
  client->channel_ = grpc::CreateCustomChannel(options.address, credentials, args);
  client->stub_ = pb::SlamService::NewStub(client->channel_);
  return client;
}

SlamClient::~SlamClient() {
  if (stream_) {
    context_->TryCancel();
    FinishStream();
  }
}

void SlamClient::Prepare(grpc::ClientContext* context, bool unary) const {
  if (!options_.token.empty()) context->AddMetadata("authorization", "Bearer " + options_.token);
  context->set_wait_for_ready(true);
  if (unary) {
    context->set_deadline(
        std::chrono::system_clock::now() +
        std::chrono::milliseconds(static_cast<int64_t>(options_.rpc_timeout_s * 1000)));
  }
}

bool SlamClient::Retryable(const grpc::Status& status) {
  switch (status.error_code()) {
    case grpc::StatusCode::UNAVAILABLE:
    case grpc::StatusCode::CANCELLED:
    case grpc::StatusCode::UNKNOWN:
    case grpc::StatusCode::INTERNAL:
    case grpc::StatusCode::DEADLINE_EXCEEDED:
      return true;
    default:
      return false;
  }
}

// ---------------------------------------------------------------------------
// Unary calls.

absl::StatusOr<pb::GetServerInfoResponse> SlamClient::GetServerInfo() {
  grpc::ClientContext context;
  Prepare(&context, true);
  pb::GetServerInfoResponse response;
  grpc::Status s = stub_->GetServerInfo(&context, pb::GetServerInfoRequest(), &response);
  if (!s.ok()) return ToAbslStatus(s);
  return response;
}

absl::StatusOr<pb::CreateSessionResponse> SlamClient::CreateSession(
    const pb::CreateSessionRequest& request) {
  grpc::ClientContext context;
  Prepare(&context, true);
  pb::CreateSessionResponse response;
  grpc::Status s = stub_->CreateSession(&context, request, &response);
  if (!s.ok()) return ToAbslStatus(s);
  return response;
}

absl::StatusOr<pb::ResumeSessionResponse> SlamClient::ResumeSession(
    const std::string& session_id, const std::string& resume_token) {
  grpc::ClientContext context;
  Prepare(&context, true);
  pb::ResumeSessionRequest request;
  request.set_session_id(session_id);
  request.set_resume_token(resume_token);
  pb::ResumeSessionResponse response;
  grpc::Status s = stub_->ResumeSession(&context, request, &response);
  if (!s.ok()) return ToAbslStatus(s);
  return response;
}

absl::StatusOr<pb::CloseSessionResponse> SlamClient::CloseSession(const std::string& session_id,
                                                                  bool persist) {
  grpc::ClientContext context;
  Prepare(&context, true);
  pb::CloseSessionRequest request;
  request.set_session_id(session_id);
  request.set_persist(persist);
  pb::CloseSessionResponse response;
  grpc::Status s = stub_->CloseSession(&context, request, &response);
  if (!s.ok()) return ToAbslStatus(s);
  return response;
}

absl::StatusOr<std::vector<pb::SessionInfo>> SlamClient::ListSessions() {
  grpc::ClientContext context;
  Prepare(&context, true);
  pb::ListSessionsResponse response;
  grpc::Status s = stub_->ListSessions(&context, pb::ListSessionsRequest(), &response);
  if (!s.ok()) return ToAbslStatus(s);
  return std::vector<pb::SessionInfo>(response.sessions().begin(), response.sessions().end());
}

absl::StatusOr<pb::PersistSessionResponse> SlamClient::PersistSession(
    const std::string& session_id) {
  grpc::ClientContext context;
  Prepare(&context, true);
  pb::PersistSessionRequest request;
  request.set_session_id(session_id);
  pb::PersistSessionResponse response;
  grpc::Status s = stub_->PersistSession(&context, request, &response);
  if (!s.ok()) return ToAbslStatus(s);
  return response;
}

absl::StatusOr<std::string> SlamClient::GetMetrics() {
  grpc::ClientContext context;
  Prepare(&context, true);
  pb::GetMetricsResponse response;
  grpc::Status s = stub_->GetMetrics(&context, pb::GetMetricsRequest(), &response);
  if (!s.ok()) return ToAbslStatus(s);
  return response.prometheus_text();
}

absl::StatusOr<std::vector<pb::MapChunk>> SlamClient::GetMap(const pb::GetMapRequest& request) {
  grpc::ClientContext context;
  Prepare(&context, true);
  std::unique_ptr<grpc::ClientReader<pb::MapChunk>> reader = stub_->GetMap(&context, request);
  std::vector<pb::MapChunk> chunks;
  pb::MapChunk chunk;
  while (reader->Read(&chunk)) chunks.push_back(chunk);
  grpc::Status s = reader->Finish();
  if (!s.ok()) return ToAbslStatus(s);
  if (chunks.empty() || !chunks.back().last())
    return absl::DataLossError("map stream ended before its last chunk");
  return chunks;
}

// ---------------------------------------------------------------------------
// Streaming.

absl::Status SlamClient::OpenStream(const std::string& session_id,
                                    const std::string& resume_token,
                                    ResponseCallback callback) {
  if (stream_) return absl::FailedPreconditionError("a stream is already open; CloseStream first");
  session_id_ = session_id;
  resume_token_ = resume_token;
  callback_ = std::move(callback);
  {
    std::lock_guard<std::mutex> lock(mu_);
    unacked_.clear();
    have_answer_ = false;
    last_answered_ts_ = 0;
  }
  return StartStream(/*replay=*/false);
}

absl::Status SlamClient::StartStream(bool replay) {
  context_ = std::make_unique<grpc::ClientContext>();
  Prepare(context_.get(), false);
  stream_ = stub_->Stream(context_.get());
  pb::StreamRequest bind;
  bind.mutable_bind()->set_session_id(session_id_);
  if (replay) {
    std::lock_guard<std::mutex> lock(mu_);
    bind.mutable_bind()->set_replay(true);
    bind.mutable_bind()->set_replay_after_timestamp_ns(have_answer_ ? last_answered_ts_
                                                                    : kNoTimestamp);
  }
  pb::StreamResponse first;
  const bool ok = stream_->Write(bind) && stream_->Read(&first);
  if (!ok || !first.has_bound()) {
    grpc::Status s = stream_->Finish();
    stream_.reset();
    context_.reset();
    if (s.ok())
      return absl::InternalError("server answered the bind with something else than `bound`");
    return ToAbslStatus(s);
  }
  {
    std::lock_guard<std::mutex> lock(mu_);
    bound_ = first.bound().session();
    replay_left_ = first.bound().replay_count();
    reader_done_ = false;
    if (replay_left_ == 0 && replay) {
      const int64_t processed_up_to =
          bound_.frames_processed() > 0 ? bound_.last_timestamp_ns() : kNoTimestamp;
      unacked_.erase(
          std::remove_if(unacked_.begin(),
                         unacked_.end(),
                         [&](const Pending& p) { return p.timestamp_ns <= processed_up_to; }),
          unacked_.end());
    }
  }
  if (callback_) callback_(first);
  reader_ = std::thread([this, stream = stream_.get()] { ReaderLoop(stream); });
  return absl::OkStatus();
}

void SlamClient::ReaderLoop(
    grpc::ClientReaderWriter<pb::StreamRequest, pb::StreamResponse>* stream) {
  pb::StreamResponse response;
  auto ack = [this](int64_t index, int64_t timestamp_ns) {
    // Answers come in send order: everything up to the answered frame is done.
    auto it = std::find_if(unacked_.begin(), unacked_.end(), [&](const Pending& p) {
      return p.index == index && p.timestamp_ns == timestamp_ns;
    });
    if (it != unacked_.end()) unacked_.erase(unacked_.begin(), it + 1);
  };
  while (stream->Read(&response)) {
    {
      std::lock_guard<std::mutex> lock(mu_);
      if (response.has_update()) {
        ack(response.update().index(), response.update().timestamp_ns());
        last_answered_ts_ = have_answer_
                                ? std::max(last_answered_ts_, response.update().timestamp_ns())
                                : response.update().timestamp_ns();
        have_answer_ = true;
        if (replay_left_ > 0 && --replay_left_ == 0) {
          // Replay complete: frames the server processed before the bind
          // but whose updates were not kept are done too.
          const int64_t up_to = bound_.last_timestamp_ns();
          unacked_.erase(std::remove_if(unacked_.begin(),
                                        unacked_.end(),
                                        [&](const Pending& p) { return p.timestamp_ns <= up_to; }),
                         unacked_.end());
        }
      } else if (response.has_error()) {
        ack(response.error().index(), response.error().timestamp_ns());
        if (response.error().index() == -1 &&
            response.error().code() == static_cast<int>(grpc::StatusCode::ABORTED)) {
          aborted_message_ = response.error().message();
        }
      } else if (response.has_dropped()) {
        for (int64_t index : response.dropped().indices()) {
          auto it = std::find_if(
              unacked_.begin(), unacked_.end(), [&](const Pending& p) { return p.index == index; });
          if (it != unacked_.end()) unacked_.erase(it);
        }
      }
    }
    cv_.notify_all();
    if (callback_) callback_(response);
  }
  {
    std::lock_guard<std::mutex> lock(mu_);
    reader_done_ = true;
  }
  cv_.notify_all();
}

grpc::Status SlamClient::FinishStream() {
  if (reader_.joinable()) reader_.join();
  grpc::Status s = stream_ ? stream_->Finish()
                           : grpc::Status(grpc::StatusCode::FAILED_PRECONDITION, "no stream");
  stream_.reset();
  context_.reset();
  std::lock_guard<std::mutex> lock(mu_);
  if (!aborted_message_.empty()) {
    // Taken over by another stream: permanent, never reconnect.
    s = grpc::Status(grpc::StatusCode::ABORTED, aborted_message_);
    aborted_message_.clear();
  }
  return s;
}

absl::Status SlamClient::Send(const pb::Frame& frame) {
  if (session_id_.empty())
    return absl::FailedPreconditionError("no stream open; call OpenStream first");
  Pending pending;
  pending.index = frame.index();
  pending.timestamp_ns = frame.timestamp_ns();
  *pending.request.mutable_frame() = frame;
  bool broken = false;
  {
    std::unique_lock<std::mutex> lock(mu_);
    cv_.wait(lock, [&] { return unacked_.size() < options_.max_unacked_frames || reader_done_; });
    unacked_.push_back(pending);
    broken = reader_done_ || !stream_;
  }
  if (!broken && stream_->Write(pending.request)) return absl::OkStatus();
  // The stream broke: find out why and continue on a new one if we can (the
  // frame is in unacked_ and is resent).
  grpc::Status status =
      stream_ ? FinishStream() : grpc::Status(grpc::StatusCode::UNAVAILABLE, "no stream");
  if (status.ok()) status = grpc::Status(grpc::StatusCode::UNAVAILABLE, "server ended the stream");
  return Reconnect(status);
}

absl::Status SlamClient::Reconnect(const grpc::Status& cause) {
  if (!Retryable(cause)) return ToAbslStatus(cause);
  double backoff = options_.reconnect_backoff_s;
  grpc::Status last = cause;
  for (int attempt = 0; attempt < options_.max_reconnect_attempts; ++attempt) {
    std::this_thread::sleep_for(std::chrono::duration<double>(backoff));
    backoff = std::min(2 * backoff, 2.0);
    // After a restart the session must be loaded again; for a live session
    // this only checks the resume token.
    absl::StatusOr<pb::ResumeSessionResponse> resumed = ResumeSession(session_id_, resume_token_);
    if (!resumed.ok()) {
      const grpc::Status s(static_cast<grpc::StatusCode>(resumed.status().code()),
                           std::string(resumed.status().message()));
      if (Retryable(s)) {
        last = s;
        continue;
      }
      return resumed.status();
    }
    if (absl::Status s = StartStream(/*replay=*/true); !s.ok()) {
      const grpc::Status gs(static_cast<grpc::StatusCode>(s.code()), std::string(s.message()));
      if (Retryable(gs)) {
        last = gs;
        continue;
      }
      return s;
    }
    std::vector<pb::StreamRequest> resend;
    {
      std::lock_guard<std::mutex> lock(mu_);
      const int64_t up_to =
          bound_.frames_processed() > 0 ? bound_.last_timestamp_ns() : kNoTimestamp;
      for (const Pending& p : unacked_) {
        if (p.timestamp_ns > up_to) resend.push_back(p.request);
      }
      ++reconnects_;
    }
    bool ok = true;
    for (const pb::StreamRequest& r : resend) {
      if (!stream_->Write(r)) {
        ok = false;
        break;
      }
    }
    if (ok) return absl::OkStatus();
    last = FinishStream();
    if (!Retryable(last)) return ToAbslStatus(last);
  }
  return absl::UnavailableError(absl::StrCat("could not resume session '",
                                             session_id_,
                                             "' after ",
                                             options_.max_reconnect_attempts,
                                             " attempts: ",
                                             last.error_message()));
}

absl::Status SlamClient::CloseStream() {
  if (session_id_.empty()) return absl::FailedPreconditionError("no stream open");
  absl::Status result;
  while (true) {
    if (!stream_) {
      result = absl::FailedPreconditionError("no stream");
      break;
    }
    stream_->WritesDone();
    const grpc::Status status = FinishStream();
    size_t left = 0;
    {
      std::lock_guard<std::mutex> lock(mu_);
      left = unacked_.size();
    }
    if (left == 0 && (status.ok() || Retryable(status))) {
      result = absl::OkStatus();
      break;
    }
    if (status.ok()) {
      result =
          absl::DataLossError(absl::StrCat("stream ended with ", left, " frame(s) unanswered"));
      break;
    }
    if (absl::Status s = Reconnect(status); !s.ok()) {
      result = s;
      break;
    }
  }
  session_id_.clear();
  return result;
}

void SlamClient::DropConnectionForTesting() {
  if (context_) context_->TryCancel();
}

int SlamClient::reconnects() const {
  std::lock_guard<std::mutex> lock(mu_);
  return reconnects_;
}

pb::SessionInfo SlamClient::bound_session() const {
  std::lock_guard<std::mutex> lock(mu_);
  return bound_;
}

}  // namespace twist::client
