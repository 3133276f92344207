// End to end on 127.0.0.1 (port 0): the real engine behind an in-process
// twistslam server, fed by the client library with rendered synthetic frames.
#include <gmock/gmock.h>
#include <gtest/gtest.h>

#include <filesystem>
#include <fstream>
#include <future>
#include <thread>

#include "tests/e2e/e2e_util.h"

namespace twist::e2e {
namespace {

using ::testing::HasSubstr;

// Liveness bound for calls that must return (never a timing assertion).
constexpr auto kMustFinish = std::chrono::seconds(90);

class E2E : public ::testing::Test {
 protected:
  static void SetUpTestSuite() {
    driving_ = new Sequence(MakeSequence("driving", 12, 0.5, 1));
    street_ = new Sequence(MakeSequence("static_street", 8, 0.4, 2));
    crossing_ = new Sequence(MakeSequence("intersection", 8, 0.6, 3));
    driving_alone_ = new std::vector<FrameResult>(RunEmbedded(*driving_));
  }
  static void TearDownTestSuite() {
    delete driving_;
    delete street_;
    delete crossing_;
    delete driving_alone_;
  }
  static Sequence* driving_;
  static Sequence* street_;
  static Sequence* crossing_;
  static std::vector<FrameResult>* driving_alone_;
};
Sequence* E2E::driving_ = nullptr;
Sequence* E2E::street_ = nullptr;
Sequence* E2E::crossing_ = nullptr;
std::vector<FrameResult>* E2E::driving_alone_ = nullptr;

// Streams `seq` (frames [0, count)) over one session and returns the updates.
std::vector<pb::FrameUpdate> Stream(client::SlamClient* client,
                                    const Sequence& seq,
                                    size_t count = 0,
                                    pb::ImageEncoding encoding = pb::IMAGE_ENCODING_PNG) {
  auto created = client->CreateSession(CreateRequest(seq.config));
  EXPECT_TRUE(created.ok()) << created.status();
  if (!created.ok()) return {};
  Collected c;
  EXPECT_TRUE(
      client->OpenStream(created->session_id(), created->resume_token(), c.callback()).ok());
  if (count == 0) count = seq.frames.size();
  for (size_t i = 0; i < count; ++i)
    EXPECT_TRUE(client->Send(ToWire(seq.frames[i], encoding)).ok());
  EXPECT_TRUE(client->CloseStream().ok());
  EXPECT_TRUE(c.errors.empty());
  return c.Sorted();
}

TEST_F(E2E, StreamedPosesEqualTheEmbeddedRun) {
  ASSERT_FALSE(driving_->frames.empty());
  auto server = StartServer(ServerTestOptions());
  auto client = Connect(server->address());
  const std::vector<pb::FrameUpdate> updates =
      Stream(client.get(), *driving_, 0, pb::IMAGE_ENCODING_RAW);
  ExpectSamePoses(updates, *driving_alone_);
  // The run moved and saw the moving cars the masks label.
  EXPECT_GT(std::abs(updates.back().world_from_camera().translation().z()), 0.5);
  EXPECT_EQ(updates.back().tracking_state(), pb::TRACKING_STATE_OK);
}

TEST_F(E2E, ThreeConcurrentSessionsWithDifferentCalibrationsEqualEachAlone) {
  ASSERT_FALSE(street_->frames.empty());
  ASSERT_FALSE(crossing_->frames.empty());
  ASSERT_NE(street_->config.camera.width, crossing_->config.camera.width);
  const std::vector<FrameResult> street_alone = RunEmbedded(*street_);
  const std::vector<FrameResult> crossing_alone = RunEmbedded(*crossing_);
  auto server = StartServer(ServerTestOptions());
  std::vector<pb::FrameUpdate> a, b, c;
  std::thread ta([&] { a = Stream(Connect(server->address()).get(), *driving_); });
  std::thread tb([&] { b = Stream(Connect(server->address()).get(), *street_); });
  std::thread tc([&] { c = Stream(Connect(server->address()).get(), *crossing_); });
  ta.join();
  tb.join();
  tc.join();
  ExpectSamePoses(a, *driving_alone_);
  ExpectSamePoses(b, street_alone);
  ExpectSamePoses(c, crossing_alone);
}

TEST_F(E2E, EveryBadInputIsRejectedAndTheNextFrameWorks) {
  auto server = StartServer(ServerTestOptions());
  auto client = Connect(server->address());
  auto created = client->CreateSession(CreateRequest(driving_->config));
  ASSERT_TRUE(created.ok());
  Collected c;
  ASSERT_TRUE(
      client->OpenStream(created->session_id(), created->resume_token(), c.callback()).ok());
  const int w = driving_->config.camera.width, h = driving_->config.camera.height;
  size_t next = 0;
  auto send_valid = [&] { ASSERT_TRUE(client->Send(ToWire(driving_->frames[next++])).ok()); };
  auto send_bad = [&](pb::Frame f, int64_t index) {
    f.set_index(index);
    // Between the previous valid frame and the next: only the defect is wrong.
    f.set_timestamp_ns(driving_->frames[next].timestamp_ns - 1);
    ASSERT_TRUE(client->Send(f).ok());
  };
  send_valid();
  pb::Frame wrong_size = ToWire(driving_->frames[next]);
  client::EncodeImage(
      cv::Mat(h, w + 4, CV_8UC1, cv::Scalar(0)), pb::IMAGE_ENCODING_PNG, wrong_size.mutable_left())
      .IgnoreError();
  send_bad(wrong_size, 1001);
  send_valid();
  pb::Frame undecodable = ToWire(driving_->frames[next]);
  undecodable.mutable_right()->set_data(std::string(1000, 'x'));
  send_bad(undecodable, 1002);
  send_valid();
  pb::Frame mask_size = ToWire(driving_->frames[next]);
  client::EncodeImage(cv::Mat(h - 1, w, CV_16UC1, cv::Scalar(7000)),
                      pb::IMAGE_ENCODING_PNG,
                      mask_size.mutable_panoptic())
      .IgnoreError();
  send_bad(mask_size, 1003);
  send_valid();
  pb::Frame mask_type = ToWire(driving_->frames[next]);
  client::EncodeImage(
      cv::Mat(h, w, CV_32FC2, cv::Scalar(0)), pb::IMAGE_ENCODING_RAW, mask_type.mutable_panoptic())
      .IgnoreError();
  send_bad(mask_type, 1004);
  send_valid();
  pb::Frame stale = ToWire(driving_->frames[0]);  // timestamp of frame 0 again
  stale.set_index(1005);
  ASSERT_TRUE(client->Send(stale).ok());
  send_valid();
  ASSERT_TRUE(client->CloseStream().ok());

  ASSERT_EQ(c.errors.size(), 5u);
  const char* expected[] = {"left image is",
                            "right image",
                            "panoptic mask is",
                            "panoptic mask is float32x2",
                            "not after the previous frame"};
  for (size_t i = 0; i < 5; ++i) {
    EXPECT_EQ(c.errors[i].index(), 1001 + static_cast<int64_t>(i));
    EXPECT_EQ(c.errors[i].code(), static_cast<int>(grpc::StatusCode::INVALID_ARGUMENT));
    EXPECT_THAT(c.errors[i].message(), HasSubstr(expected[i]));
  }
  // The valid frames were processed exactly as without the bad ones.
  ExpectSamePoses(c.Sorted(), RunEmbedded(*driving_, next));

  // Session-level errors.
  Collected unused;
  absl::Status s = client->OpenStream("ffffffffffffffffffffffffffffffff", "", unused.callback());
  EXPECT_TRUE(absl::IsNotFound(s)) << s;
  ASSERT_TRUE(client->CloseSession(created->session_id(), false).ok());
  s = client->OpenStream(created->session_id(), created->resume_token(), unused.callback());
  EXPECT_TRUE(absl::IsFailedPrecondition(s)) << s;
}

TEST_F(E2E, CancelMidStreamReconnectAndContinue) {
  auto server = StartServer(ServerTestOptions());
  auto client = Connect(server->address());
  auto created = client->CreateSession(CreateRequest(driving_->config));
  ASSERT_TRUE(created.ok());
  Collected c;
  ASSERT_TRUE(
      client->OpenStream(created->session_id(), created->resume_token(), c.callback()).ok());
  for (size_t i = 0; i < 5; ++i) ASSERT_TRUE(client->Send(ToWire(driving_->frames[i])).ok());
  client->DropConnectionForTesting();  // automatic: resume, replay, resend
  for (size_t i = 5; i < 8; ++i) ASSERT_TRUE(client->Send(ToWire(driving_->frames[i])).ok());
  ASSERT_TRUE(client->CloseStream().ok());
  EXPECT_GE(client->reconnects(), 1);

  // Manual: a brand-new client continues the same session where it stopped.
  auto other = Connect(server->address());
  Collected c2;
  ASSERT_TRUE(
      other->OpenStream(created->session_id(), created->resume_token(), c2.callback()).ok());
  EXPECT_EQ(other->bound_session().last_frame_index(), 7);
  for (size_t i = 8; i < driving_->frames.size(); ++i)
    ASSERT_TRUE(other->Send(ToWire(driving_->frames[i])).ok());
  ASSERT_TRUE(other->CloseStream().ok());
  std::vector<pb::FrameUpdate> all = c.Sorted();
  for (const auto& u : c2.Sorted()) all.push_back(u);
  ExpectSamePoses(all, *driving_alone_);
}

TEST_F(E2E, RestartAndResumeFromTheStateDirectoryLosesNothing) {
  const std::string state = ::testing::TempDir() + "/twist_e2e_state";
  std::filesystem::remove_all(state);
  server::ServerOptions options = ServerTestOptions();
  options.sessions.state_dir = state;
  auto server = StartServer(options);
  auto client = Connect(server->address());
  auto created = client->CreateSession(CreateRequest(driving_->config));
  ASSERT_TRUE(created.ok());
  Collected c;
  ASSERT_TRUE(
      client->OpenStream(created->session_id(), created->resume_token(), c.callback()).ok());
  for (size_t i = 0; i < 6; ++i) ASSERT_TRUE(client->Send(ToWire(driving_->frames[i])).ok());
  ASSERT_TRUE(client->CloseStream().ok());
  server->Shutdown();  // persists on shutdown
  server.reset();

  server = StartServer(options);
  client = Connect(server->address());
  auto resumed = client->ResumeSession(created->session_id(), created->resume_token());
  ASSERT_TRUE(resumed.ok()) << resumed.status();
  EXPECT_TRUE(resumed->loaded_from_disk());
  EXPECT_EQ(resumed->session().last_frame_index(), 5);
  Collected c2;
  ASSERT_TRUE(
      client->OpenStream(created->session_id(), created->resume_token(), c2.callback()).ok());
  for (size_t i = 6; i < driving_->frames.size(); ++i)
    ASSERT_TRUE(client->Send(ToWire(driving_->frames[i])).ok());
  ASSERT_TRUE(client->CloseStream().ok());
  std::vector<pb::FrameUpdate> all = c.Sorted();
  for (const auto& u : c2.Sorted()) all.push_back(u);
  // Camera poses and objects continue exactly across the restart:
  // SlamSystem::Save/Load persists the camera state, the map and the object
  // stage (state format 4).
  ExpectSamePoses(all, *driving_alone_, /*compare_objects=*/true);
  std::filesystem::remove_all(state);
}

TEST_F(E2E, AuthRequiredRejectedAndIsolatedPerToken) {
  const std::string tokens = ::testing::TempDir() + "/twist_e2e_tokens";
  {
    std::ofstream out(tokens);
    out << "e2e-token-one one\ne2e-token-two two\n";
  }
  server::ServerOptions options = ServerTestOptions();
  options.auth_token_file = tokens;
  auto server = StartServer(options);
  EXPECT_TRUE(absl::IsUnauthenticated(
      Connect(server->address())->CreateSession(CreateRequest(street_->config)).status()));
  EXPECT_TRUE(absl::IsUnauthenticated(
      Connect(server->address(), "e2e-token-bad")->GetServerInfo().status()));
  auto one = Connect(server->address(), "e2e-token-one");
  auto two = Connect(server->address(), "e2e-token-two");
  const std::vector<pb::FrameUpdate> updates = Stream(one.get(), *street_, 3);
  EXPECT_EQ(updates.size(), 3u);
  auto created = one->CreateSession(CreateRequest(street_->config));
  ASSERT_TRUE(created.ok());
  Collected c;
  EXPECT_TRUE(absl::IsNotFound(
      two->OpenStream(created->session_id(), created->resume_token(), c.callback())));
  EXPECT_TRUE(two->ListSessions()->empty());
  EXPECT_FALSE(one->ListSessions()->empty());
}

TEST_F(E2E, ShutdownWithOpenStreamsCompletesWithinItsDeadline) {
  server::ServerOptions options = ServerTestOptions();
  options.drain_timeout_s = 1;
  options.shutdown_deadline_s = 3;
  auto server = StartServer(options);
  std::vector<std::unique_ptr<client::SlamClient>> clients;
  std::vector<std::unique_ptr<Collected>> collected;
  for (int k = 0; k < 2; ++k) {
    clients.push_back(Connect(server->address()));
    collected.push_back(std::make_unique<Collected>());
    auto created = clients.back()->CreateSession(CreateRequest(driving_->config));
    ASSERT_TRUE(created.ok());
    ASSERT_TRUE(clients.back()
                    ->OpenStream(created->session_id(),
                                 created->resume_token(),
                                 collected.back()->callback())
                    .ok());
    for (size_t i = 0; i < 4; ++i)
      ASSERT_TRUE(clients.back()->Send(ToWire(driving_->frames[i])).ok());
  }
  // Streams stay open (no half-close) while the server shuts down.
  auto done = std::async(std::launch::async, [&] { server->Shutdown(); });
  ASSERT_EQ(done.wait_for(kMustFinish), std::future_status::ready);
  for (auto& c : clients) c->DropConnectionForTesting();
}

}  // namespace
}  // namespace twist::e2e
