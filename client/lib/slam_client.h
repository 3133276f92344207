// SlamClient: one C++ class over the twistslam.v1 stub. Connects (optionally
// with TLS and a bearer token), manages sessions, and streams frames with a
// reader thread delivering every answer to a callback. A dropped connection
// or a server restart is survived: the client resumes the session, asks the
// server to replay the updates it missed and resends the frames the server
// had not processed, so no frame is lost or processed twice.
//
//   auto client = SlamClient::Connect({.address = "127.0.0.1:50051"});
//   auto created = (*client)->CreateSession(request);
//   (*client)->OpenStream(created->session_id(), created->resume_token(),
//                         [](const pb::StreamResponse& r) { ... });
//   for (...) (*client)->Send(frame);        // blocks under back-pressure
//   absl::Status s = (*client)->CloseStream();  // every frame answered
#pragma once

#include <grpcpp/grpcpp.h>

#include <condition_variable>
#include <cstdint>
#include <deque>
#include <functional>
#include <memory>
#include <mutex>
#include <string>
#include <thread>
#include <vector>

#include "absl/status/status.h"
#include "absl/status/statusor.h"
#include "twistslam/v1/slam_service.grpc.pb.h"

namespace twist::client {

namespace pb = ::twistslam::v1;

struct ClientOptions {
  std::string address;                   // HOST:PORT
  std::string token;                     // bearer token; empty = none
  std::string tls_ca_file;               // PEM root certificates; enables TLS
  std::string tls_server_name;           // expected certificate name (default: host)
  int64_t max_message_bytes = 64 << 20;  // receive/send limit (server's is 64 MiB)
  double rpc_timeout_s = 60.0;           // deadline of unary calls
  // Reconnection of a broken stream: attempts and first back-off (doubles,
  // capped at 2 s). While the server restarts, calls wait for it to be ready.
  int max_reconnect_attempts = 20;
  double reconnect_backoff_s = 0.05;
  // Frames sent but not yet answered; Send blocks beyond this (they are kept
  // for resending after a reconnect).
  size_t max_unacked_frames = 32;
};

// Maps a grpc::Status to absl::Status (same code and message).
absl::Status ToAbslStatus(const grpc::Status& status);

class SlamClient {
 public:
  using ResponseCallback = std::function<void(const pb::StreamResponse&)>;

  static absl::StatusOr<std::unique_ptr<SlamClient>> Connect(const ClientOptions& options);
  ~SlamClient();
  SlamClient(const SlamClient&) = delete;
  SlamClient& operator=(const SlamClient&) = delete;

  // Unary calls.
  absl::StatusOr<pb::GetServerInfoResponse> GetServerInfo();
  absl::StatusOr<pb::CreateSessionResponse> CreateSession(const pb::CreateSessionRequest& request);
  absl::StatusOr<pb::ResumeSessionResponse> ResumeSession(const std::string& session_id,
                                                          const std::string& resume_token);
  absl::StatusOr<pb::CloseSessionResponse> CloseSession(const std::string& session_id,
                                                        bool persist);
  absl::StatusOr<std::vector<pb::SessionInfo>> ListSessions();
  absl::StatusOr<pb::PersistSessionResponse> PersistSession(const std::string& session_id);
  absl::StatusOr<std::string> GetMetrics();
  // The whole map, chunk by chunk (chunk 0 holds the summary).
  absl::StatusOr<std::vector<pb::MapChunk>> GetMap(const pb::GetMapRequest& request);

  // Streaming. OpenStream binds a new stream to the session (the callback
  // runs on the reader thread, also for the `bound` answer and replays).
  absl::Status OpenStream(const std::string& session_id,
                          const std::string& resume_token,
                          ResponseCallback callback);
  // Sends one frame (reconnecting if needed). Blocks while max_unacked_frames
  // are unanswered. A permanent stream error (e.g. taken over, session
  // closed) is returned.
  absl::Status Send(const pb::Frame& frame);
  // Half-closes and waits until every sent frame is answered (reconnecting if
  // the stream breaks meanwhile). Returns the stream's final status.
  absl::Status CloseStream();

  // Tests: breaks the current stream as a network failure would.
  void DropConnectionForTesting();
  int reconnects() const;
  // The session as reported by the last `bound` answer.
  pb::SessionInfo bound_session() const;
  const std::string& bearer_token() const { return options_.token; }
  pb::SlamService::Stub* stub() { return stub_.get(); }

 private:
  struct Pending {
    int64_t index = 0;
    int64_t timestamp_ns = 0;
    pb::StreamRequest request;
  };

  explicit SlamClient(ClientOptions options) : options_(std::move(options)) {}
  void Prepare(grpc::ClientContext* context, bool unary) const;
  // Opens a stream, binds (with replay when `replay`), starts the reader.
  absl::Status StartStream(bool replay);
  void ReaderLoop(grpc::ClientReaderWriter<pb::StreamRequest, pb::StreamResponse>* stream);
  // Waits for the reader to end and returns the stream's status.
  grpc::Status FinishStream();
  // Resume + new stream + resend; retries with back-off.
  absl::Status Reconnect(const grpc::Status& cause);
  static bool Retryable(const grpc::Status& status);

  const ClientOptions options_;
  std::shared_ptr<grpc::Channel> channel_;
  std::unique_ptr<pb::SlamService::Stub> stub_;

  // Stream state; only the caller's thread (Send/CloseStream) writes and
  // replaces the stream, the reader thread only reads.
  std::string session_id_;
  std::string resume_token_;
  ResponseCallback callback_;
  std::unique_ptr<grpc::ClientContext> context_;
  std::unique_ptr<grpc::ClientReaderWriter<pb::StreamRequest, pb::StreamResponse>> stream_;
  std::thread reader_;
  bool writes_done_ = false;

  mutable std::mutex mu_;
  std::condition_variable cv_;
  std::deque<Pending> unacked_;   // guarded by mu_
  bool reader_done_ = true;       // guarded by mu_
  bool have_answer_ = false;      // guarded by mu_
  int64_t last_answered_ts_ = 0;  // guarded by mu_
  pb::SessionInfo bound_;         // guarded by mu_
  int replay_left_ = 0;           // guarded by mu_
  int reconnects_ = 0;            // guarded by mu_
  std::string aborted_message_;   // guarded by mu_: server said "taken over"
};

}  // namespace twist::client
