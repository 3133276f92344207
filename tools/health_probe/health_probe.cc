// twistslam-health-probe: asks a gRPC server for its health
// (grpc.health.v1.Health/Check) and exits 0 only when it answers SERVING.
//
//   twistslam-health-probe [--addr HOST:PORT] [--service NAME]
//       [--timeout-ms N] [--wait-ms N]
//       [--tls] [--tls-ca FILE] [--tls-server-name NAME] [--token-file FILE]
//
// The token file may be the server's own --auth-token-file (the first token
// in it is used) or a file holding just one token.
//
// Exit codes (compatible with Docker HEALTHCHECK, where 0 = healthy,
// 1 = unhealthy and 2 is reserved):
//   0  the server answered SERVING
//   1  not serving, unreachable, timed out, rejected the call, ...
//   3  bad command line or unreadable file
// One line on stdout says what was seen ("SERVING", "NOT_SERVING", or the
// failed call's status code and message), so `docker inspect` / pod events
// show a reason.
//
// --wait-ms N retries (every 200 ms) until the server is SERVING or N ms have
// passed: scripts use it to wait for a server that is still starting.

#include <grpcpp/grpcpp.h>

#include <cerrno>
#include <chrono>
#include <cstdint>
#include <cstdio>
#include <cstdlib>
#include <cstring>
#include <fstream>
#include <iostream>
#include <memory>
#include <optional>
#include <sstream>
#include <string>
#include <thread>

#include "health.grpc.pb.h"

namespace twist::tools {
namespace {

constexpr int kExitServing = 0;
constexpr int kExitUnhealthy = 1;
constexpr int kExitUsage = 3;

struct ProbeOptions {
  std::string addr = "127.0.0.1:50051";
  std::string service;  // "" = overall server health.
  int64_t timeout_ms = 2000;
  int64_t wait_ms = 0;
  bool tls = false;
  std::string tls_ca_file;
  std::string tls_server_name;
  std::string token_file;
};

void PrintUsage(std::ostream& out) {
  out << "usage: twistslam-health-probe [--addr HOST:PORT] [--service NAME]\n"
         "         [--timeout-ms N] [--wait-ms N]\n"
         "         [--tls] [--tls-ca FILE] [--tls-server-name NAME]"
         " [--token-file FILE]\n"
         "  --addr HOST:PORT        server to ask (default 127.0.0.1:50051)\n"
         "  --service NAME          service to ask about (default \"\": the"
         " whole server)\n"
         "  --timeout-ms N          deadline of one Check call (default 2000)\n"
         "  --wait-ms N             retry until SERVING or N ms passed"
         " (default 0: one try)\n"
         "  --tls                   connect with TLS (implied by --tls-ca)\n"
         "  --tls-ca FILE           PEM roots to verify the server (default:"
         " system roots)\n"
         "  --tls-server-name NAME  name expected in the server certificate\n"
         "  --token-file FILE       send 'authorization: Bearer <token>' (first\n"
         "                          word of the first non-comment line)\n"
         "exit: 0 SERVING, 1 not serving or unreachable, 3 bad arguments\n";
}

bool ParseInt(const std::string& text, int64_t* value) {
  if (text.empty()) return false;
  char* end = nullptr;
  errno = 0;
  const long long parsed = std::strtoll(text.c_str(), &end, 10);
  if (errno != 0 || end == nullptr || *end != '\0' || parsed < 0) return false;
  *value = parsed;
  return true;
}

// Reads the whole file; nullopt when it cannot be read.
std::optional<std::string> ReadFile(const std::string& path) {
  std::ifstream in(path, std::ios::binary);
  if (!in) return std::nullopt;
  std::ostringstream content;
  content << in.rdbuf();
  if (in.bad()) return std::nullopt;
  return content.str();
}

// The token in a token file: the first word of the first line that is
// neither blank nor a '#' comment. Accepts a bare token file as well as the
// server's `<token> [<principal>]` format.
std::string FirstToken(const std::string& text) {
  std::istringstream lines(text);
  std::string line;
  while (std::getline(lines, line)) {
    std::istringstream words(line);
    std::string word;
    if (words >> word && word[0] != '#') return word;
  }
  return "";
}

// Parses argv; on failure prints one line and returns nullopt with *exit_code
// set (0 for --help).
std::optional<ProbeOptions> ParseArgs(int argc, char** argv, int* exit_code) {
  ProbeOptions options;
  for (int i = 1; i < argc; ++i) {
    std::string key = argv[i];
    if (key == "--help" || key == "-h") {
      PrintUsage(std::cout);
      *exit_code = 0;
      return std::nullopt;
    }
    if (key == "--tls") {
      options.tls = true;
      continue;
    }
    std::string value;
    const size_t eq = key.find('=');
    const bool inline_value = key.rfind("--", 0) == 0 && eq != std::string::npos;
    if (inline_value) {
      value = key.substr(eq + 1);
      key = key.substr(0, eq);
    }
    static constexpr const char* kValueKeys[] = {
        "--addr", "--service", "--timeout-ms", "--wait-ms",
        "--tls-ca", "--tls-server-name", "--token-file"};
    bool known = false;
    for (const char* k : kValueKeys) known = known || key == k;
    if (!known) {
      std::cerr << "twistslam-health-probe: unknown option " << key
                << " (see --help)\n";
      *exit_code = kExitUsage;
      return std::nullopt;
    }
    if (!inline_value && i + 1 < argc) {
      value = argv[++i];
    } else if (!inline_value) {
      std::cerr << "twistslam-health-probe: " << key << " needs a value\n";
      *exit_code = kExitUsage;
      return std::nullopt;
    }
    bool ok = true;
    if (key == "--addr") {
      options.addr = value;
      ok = !value.empty();
    } else if (key == "--service") {
      options.service = value;
    } else if (key == "--timeout-ms") {
      ok = ParseInt(value, &options.timeout_ms) && options.timeout_ms > 0;
    } else if (key == "--wait-ms") {
      ok = ParseInt(value, &options.wait_ms);
    } else if (key == "--tls-ca") {
      options.tls_ca_file = value;
      options.tls = true;
    } else if (key == "--tls-server-name") {
      options.tls_server_name = value;
    } else if (key == "--token-file") {
      options.token_file = value;
    }
    if (!ok) {
      std::cerr << "twistslam-health-probe: bad value '" << value << "' for "
                << key << "\n";
      *exit_code = kExitUsage;
      return std::nullopt;
    }
  }
  return options;
}

const char* StatusName(grpc::health::v1::HealthCheckResponse::ServingStatus s) {
  switch (s) {
    case grpc::health::v1::HealthCheckResponse::SERVING:
      return "SERVING";
    case grpc::health::v1::HealthCheckResponse::NOT_SERVING:
      return "NOT_SERVING";
    case grpc::health::v1::HealthCheckResponse::SERVICE_UNKNOWN:
      return "SERVICE_UNKNOWN";
    default:
      return "UNKNOWN";
  }
}

int Run(int argc, char** argv) {
  int exit_code = kExitUsage;
  const std::optional<ProbeOptions> parsed = ParseArgs(argc, argv, &exit_code);
  if (!parsed) return exit_code;
  const ProbeOptions& options = *parsed;

  std::shared_ptr<grpc::ChannelCredentials> credentials;
  grpc::ChannelArguments channel_args;
  if (options.tls) {
    grpc::SslCredentialsOptions ssl;
    if (!options.tls_ca_file.empty()) {
      std::optional<std::string> roots = ReadFile(options.tls_ca_file);
      if (!roots || roots->empty()) {
        std::cerr << "twistslam-health-probe: cannot read CA file "
                  << options.tls_ca_file << "\n";
        return kExitUsage;
      }
      ssl.pem_root_certs = *roots;
    }
    credentials = grpc::SslCredentials(ssl);
    if (!options.tls_server_name.empty()) {
      channel_args.SetSslTargetNameOverride(options.tls_server_name);
    }
  } else {
    credentials = grpc::InsecureChannelCredentials();
  }
  std::string token;
  if (!options.token_file.empty()) {
    std::optional<std::string> content = ReadFile(options.token_file);
    token = content ? FirstToken(*content) : "";
    if (token.empty()) {
      std::cerr << "twistslam-health-probe: no token in "
                << options.token_file << "\n";
      return kExitUsage;
    }
  }

  const std::shared_ptr<grpc::Channel> channel =
      grpc::CreateCustomChannel(options.addr, credentials, channel_args);
  const std::unique_ptr<grpc::health::v1::Health::Stub> stub =
      grpc::health::v1::Health::NewStub(channel);

  const auto give_up_at = std::chrono::steady_clock::now() +
                          std::chrono::milliseconds(options.wait_ms);
  std::string last_reason;
  while (true) {
    grpc::ClientContext context;
    context.set_deadline(std::chrono::system_clock::now() +
                         std::chrono::milliseconds(options.timeout_ms));
    if (!token.empty()) context.AddMetadata("authorization", "Bearer " + token);
    grpc::health::v1::HealthCheckRequest request;
    request.set_service(options.service);
    grpc::health::v1::HealthCheckResponse response;
    const grpc::Status status = stub->Check(&context, request, &response);
    if (status.ok()) {
      if (response.status() == grpc::health::v1::HealthCheckResponse::SERVING) {
        std::cout << "SERVING\n";
        return kExitServing;
      }
      last_reason = StatusName(response.status());
    } else {
      last_reason = "check failed: code " +
                    std::to_string(static_cast<int>(status.error_code())) +
                    " (" + status.error_message() + ")";
    }
    if (std::chrono::steady_clock::now() >= give_up_at) break;
    std::this_thread::sleep_for(std::chrono::milliseconds(200));
  }
  std::cout << last_reason << "\n";
  return kExitUnhealthy;
}

}  // namespace
}  // namespace twist::tools

int main(int argc, char** argv) { return twist::tools::Run(argc, argv); }
