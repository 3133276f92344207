// SlamService implementation (synchronous gRPC API). Each Stream call runs a
// reader (this handler thread: reads, decodes and validates frames into the
// session's bounded queue) and a worker thread (runs the engine and writes
// the updates: the only writer, so at most one write is in flight).
#pragma once

#include <string>
#include <vector>

#include "server/auth.h"
#include "server/metrics.h"
#include "server/session_manager.h"
#include "twistslam/v1/slam_service.grpc.pb.h"

namespace twist::server {

struct ServiceInfo {
  std::string version;
  int64_t max_message_bytes = 0;
  std::vector<std::string> capabilities;
};

class SlamServiceImpl final : public pb::SlamService::Service {
 public:
  SlamServiceImpl(SessionManager* manager,
                  Metrics* metrics,
                  const TokenAuthenticator* auth,
                  ServiceInfo info);

  grpc::Status CreateSession(grpc::ServerContext* context,
                             const pb::CreateSessionRequest* request,
                             pb::CreateSessionResponse* response) override;
  grpc::Status Stream(
      grpc::ServerContext* context,
      grpc::ServerReaderWriter<pb::StreamResponse, pb::StreamRequest>* stream) override;
  grpc::Status GetMap(grpc::ServerContext* context,
                      const pb::GetMapRequest* request,
                      grpc::ServerWriter<pb::MapChunk>* writer) override;
  grpc::Status CloseSession(grpc::ServerContext* context,
                            const pb::CloseSessionRequest* request,
                            pb::CloseSessionResponse* response) override;
  grpc::Status ListSessions(grpc::ServerContext* context,
                            const pb::ListSessionsRequest* request,
                            pb::ListSessionsResponse* response) override;
  grpc::Status PersistSession(grpc::ServerContext* context,
                              const pb::PersistSessionRequest* request,
                              pb::PersistSessionResponse* response) override;
  grpc::Status ResumeSession(grpc::ServerContext* context,
                             const pb::ResumeSessionRequest* request,
                             pb::ResumeSessionResponse* response) override;
  grpc::Status GetServerInfo(grpc::ServerContext* context,
                             const pb::GetServerInfoRequest* request,
                             pb::GetServerInfoResponse* response) override;
  grpc::Status GetMetrics(grpc::ServerContext* context,
                          const pb::GetMetricsRequest* request,
                          pb::GetMetricsResponse* response) override;

  std::string MetricsText() const;

 private:
  SessionManager* const manager_;
  Metrics* const metrics_;
  const TokenAuthenticator* const auth_;
  const ServiceInfo info_;
};

}  // namespace twist::server
