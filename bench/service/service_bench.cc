// Service benchmark (not a test; prints numbers and JSON, asserts nothing):
//  - per-frame latency through gRPC (client Send -> update received, one
//    frame in flight) vs the embedded engine (Process), and their ratio;
//  - throughput (frames/s over all sessions) with 1, 2 and 4 concurrent
//    sessions streaming pipelined;
//  - memory per session: heap bytes in use (and RSS growth) per loaded
//    session after streaming the whole sequence into it.
// Frames: the synthetic "driving" scenario at half KITTI size, rendered once
// into a temporary directory.
//
//   service_bench [--frames N] [--scale S] [--json FILE]
#include <glog/logging.h>
#include <malloc.h>
#include <unistd.h>

#include <algorithm>
#include <chrono>
#include <condition_variable>
#include <cstdio>
#include <cstring>
#include <filesystem>
#include <fstream>
#include <iostream>
#include <mutex>
#include <thread>

#include "client/lib/frame_encoding.h"
#include "client/lib/slam_client.h"
#include "client/lib/slam_convert.h"
#include "server/server.h"
#include "slam/io/json_writer.h"
#include "slam/io/sequence.h"
#include "slam/sim/scenarios.h"
#include "slam/sim/writer.h"
#include "slam/system/slam_system.h"

namespace {

namespace pb = ::twistslam::v1;
using Clock = std::chrono::steady_clock;

double Ms(Clock::duration d) { return std::chrono::duration<double, std::milli>(d).count(); }

double Median(std::vector<double> v) {
  if (v.empty()) return 0;
  std::sort(v.begin(), v.end());
  return v[v.size() / 2];
}
double P95(std::vector<double> v) {
  if (v.empty()) return 0;
  std::sort(v.begin(), v.end());
  return v[std::min(v.size() - 1, static_cast<size_t>(0.95 * v.size()))];
}

// Heap bytes in use (glibc), immune to the allocator reusing freed pages.
double HeapMiB() { return mallinfo2().uordblks / (1024.0 * 1024.0); }

double RssMiB() {
  std::ifstream in("/proc/self/statm");
  long pages = 0, resident = 0;
  in >> pages >> resident;
  return resident * static_cast<double>(sysconf(_SC_PAGESIZE)) / (1024.0 * 1024.0);
}

struct Data {
  twist::SessionConfig config;
  std::vector<twist::StereoFrame> frames;
  std::vector<pb::Frame> wire;
};

Data Load(int num_frames, double scale) {
  Data d;
  absl::StatusOr<twist::sim::Scenario> scenario =
      twist::sim::MakeScenario("driving", 1, num_frames);
  if (!scenario.ok()) {
    std::cerr << scenario.status() << "\n";
    std::exit(1);
  }
  auto& cam = scenario->camera;
  cam.fx *= scale;
  cam.fy *= scale;
  cam.cx *= scale;
  cam.cy *= scale;
  cam.width = static_cast<int>(cam.width * scale);
  cam.height = static_cast<int>(cam.height * scale);
  const std::string dir = (std::filesystem::temp_directory_path() /
                           ("twist_service_bench_" + std::to_string(num_frames) + "_" +
                            std::to_string(static_cast<int>(scale * 1000))))
                              .string();
  if (!std::filesystem::exists(dir + "/image_02/0000")) {
    twist::sim::WriteOptions options;
    options.render.gray = true;
    absl::Status s = twist::sim::WriteSequence(*scenario, dir, options);
    if (!s.ok()) {
      std::cerr << s << "\n";
      std::exit(1);
    }
  }
  auto reader = twist::io::OpenSequence(dir, "kitti-tracking", "0000");
  if (!reader.ok()) {
    std::cerr << reader.status() << "\n";
    std::exit(1);
  }
  d.config.camera = (*reader)->camera();
  d.config.options.mapping_mode = twist::MappingMode::kSynchronous;
  if (!(*reader)->class_table_text().empty()) {
    d.config.classes = *twist::joints::ClassTable::FromText((*reader)->class_table_text());
  }
  for (int64_t i = 0; i < (*reader)->size(); ++i) {
    d.frames.push_back(*(*reader)->ReadFrame(i));
    twist::client::FrameImages images;
    images.index = i;
    images.timestamp_ns = d.frames.back().timestamp_ns;
    images.left = d.frames.back().left;
    images.right = d.frames.back().right;
    images.panoptic = d.frames.back().panoptic;
    pb::Frame f;
    twist::client::MakeFrame(images, pb::IMAGE_ENCODING_RAW, &f).IgnoreError();
    d.wire.push_back(std::move(f));
  }
  return d;
}

pb::CreateSessionRequest Request(const twist::SessionConfig& config) {
  pb::CreateSessionRequest r;
  r.set_name("bench");
  *r.mutable_config() = twist::client::SessionConfigToProto(config);
  r.mutable_config()->mutable_options()->set_mapping_mode(pb::MAPPING_MODE_SYNCHRONOUS);
  return r;  // default (Cityscapes) class table: same ids as the generator's
}

std::unique_ptr<twist::client::SlamClient> Connect(const std::string& address) {
  twist::client::ClientOptions o;
  o.address = address;
  return std::move(*twist::client::SlamClient::Connect(o));
}

}  // namespace

int main(int argc, char** argv) {
  int num_frames = 30;
  double scale = 0.5;
  std::string json_path;
  for (int i = 1; i + 1 < argc; i += 2) {
    if (!std::strcmp(argv[i], "--frames"))
      num_frames = std::atoi(argv[i + 1]);
    else if (!std::strcmp(argv[i], "--scale"))
      scale = std::atof(argv[i + 1]);
    else if (!std::strcmp(argv[i], "--json"))
      json_path = argv[i + 1];
  }
  google::InitGoogleLogging(argv[0]);
  FLAGS_minloglevel = 1;
  const Data data = Load(num_frames, scale);
  std::fprintf(stderr,
               "frames: %zu of %dx%d\n",
               data.frames.size(),
               data.config.camera.width,
               data.config.camera.height);

  // 1. Embedded latency.
  std::vector<double> embedded_ms;
  for (int round = 0; round < 2; ++round) {  // round 0 warms caches and allocators
    embedded_ms.clear();
    auto system = std::move(*twist::SlamSystem::Create(data.config));
    for (const auto& f : data.frames) {
      const auto t0 = Clock::now();
      system->Process(f).IgnoreError();
      embedded_ms.push_back(Ms(Clock::now() - t0));
    }
  }

  twist::server::ServerOptions options;
  options.listen = "127.0.0.1:0";
  options.sessions.max_sessions = 64;
  twist::server::SlamSystemFactory factory;
  factory.create = [](const twist::SessionConfig& c) { return twist::SlamSystem::Create(c); };
  factory.load = [](const std::string& p) { return twist::SlamSystem::Load(p); };
  auto server = std::move(*twist::server::TwistServer::Start(options, factory));

  // 2. gRPC latency, one frame in flight.
  std::vector<double> grpc_ms, grpc_engine_ms;
  {
    auto client = Connect(server->address());
    auto created = client->CreateSession(Request(data.config));
    std::mutex mu;
    std::condition_variable cv;
    int answered = 0;
    client
        ->OpenStream(created->session_id(),
                     created->resume_token(),
                     [&](const pb::StreamResponse& r) {
                       if (!r.has_update() && !r.has_error()) return;
                       std::lock_guard<std::mutex> lock(mu);
                       for (const auto& t : r.update().timings()) {
                         if (t.stage() == "engine") grpc_engine_ms.push_back(t.ms());
                       }
                       ++answered;
                       cv.notify_all();
                     })
        .IgnoreError();
    for (size_t i = 0; i < data.wire.size(); ++i) {
      const auto t0 = Clock::now();
      client->Send(data.wire[i]).IgnoreError();
      std::unique_lock<std::mutex> lock(mu);
      cv.wait(lock, [&] { return answered > static_cast<int>(i); });
      grpc_ms.push_back(Ms(Clock::now() - t0));
    }
    client->CloseStream().IgnoreError();
    client->CloseSession(created->session_id(), false).IgnoreError();
  }

  // 3. Throughput with 1, 2, 4 concurrent sessions (pipelined).
  std::vector<std::pair<int, double>> throughput;
  for (int sessions : {1, 2, 4}) {
    std::vector<std::thread> threads;
    const auto t0 = Clock::now();
    for (int k = 0; k < sessions; ++k) {
      threads.emplace_back([&] {
        auto client = Connect(server->address());
        auto created = client->CreateSession(Request(data.config));
        client->OpenStream(created->session_id(), created->resume_token(), nullptr).IgnoreError();
        for (const auto& f : data.wire) client->Send(f).IgnoreError();
        client->CloseStream().IgnoreError();
        client->CloseSession(created->session_id(), false).IgnoreError();
      });
    }
    for (auto& t : threads) t.join();
    const double s = std::chrono::duration<double>(Clock::now() - t0).count();
    throughput.push_back({sessions, sessions * data.wire.size() / s});
    std::fprintf(stderr, "%d session(s): %.2f frames/s\n", sessions, throughput.back().second);
  }

  // 4. Memory per loaded session (after streaming every frame into it).
  constexpr int kMemSessions = 4;
  const double rss_before = RssMiB();
  const double heap_before = HeapMiB();
  std::vector<std::string> kept;
  {
    auto client = Connect(server->address());
    for (int k = 0; k < kMemSessions; ++k) {
      auto created = client->CreateSession(Request(data.config));
      client->OpenStream(created->session_id(), created->resume_token(), nullptr).IgnoreError();
      for (const auto& f : data.wire) client->Send(f).IgnoreError();
      client->CloseStream().IgnoreError();
      kept.push_back(created->session_id());
    }
  }
  const double rss_after = RssMiB();
  const double heap_after = HeapMiB();
  server->Shutdown();

  const double emb = Median(embedded_ms), grpc = Median(grpc_ms);
  // Per-frame overhead: client-measured latency minus the engine time of the
  // same frame measured inside the server (robust to the engine's variance).
  std::vector<double> overhead_ms, ratio;
  for (size_t i = 0; i < grpc_ms.size() && i < grpc_engine_ms.size(); ++i) {
    overhead_ms.push_back(grpc_ms[i] - grpc_engine_ms[i]);
    if (grpc_engine_ms[i] > 0) ratio.push_back(grpc_ms[i] / grpc_engine_ms[i]);
  }
  twist::io::JsonWriter w;
  w.BeginObject();
  w.Key("frames").Int(static_cast<int64_t>(data.frames.size()));
  w.Key("width").Int(data.config.camera.width).Key("height").Int(data.config.camera.height);
  w.Key("encoding").String("raw");
  w.Key("embedded_latency_ms")
      .BeginObject()
      .Key("median")
      .Number(emb)
      .Key("p95")
      .Number(P95(embedded_ms))
      .EndObject();
  w.Key("grpc_latency_ms")
      .BeginObject()
      .Key("median")
      .Number(grpc)
      .Key("p95")
      .Number(P95(grpc_ms))
      .EndObject();
  w.Key("grpc_over_embedded_median_ratio").Number(emb > 0 ? grpc / emb : 0);
  w.Key("per_frame_overhead_ms").BeginObject().Key("median").Number(Median(overhead_ms));
  w.Key("p95").Number(P95(overhead_ms)).EndObject();
  w.Key("per_frame_overhead_ratio_median").Number(Median(ratio));
  w.Key("throughput_frames_per_s").BeginObject();
  for (const auto& [n, fps] : throughput) w.Key(std::to_string(n) + "_sessions").Number(fps);
  w.EndObject();
  w.Key("heap_per_session_mib").Number((heap_after - heap_before) / kMemSessions);
  w.Key("rss_growth_per_session_mib").Number((rss_after - rss_before) / kMemSessions);
  w.Key("memory_frames_per_session").Int(static_cast<int64_t>(data.wire.size()));
  w.Key("cores").Int(static_cast<int64_t>(std::thread::hardware_concurrency()));
  w.EndObject();
  std::cout << w.str() << "\n";
  if (!json_path.empty()) std::ofstream(json_path) << w.str() << "\n";
  return 0;
}
