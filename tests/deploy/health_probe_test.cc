// Runs the built twistslam-health-probe executable against an in-process gRPC
// server that uses gRPC's own health service (the one twistslam-server
// enables), on a loopback port picked by the kernel.

#include <grpcpp/generic/async_generic_service.h>
#include <grpcpp/grpcpp.h>
#include <grpcpp/health_check_service_interface.h>
#include <gtest/gtest.h>
#include <sys/wait.h>

#include <array>
#include <chrono>
#include <cstdio>
#include <fstream>
#include <memory>
#include <string>
#include <thread>

namespace twist::tools {
namespace {

struct ProbeRun {
  int exit_code = -1;
  std::string output;
};

// Runs the probe with `args` (already shell-quoted where needed) and returns
// its exit code and stdout+stderr.
ProbeRun RunProbe(const std::string& args) {
  const std::string command =
      std::string("'") + TWIST_HEALTH_PROBE_PATH + "' " + args + " 2>&1";
  ProbeRun run;
  FILE* pipe = popen(command.c_str(), "r");
  if (pipe == nullptr) return run;
  std::array<char, 512> buffer{};
  while (fgets(buffer.data(), buffer.size(), pipe) != nullptr) {
    run.output += buffer.data();
  }
  const int status = pclose(pipe);
  if (WIFEXITED(status)) run.exit_code = WEXITSTATUS(status);
  return run;
}

class HealthProbeTest : public ::testing::Test {
 protected:
  void SetUp() override {
    grpc::EnableDefaultHealthCheckService(true);
    grpc::ServerBuilder builder;
    // A server needs at least one service besides the health service.
    builder.RegisterCallbackGenericService(&generic_service_);
    builder.AddListeningPort("127.0.0.1:0", grpc::InsecureServerCredentials(),
                             &port_);
    server_ = builder.BuildAndStart();
    ASSERT_NE(server_, nullptr);
    ASSERT_GT(port_, 0);
    addr_ = "127.0.0.1:" + std::to_string(port_);
  }
  void TearDown() override {
    if (server_) server_->Shutdown();
  }

  grpc::CallbackGenericService generic_service_;
  int port_ = 0;
  std::string addr_;
  std::unique_ptr<grpc::Server> server_;
};

TEST_F(HealthProbeTest, ServingServerExitsZero) {
  const ProbeRun run = RunProbe("--addr " + addr_);
  EXPECT_EQ(run.exit_code, 0) << run.output;
  EXPECT_EQ(run.output, "SERVING\n");
}

TEST_F(HealthProbeTest, NotServingServerExitsOne) {
  server_->GetHealthCheckService()->SetServingStatus(false);
  const ProbeRun run = RunProbe("--addr=" + addr_ + " --timeout-ms 1000");
  EXPECT_EQ(run.exit_code, 1) << run.output;
  EXPECT_EQ(run.output, "NOT_SERVING\n");
}

TEST_F(HealthProbeTest, PerServiceStatus) {
  server_->GetHealthCheckService()->SetServingStatus("twistslam.v1.SlamService",
                                                     true);
  EXPECT_EQ(RunProbe("--addr " + addr_ + " --service twistslam.v1.SlamService")
                .exit_code,
            0);
  // An unregistered service is NOT_FOUND: unhealthy, with the code printed.
  const ProbeRun unknown = RunProbe("--addr " + addr_ + " --service no.Such");
  EXPECT_EQ(unknown.exit_code, 1);
  EXPECT_NE(unknown.output.find("code 5"), std::string::npos) << unknown.output;
}

TEST_F(HealthProbeTest, UnreachableServerExitsOne) {
  server_->Shutdown();
  server_.reset();
  const ProbeRun run = RunProbe("--addr " + addr_ + " --timeout-ms 500");
  EXPECT_EQ(run.exit_code, 1) << run.output;
  EXPECT_NE(run.output.find("check failed"), std::string::npos) << run.output;
}

TEST_F(HealthProbeTest, WaitRetriesUntilServing) {
  server_->GetHealthCheckService()->SetServingStatus(false);
  // Flip to SERVING from another thread while the probe is retrying.
  std::thread flipper([this] {
    std::this_thread::sleep_for(std::chrono::milliseconds(500));
    server_->GetHealthCheckService()->SetServingStatus(true);
  });
  const ProbeRun run = RunProbe("--addr " + addr_ + " --wait-ms 20000");
  flipper.join();
  EXPECT_EQ(run.exit_code, 0) << run.output;
}

TEST_F(HealthProbeTest, TokenFileInServerFormatIsAccepted) {
  const std::string dir = ::testing::TempDir();
  const std::string good = dir + "/probe_tokens_good";
  const std::string empty = dir + "/probe_tokens_empty";
  std::ofstream(good) << "# comment\n\n  s3cret alice\nother bob\n";
  std::ofstream(empty) << "# only a comment\n\n";
  EXPECT_EQ(RunProbe("--addr " + addr_ + " --token-file " + good).exit_code, 0);
  EXPECT_EQ(RunProbe("--addr " + addr_ + " --token-file " + empty).exit_code,
            3);
}

TEST(HealthProbeArgsTest, BadArgumentsExitThree) {
  EXPECT_EQ(RunProbe("--bogus 1").exit_code, 3);
  EXPECT_EQ(RunProbe("--timeout-ms abc").exit_code, 3);
  EXPECT_EQ(RunProbe("--addr").exit_code, 3);
  EXPECT_EQ(RunProbe("--tls-ca /nonexistent/ca.pem").exit_code, 3);
  EXPECT_EQ(RunProbe("--token-file /nonexistent/token").exit_code, 3);
  const ProbeRun help = RunProbe("--help");
  EXPECT_EQ(help.exit_code, 0);
  EXPECT_NE(help.output.find("usage:"), std::string::npos);
}

}  // namespace
}  // namespace twist::tools
