// The client library's conversions against the server's (they meet only
// through the .proto): encoding, session config, updates, map chunks, PLY;
// and SlamClient's misuse errors.
#include <gmock/gmock.h>
#include <gtest/gtest.h>

#include "client/lib/frame_encoding.h"
#include "client/lib/map_ply.h"
#include "client/lib/slam_client.h"
#include "client/lib/slam_convert.h"
#include "server/convert.h"
#include "server/session.h"

namespace twist::client {
namespace {

using ::testing::HasSubstr;

TEST(FrameEncoding, EveryTypeRoundTripsThroughTheServerDecoder) {
  cv::RNG rng(7);
  struct Case {
    int type;
    pb::ImageEncoding encoding;
  };
  const Case cases[] = {{CV_8UC1, pb::IMAGE_ENCODING_RAW},
                        {CV_8UC3, pb::IMAGE_ENCODING_RAW},
                        {CV_16UC1, pb::IMAGE_ENCODING_RAW},
                        {CV_32SC1, pb::IMAGE_ENCODING_RAW},
                        {CV_32FC2, pb::IMAGE_ENCODING_RAW},
                        {CV_8UC1, pb::IMAGE_ENCODING_PNG},
                        {CV_8UC3, pb::IMAGE_ENCODING_PNG},
                        {CV_16UC1, pb::IMAGE_ENCODING_PNG}};
  for (const Case& c : cases) {
    cv::Mat image(17, 23, c.type);
    rng.fill(image, cv::RNG::UNIFORM, 0, 200);
    pb::Image wire;
    ASSERT_TRUE(EncodeImage(image, c.encoding, &wire).ok());
    absl::StatusOr<cv::Mat> back = server::DecodeImage(wire, "image", 23, 17);
    ASSERT_TRUE(back.ok()) << back.status();
    ASSERT_EQ(back->type(), c.type);
    EXPECT_EQ(cv::norm(*back, image, cv::NORM_INF), 0.0)
        << "type " << c.type << " encoding " << c.encoding;
  }
  cv::Mat view = cv::Mat(40, 40, CV_8UC1, cv::Scalar(9))(cv::Rect(3, 4, 20, 10));  // non-contiguous
  pb::Image wire;
  ASSERT_TRUE(EncodeImage(view, pb::IMAGE_ENCODING_RAW, &wire).ok());
  EXPECT_EQ(wire.data().size(), 200u);
  EXPECT_TRUE(absl::IsInvalidArgument(EncodeImage(cv::Mat(), pb::IMAGE_ENCODING_RAW, &wire)));
  EXPECT_TRUE(absl::IsInvalidArgument(
      EncodeImage(cv::Mat(4, 4, CV_16UC1), pb::IMAGE_ENCODING_JPEG, &wire)));
  EXPECT_TRUE(
      absl::IsInvalidArgument(EncodeImage(cv::Mat(4, 4, CV_64FC1), pb::IMAGE_ENCODING_RAW, &wire)));
}

TEST(SlamConvert, SessionConfigSurvivesTheServerSetup) {
  SessionConfig config;
  config.camera = {700.0, 710.0, 300.5, 150.25, 0.54, 640, 320};
  config.options.num_features = 1234;
  config.options.mapping_mode = MappingMode::kBackground;
  config.options.constrain_objects = false;
  config.options.seed = 99;
  config.options.object_ba_window_frames = 7;
  config.options.object_ba_iterations = 3;
  config.options.parked_objects_static = false;   // not the default
  config.options.dense_keyframes = false;         // not the default
  config.options.extra_camera_keypoints = false;  // not the default
  config.options.stereo_by_point_depth = true;    // not the default
  config.options.disparity_offset_px = -0.05;     // not the default
  const pb::SessionConfig wire = SessionConfigToProto(config);
  pb::CreateSessionRequest request;
  *request.mutable_config() = wire;
  absl::StatusOr<server::SessionSetup> setup =
      server::BuildSessionSetup(request, server::SetupLimits());
  ASSERT_TRUE(setup.ok()) << setup.status();
  EXPECT_EQ(setup->config.camera.fx, 700.0);
  EXPECT_EQ(setup->config.camera.cy, 150.25);
  EXPECT_EQ(setup->config.camera.width, 640);
  EXPECT_EQ(setup->config.options.num_features, 1234);
  EXPECT_EQ(setup->config.options.mapping_mode, MappingMode::kBackground);
  EXPECT_FALSE(setup->config.options.constrain_objects);
  EXPECT_EQ(setup->config.options.seed, 99u);
  EXPECT_EQ(setup->config.options.object_ba_window_frames, 7);
  EXPECT_EQ(setup->config.options.object_ba_iterations, 3);
  EXPECT_FALSE(setup->config.options.parked_objects_static);
  EXPECT_FALSE(setup->config.options.dense_keyframes);
  EXPECT_FALSE(setup->config.options.extra_camera_keypoints);
  EXPECT_TRUE(setup->config.options.stereo_by_point_depth);
  EXPECT_EQ(setup->config.options.disparity_offset_px, -0.05);
  EXPECT_EQ(setup->config.classes.ToText(), config.classes.ToText());
  EXPECT_EQ(setup->policy.queue_capacity(), 4);
  EXPECT_EQ(setup->policy.overflow(), pb::OVERFLOW_POLICY_BLOCK);
}

// `twistslam run --server` sends only the options its --config gave; the
// server fills in the rest from its defaults, mapping in the background
// among them. Every wire field is a `slam:` key of the config files.
TEST(SlamConvert, OnlyTheGivenOptionsAreSentAndTheServerDefaultsTheRest) {
  SessionConfig config;
  config.camera = {700.0, 710.0, 300.5, 150.25, 0.54, 640, 320};
  config.options.num_features = 1234;
  config.options.stereo_by_point_depth = true;
  pb::CreateSessionRequest request;
  *request.mutable_config() = SessionConfigToProto(config);
  ASSERT_TRUE(KeepOnlyOptions({"num_features"}, request.mutable_config()->mutable_options()).ok());
  const pb::SlamOptions& sent = request.config().options();
  EXPECT_EQ(sent.num_features(), 1234);
  EXPECT_FALSE(sent.has_stereo_by_point_depth());
  EXPECT_FALSE(sent.has_num_levels());
  EXPECT_EQ(sent.mapping_mode(), pb::MAPPING_MODE_UNSPECIFIED);

  server::SetupLimits limits;
  limits.default_options.num_levels = 5;  // a server --config's slam.num_levels
  absl::StatusOr<server::SessionSetup> setup = server::BuildSessionSetup(request, limits);
  ASSERT_TRUE(setup.ok()) << setup.status();
  EXPECT_EQ(setup->config.options.num_features, 1234);
  EXPECT_EQ(setup->config.options.num_levels, 5);
  EXPECT_FALSE(setup->config.options.stereo_by_point_depth);  // the server's default
  EXPECT_EQ(setup->config.options.mapping_mode, MappingMode::kBackground);
  EXPECT_EQ(server::SetupLimits().default_options.mapping_mode, MappingMode::kBackground);

  // Asked for, the engine's deterministic mode.
  *request.mutable_config() = SessionConfigToProto(config);
  ASSERT_TRUE(KeepOnlyOptions({"mapping_mode"}, request.mutable_config()->mutable_options()).ok());
  setup = server::BuildSessionSetup(request, limits);
  ASSERT_TRUE(setup.ok()) << setup.status();
  EXPECT_EQ(setup->config.options.mapping_mode, MappingMode::kSynchronous);
  EXPECT_EQ(setup->config.options.num_features, SlamOptions().num_features);

  pb::SlamOptions options = SessionConfigToProto(config).options();
  const absl::Status bad = KeepOnlyOptions({"num_features", "bogus"}, &options);
  EXPECT_TRUE(absl::IsInvalidArgument(bad));
  EXPECT_THAT(std::string(bad.message()), HasSubstr("slam.bogus"));

  const google::protobuf::Descriptor* d = pb::SlamOptions::descriptor();
  for (int i = 0; i < d->field_count(); ++i) {
    const std::string name = d->field(i)->name();
    if (name == "mapping_mode") continue;  // a string key, parsed on its own
    SlamOptions o;
    EXPECT_TRUE(SetNumericSlamOption(name, 1.0, &o)) << name << " is no slam: config key";
  }
}

TEST(SlamConvert, FrameResultRoundTrip) {
  FrameResult r;
  r.index = 12;
  r.timestamp_ns = 1200;
  r.state = TrackingState::kRelocalized;
  r.world_from_camera =
      geometry::SE3d(Eigen::Quaterniond(Eigen::AngleAxisd(0.2, Eigen::Vector3d::UnitY())),
                     Eigen::Vector3d(1, 2, 3));
  r.num_map_points = 77;
  ObjectResult o;
  o.id = 3;
  o.class_id = 26;
  o.state = ObjectState::kLost;
  o.joint = "revolute";
  o.twist_in_joint << 0, 0, 0, 0, 0, 0.5;
  r.objects.push_back(o);
  ClusterEvent e;
  e.type = ClusterEventType::kRemoved;
  e.cluster_id = 4;
  r.cluster_events.push_back(e);
  r.timings.push_back({"orb", 3.0});
  pb::FrameUpdate wire;
  server::ToProto(r, &wire);
  const FrameResult back = FrameResultFromProto(wire);
  EXPECT_EQ(back.index, 12);
  EXPECT_EQ(back.state, TrackingState::kRelocalized);
  EXPECT_LT((back.world_from_camera.matrix() - r.world_from_camera.matrix()).norm(), 1e-12);
  EXPECT_EQ(back.num_map_points, 77);
  ASSERT_EQ(back.objects.size(), 1u);
  EXPECT_EQ(back.objects[0].joint, "revolute");
  EXPECT_EQ(back.objects[0].state, ObjectState::kLost);
  EXPECT_EQ(back.objects[0].twist_in_joint[5], 0.5);
  ASSERT_EQ(back.cluster_events.size(), 1u);
  EXPECT_EQ(back.cluster_events[0].type, ClusterEventType::kRemoved);
  EXPECT_FALSE(back.cluster_events[0].plane.has_value());
  EXPECT_EQ(back.timings[0].stage, "orb");
}

TEST(SlamConvert, MapChunksReassembleAndExportToPly) {
  MapSnapshot map;
  for (int i = 0; i < 5000; ++i)
    map.points.push_back({Eigen::Vector3d(i, 1, 2), i % 3 == 0 ? 26 : 7, i % 5 - 1});
  map.keyframes.push_back(
      {1, 100, geometry::SE3d(Eigen::Quaterniond::Identity(), Eigen::Vector3d(0, 0, 4))});
  MapSnapshot::Cluster c;
  c.id = 8;
  c.plane = Eigen::Vector4d(0, -1, 0, 1.65);
  c.trajectory.emplace_back(5, geometry::SE3d());
  map.clusters.push_back(c);
  server::MapChunkOptions options;
  options.max_chunk_bytes = 16 << 10;
  const std::vector<pb::MapChunk> chunks = server::MapToChunks(map, options);
  ASSERT_GT(chunks.size(), 3u);
  const MapSnapshot back = MapFromChunks(chunks);
  ASSERT_EQ(back.points.size(), map.points.size());
  EXPECT_EQ(back.points[4999].p_in_world.x(), 4999);
  EXPECT_EQ(back.points[3].class_id, 26);
  EXPECT_EQ(back.points[3].cluster_id, 2);
  ASSERT_EQ(back.clusters.size(), 1u);
  EXPECT_EQ((*back.clusters[0].plane)[3], 1.65);
  EXPECT_EQ(back.clusters[0].trajectory.size(), 1u);

  const std::string ply = MapToPly(back);
  EXPECT_THAT(ply, HasSubstr("element vertex 5001\n"));
  EXPECT_THAT(ply, HasSubstr("end_header\n0.000000 1.000000 2.000000 0 0 142 26 -1\n"));
  EXPECT_THAT(ply, HasSubstr("0.000000 0.000000 4.000000 255 255 255 -1 -1\n"));
  EXPECT_EQ(std::count(ply.begin(), ply.end(), '\n'), 13 + 5001);
}

// Object trajectories longer than a chunk's share travel in pieces, and come
// back whole and in order.
TEST(SlamConvert, LongObjectTrajectoriesReassemble) {
  MapSnapshot map;
  for (int64_t id : {2, 5, 9}) {
    MapSnapshot::Object o;
    o.id = id;
    o.class_id = 26;
    o.instance_id = static_cast<int>(id) + 100;
    o.cluster_id = id == 5 ? -1 : id * 10;
    const int n = id == 5 ? 3000 : 7;
    for (int k = 0; k < n; ++k) {
      o.trajectory.emplace_back(
          1000 + k, geometry::SE3d(Eigen::Quaterniond::Identity(), Eigen::Vector3d(k, id, 0)));
    }
    map.objects.push_back(std::move(o));
  }
  server::MapChunkOptions options;
  options.max_chunk_bytes = 64 << 10;
  const std::vector<pb::MapChunk> chunks = server::MapToChunks(map, options);
  int pieces = 0;
  for (const pb::MapChunk& c : chunks) {
    EXPECT_LE(c.ByteSizeLong(), static_cast<size_t>(options.max_chunk_bytes) + 64);
    pieces += c.objects_size();
  }
  EXPECT_GT(pieces, 4);  // the 3000-pose trajectory is split
  EXPECT_EQ(chunks[0].summary().num_objects(), 3);
  const MapSnapshot back = MapFromChunks(chunks);
  ASSERT_EQ(back.objects.size(), 3u);
  for (size_t i = 0; i < 3; ++i) {
    const MapSnapshot::Object& a = map.objects[i];
    const MapSnapshot::Object& b = back.objects[i];
    EXPECT_EQ(b.id, a.id);
    EXPECT_EQ(b.class_id, 26);
    EXPECT_EQ(b.instance_id, a.instance_id);
    EXPECT_EQ(b.cluster_id, a.cluster_id);
    ASSERT_EQ(b.trajectory.size(), a.trajectory.size());
    for (size_t k = 0; k < a.trajectory.size(); ++k) {
      EXPECT_EQ(b.trajectory[k].first, a.trajectory[k].first);
      EXPECT_EQ(b.trajectory[k].second.translation(), a.trajectory[k].second.translation());
    }
  }
  options.skip_objects = true;
  const std::vector<pb::MapChunk> none = server::MapToChunks(map, options);
  ASSERT_EQ(none.size(), 1u);
  EXPECT_EQ(none[0].objects_size(), 0);
  EXPECT_EQ(none[0].summary().num_objects(), 0);
}

TEST(SlamClient, MisuseIsReportedNotFatal) {
  EXPECT_TRUE(absl::IsInvalidArgument(SlamClient::Connect(ClientOptions()).status()));
  ClientOptions options;
  options.address = "127.0.0.1:1";
  options.tls_ca_file = "/nonexistent/ca.pem";
  EXPECT_TRUE(absl::IsNotFound(SlamClient::Connect(options).status()));
  options.tls_ca_file.clear();
  options.rpc_timeout_s = 0.2;
  auto client = std::move(*SlamClient::Connect(options));
  EXPECT_TRUE(absl::IsFailedPrecondition(client->Send(pb::Frame())));
  EXPECT_TRUE(absl::IsFailedPrecondition(client->CloseStream()));
  // Nothing listens on port 1: the call fails after its deadline.
  EXPECT_FALSE(client->GetServerInfo().ok());
}

}  // namespace
}  // namespace twist::client
