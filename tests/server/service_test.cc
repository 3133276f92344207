// The server's mechanics end to end on loopback with a fake engine: sessions,
// limits, bad input, flow control, takeover/reconnect, persistence across a
// restart, auth, shutdown, map chunks, metrics, health.
#include <gmock/gmock.h>
#include <grpcpp/generic/generic_stub.h>
#include <gtest/gtest.h>

#include <filesystem>
#include <fstream>
#include <future>
#include <mutex>

#include "client/lib/slam_client.h"
#include "server/server.h"
#include "tests/server/fake_slam_system.h"
#include "tests/server/test_util.h"

namespace twist::server {
namespace {

using ::testing::HasSubstr;
using twist::testing::FakeFactory;
using twist::testing::MakeCreateRequest;
using twist::testing::MakeTestFrame;

constexpr int kW = 64;
constexpr int kH = 48;
// Liveness bound for operations that must finish (not a timing assertion).
constexpr auto kMustFinish = std::chrono::seconds(60);

ServerOptions TestOptions() {
  ServerOptions o;
  o.listen = "127.0.0.1:0";
  o.sessions.housekeeping_period_s = 0;  // tests drive housekeeping explicitly
  o.drain_timeout_s = 2;
  o.shutdown_deadline_s = 5;
  return o;
}

std::unique_ptr<TwistServer> StartServer(const ServerOptions& options, int delay_ms = 0) {
  absl::StatusOr<std::unique_ptr<TwistServer>> s =
      TwistServer::Start(options, FakeFactory(delay_ms));
  EXPECT_TRUE(s.ok()) << s.status();
  return s.ok() ? std::move(*s) : nullptr;
}

std::unique_ptr<client::SlamClient> Connect(const std::string& address,
                                            const std::string& token = "") {
  client::ClientOptions o;
  o.address = address;
  o.token = token;
  o.rpc_timeout_s = 20;
  absl::StatusOr<std::unique_ptr<client::SlamClient>> c = client::SlamClient::Connect(o);
  EXPECT_TRUE(c.ok()) << c.status();
  return std::move(*c);
}

// Collects what a stream answers.
struct Collector {
  std::mutex mu;
  std::vector<pb::FrameUpdate> updates;
  std::vector<pb::FrameError> errors;
  std::vector<int64_t> dropped;
  client::SlamClient::ResponseCallback callback() {
    return [this](const pb::StreamResponse& r) {
      std::lock_guard<std::mutex> lock(mu);
      if (r.has_update()) updates.push_back(r.update());
      if (r.has_error()) errors.push_back(r.error());
      if (r.has_dropped())
        dropped.insert(dropped.end(), r.dropped().indices().begin(), r.dropped().indices().end());
    };
  }
};

// Poses the fake engine gives for frames [0, n) when run directly.
std::vector<geometry::SE3d> EmbeddedPoses(int n,
                                          int width = kW,
                                          int height = kH,
                                          uint64_t seed = 1) {
  SessionConfig config;
  config.camera.fx = 100;
  config.camera.width = width;
  config.camera.height = height;
  twist::testing::FakeSlamSystem fake(config, 0);
  std::vector<geometry::SE3d> poses;
  for (int i = 0; i < n; ++i) {
    StereoFrame f;
    f.index = i;
    f.timestamp_ns = 1'000'000'000LL + i * 100'000'000LL;
    f.left = twist::testing::TestImage(width, height, seed, i);
    f.right = twist::testing::TestImage(width, height, seed + 7, i);
    poses.push_back(fake.Process(f)->world_from_camera);
  }
  return poses;
}

void ExpectPosesEqual(const std::vector<pb::FrameUpdate>& updates,
                      const std::vector<geometry::SE3d>& expected) {
  ASSERT_EQ(updates.size(), expected.size());
  for (size_t i = 0; i < updates.size(); ++i) {
    EXPECT_EQ(updates[i].index(), static_cast<int64_t>(i));
    const pb::Pose& p = updates[i].world_from_camera();
    EXPECT_NEAR(p.translation().z(), expected[i].translation().z(), 1e-12) << "frame " << i;
    EXPECT_NEAR(p.rotation().y(), expected[i].unit_quaternion().y(), 1e-12) << "frame " << i;
  }
}

TEST(Service, CreateStreamListCloseWithDifferentCalibrations) {
  auto server = StartServer(TestOptions());
  auto client = Connect(server->address());
  absl::StatusOr<pb::GetServerInfoResponse> info = client->GetServerInfo();
  ASSERT_TRUE(info.ok()) << info.status();
  EXPECT_EQ(info->protocol(), "twistslam.v1");
  EXPECT_GT(info->limits().max_message_bytes(), 4 << 20);
  EXPECT_THAT(std::vector<std::string>(info->capabilities().begin(), info->capabilities().end()),
              ::testing::IsSupersetOf({"health", "reflection"}));

  auto a = client->CreateSession(MakeCreateRequest(kW, kH));
  auto b = client->CreateSession(MakeCreateRequest(2 * kW, 2 * kH, 250.0, 0.3));
  ASSERT_TRUE(a.ok() && b.ok());
  EXPECT_NE(a->session_id(), b->session_id());
  EXPECT_EQ(b->effective_calibration().width(), 2 * kW);
  EXPECT_FALSE(a->resume_token().empty());

  Collector collected;
  ASSERT_TRUE(client->OpenStream(a->session_id(), a->resume_token(), collected.callback()).ok());
  for (int i = 0; i < 8; ++i) ASSERT_TRUE(client->Send(MakeTestFrame(i, kW, kH)).ok());
  ASSERT_TRUE(client->CloseStream().ok());
  ExpectPosesEqual(collected.updates, EmbeddedPoses(8));
  // The server adds its own stages to the engine's.
  std::vector<std::string> stages;
  for (const auto& t : collected.updates[0].timings()) stages.push_back(t.stage());
  EXPECT_THAT(stages, ::testing::IsSupersetOf({"fake", "decode", "queue"}));
  EXPECT_EQ(collected.updates[0].cluster_events(0).type(), pb::CLUSTER_EVENT_TYPE_CREATED);

  absl::StatusOr<std::vector<pb::SessionInfo>> list = client->ListSessions();
  ASSERT_TRUE(list.ok());
  ASSERT_EQ(list->size(), 2u);
  for (const pb::SessionInfo& s : *list) {
    if (s.session_id() == a->session_id()) {
      EXPECT_EQ(s.frames_processed(), 8);
      EXPECT_EQ(s.last_frame_index(), 7);
      EXPECT_EQ(s.state(), pb::SESSION_STATE_IDLE);
    }
  }
  ASSERT_TRUE(client->CloseSession(a->session_id(), false).ok());
  EXPECT_EQ(client->ListSessions()->size(), 1u);
  Collector after;
  absl::Status closed = client->OpenStream(a->session_id(), a->resume_token(), after.callback());
  EXPECT_TRUE(absl::IsFailedPrecondition(closed)) << closed;
  EXPECT_THAT(std::string(closed.message()), HasSubstr("closed"));
  EXPECT_TRUE(absl::IsNotFound(client->CloseSession("nonexistent", false).status()));
}

TEST(Service, EveryBadInputIsAnsweredAndTheNextFrameWorks) {
  auto server = StartServer(TestOptions());
  auto client = Connect(server->address());
  // Session creation errors.
  pb::CreateSessionRequest bad = MakeCreateRequest(kW, kH);
  bad.mutable_config()->mutable_calibration()->set_baseline(-1);
  absl::Status s = client->CreateSession(bad).status();
  EXPECT_TRUE(absl::IsInvalidArgument(s));
  EXPECT_THAT(std::string(s.message()), HasSubstr("baseline"));
  EXPECT_TRUE(absl::IsInvalidArgument(client->CreateSession(pb::CreateSessionRequest()).status()));

  auto created = client->CreateSession(MakeCreateRequest(kW, kH));
  ASSERT_TRUE(created.ok());
  Collector c;
  ASSERT_TRUE(
      client->OpenStream(created->session_id(), created->resume_token(), c.callback()).ok());
  int64_t next = 0;
  auto valid = [&] { return MakeTestFrame(next++, kW, kH); };
  std::vector<std::pair<pb::Frame, std::string>> bad_frames;
  pb::Frame f = MakeTestFrame(100, kW + 8, kH);  // wrong size
  bad_frames.push_back({f, "session expects 64x48"});
  f = MakeTestFrame(101, kW, kH, 1, pb::IMAGE_ENCODING_PNG);
  f.mutable_left()->set_data("garbage that is not an image");
  bad_frames.push_back({f, "left image"});
  f = MakeTestFrame(102, kW, kH);
  client::EncodeImage(
      cv::Mat(kH / 2, kW, CV_16UC1, cv::Scalar(7000)), pb::IMAGE_ENCODING_PNG, f.mutable_panoptic())
      .IgnoreError();
  bad_frames.push_back({f, "panoptic mask is 64x24"});
  f = MakeTestFrame(103, kW, kH);
  client::EncodeImage(
      cv::Mat(kH, kW, CV_8UC1, cv::Scalar(7)), pb::IMAGE_ENCODING_RAW, f.mutable_panoptic())
      .IgnoreError();
  bad_frames.push_back({f, "panoptic mask is 8-bit gray"});

  ASSERT_TRUE(client->Send(valid()).ok());
  for (auto& [frame, message] : bad_frames) {
    // Timestamps stay increasing so only the defect under test is wrong.
    frame.set_timestamp_ns(1'000'000'000 + next * 100'000'000 - 50'000'000);
    ASSERT_TRUE(client->Send(frame).ok());
    ASSERT_TRUE(client->Send(valid()).ok());
  }
  // Non-increasing timestamp (a copy of frame 0's timestamp).
  pb::Frame stale = MakeTestFrame(0, kW, kH);
  stale.set_index(200);
  ASSERT_TRUE(client->Send(stale).ok());
  ASSERT_TRUE(client->Send(valid()).ok());
  ASSERT_TRUE(client->CloseStream().ok());

  ASSERT_EQ(c.errors.size(), bad_frames.size() + 1);
  for (size_t i = 0; i < bad_frames.size(); ++i) {
    EXPECT_EQ(c.errors[i].code(), static_cast<int>(grpc::StatusCode::INVALID_ARGUMENT));
    EXPECT_THAT(c.errors[i].message(), HasSubstr(bad_frames[i].second));
  }
  EXPECT_EQ(c.errors.back().index(), 200);
  EXPECT_THAT(c.errors.back().message(), HasSubstr("not after the previous frame"));
  // Every valid frame was processed, in order, as if the bad ones never came.
  ExpectPosesEqual(c.updates, EmbeddedPoses(static_cast<int>(next)));
  auto list = client->ListSessions();
  EXPECT_EQ((*list)[0].frames_rejected(), static_cast<int64_t>(bad_frames.size() + 1));
}

// Raw stream calls for what the client library never sends.
TEST(Service, StreamProtocolErrors) {
  auto server = StartServer(TestOptions());
  auto client = Connect(server->address());
  auto created = client->CreateSession(MakeCreateRequest(kW, kH));
  ASSERT_TRUE(created.ok());
  auto raw_stream = [&](const std::vector<pb::StreamRequest>& requests,
                        std::vector<pb::StreamResponse>* out) {
    grpc::ClientContext context;
    auto stream = client->stub()->Stream(&context);
    for (const auto& r : requests) stream->Write(r);
    stream->WritesDone();
    pb::StreamResponse response;
    while (stream->Read(&response)) out->push_back(response);
    return stream->Finish();
  };
  std::vector<pb::StreamResponse> responses;
  pb::StreamRequest frame;
  *frame.mutable_frame() = MakeTestFrame(0, kW, kH);
  grpc::Status s = raw_stream({frame}, &responses);
  EXPECT_EQ(s.error_code(), grpc::StatusCode::FAILED_PRECONDITION);
  EXPECT_THAT(s.error_message(), HasSubstr("before binding"));

  pb::StreamRequest bind;
  bind.mutable_bind()->set_session_id("0123456789abcdef");
  EXPECT_EQ(raw_stream({bind}, &responses).error_code(), grpc::StatusCode::NOT_FOUND);

  bind.mutable_bind()->set_session_id(created->session_id());
  pb::StreamRequest empty;
  responses.clear();
  s = raw_stream({bind, empty, bind, frame}, &responses);
  EXPECT_TRUE(s.ok()) << s.error_message();
  ASSERT_EQ(responses.size(), 4u);
  EXPECT_TRUE(responses[0].has_bound());
  EXPECT_THAT(responses[1].error().message(), HasSubstr("empty StreamRequest"));
  EXPECT_THAT(responses[2].error().message(), HasSubstr("already bound"));
  EXPECT_TRUE(responses[3].has_update());
}

TEST(Service, SessionLimitAndLargeMessages) {
  ServerOptions options = TestOptions();
  options.sessions.max_sessions = 2;
  auto server = StartServer(options);
  auto client = Connect(server->address());
  // A raw 1600x1400 gray stereo pair is 4.5 MB: above gRPC's 4 MiB default.
  constexpr int kBigW = 1600, kBigH = 1400;
  auto big = client->CreateSession(MakeCreateRequest(kBigW, kBigH, 1000));
  ASSERT_TRUE(big.ok()) << big.status();
  ASSERT_TRUE(client->CreateSession(MakeCreateRequest(kW, kH)).ok());
  absl::Status s = client->CreateSession(MakeCreateRequest(kW, kH)).status();
  EXPECT_TRUE(absl::IsResourceExhausted(s)) << s;
  EXPECT_THAT(std::string(s.message()), HasSubstr("limit of 2 sessions"));

  Collector c;
  ASSERT_TRUE(client->OpenStream(big->session_id(), big->resume_token(), c.callback()).ok());
  const pb::Frame frame = MakeTestFrame(0, kBigW, kBigH);
  ASSERT_GT(frame.ByteSizeLong(), 4u << 20);
  ASSERT_TRUE(client->Send(frame).ok());
  ASSERT_TRUE(client->CloseStream().ok());
  ASSERT_EQ(c.updates.size(), 1u);
  EXPECT_TRUE(c.errors.empty());
}

TEST(Service, DropOldestReportsDropsAndBlockLosesNothing) {
  auto server = StartServer(TestOptions(), /*delay_ms=*/40);
  auto client = Connect(server->address());
  pb::CreateSessionRequest request = MakeCreateRequest(kW, kH);
  request.mutable_policy()->set_queue_capacity(1);
  request.mutable_policy()->set_overflow(pb::OVERFLOW_POLICY_DROP_OLDEST);
  auto dropping = client->CreateSession(request);
  ASSERT_TRUE(dropping.ok());
  EXPECT_EQ(dropping->session().policy().queue_capacity(), 1);
  Collector c;
  ASSERT_TRUE(
      client->OpenStream(dropping->session_id(), dropping->resume_token(), c.callback()).ok());
  constexpr int kFrames = 12;
  for (int i = 0; i < kFrames; ++i) ASSERT_TRUE(client->Send(MakeTestFrame(i, kW, kH)).ok());
  ASSERT_TRUE(client->CloseStream().ok());
  EXPECT_GT(c.dropped.size(), 0u);
  EXPECT_EQ(c.updates.size() + c.dropped.size(), static_cast<size_t>(kFrames));
  EXPECT_EQ(c.updates.back().index(), kFrames - 1);  // the newest frame is never dropped

  request.mutable_policy()->set_overflow(pb::OVERFLOW_POLICY_BLOCK);
  auto blocking = client->CreateSession(request);
  Collector b;
  ASSERT_TRUE(
      client->OpenStream(blocking->session_id(), blocking->resume_token(), b.callback()).ok());
  for (int i = 0; i < kFrames; ++i) ASSERT_TRUE(client->Send(MakeTestFrame(i, kW, kH)).ok());
  ASSERT_TRUE(client->CloseStream().ok());
  EXPECT_TRUE(b.dropped.empty());
  ExpectPosesEqual(b.updates, EmbeddedPoses(kFrames));
}

TEST(Service, BrokenStreamReconnectsAndContinuesExactly) {
  auto server = StartServer(TestOptions(), /*delay_ms=*/5);
  auto client = Connect(server->address());
  auto created = client->CreateSession(MakeCreateRequest(kW, kH));
  Collector c;
  ASSERT_TRUE(
      client->OpenStream(created->session_id(), created->resume_token(), c.callback()).ok());
  constexpr int kFrames = 20;
  for (int i = 0; i < kFrames; ++i) {
    if (i == 7 || i == 13) client->DropConnectionForTesting();
    ASSERT_TRUE(client->Send(MakeTestFrame(i, kW, kH)).ok()) << "frame " << i;
  }
  ASSERT_TRUE(client->CloseStream().ok());
  EXPECT_GE(client->reconnects(), 2);
  // Nothing lost, nothing processed twice: the same poses as one clean run.
  std::sort(
      c.updates.begin(), c.updates.end(), [](const pb::FrameUpdate& a, const pb::FrameUpdate& b) {
        return a.index() < b.index();
      });
  c.updates.erase(std::unique(c.updates.begin(),
                              c.updates.end(),
                              [](const pb::FrameUpdate& a, const pb::FrameUpdate& b) {
                                return a.index() == b.index();
                              }),
                  c.updates.end());
  ExpectPosesEqual(c.updates, EmbeddedPoses(kFrames));
  EXPECT_EQ(client->ListSessions()->at(0).frames_processed(), kFrames);
}

TEST(Service, ANewStreamTakesOverTheSession) {
  auto server = StartServer(TestOptions());
  auto first = Connect(server->address());
  auto created = first->CreateSession(MakeCreateRequest(kW, kH));
  first->Send(MakeTestFrame(0, kW, kH)).IgnoreError();  // no stream: refused
  Collector c1, c2;
  ASSERT_TRUE(
      first->OpenStream(created->session_id(), created->resume_token(), c1.callback()).ok());
  ASSERT_TRUE(first->Send(MakeTestFrame(0, kW, kH)).ok());
  // Wait until frame 0 is answered so the takeover cannot discard it.
  for (int i = 0; i < 2000 && first->ListSessions()->at(0).frames_processed() < 1; ++i)
    absl::SleepFor(absl::Milliseconds(5));

  auto second = Connect(server->address());
  ASSERT_TRUE(
      second->OpenStream(created->session_id(), created->resume_token(), c2.callback()).ok());
  EXPECT_EQ(second->bound_session().last_frame_index(), 0);
  ASSERT_TRUE(second->Send(MakeTestFrame(1, kW, kH)).ok());
  ASSERT_TRUE(second->CloseStream().ok());
  absl::Status s = first->CloseStream();
  EXPECT_TRUE(absl::IsAborted(s)) << s;
  EXPECT_THAT(std::string(s.message()), HasSubstr("taken over"));
  ASSERT_EQ(c2.updates.size(), 1u);
  EXPECT_NEAR(c2.updates[0].world_from_camera().translation().z(),
              EmbeddedPoses(2)[1].translation().z(),
              1e-12);
}

TEST(Service, RestartResumesFromTheStateDirectoryWithNothingLost) {
  const std::string state = ::testing::TempDir() + "/twist_state_restart";
  std::filesystem::remove_all(state);
  ServerOptions options = TestOptions();
  options.sessions.state_dir = state;
  auto server = StartServer(options, /*delay_ms=*/5);
  const int port = server->port();
  auto client = Connect(server->address());
  auto created = client->CreateSession(MakeCreateRequest(kW, kH));
  ASSERT_TRUE(created.ok());
  Collector c;
  ASSERT_TRUE(
      client->OpenStream(created->session_id(), created->resume_token(), c.callback()).ok());
  constexpr int kFrames = 16;
  std::future<void> restart;
  for (int i = 0; i < kFrames; ++i) {
    if (i == 6) {
      // Graceful restart on the same port while the stream is open: the
      // client notices, waits, resumes and continues.
      server->Shutdown();
      server.reset();
      options.listen = "127.0.0.1:" + std::to_string(port);
      server = StartServer(options, 5);
      ASSERT_NE(server, nullptr);
    }
    ASSERT_TRUE(client->Send(MakeTestFrame(i, kW, kH)).ok()) << "frame " << i;
  }
  ASSERT_TRUE(client->CloseStream().ok());
  EXPECT_GE(client->reconnects(), 1);
  std::sort(
      c.updates.begin(), c.updates.end(), [](const pb::FrameUpdate& a, const pb::FrameUpdate& b) {
        return a.index() < b.index();
      });
  // Updates the old server could not deliver are not replayed across a
  // restart; every frame's effect is still in the state (poses continue).
  ASSERT_FALSE(c.updates.empty());
  EXPECT_EQ(c.updates.back().index(), kFrames - 1);
  const std::vector<geometry::SE3d> expected = EmbeddedPoses(kFrames);
  for (const pb::FrameUpdate& u : c.updates) {
    EXPECT_NEAR(
        u.world_from_camera().translation().z(), expected[u.index()].translation().z(), 1e-12);
  }
  EXPECT_EQ(client->ListSessions()->at(0).frames_processed(), kFrames);

  // A cold restart: only the state directory survives; ResumeSession loads.
  server->Shutdown();
  server.reset();
  options.listen = "127.0.0.1:0";
  server = StartServer(options);
  auto fresh = Connect(server->address());
  auto list = fresh->ListSessions();
  ASSERT_EQ(list->size(), 1u);
  EXPECT_EQ(list->at(0).state(), pb::SESSION_STATE_STORED);
  Collector unused;
  EXPECT_TRUE(
      absl::IsFailedPrecondition(fresh->OpenStream(created->session_id(), "", unused.callback())));
  EXPECT_TRUE(
      absl::IsPermissionDenied(fresh->ResumeSession(created->session_id(), "wrong").status()));
  auto resumed = fresh->ResumeSession(created->session_id(), created->resume_token());
  ASSERT_TRUE(resumed.ok()) << resumed.status();
  EXPECT_TRUE(resumed->loaded_from_disk());
  EXPECT_EQ(resumed->session().frames_processed(), kFrames);
  EXPECT_EQ(resumed->session().last_frame_index(), kFrames - 1);
  // Persist on request and close with persist keeps it stored.
  auto persisted = fresh->PersistSession(created->session_id());
  ASSERT_TRUE(persisted.ok());
  EXPECT_EQ(persisted->frames_persisted(), kFrames);
  auto closed = fresh->CloseSession(created->session_id(), /*persist=*/true);
  ASSERT_TRUE(closed.ok());
  EXPECT_TRUE(closed->persisted());
  std::filesystem::remove_all(state);
}

TEST(Service, IdleSessionsArePersistedAndUnloaded) {
  const std::string state = ::testing::TempDir() + "/twist_state_idle";
  std::filesystem::remove_all(state);
  ServerOptions options = TestOptions();
  options.sessions.state_dir = state;
  auto server = StartServer(options);
  auto client = Connect(server->address());
  pb::CreateSessionRequest request = MakeCreateRequest(kW, kH);
  request.mutable_policy()->set_idle_timeout_s(30);
  auto created = client->CreateSession(request);
  auto keep = client->CreateSession(MakeCreateRequest(kW, kH));  // default 600 s
  Collector c;
  ASSERT_TRUE(
      client->OpenStream(created->session_id(), created->resume_token(), c.callback()).ok());
  ASSERT_TRUE(client->Send(MakeTestFrame(0, kW, kH)).ok());
  ASSERT_TRUE(client->CloseStream().ok());
  server->sessions()->Housekeeping(absl::Now() + absl::Seconds(60));
  EXPECT_EQ(server->sessions()->num_loaded(), 1);
  auto resumed = client->ResumeSession(created->session_id(), created->resume_token());
  ASSERT_TRUE(resumed.ok()) << resumed.status();
  EXPECT_TRUE(resumed->loaded_from_disk());
  EXPECT_EQ(resumed->session().frames_processed(), 1);
  std::filesystem::remove_all(state);
}

TEST(Service, AuthRequiredAndSessionsIsolatedPerToken) {
  const std::string tokens = ::testing::TempDir() + "/twist_tokens";
  {
    std::ofstream out(tokens);
    out << "token-alice-123 alice\ntoken-bob-456 bob\n";
  }
  ServerOptions options = TestOptions();
  options.auth_token_file = tokens;
  auto server = StartServer(options);
  auto anonymous = Connect(server->address());
  absl::Status s = anonymous->CreateSession(MakeCreateRequest(kW, kH)).status();
  EXPECT_TRUE(absl::IsUnauthenticated(s)) << s;
  EXPECT_TRUE(absl::IsUnauthenticated(
      Connect(server->address(), "token-mallory")->ListSessions().status()));
  Collector unused;
  EXPECT_TRUE(absl::IsUnauthenticated(anonymous->OpenStream("x", "", unused.callback())));

  auto alice = Connect(server->address(), "token-alice-123");
  auto bob = Connect(server->address(), "token-bob-456");
  auto created = alice->CreateSession(MakeCreateRequest(kW, kH));
  ASSERT_TRUE(created.ok()) << created.status();
  EXPECT_EQ(alice->ListSessions()->size(), 1u);
  EXPECT_EQ(bob->ListSessions()->size(), 0u);
  EXPECT_TRUE(absl::IsNotFound(
      bob->OpenStream(created->session_id(), created->resume_token(), unused.callback())));
  EXPECT_TRUE(absl::IsNotFound(bob->CloseSession(created->session_id(), false).status()));
  pb::GetMapRequest map_request;
  map_request.set_session_id(created->session_id());
  EXPECT_TRUE(absl::IsNotFound(bob->GetMap(map_request).status()));
  EXPECT_TRUE(absl::IsNotFound(
      bob->ResumeSession(created->session_id(), created->resume_token()).status()));
  EXPECT_TRUE(alice->GetMap(map_request).ok());
  EXPECT_TRUE(alice->GetServerInfo()->auth_required());
}

int HealthStatus(const std::string& address) {
  auto channel = grpc::CreateChannel(address, grpc::InsecureChannelCredentials());
  grpc::GenericStub stub(channel);
  grpc::ClientContext context;
  context.set_deadline(std::chrono::system_clock::now() + std::chrono::seconds(10));
  const grpc::Slice empty;
  grpc::ByteBuffer request(&empty, 1), response;
  std::promise<grpc::Status> done;
  stub.UnaryCall(&context,
                 "/grpc.health.v1.Health/Check",
                 grpc::StubOptions(),
                 &request,
                 &response,
                 [&done](grpc::Status s) { done.set_value(s); });
  const grpc::Status s = done.get_future().get();
  if (!s.ok()) return -static_cast<int>(s.error_code());
  std::vector<grpc::Slice> slices;
  response.Dump(&slices);
  std::string bytes;
  for (const auto& slice : slices)
    bytes.append(reinterpret_cast<const char*>(slice.begin()), slice.size());
  // HealthCheckResponse{status = 1 SERVING | 2 NOT_SERVING}: field 1 varint.
  return bytes.size() == 2 && bytes[0] == 0x08 ? bytes[1] : 0;
}

TEST(Service, ShutdownWithOpenStreamsFinishesAndPersists) {
  const std::string state = ::testing::TempDir() + "/twist_state_shutdown";
  std::filesystem::remove_all(state);
  ServerOptions options = TestOptions();
  options.sessions.state_dir = state;
  options.drain_timeout_s = 0.5;
  options.shutdown_deadline_s = 2;
  auto server = StartServer(options, /*delay_ms=*/100);
  EXPECT_EQ(HealthStatus(server->address()), 1);
  auto client = Connect(server->address());
  auto created = client->CreateSession(MakeCreateRequest(kW, kH));
  // A raw stream that never half-closes and never reads: the worst client.
  grpc::ClientContext context;
  auto stream = client->stub()->Stream(&context);
  pb::StreamRequest bind;
  bind.mutable_bind()->set_session_id(created->session_id());
  ASSERT_TRUE(stream->Write(bind));
  for (int i = 0; i < 6; ++i) {
    pb::StreamRequest r;
    *r.mutable_frame() = MakeTestFrame(i, kW, kH);
    stream->Write(r);
  }
  // Wait (bounded) until the engine is busy with the stream.
  for (int i = 0; i < 2000 && client->ListSessions()->at(0).frames_processed() < 1; ++i) {
    absl::SleepFor(absl::Milliseconds(5));
  }
  auto done = std::async(std::launch::async, [&] { server->Shutdown(); });
  ASSERT_EQ(done.wait_for(kMustFinish), std::future_status::ready);
  // Drained and persisted: whatever was processed is on disk.
  auto restarted = StartServer(options);
  auto fresh = Connect(restarted->address());
  auto resumed = fresh->ResumeSession(created->session_id(), created->resume_token());
  ASSERT_TRUE(resumed.ok()) << resumed.status();
  EXPECT_GE(resumed->session().frames_processed(), 1);
  context.TryCancel();
  stream->Finish();
  std::filesystem::remove_all(state);
}

TEST(Service, MapChunksMetricsAndUnrectifiedRig) {
  ServerOptions options = TestOptions();
  auto server = StartServer(options);
  auto client = Connect(server->address());
  pb::CreateSessionRequest request = MakeCreateRequest(kW, kH);
  pb::UnrectifiedRig* rig = request.mutable_config()->mutable_calibration()->mutable_unrectified();
  for (pb::CameraIntrinsics* cam : {rig->mutable_left(), rig->mutable_right()}) {
    cam->set_fx(100);
    cam->set_fy(100);
    cam->set_cx(kW / 2.0);
    cam->set_cy(kH / 2.0);
    cam->add_distortion(-0.01);
    cam->add_distortion(0);
    cam->add_distortion(0);
    cam->add_distortion(0);
  }
  rig->mutable_right_from_left()->mutable_rotation()->set_w(1);
  rig->mutable_right_from_left()->mutable_translation()->set_x(-0.4);
  auto created = client->CreateSession(request);
  ASSERT_TRUE(created.ok()) << created.status();
  EXPECT_NEAR(created->effective_calibration().baseline(), 0.4, 1e-9);
  Collector c;
  ASSERT_TRUE(
      client->OpenStream(created->session_id(), created->resume_token(), c.callback()).ok());
  for (int i = 0; i < 30; ++i)
    ASSERT_TRUE(client->Send(MakeTestFrame(i, kW, kH, 1, pb::IMAGE_ENCODING_PNG, true)).ok());
  ASSERT_TRUE(client->CloseStream().ok());
  ASSERT_EQ(c.updates.size(), 30u);
  ASSERT_EQ(c.updates[0].objects_size(), 1);  // the car instance in the mask
  EXPECT_EQ(c.updates[0].objects(0).class_id(), 26);

  pb::GetMapRequest map_request;
  map_request.set_session_id(created->session_id());
  map_request.set_max_chunk_bytes(1);  // clamped to 64 KiB
  auto chunks = client->GetMap(map_request);
  ASSERT_TRUE(chunks.ok()) << chunks.status();
  int64_t points = 0;
  for (const auto& chunk : *chunks) points += chunk.points_size();
  EXPECT_EQ(points, 300);
  EXPECT_EQ((*chunks)[0].summary().num_points(), 300);
  EXPECT_EQ((*chunks)[0].summary().frames_processed(), 30);

  auto metrics = client->GetMetrics();
  ASSERT_TRUE(metrics.ok());
  EXPECT_THAT(*metrics, HasSubstr("twistslam_frames_processed_total 30\n"));
  EXPECT_THAT(*metrics, HasSubstr("twistslam_sessions 1\n"));
}

}  // namespace
}  // namespace twist::server

namespace twist::server {
namespace {

TEST(Service, TlsServesOnlyTlsClients) {
  const std::string dir = std::string(TWIST_SOURCE_DIR) + "/tests/server/testdata";
  ServerOptions options = TestOptions();
  options.tls_cert_file = dir + "/server.crt";
  options.tls_key_file = dir + "/server.key";
  auto server = StartServer(options);
  ASSERT_NE(server, nullptr);
  client::ClientOptions o;
  o.address = server->address();
  o.tls_ca_file = dir + "/server.crt";
  o.tls_server_name = "localhost";
  auto tls_client = std::move(*client::SlamClient::Connect(o));
  auto info = tls_client->GetServerInfo();
  ASSERT_TRUE(info.ok()) << info.status();
  EXPECT_THAT(std::vector<std::string>(info->capabilities().begin(), info->capabilities().end()),
              ::testing::Contains("tls"));
  auto created = tls_client->CreateSession(MakeCreateRequest(kW, kH));
  ASSERT_TRUE(created.ok());
  Collector c;
  ASSERT_TRUE(
      tls_client->OpenStream(created->session_id(), created->resume_token(), c.callback()).ok());
  ASSERT_TRUE(tls_client->Send(MakeTestFrame(0, kW, kH)).ok());
  ASSERT_TRUE(tls_client->CloseStream().ok());
  EXPECT_EQ(c.updates.size(), 1u);

  client::ClientOptions plain;
  plain.address = server->address();
  plain.rpc_timeout_s = 2;
  auto plain_client = std::move(*client::SlamClient::Connect(plain));
  EXPECT_FALSE(plain_client->GetServerInfo().ok());

  options.tls_key_file = dir + "/missing.key";
  EXPECT_TRUE(absl::IsNotFound(TwistServer::Start(options, FakeFactory()).status()));
}

}  // namespace
}  // namespace twist::server

namespace twist::server {
namespace {

// A stalled engine (and a client that writes as fast as it can and never
// reads): the queue fills, the reader stops reading, and HTTP/2 flow control
// blocks the client's writes. Memory stays bounded: the session's queue never
// exceeds its capacity and the client cannot push the whole (~900 MB)
// sequence into the server.
TEST(Service, StalledEngineBackPressuresTheClient) {
  auto gate = std::make_shared<absl::Notification>();
  absl::StatusOr<std::unique_ptr<TwistServer>> started =
      TwistServer::Start(TestOptions(), FakeFactory(0, gate));
  ASSERT_TRUE(started.ok());
  auto server = std::move(*started);
  auto client = Connect(server->address());
  constexpr int kBigW = 1600, kBigH = 1400;  // 4.5 MB per raw frame
  pb::CreateSessionRequest request = MakeCreateRequest(kBigW, kBigH, 1000);
  request.mutable_policy()->set_queue_capacity(2);
  auto created = client->CreateSession(request);
  ASSERT_TRUE(created.ok());
  grpc::ClientContext context;
  auto stream = client->stub()->Stream(&context);
  pb::StreamRequest bind;
  bind.mutable_bind()->set_session_id(created->session_id());
  ASSERT_TRUE(stream->Write(bind));
  pb::StreamRequest frame;
  *frame.mutable_frame() = MakeTestFrame(0, kBigW, kBigH);
  constexpr int kFrames = 200;
  std::atomic<int> written{0};
  std::thread writer([&] {
    for (int i = 0; i < kFrames; ++i) {
      frame.mutable_frame()->set_index(i);
      frame.mutable_frame()->set_timestamp_ns(1'000'000'000LL + i * 1'000'000LL);
      if (!stream->Write(frame)) return;
      ++written;
    }
  });
  // Wait (bounded) until the writer stops making progress.
  int last = -1;
  for (int i = 0; i < 300 && written != last; ++i) {
    last = written;
    absl::SleepFor(absl::Milliseconds(300));
  }
  EXPECT_LT(written.load(), kFrames);
  int max_depth = 0;
  absl::StatusOr<std::vector<pb::SessionInfo>> sessions = client->ListSessions();
  ASSERT_TRUE(sessions.ok());
  for (const pb::SessionInfo& s : *sessions) max_depth = std::max(max_depth, s.queue_depth());
  EXPECT_LE(max_depth, 2);
  gate->Notify();
  context.TryCancel();
  writer.join();
  stream->Finish();
}

}  // namespace
}  // namespace twist::server

namespace twist::server {
namespace {

// A one-message call on any method (gRPC frames unary and streaming calls
// alike): returns the response bytes, or "" on error.
std::string RawCall(const std::string& address,
                    const std::string& method,
                    const std::string& request_bytes) {
  auto channel = grpc::CreateChannel(address, grpc::InsecureChannelCredentials());
  grpc::GenericStub stub(channel);
  grpc::ClientContext context;
  context.set_deadline(std::chrono::system_clock::now() + std::chrono::seconds(10));
  const grpc::Slice slice(request_bytes);
  grpc::ByteBuffer request(&slice, 1), response;
  std::promise<grpc::Status> done;
  stub.UnaryCall(
      &context, method, grpc::StubOptions(), &request, &response, [&done](grpc::Status s) {
        done.set_value(s);
      });
  if (!done.get_future().get().ok()) return "";
  std::vector<grpc::Slice> slices;
  response.Dump(&slices);
  std::string bytes;
  for (const auto& s : slices) bytes.append(reinterpret_cast<const char*>(s.begin()), s.size());
  return bytes;
}

TEST(Service, ReflectionListsTheServiceAndHealthTurnsNotServingOnShutdown) {
  auto gate = std::make_shared<absl::Notification>();
  ServerOptions options = TestOptions();
  options.drain_timeout_s = 2;
  absl::StatusOr<std::unique_ptr<TwistServer>> started =
      TwistServer::Start(options, FakeFactory(0, gate));
  ASSERT_TRUE(started.ok());
  auto server = std::move(*started);
  // ServerReflectionRequest{list_services: ""} = field 7, length 0.
  const std::string listing =
      RawCall(server->address(),
              "/grpc.reflection.v1alpha.ServerReflection/ServerReflectionInfo",
              std::string("\x3a\x00", 2));
  EXPECT_THAT(listing, HasSubstr("twistslam.v1.SlamService"));
  EXPECT_THAT(listing, HasSubstr("grpc.health.v1.Health"));
  EXPECT_EQ(HealthStatus(server->address()), 1);

  // A stream whose frame is stuck in the engine keeps the drain busy.
  auto client = Connect(server->address());
  auto created = client->CreateSession(MakeCreateRequest(kW, kH));
  Collector c;
  ASSERT_TRUE(
      client->OpenStream(created->session_id(), created->resume_token(), c.callback()).ok());
  ASSERT_TRUE(client->Send(MakeTestFrame(0, kW, kH)).ok());
  ASSERT_TRUE(client->Send(MakeTestFrame(1, kW, kH)).ok());
  // Frame 0 is in the (stalled) engine once frame 1 waits in the queue.
  for (int i = 0; i < 2000 && client->ListSessions()->at(0).queue_depth() < 1; ++i) {
    absl::SleepFor(absl::Milliseconds(5));
  }
  auto done = std::async(std::launch::async, [&] { server->Shutdown(); });
  int status = 1;
  std::string seen;
  for (int i = 0; i < 1000 && status == 1; ++i) {
    status = HealthStatus(server->address());
    seen += std::to_string(status) + " ";
    absl::SleepFor(absl::Milliseconds(2));
  }
  SCOPED_TRACE(seen);
  EXPECT_EQ(status, 2);  // NOT_SERVING while draining
  EXPECT_TRUE(absl::IsUnavailable(client->CreateSession(MakeCreateRequest(kW, kH)).status()));
  gate->Notify();
  ASSERT_EQ(done.wait_for(kMustFinish), std::future_status::ready);
  client->DropConnectionForTesting();
}

}  // namespace
}  // namespace twist::server
