// TwistServer: the gRPC server of twistslam-server, usable in-process (tests,
// benchmarks): listening address, TLS, auth, message limits, health and
// reflection services, metrics endpoint, and graceful shutdown.
#pragma once

#include <grpcpp/server.h>

#include <memory>
#include <string>

#include "absl/status/statusor.h"
#include "absl/time/time.h"
#include "server/auth.h"
#include "server/metrics.h"
#include "server/metrics_http.h"
#include "server/service.h"
#include "server/session_manager.h"

namespace twist::server {

inline constexpr char kServerVersion[] = "0.1.0";

struct ServerOptions {
  std::string listen = "127.0.0.1:0";  // HOST:PORT; port 0 picks a free port
  std::string tls_cert_file;           // PEM; with tls_key_file enables TLS
  std::string tls_key_file;
  std::string auth_token_file;  // enables bearer-token auth
  std::string metrics_listen;   // HOST:PORT of the Prometheus endpoint; empty = off
  // Largest message either way. Deliberately far above gRPC's 4 MiB default:
  // a raw 1242x375 RGB stereo pair with mask is ~3.2 MiB.
  int64_t max_message_bytes = 64 << 20;
  double drain_timeout_s = 5.0;       // shutdown: time to answer queued frames
  double shutdown_deadline_s = 10.0;  // shutdown: hard deadline for open calls
  int sync_server_threads = 0;        // 0 = gRPC default
  SessionManagerOptions sessions;
};

class TwistServer {
 public:
  static absl::StatusOr<std::unique_ptr<TwistServer>> Start(const ServerOptions& options,
                                                            SlamSystemFactory factory);
  ~TwistServer();

  int port() const { return port_; }
  // "HOST:PORT" with the bound port.
  std::string address() const { return address_; }
  int metrics_port() const { return metrics_port_; }
  SessionManager* sessions() { return manager_.get(); }
  std::string MetricsText() const { return service_->MetricsText(); }

  // Graceful shutdown (idempotent): health NOT_SERVING, refuse new sessions
  // and streams, let streams answer their queued frames (drain_timeout_s),
  // cancel them, persist every changed session, then stop gRPC with the
  // deadline (open calls are cancelled at the deadline; nothing hangs).
  void Shutdown();
  // Blocks until the server has shut down.
  void Wait();

 private:
  TwistServer() = default;

  ServerOptions options_;
  Metrics metrics_;
  TokenAuthenticator auth_;
  std::unique_ptr<SessionManager> manager_;
  std::unique_ptr<SlamServiceImpl> service_;
  std::unique_ptr<grpc::Server> server_;
  MetricsHttpServer metrics_http_;
  int port_ = 0;
  int metrics_port_ = 0;
  std::string address_;
  absl::Mutex shutdown_mu_;
  bool shut_down_ ABSL_GUARDED_BY(shutdown_mu_) = false;
};

}  // namespace twist::server
