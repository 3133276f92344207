// `twistslam run`: streams a dataset sequence through a server (--server) or
// the embedded engine (--embedded) and writes the run outputs of DESIGN.md §6
// plus updates.jsonl (one JSON object per frame), map.ply and
// objects_refined.txt (the objects' trajectories from the final map).
#include <unistd.h>

#include <algorithm>
#include <chrono>
#include <cstdio>
#include <filesystem>
#include <fstream>
#include <iostream>
#include <map>
#include <mutex>
#include <opencv2/core/persistence.hpp>
#include <set>
#include <sstream>
#include <thread>
#include <vector>

#include "absl/strings/str_cat.h"
#include "client/cli_util.h"
#include "client/commands.h"
#include "client/lib/frame_encoding.h"
#include "client/lib/map_ply.h"
#include "client/lib/slam_client.h"
#include "client/lib/slam_convert.h"
#include "slam/common/config_text.h"
#include "slam/io/frame_prefetcher.h"
#include "slam/io/json_writer.h"
#include "slam/io/run_output.h"
#include "slam/io/sequence.h"
#include "slam/system/slam_system.h"

namespace twist::cli {
namespace {

constexpr char kCommand[] = "run";

// Progress on stderr: a bar, frames done / total and frames per second,
// redrawn at most 10 times a second (and on the last frame).
class Progress {
 public:
  explicit Progress(int64_t total) : total_(total), start_(Clock::now()), last_draw_(start_) {}
  void Update(int64_t done, bool force = false) {
    const auto now = Clock::now();
    if (!force && now - last_draw_ < std::chrono::milliseconds(100) && done < total_) return;
    last_draw_ = now;
    const double elapsed = std::chrono::duration<double>(now - start_).count();
    const double fps = elapsed > 0 ? done / elapsed : 0.0;
    constexpr int kWidth = 30;
    const int filled = total_ > 0 ? static_cast<int>(kWidth * done / total_) : 0;
    std::string bar(static_cast<size_t>(filled), '=');
    if (filled < kWidth) bar += '>';
    bar.resize(kWidth, ' ');
    std::fprintf(stderr,
                 "\r[%s] %lld/%lld frames  %.1f frames/s ",
                 bar.c_str(),
                 static_cast<long long>(done),
                 static_cast<long long>(total_),
                 fps);
    std::fflush(stderr);
  }
  void Finish(int64_t done) {
    Update(done, true);
    std::fprintf(stderr, "\n");
  }
  double ElapsedS() const { return std::chrono::duration<double>(Clock::now() - start_).count(); }

 private:
  using Clock = std::chrono::steady_clock;
  int64_t total_;
  Clock::time_point start_, last_draw_;
};

void WritePose(io::JsonWriter* w, const geometry::SE3d& pose) {
  const Eigen::Quaterniond& q = pose.unit_quaternion();
  w->BeginObject()
      .Key("q_xyzw")
      .BeginArray()
      .Number(q.x())
      .Number(q.y())
      .Number(q.z())
      .Number(q.w())
      .EndArray();
  w->Key("t")
      .BeginArray()
      .Number(pose.translation().x())
      .Number(pose.translation().y())
      .Number(pose.translation().z());
  w->EndArray().EndObject();
}

void WriteTwist(io::JsonWriter* w, const geometry::Vector6d& xi) {
  w->BeginArray();
  for (int i = 0; i < 6; ++i) w->Number(xi[i]);
  w->EndArray();
}

std::string UpdateJson(const FrameResult& r) {
  io::JsonWriter w(/*pretty=*/false);
  w.BeginObject();
  w.Key("index").Int(r.index).Key("timestamp_ns").Int(r.timestamp_ns);
  w.Key("state").String(TrackingStateName(r.state));
  w.Key("world_from_camera");
  WritePose(&w, r.world_from_camera);
  w.Key("is_keyframe").Bool(r.is_keyframe);
  w.Key("num_tracked_points").Int(r.num_tracked_points);
  w.Key("num_map_points").Int(r.num_map_points).Key("num_keyframes").Int(r.num_keyframes);
  w.Key("objects").BeginArray();
  for (const ObjectResult& o : r.objects) {
    w.BeginObject()
        .Key("id")
        .Int(o.id)
        .Key("class_id")
        .Int(o.class_id)
        .Key("instance_id")
        .Int(o.instance_id);
    w.Key("state").String(ObjectStateName(o.state)).Key("world_from_object");
    WritePose(&w, o.world_from_object);
    w.Key("twist_in_world");
    WriteTwist(&w, o.twist_in_world);
    w.Key("twist_in_joint");
    WriteTwist(&w, o.twist_in_joint);
    w.Key("speed_mps")
        .Number(o.speed_mps)
        .Key("joint")
        .String(o.joint)
        .Key("num_points")
        .Int(o.num_points);
    w.EndObject();
  }
  w.EndArray().Key("cluster_events").BeginArray();
  for (const ClusterEvent& e : r.cluster_events) {
    w.BeginObject()
        .Key("type")
        .String(ClusterEventTypeName(e.type))
        .Key("cluster_id")
        .Int(e.cluster_id);
    w.Key("class_id")
        .Int(e.class_id)
        .Key("instance_id")
        .Int(e.instance_id)
        .Key("is_dynamic")
        .Bool(e.is_dynamic);
    if (e.plane) {
      w.Key("plane").BeginArray();
      for (int i = 0; i < 4; ++i) w.Number((*e.plane)[i]);
      w.EndArray();
    }
    w.EndObject();
  }
  w.EndArray().Key("timings_ms").BeginObject();
  for (const StageTiming& t : r.timings) w.Key(t.stage).Number(t.ms);
  w.EndObject().EndObject();
  return w.str();
}

// The client's --config: engine options (`slam:` map, same keys as the
// server's), the class table (`classes_file:` path or `class_table:` text),
// the wire encoding and the session policy.
struct RunConfig {
  SlamOptions options;
  std::set<std::string> slam_keys;  // the `slam:` keys given (sent to a server)
  std::string class_table_text;
  client::pb::ImageEncoding encoding = client::pb::IMAGE_ENCODING_RAW;
  int queue_capacity = 0;
  bool drop_oldest = false;
};

bool ReadRunConfig(const std::string& path, RunConfig* config, std::string* error) {
  const std::optional<std::string> text = ReadConfigText(path);
  if (!text.has_value()) {
    *error = "cannot read config " + path;
    return false;
  }
  cv::FileStorage fs;
  try {
    if (!fs.open(*text, cv::FileStorage::READ | cv::FileStorage::MEMORY)) {
      *error = "cannot parse config " + path + " (YAML or JSON expected)";
      return false;
    }
  } catch (const cv::Exception& e) {
    *error = "config " + path + ": " + e.what();
    return false;
  }
  const cv::FileNode root = fs.root();
  for (cv::FileNodeIterator it = root.begin(); it != root.end(); ++it) {
    const cv::FileNode n = *it;
    const std::string key = n.name();
    if (key == "slam") {
      for (cv::FileNodeIterator jt = n.begin(); jt != n.end(); ++jt) {
        const cv::FileNode o = *jt;
        const std::string k = o.name();
        SlamOptions& s = config->options;
        config->slam_keys.insert(k);
        if (k == "mapping_mode") {
          const std::string v = o.string();
          if (v != "synchronous" && v != "background") {
            *error = "config: slam.mapping_mode must be synchronous or background";
            return false;
          }
          s.mapping_mode = v == "background" ? MappingMode::kBackground : MappingMode::kSynchronous;
          continue;
        }
        if (!o.isInt() && !o.isReal()) {
          *error = "config: slam." + k + " must be a number";
          return false;
        }
        const double v = o.real();
        if (!SetNumericSlamOption(k, v, &s)) {
          *error = "config: unknown key slam." + k;
          return false;
        }
      }
    } else if (key == "classes_file") {
      std::filesystem::path p = n.string();
      if (p.is_relative()) p = std::filesystem::path(path).parent_path() / p;
      std::ifstream in(p);
      if (!in) {
        *error = "config: cannot read classes_file " + p.string();
        return false;
      }
      std::stringstream ss;
      ss << in.rdbuf();
      config->class_table_text = ss.str();
    } else if (key == "class_table") {
      config->class_table_text = n.string();
    } else if (key == "encoding") {
      const std::string v = n.string();
      if (v == "raw")
        config->encoding = client::pb::IMAGE_ENCODING_RAW;
      else if (v == "png")
        config->encoding = client::pb::IMAGE_ENCODING_PNG;
      else if (v == "jpeg")
        config->encoding = client::pb::IMAGE_ENCODING_JPEG;
      else {
        *error = "config: encoding must be raw, png or jpeg";
        return false;
      }
    } else if (key == "queue_capacity") {
      config->queue_capacity = static_cast<int>(n.real());
    } else if (key == "overflow") {
      config->drop_oldest = n.string() == "drop_oldest";
      if (!config->drop_oldest && n.string() != "block") {
        *error = "config: overflow must be block or drop_oldest";
        return false;
      }
    } else {
      *error = "config: unknown key " + key;
      return false;
    }
  }
  return true;
}

// --realtime: each frame goes to the engine or the stream no earlier than
// its timestamp's offset from the first frame's, as a camera would deliver
// it. A frame that comes late (the engine was slower than the stream) goes
// at once: nothing is dropped here (the server's overflow policy may).
class Pacer {
 public:
  explicit Pacer(bool on) : on_(on) {}
  void WaitFor(int64_t timestamp_ns) {
    if (!on_) return;
    const auto now = std::chrono::steady_clock::now();
    if (!started_) {
      started_ = true;
      start_ = now;
      first_ns_ = timestamp_ns;
      return;
    }
    const auto due = start_ + std::chrono::nanoseconds(timestamp_ns - first_ns_);
    if (due > now) {
      std::this_thread::sleep_until(due);
    } else {
      ++late_;
    }
  }
  int64_t late() const { return late_; }

 private:
  bool on_;
  bool started_ = false;
  std::chrono::steady_clock::time_point start_;
  int64_t first_ns_ = 0;
  int64_t late_ = 0;
};

// The sequence's frames 0 .. total-1, decoded on a thread of their own while
// the frames before are processed or sent: three frames ahead (~12 MB at
// KITTI size), at nice 10. On a 2-core machine the decoding (~35 ms a KITTI
// frame) would otherwise take its share of a core from the engine's tracking
// thread; lowered, it runs in the time the tracking leaves, still before the
// background mapper (nice 19), and the frames ahead absorb the waits.
constexpr int kPrefetchDepth = 3;
constexpr int kPrefetchNiceness = 10;

io::FramePrefetcher Prefetch(const io::SequenceReader& reader, int64_t total) {
  return io::FramePrefetcher([&reader](int64_t i) { return reader.ReadFrame(i); },
                             total,
                             kPrefetchDepth,
                             kPrefetchNiceness);
}

}  // namespace

// First token of a token file (the server's format `<token> [<principal>]`).
std::string ReadTokenFile(const std::string& path, std::string* error) {
  std::ifstream in(path);
  if (!in) {
    *error = "cannot read token file " + path;
    return "";
  }
  std::string line;
  while (std::getline(in, line)) {
    std::istringstream ss(line);
    std::string token;
    if (ss >> token && token[0] != '#') return token;
  }
  *error = "token file " + path + " has no token";
  return "";
}

int RunCommand(int argc, char** argv) {
  ArgParser parser(kCommand);
  parser.AddValue("dataset", "DIR", "dataset root")
      .AddValue("format", "FORMAT", "kitti-odometry | kitti-tracking")
      .AddValue("seq", "SEQ", "sequence name (06, 0001, ...)")
      .AddValue("out", "OUTDIR", "output directory")
      .AddValue("server", "HOST:PORT", "stream to a twistslam-server", /*required=*/false)
      .AddFlag("embedded", "run the engine in this process instead of a server")
      .AddValue("config",
                "FILE",
                "YAML/JSON: slam options, classes_file, encoding, queue_capacity, overflow",
                /*required=*/false)
      .AddValue(
          "token-file", "FILE", "bearer token for the server (first token of the file)", false)
      .AddValue("tls-ca", "FILE", "PEM roots: connect with TLS", false)
      .AddValue("max-frames", "N", "process at most N frames", false, "all")
      .AddValue("name", "NAME", "session name shown by the server", false, "the sequence")
      .AddFlag("realtime",
               "send each frame at its timestamp (a live camera's pace) instead of at once")
      .AddFlag("keep-session",
               "leave the server session open (for `twistslam map`) and print its id");
  std::optional<Args> args = parser.Parse(argc, argv);
  if (!args) return parser.exit_code();
  const bool embedded = args->Flag("embedded");
  if (embedded == args->Has("server"))
    return Fail(kCommand, "give exactly one of --server HOST:PORT and --embedded", 2);
  std::optional<int64_t> max_frames = args->GetInt("max-frames", -1);
  if (!max_frames) return Fail(kCommand, "--max-frames must be an integer", 2);

  RunConfig config;
  std::string error;
  if (args->Has("config") && !ReadRunConfig(args->Get("config"), &config, &error))
    return Fail(kCommand, error, 2);

  absl::StatusOr<std::unique_ptr<io::SequenceReader>> seq =
      io::OpenSequence(args->Get("dataset"), args->Get("format"), args->Get("seq"));
  if (!seq.ok()) return Fail(kCommand, std::string(seq.status().message()), 1);
  const io::SequenceReader& reader = **seq;
  const int64_t total = *max_frames >= 0 ? std::min(*max_frames, reader.size()) : reader.size();

  SessionConfig session;
  session.camera = reader.camera();
  session.options = config.options;
  const std::string classes_text =
      !config.class_table_text.empty() ? config.class_table_text : reader.class_table_text();
  if (!classes_text.empty()) {
    absl::StatusOr<joints::ClassTable> classes = joints::ClassTable::FromText(classes_text);
    if (!classes.ok()) return Fail(kCommand, std::string(classes.status().message()), 1);
    session.classes = std::move(*classes);
  }

  std::string out_error;
  if (!MakeDirs(args->Get("out"), &out_error)) return Fail(kCommand, out_error, 1);

  std::vector<FrameResult> results;
  std::vector<std::string> frame_errors;
  MapSnapshot map;
  io::RunInfo info;
  info.dataset = args->Get("dataset");
  info.format = args->Get("format");
  info.sequence = reader.sequence();
  int64_t dropped = 0;
  int reconnects = 0;
  Progress progress(total);
  Pacer pacer(args->Flag("realtime"));

  if (embedded) {
    info.mode = "embedded";
    info.strings.push_back({"mapping_mode", MappingModeName(session.options.mapping_mode)});
    absl::StatusOr<std::unique_ptr<SlamSystem>> system = SlamSystem::Create(session);
    if (!system.ok()) return Fail(kCommand, std::string(system.status().message()), 1);
    io::FramePrefetcher frames = Prefetch(reader, total);
    for (int64_t i = 0; i < total; ++i) {
      absl::StatusOr<StereoFrame> frame = frames.Next();
      if (!frame.ok()) {
        // A frame that cannot be read is skipped and reported (exit 3); the
        // run goes on and its outputs are written.
        frame_errors.push_back(absl::StrCat("frame ", i, ": ", frame.status().message()));
        progress.Update(i + 1);
        continue;
      }
      pacer.WaitFor(frame->timestamp_ns);
      absl::StatusOr<FrameResult> r = (*system)->Process(*frame);
      if (!r.ok()) {
        frame_errors.push_back(absl::StrCat("frame ", i, ": ", r.status().message()));
      } else {
        results.push_back(std::move(*r));
      }
      progress.Update(i + 1);
    }
    map = (*system)->Snapshot();
    (*system)->Shutdown();
  } else {
    info.mode = "server " + args->Get("server");
    client::ClientOptions options;
    options.address = args->Get("server");
    options.tls_ca_file = args->Get("tls-ca");
    if (args->Has("token-file")) {
      options.token = ReadTokenFile(args->Get("token-file"), &error);
      if (options.token.empty()) return Fail(kCommand, error, 2);
    }
    absl::StatusOr<std::unique_ptr<client::SlamClient>> client =
        client::SlamClient::Connect(options);
    if (!client.ok()) return Fail(kCommand, std::string(client.status().message()), 1);
    client::pb::CreateSessionRequest request;
    request.set_name(args->Get("name", reader.sequence()));
    *request.mutable_config() = client::SessionConfigToProto(session);
    // Only the options the --config gave: the server's defaults apply to the
    // rest (its own --config, and mapping in the session's thread).
    if (absl::Status s =
            client::KeepOnlyOptions(config.slam_keys, request.mutable_config()->mutable_options());
        !s.ok()) {
      return Fail(kCommand, absl::StrCat("config: ", s.message()), 2);
    }
    request.mutable_policy()->set_queue_capacity(config.queue_capacity);
    request.mutable_policy()->set_overflow(config.drop_oldest
                                               ? client::pb::OVERFLOW_POLICY_DROP_OLDEST
                                               : client::pb::OVERFLOW_POLICY_BLOCK);
    absl::StatusOr<client::pb::CreateSessionResponse> created = (*client)->CreateSession(request);
    if (!created.ok()) {
      return Fail(
          kCommand,
          absl::StrCat(
              "cannot create a session on ", options.address, ": ", created.status().message()));
    }
    // The session's effective mode ("unknown" from a server that predates
    // SessionInfo.options).
    const client::pb::MappingMode mode = created->session().options().mapping_mode();
    info.strings.push_back({"mapping_mode",
                            mode == client::pb::MAPPING_MODE_UNSPECIFIED
                                ? "unknown"
                                : MappingModeName(mode == client::pb::MAPPING_MODE_BACKGROUND
                                                      ? MappingMode::kBackground
                                                      : MappingMode::kSynchronous)});
    std::mutex mu;
    std::map<int64_t, client::pb::FrameUpdate> updates;
    int64_t answered = 0;
    absl::Status stream = (*client)->OpenStream(
        created->session_id(), created->resume_token(), [&](const client::pb::StreamResponse& r) {
          std::lock_guard<std::mutex> lock(mu);
          if (r.has_update()) {
            updates[r.update().index()] = r.update();
            ++answered;
          } else if (r.has_error()) {
            frame_errors.push_back(
                absl::StrCat("frame ", r.error().index(), ": ", r.error().message()));
            ++answered;
          } else if (r.has_dropped()) {
            dropped += r.dropped().indices_size();
            answered += r.dropped().indices_size();
          }
        });
    if (!stream.ok()) return Fail(kCommand, std::string(stream.message()));
    io::FramePrefetcher frames = Prefetch(reader, total);
    for (int64_t i = 0; i < total; ++i) {
      absl::StatusOr<StereoFrame> frame = frames.Next();
      if (!frame.ok()) {
        // Not sent: skipped and reported as in the embedded mode.
        std::lock_guard<std::mutex> lock(mu);
        frame_errors.push_back(absl::StrCat("frame ", i, ": ", frame.status().message()));
        continue;
      }
      client::FrameImages images;
      images.index = i;
      images.timestamp_ns = frame->timestamp_ns;
      images.left = frame->left;
      images.right = frame->right;
      images.panoptic = frame->panoptic;
      images.flow = frame->flow;
      client::pb::Frame wire;
      if (absl::Status s = client::MakeFrame(images, config.encoding, &wire); !s.ok()) {
        return Fail(kCommand, absl::StrCat("frame ", i, ": ", s.message()));
      }
      for (const DetectionBox& b : frame->boxes) {
        client::pb::DetectionBox* pb_box = wire.add_boxes();
        pb_box->set_class_id(b.class_id);
        pb_box->set_instance_id(b.instance_id);
        pb_box->set_x_min(b.x_min);
        pb_box->set_y_min(b.y_min);
        pb_box->set_x_max(b.x_max);
        pb_box->set_y_max(b.y_max);
      }
      pacer.WaitFor(frame->timestamp_ns);
      if (absl::Status s = (*client)->Send(wire); !s.ok()) {
        return Fail(kCommand, absl::StrCat("stream failed at frame ", i, ": ", s.message()));
      }
      int64_t done;
      {
        std::lock_guard<std::mutex> lock(mu);
        done = answered;
      }
      progress.Update(done);
    }
    if (absl::Status s = (*client)->CloseStream(); !s.ok()) {
      return Fail(kCommand, absl::StrCat("stream failed: ", s.message()));
    }
    reconnects = (*client)->reconnects();
    for (auto& [index, update] : updates) results.push_back(client::FrameResultFromProto(update));
    client::pb::GetMapRequest map_request;
    map_request.set_session_id(created->session_id());
    absl::StatusOr<std::vector<client::pb::MapChunk>> chunks = (*client)->GetMap(map_request);
    if (!chunks.ok())
      return Fail(kCommand, absl::StrCat("cannot fetch the map: ", chunks.status().message()));
    map = client::MapFromChunks(*chunks);
    if (args->Flag("keep-session")) {
      std::cout << "session " << created->session_id() << " resume_token "
                << created->resume_token() << "\n";
    } else {
      (*client)->CloseSession(created->session_id(), /*persist=*/false).IgnoreError();
    }
  }
  progress.Finish(static_cast<int64_t>(results.size() + frame_errors.size()) + dropped);

  info.wall_time_s = progress.ElapsedS();
  info.numbers.push_back({"frames_total", static_cast<double>(total)});
  info.numbers.push_back({"frames_processed", static_cast<double>(results.size())});
  info.numbers.push_back({"frame_errors", static_cast<double>(frame_errors.size())});
  info.numbers.push_back({"frames_dropped", static_cast<double>(dropped)});
  info.numbers.push_back({"reconnects", static_cast<double>(reconnects)});
  if (args->Flag("realtime")) {
    // Frames the engine or the stream took after their due time.
    info.numbers.push_back({"realtime_late_frames", static_cast<double>(pacer.late())});
  }
  info.numbers.push_back(
      {"frames_per_second", info.wall_time_s > 0 ? results.size() / info.wall_time_s : 0.0});

  // updates.jsonl and map.ply first; RunOutputWriter writes summary.json last,
  // so a directory with summary.json holds a complete run.
  std::string jsonl;
  io::RunOutputWriter writer;
  for (const FrameResult& r : results) {
    jsonl += UpdateJson(r);
    jsonl += '\n';
    writer.Add(r);
  }
  std::vector<io::TimedObjectTrajectory> refined;
  for (const MapSnapshot::Object& o : map.objects) {
    refined.push_back({o.id, o.class_id, o.instance_id, o.trajectory});
  }
  writer.SetRefinedObjects(std::move(refined));
  std::vector<std::pair<int64_t, geometry::SE3d>> keyframes;
  for (const MapSnapshot::KeyFrame& kf : map.keyframes) {
    keyframes.push_back({kf.timestamp_ns, kf.world_from_camera});
  }
  writer.SetRefinedKeyFrames(std::move(keyframes));
  const std::filesystem::path out_dir = args->Get("out");
  if (!WriteFileAtomic((out_dir / "updates.jsonl").string(), jsonl, &out_error) ||
      !WriteFileAtomic((out_dir / "map.ply").string(), client::MapToPly(map), &out_error)) {
    return Fail(kCommand, out_error);
  }
  if (absl::Status s = writer.Write(out_dir.string(), info); !s.ok())
    return Fail(kCommand, std::string(s.message()));
  for (size_t i = 0; i < frame_errors.size() && i < 5; ++i)
    std::cerr << "twistslam run: " << frame_errors[i] << "\n";
  std::fprintf(stderr,
               "%zu/%lld frames processed (%zu errors, %lld dropped) in %.1f s; outputs in %s\n",
               results.size(),
               static_cast<long long>(total),
               frame_errors.size(),
               static_cast<long long>(dropped),
               info.wall_time_s,
               out_dir.c_str());
  return frame_errors.empty() ? 0 : 3;
}

}  // namespace twist::cli
