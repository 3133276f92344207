// Shared pieces of the end-to-end tests: a small synthetic sequence rendered
// once per test binary, the real engine embedded and behind an in-process
// server on 127.0.0.1:0, and pose comparisons.
#pragma once

#include <gtest/gtest.h>

#include <filesystem>
#include <memory>
#include <mutex>
#include <string>
#include <vector>

#include "client/lib/frame_encoding.h"
#include "client/lib/slam_client.h"
#include "client/lib/slam_convert.h"
#include "server/server.h"
#include "slam/io/sequence.h"
#include "slam/sim/scenarios.h"
#include "slam/sim/writer.h"
#include "slam/system/slam_system.h"

namespace twist::e2e {

namespace pb = ::twistslam::v1;

// Poses through the server must equal the embedded engine's bit for bit up to
// the wire's double precision (the engine is deterministic in synchronous
// mapping mode); 1e-9 m / 1e-9 leaves room only for serialization.
constexpr double kPoseTolerance = 1e-9;

struct Sequence {
  SessionConfig config;
  std::vector<StereoFrame> frames;
};

// Renders `num_frames` of a scenario with the camera scaled by `scale` into
// a temporary dataset and loads it back through slam/io (the same path as
// `twistslam run`).
inline Sequence MakeSequence(const std::string& scenario_name,
                             int num_frames,
                             double scale,
                             uint32_t seed) {
  Sequence out;
  absl::StatusOr<sim::Scenario> scenario = sim::MakeScenario(scenario_name, seed, num_frames);
  EXPECT_TRUE(scenario.ok()) << scenario.status();
  if (!scenario.ok()) return out;
  geometry::StereoCamera& cam = scenario->camera;
  cam.fx *= scale;
  cam.fy *= scale;
  cam.cx *= scale;
  cam.cy *= scale;
  cam.width = static_cast<int>(cam.width * scale);
  cam.height = static_cast<int>(cam.height * scale);
  const std::string dir = ::testing::TempDir() + "/twist_e2e_" + scenario_name + "_" +
                          std::to_string(seed) + "_" + std::to_string(num_frames) + "_" +
                          std::to_string(static_cast<int>(scale * 1000));
  if (!std::filesystem::exists(dir + "/image_02/0000")) {
    std::filesystem::remove_all(dir);
    sim::WriteOptions options;
    options.render.gray = true;
    absl::Status s = sim::WriteSequence(*scenario, dir, options);
    EXPECT_TRUE(s.ok()) << s;
  }
  absl::StatusOr<std::unique_ptr<io::SequenceReader>> reader =
      io::OpenSequence(dir, "kitti-tracking", "0000");
  EXPECT_TRUE(reader.ok()) << reader.status();
  if (!reader.ok()) return out;
  out.config.camera = (*reader)->camera();
  out.config.options.num_features = 800;
  out.config.options.mapping_mode = MappingMode::kSynchronous;
  if (!(*reader)->class_table_text().empty()) {
    absl::StatusOr<joints::ClassTable> classes =
        joints::ClassTable::FromText((*reader)->class_table_text());
    EXPECT_TRUE(classes.ok()) << classes.status();
    if (classes.ok()) out.config.classes = *classes;
  }
  for (int64_t i = 0; i < (*reader)->size(); ++i) {
    absl::StatusOr<StereoFrame> frame = (*reader)->ReadFrame(i);
    EXPECT_TRUE(frame.ok()) << frame.status();
    if (frame.ok()) out.frames.push_back(std::move(*frame));
  }
  return out;
}

inline std::vector<FrameResult> RunEmbedded(const Sequence& seq, size_t count = 0) {
  std::vector<FrameResult> results;
  absl::StatusOr<std::unique_ptr<SlamSystem>> system = SlamSystem::Create(seq.config);
  EXPECT_TRUE(system.ok()) << system.status();
  if (!system.ok()) return results;
  if (count == 0) count = seq.frames.size();
  for (size_t i = 0; i < count; ++i) {
    absl::StatusOr<FrameResult> r = (*system)->Process(seq.frames[i]);
    EXPECT_TRUE(r.ok()) << r.status();
    if (r.ok()) results.push_back(*r);
  }
  return results;
}

inline server::SlamSystemFactory RealFactory() {
  server::SlamSystemFactory f;
  f.create = [](const SessionConfig& c) { return SlamSystem::Create(c); };
  f.load = [](const std::string& path) { return SlamSystem::Load(path); };
  return f;
}

inline server::ServerOptions ServerTestOptions() {
  server::ServerOptions o;
  o.listen = "127.0.0.1:0";
  o.sessions.housekeeping_period_s = 0;
  o.drain_timeout_s = 5;
  o.shutdown_deadline_s = 10;
  return o;
}

inline std::unique_ptr<server::TwistServer> StartServer(const server::ServerOptions& options) {
  absl::StatusOr<std::unique_ptr<server::TwistServer>> s =
      server::TwistServer::Start(options, RealFactory());
  EXPECT_TRUE(s.ok()) << s.status();
  return s.ok() ? std::move(*s) : nullptr;
}

inline std::unique_ptr<client::SlamClient> Connect(const std::string& address,
                                                   const std::string& token = "") {
  client::ClientOptions o;
  o.address = address;
  o.token = token;
  absl::StatusOr<std::unique_ptr<client::SlamClient>> c = client::SlamClient::Connect(o);
  EXPECT_TRUE(c.ok()) << c.status();
  return c.ok() ? std::move(*c) : nullptr;
}

inline pb::CreateSessionRequest CreateRequest(const SessionConfig& config,
                                              const std::string& name = "e2e") {
  pb::CreateSessionRequest request;
  request.set_name(name);
  *request.mutable_config() = client::SessionConfigToProto(config);
  // Streamed results are compared with synchronous embedded runs.
  request.mutable_config()->mutable_options()->set_mapping_mode(pb::MAPPING_MODE_SYNCHRONOUS);
  return request;
}

inline pb::Frame ToWire(const StereoFrame& f, pb::ImageEncoding encoding = pb::IMAGE_ENCODING_PNG) {
  client::FrameImages images;
  images.index = f.index;
  images.timestamp_ns = f.timestamp_ns;
  images.left = f.left;
  images.right = f.right;
  images.panoptic = f.panoptic;
  pb::Frame frame;
  EXPECT_TRUE(client::MakeFrame(images, encoding, &frame).ok());
  for (const DetectionBox& b : f.boxes) {
    pb::DetectionBox* box = frame.add_boxes();
    box->set_class_id(b.class_id);
    box->set_instance_id(b.instance_id);
    box->set_x_min(b.x_min);
    box->set_y_min(b.y_min);
    box->set_x_max(b.x_max);
    box->set_y_max(b.y_max);
  }
  return frame;
}

struct Collected {
  std::mutex mu;
  std::vector<pb::FrameUpdate> updates;
  std::vector<pb::FrameError> errors;
  client::SlamClient::ResponseCallback callback() {
    return [this](const pb::StreamResponse& r) {
      std::lock_guard<std::mutex> lock(mu);
      if (r.has_update()) updates.push_back(r.update());
      if (r.has_error()) errors.push_back(r.error());
    };
  }
  // Sorted by index, duplicates (replays) removed.
  std::vector<pb::FrameUpdate> Sorted() {
    std::lock_guard<std::mutex> lock(mu);
    std::vector<pb::FrameUpdate> out = updates;
    std::sort(
        out.begin(), out.end(), [](const auto& a, const auto& b) { return a.index() < b.index(); });
    out.erase(std::unique(out.begin(),
                          out.end(),
                          [](const auto& a, const auto& b) { return a.index() == b.index(); }),
              out.end());
    return out;
  }
};

// `compare_objects` = false checks the camera only (see the restart test).
inline void ExpectSamePoses(const std::vector<pb::FrameUpdate>& updates,
                            const std::vector<FrameResult>& expected,
                            bool compare_objects = true) {
  ASSERT_EQ(updates.size(), expected.size());
  for (size_t i = 0; i < updates.size(); ++i) {
    EXPECT_EQ(updates[i].index(), expected[i].index);
    EXPECT_EQ(static_cast<int>(updates[i].tracking_state()),
              static_cast<int>(expected[i].state) + 1);
    const pb::Pose& p = updates[i].world_from_camera();
    const Eigen::Vector3d t = expected[i].world_from_camera.translation();
    const Eigen::Quaterniond& q = expected[i].world_from_camera.unit_quaternion();
    EXPECT_NEAR(p.translation().x(), t.x(), kPoseTolerance) << "frame " << i;
    EXPECT_NEAR(p.translation().y(), t.y(), kPoseTolerance) << "frame " << i;
    EXPECT_NEAR(p.translation().z(), t.z(), kPoseTolerance) << "frame " << i;
    EXPECT_NEAR(std::abs(p.rotation().x() * q.x() + p.rotation().y() * q.y() +
                         p.rotation().z() * q.z() + p.rotation().w() * q.w()),
                1.0,
                kPoseTolerance)
        << "frame " << i;
    if (compare_objects) {
      ASSERT_EQ(updates[i].objects_size(), static_cast<int>(expected[i].objects.size()))
          << "frame " << i;
      for (int k = 0; k < updates[i].objects_size(); ++k) {
        const pb::ObjectUpdate& o = updates[i].objects(k);
        const ObjectResult& e = expected[i].objects[k];
        EXPECT_EQ(o.id(), e.id) << "frame " << i;
        EXPECT_EQ(o.class_id(), e.class_id) << "frame " << i;
        EXPECT_EQ(o.instance_id(), e.instance_id) << "frame " << i;
        EXPECT_EQ(o.num_points(), e.num_points) << "frame " << i;
        const Eigen::Vector3d ot = e.world_from_object.translation();
        EXPECT_NEAR(o.world_from_object().translation().x(), ot.x(), kPoseTolerance) << i;
        EXPECT_NEAR(o.world_from_object().translation().y(), ot.y(), kPoseTolerance) << i;
        EXPECT_NEAR(o.world_from_object().translation().z(), ot.z(), kPoseTolerance) << i;
        EXPECT_NEAR(o.speed_mps(), e.speed_mps, kPoseTolerance) << "frame " << i;
      }
    }
  }
}

}  // namespace twist::e2e
