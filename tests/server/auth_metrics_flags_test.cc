#include <arpa/inet.h>
#include <gmock/gmock.h>
#include <gtest/gtest.h>
#include <netinet/in.h>
#include <sys/socket.h>
#include <unistd.h>

#include <fstream>

#include "server/auth.h"
#include "server/metrics.h"
#include "server/metrics_http.h"
#include "server/server_flags.h"

namespace twist::server {
namespace {

using ::testing::HasSubstr;

TEST(TokenAuthenticator, ParsesTokensAndChecksBearerHeaders) {
  absl::StatusOr<TokenAuthenticator> auth =
      TokenAuthenticator::FromText("# operators\nsecret-token-1 alice\n\n  secret-token-2  \n");
  ASSERT_TRUE(auth.ok()) << auth.status();
  EXPECT_TRUE(auth->enabled());
  EXPECT_EQ(*auth->AuthenticateHeader("Bearer secret-token-1"), "alice");
  const std::string bob = *auth->AuthenticateHeader("bearer secret-token-2");
  EXPECT_THAT(bob, HasSubstr("token-"));
  EXPECT_EQ(*auth->AuthenticateHeader("Bearer secret-token-2"), bob);  // stable name
  EXPECT_TRUE(absl::IsUnauthenticated(auth->AuthenticateHeader("").status()));
  EXPECT_TRUE(absl::IsUnauthenticated(auth->AuthenticateHeader("Bearer nope-nope-nope").status()));
  EXPECT_TRUE(absl::IsUnauthenticated(auth->AuthenticateHeader("Basic secret-token-1").status()));
}

TEST(TokenAuthenticator, RejectsBadFiles) {
  EXPECT_TRUE(absl::IsInvalidArgument(TokenAuthenticator::FromText("\n# none\n").status()));
  EXPECT_TRUE(absl::IsInvalidArgument(TokenAuthenticator::FromText("short\n").status()));
  EXPECT_TRUE(
      absl::IsInvalidArgument(TokenAuthenticator::FromText("aaaaaaaaa x\naaaaaaaaa y\n").status()));
  EXPECT_TRUE(absl::IsInvalidArgument(TokenAuthenticator::FromText("aaaaaaaaa x y\n").status()));
  EXPECT_TRUE(absl::IsNotFound(TokenAuthenticator::FromFile("/nonexistent/tokens").status()));
  TokenAuthenticator off;
  EXPECT_FALSE(off.enabled());
  EXPECT_EQ(*off.AuthenticateHeader(""), "");
}

TEST(Metrics, QuantilesAndPrometheusText) {
  EXPECT_EQ(Quantile({}, 0.5), 0.0);
  EXPECT_EQ(Quantile({3, 1, 2}, 0.5), 2.0);
  EXPECT_EQ(Quantile({1, 2, 3, 4}, 0.99), 4.0);
  Metrics m;
  m.SessionCreated();
  for (int i = 1; i <= 100; ++i) m.FrameProcessed(i, 2 * i);
  m.FrameRejected();
  m.FramesDropped(3);
  MetricGauges g;
  g.sessions_loaded = 2;
  g.queue_depth_total = 5;
  const std::string text = m.PrometheusText(g);
  EXPECT_THAT(text,
              HasSubstr("# TYPE twistslam_frames_processed_total "
                        "counter\ntwistslam_frames_processed_total 100\n"));
  EXPECT_THAT(text, HasSubstr("twistslam_frames_rejected_total 1\n"));
  EXPECT_THAT(text, HasSubstr("twistslam_frames_dropped_total 3\n"));
  EXPECT_THAT(text, HasSubstr("twistslam_sessions 2\n"));
  EXPECT_THAT(text, HasSubstr("twistslam_engine_latency_seconds{quantile=\"0.5\"} 0.05\n"));
  EXPECT_THAT(text, HasSubstr("twistslam_frame_latency_seconds{quantile=\"0.9\"} 0.18\n"));
  EXPECT_THAT(text, HasSubstr("twistslam_engine_latency_seconds_count 100\n"));
  EXPECT_GT(m.FramesPerSecond(), 0.0);
}

std::string HttpGet(int port, const std::string& path) {
  const int fd = socket(AF_INET, SOCK_STREAM, 0);
  sockaddr_in addr{};
  addr.sin_family = AF_INET;
  addr.sin_port = htons(static_cast<uint16_t>(port));
  inet_pton(AF_INET, "127.0.0.1", &addr.sin_addr);
  if (connect(fd, reinterpret_cast<sockaddr*>(&addr), sizeof(addr)) != 0) {
    close(fd);
    return "";
  }
  const std::string request = "GET " + path + " HTTP/1.0\r\n\r\n";
  send(fd, request.data(), request.size(), 0);
  std::string response;
  char buf[4096];
  ssize_t n;
  while ((n = recv(fd, buf, sizeof(buf), 0)) > 0) response.append(buf, static_cast<size_t>(n));
  close(fd);
  return response;
}

TEST(MetricsHttpServer, ServesMetricsOnLoopback) {
  MetricsHttpServer http;
  absl::StatusOr<int> port =
      http.Start("127.0.0.1:0", [] { return std::string("twistslam_up 1\n"); });
  ASSERT_TRUE(port.ok()) << port.status();
  const std::string ok = HttpGet(*port, "/metrics");
  EXPECT_THAT(ok, HasSubstr("HTTP/1.0 200 OK"));
  EXPECT_THAT(ok, HasSubstr("text/plain; version=0.0.4"));
  EXPECT_THAT(ok, HasSubstr("\r\n\r\ntwistslam_up 1\n"));
  EXPECT_THAT(HttpGet(*port, "/other"), HasSubstr("404"));
  http.Stop();
  EXPECT_TRUE(absl::IsInvalidArgument(
      MetricsHttpServer().Start("nonsense", [] { return std::string(); }).status()));
}

absl::StatusOr<ParsedServerFlags> Parse(std::vector<std::string> args) {
  args.insert(args.begin(), "twistslam-server");
  std::vector<char*> argv;
  for (std::string& a : args) argv.push_back(a.data());
  return ParseServerFlags(static_cast<int>(argv.size()), argv.data());
}

TEST(ServerFlags, FlagsConfigAndErrors) {
  absl::StatusOr<ParsedServerFlags> f = Parse({"--listen",
                                               "127.0.0.1:0",
                                               "--state-dir=/tmp/x",
                                               "--max-sessions",
                                               "3",
                                               "--max-message-mb",
                                               "32"});
  ASSERT_TRUE(f.ok()) << f.status();
  EXPECT_EQ(f->options.listen, "127.0.0.1:0");
  EXPECT_EQ(f->options.sessions.state_dir, "/tmp/x");
  EXPECT_EQ(f->options.sessions.max_sessions, 3);
  EXPECT_EQ(f->options.max_message_bytes, 32 << 20);
  EXPECT_THAT(std::string(Parse({"--bogus", "1"}).status().message()),
              HasSubstr("unknown flag --bogus"));
  EXPECT_THAT(std::string(Parse({"--max-sessions", "x"}).status().message()),
              HasSubstr("--max-sessions"));
  EXPECT_THAT(std::string(Parse({"--max-message-mb", "2"}).status().message()),
              HasSubstr("[4, 1024]"));
  EXPECT_THAT(std::string(Parse({"--listen"}).status().message()), HasSubstr("needs a value"));
  EXPECT_TRUE(Parse({"--help"})->help);

  const std::string config = ::testing::TempDir() + "/server_config.yaml";
  {
    std::ofstream out(config);
    out << "%YAML:1.0\nmax_sessions: 7\nidle_timeout_s: 30\nmetrics_listen: \"127.0.0.1:0\"\n"
           "slam:\n  num_features: 500\n  mapping_mode: background\n";
  }
  f = Parse({"--config", config, "--max-sessions", "9"});
  ASSERT_TRUE(f.ok()) << f.status();
  EXPECT_EQ(f->options.sessions.max_sessions, 9);  // flag wins over the file
  EXPECT_EQ(f->options.sessions.limits.default_idle_timeout_s, 30);
  EXPECT_EQ(f->options.metrics_listen, "127.0.0.1:0");
  EXPECT_EQ(f->options.sessions.limits.default_options.num_features, 500);
  EXPECT_EQ(f->options.sessions.limits.default_options.mapping_mode, MappingMode::kBackground);
  {
    std::ofstream out(config);
    out << "%YAML:1.0\nmax_sesions: 7\n";
  }
  EXPECT_THAT(std::string(Parse({"--config", config}).status().message()),
              HasSubstr("unknown key max_sesions"));
  EXPECT_TRUE(absl::IsNotFound(Parse({"--config", "/nonexistent.yaml"}).status()));
}

}  // namespace
}  // namespace twist::server
