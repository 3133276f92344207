// A minimal HTTP/1.0 endpoint for Prometheus scrapes: GET /metrics (or /)
// answers the text of a callback; anything else is 404. One thread, one
// connection at a time, short timeouts: it serves a scraper, not the world.
#pragma once

#include <atomic>
#include <functional>
#include <string>
#include <thread>

#include "absl/status/statusor.h"

namespace twist::server {

class MetricsHttpServer {
 public:
  using Render = std::function<std::string()>;

  MetricsHttpServer() = default;
  ~MetricsHttpServer();
  MetricsHttpServer(const MetricsHttpServer&) = delete;
  MetricsHttpServer& operator=(const MetricsHttpServer&) = delete;

  // Binds HOST:PORT (numeric IPv4 host or "localhost"; port 0 picks one) and
  // starts serving. Returns the bound port.
  absl::StatusOr<int> Start(const std::string& host_port, Render render);
  void Stop();

 private:
  void Serve();

  int listen_fd_ = -1;
  Render render_;
  std::atomic<bool> stop_{false};
  std::thread thread_;
};

}  // namespace twist::server
