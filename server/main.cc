// twistslam-server: the TwistSLAM gRPC service (DESIGN.md §7, docs/server.md).
#include <glog/logging.h>

#include <chrono>
#include <csignal>
#include <cstdio>
#include <cstdlib>
#include <future>
#include <iostream>

#include "server/server.h"
#include "server/server_flags.h"
#include "slam/system/slam_system.h"

int main(int argc, char** argv) {
  google::InitGoogleLogging(argv[0]);
  FLAGS_logtostderr = true;
  absl::StatusOr<twist::server::ParsedServerFlags> flags =
      twist::server::ParseServerFlags(argc, argv);
  if (!flags.ok()) {
    std::cerr << "twistslam-server: " << flags.status().message() << " (see --help)\n";
    return 2;
  }
  if (flags->help) {
    std::cout << twist::server::ServerUsage();
    return 0;
  }
  FLAGS_v = flags->verbosity;

  // Block the shutdown signals in every thread (gRPC's included) and wait for
  // them on this one.
  sigset_t signals;
  sigemptyset(&signals);
  sigaddset(&signals, SIGINT);
  sigaddset(&signals, SIGTERM);
  pthread_sigmask(SIG_BLOCK, &signals, nullptr);

  twist::server::SlamSystemFactory factory;
  factory.create = [](const twist::SessionConfig& config) {
    return twist::SlamSystem::Create(config);
  };
  factory.load = [](const std::string& path) { return twist::SlamSystem::Load(path); };
  absl::StatusOr<std::unique_ptr<twist::server::TwistServer>> server =
      twist::server::TwistServer::Start(flags->options, std::move(factory));
  if (!server.ok()) {
    std::cerr << "twistslam-server: " << server.status().message() << "\n";
    return 1;
  }
  std::cout << "listening on " << (*server)->address() << std::endl;
  if ((*server)->metrics_port() > 0) {
    std::cout << "metrics on port " << (*server)->metrics_port() << " (/metrics)" << std::endl;
  }

  int received = 0;
  sigwait(&signals, &received);
  LOG(INFO) << "received " << (received == SIGTERM ? "SIGTERM" : "SIGINT");
  // Shutdown has its own deadlines; an engine stuck inside a frame could
  // still hold a handler, so the process enforces an outer bound.
  const double bound_s = flags->options.drain_timeout_s + flags->options.shutdown_deadline_s + 5.0;
  std::future<void> done = std::async(std::launch::async, [&server] {
    (*server)->Shutdown();
    (*server)->Wait();
  });
  if (done.wait_for(std::chrono::duration<double>(bound_s)) != std::future_status::ready) {
    LOG(ERROR) << "shutdown did not finish within " << bound_s
               << " s (an engine call is stuck); exiting";
    std::cout.flush();
    std::_Exit(1);
  }
  return 0;
}
