#include "server/server.h"

#include <glog/logging.h>
#include <grpcpp/ext/proto_server_reflection_plugin.h>
#include <grpcpp/health_check_service_interface.h>
#include <grpcpp/security/server_credentials.h>
#include <grpcpp/server_builder.h>

#include <fstream>
#include <sstream>

#include "absl/strings/str_cat.h"

namespace twist::server {
namespace {

absl::StatusOr<std::string> ReadWholeFile(const std::string& path, const char* what) {
  std::ifstream in(path, std::ios::binary);
  if (!in) return absl::NotFoundError(absl::StrCat("cannot read ", what, " ", path));
  std::stringstream ss;
  ss << in.rdbuf();
  return ss.str();
}

}  // namespace

absl::StatusOr<std::unique_ptr<TwistServer>> TwistServer::Start(const ServerOptions& options,
                                                                SlamSystemFactory factory) {
  std::unique_ptr<TwistServer> s(new TwistServer());
  s->options_ = options;
  if (options.max_message_bytes < (4 << 20) || options.max_message_bytes > (1LL << 30)) {
    return absl::InvalidArgumentError(absl::StrCat(
        "max message size ", options.max_message_bytes, " bytes must be in [4 MiB, 1 GiB]"));
  }
  if (!options.auth_token_file.empty()) {
    absl::StatusOr<TokenAuthenticator> auth = TokenAuthenticator::FromFile(options.auth_token_file);
    if (!auth.ok()) return auth.status();
    s->auth_ = std::move(*auth);
  }
  std::shared_ptr<grpc::ServerCredentials> credentials = grpc::InsecureServerCredentials();
  const bool tls = !options.tls_cert_file.empty() || !options.tls_key_file.empty();
  if (tls) {
    if (options.tls_cert_file.empty() || options.tls_key_file.empty()) {
      return absl::InvalidArgumentError("TLS needs both --tls-cert and --tls-key");
    }
    absl::StatusOr<std::string> cert = ReadWholeFile(options.tls_cert_file, "TLS certificate");
    if (!cert.ok()) return cert.status();
    absl::StatusOr<std::string> key = ReadWholeFile(options.tls_key_file, "TLS key");
    if (!key.ok()) return key.status();
    grpc::SslServerCredentialsOptions ssl;
    ssl.pem_key_cert_pairs.push_back({*key, *cert});
    credentials = grpc::SslServerCredentials(ssl);
  }

  s->manager_ =
      std::make_unique<SessionManager>(options.sessions, std::move(factory), &s->metrics_);
  ServiceInfo info;
  info.version = kServerVersion;
  info.max_message_bytes = options.max_message_bytes;
  info.capabilities = {"health", "reflection", "rectification", "drop_oldest"};
  if (!options.sessions.state_dir.empty()) info.capabilities.push_back("persistence");
  if (s->auth_.enabled()) info.capabilities.push_back("auth");
  if (tls) info.capabilities.push_back("tls");
  if (!options.metrics_listen.empty()) info.capabilities.push_back("metrics_http");
  s->service_ = std::make_unique<SlamServiceImpl>(s->manager_.get(), &s->metrics_, &s->auth_, info);

  grpc::EnableDefaultHealthCheckService(true);
  grpc::reflection::InitProtoReflectionServerBuilderPlugin();
  grpc::ServerBuilder builder;
  builder.AddListeningPort(options.listen, credentials, &s->port_);
  builder.RegisterService(s->service_.get());
  builder.SetMaxReceiveMessageSize(static_cast<int>(options.max_message_bytes));
  builder.SetMaxSendMessageSize(static_cast<int>(options.max_message_bytes));
  if (options.sync_server_threads > 0) {
    builder.SetSyncServerOption(grpc::ServerBuilder::SyncServerOption::MAX_POLLERS,
                                options.sync_server_threads);
  }
  // Detect dead peers of long-lived streams.
  builder.AddChannelArgument(GRPC_ARG_KEEPALIVE_TIME_MS, 30000);
  builder.AddChannelArgument(GRPC_ARG_KEEPALIVE_TIMEOUT_MS, 10000);
  builder.AddChannelArgument(GRPC_ARG_HTTP2_MIN_RECV_PING_INTERVAL_WITHOUT_DATA_MS, 5000);
  builder.AddChannelArgument(GRPC_ARG_KEEPALIVE_PERMIT_WITHOUT_CALLS, 1);
  s->server_ = builder.BuildAndStart();
  if (!s->server_ || s->port_ == 0) {
    return absl::UnavailableError(absl::StrCat("cannot listen on ", options.listen));
  }
  const size_t colon = options.listen.rfind(':');
  s->address_ = absl::StrCat(options.listen.substr(0, colon), ":", s->port_);
  if (grpc::HealthCheckServiceInterface* health = s->server_->GetHealthCheckService()) {
    health->SetServingStatus(true);
  }
  if (!options.metrics_listen.empty()) {
    TwistServer* raw = s.get();
    absl::StatusOr<int> port =
        s->metrics_http_.Start(options.metrics_listen, [raw] { return raw->MetricsText(); });
    if (!port.ok()) {
      s->Shutdown();
      return port.status();
    }
    s->metrics_port_ = *port;
  }
  LOG(INFO) << "twistslam-server " << kServerVersion << " listening on " << s->address_
            << (tls ? " (TLS)" : "") << (s->auth_.enabled() ? " (auth)" : "");
  return s;
}

TwistServer::~TwistServer() { Shutdown(); }

void TwistServer::Shutdown() {
  {
    absl::MutexLock lock(&shutdown_mu_);
    if (shut_down_ || server_ == nullptr) return;  // nothing started (Start failed)
    shut_down_ = true;
  }
  LOG(INFO) << "shutting down: not serving, draining streams";
  if (grpc::HealthCheckServiceInterface* health = server_->GetHealthCheckService()) {
    health->SetServingStatus(false);
  }
  manager_->StopAccepting();
  const absl::Time start = absl::Now();
  manager_->DrainStreams(start + absl::Seconds(options_.drain_timeout_s));
  manager_->PersistAll();
  const auto deadline =
      std::chrono::system_clock::now() +
      std::chrono::milliseconds(static_cast<int64_t>(
          std::max(0.0, options_.shutdown_deadline_s - absl::ToDoubleSeconds(absl::Now() - start)) *
          1000));
  server_->Shutdown(deadline);
  metrics_http_.Stop();
  LOG(INFO) << "shut down in " << absl::ToDoubleSeconds(absl::Now() - start) << " s";
}

void TwistServer::Wait() { server_->Wait(); }

}  // namespace twist::server
