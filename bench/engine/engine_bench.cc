// Engine benchmark on the KITTI clip: per-stage median / p95 (ORB, stereo
// matching, tracking, keyframe creation, local mapping, local BA), end-to-end
// frames/s in synchronous and background mapping modes, accuracy (RPE, ATE),
// peak RSS and memory per keyframe. Prints a table and JSON; never asserts.
//
//   engine_bench [--data DIR] [--seq 06] [--mode sync|background|both]
//                [--features N] [--repeat R] [--json FILE]
//                [--stereo-by-point-depth 0|1] [--realtime] [--disparity-offset PX]
//
// Accuracy is given for the online poses (what Process returned for each
// frame) and for the refined ones (the same corrected by the final map's
// keyframes, io::RefineCameraWithKeyFrames: camera_refined.txt, the
// trajectory ORB-SLAM2 writes at the end of a run). --realtime hands each
// frame to the engine no earlier than its timestamp, as a 10 Hz camera
// would, which is how ORB-SLAM2's stereo example ran for BASELINES.md; with
// the background mapper that changes how many keyframes it makes. With
// --repeat R > 1 each mode also gets a line of medians [min-max] over its
// runs (the background mode is not deterministic).
#include <sys/resource.h>
#include <sys/stat.h>

#include <algorithm>
#include <chrono>
#include <cstdio>
#include <cstring>
#include <fstream>
#include <map>
#include <sstream>
#include <string>
#include <thread>
#include <vector>

#include "slam/common/timer.h"
#include "slam/io/metrics.h"
#include "slam/io/run_output.h"
#include "slam/io/sequence.h"
#include "slam/system/slam_system.h"

namespace {

using twist::SlamSystem;
using twist::StereoFrame;

double Percentile(std::vector<double> v, double q) {
  if (v.empty()) return 0.0;
  std::sort(v.begin(), v.end());
  const size_t k = std::min(v.size() - 1, static_cast<size_t>(q * (v.size() - 1) + 0.5));
  return v[k];
}

long CurrentRssKb() {
  std::ifstream in("/proc/self/status");
  std::string line;
  while (std::getline(in, line)) {
    if (line.rfind("VmRSS:", 0) == 0) return std::atol(line.c_str() + 6);
  }
  return 0;
}

double ProcessCpuMs() {
  struct rusage ru;
  getrusage(RUSAGE_SELF, &ru);
  return (ru.ru_utime.tv_sec + ru.ru_stime.tv_sec) * 1e3 +
         (ru.ru_utime.tv_usec + ru.ru_stime.tv_usec) * 1e-3;
}

double LoadAverage() {
  std::ifstream in("/proc/loadavg");
  double l = 0;
  in >> l;
  return l;
}

long PeakRssKb() {
  struct rusage ru;
  getrusage(RUSAGE_SELF, &ru);
  return ru.ru_maxrss;
}

struct RunResult {
  std::string mode;
  std::map<std::string, std::vector<double>> stages;  // per frame where present
  std::vector<double> frame_latency_ms;               // Process() wall time
  double wall_s = 0.0;
  double cpu_ms_per_frame = 0.0;  // all threads of the process
  double load_average = 0.0;
  double fps = 0.0;
  int lost = 0;
  int keyframes = 0;
  int map_points = 0;
  double rpe_t = 0, rpe_r = 0, ate = 0, path = 0, ate_sim3 = 0;
  double refined_rpe_t = 0, refined_rpe_r = 0, refined_ate = 0;
  int late_frames = 0;  // --realtime: frames the engine took after their due time
  long rss_before_kb = 0, rss_after_kb = 0;
};

RunResult RunOnce(const twist::SessionConfig& config,
                  const std::vector<StereoFrame>& frames,
                  const std::vector<twist::geometry::SE3d>& gt,
                  bool realtime) {
  RunResult r;
  r.mode = config.options.mapping_mode == twist::MappingMode::kBackground ? "background" : "sync";
  r.rss_before_kb = CurrentRssKb();
  auto sys = SlamSystem::Create(config);
  if (!sys.ok()) {
    std::fprintf(stderr, "engine_bench: %s\n", std::string(sys.status().message()).c_str());
    std::exit(2);
  }
  std::vector<std::pair<int64_t, twist::geometry::SE3d>> est;
  const double cpu0 = ProcessCpuMs();
  twist::Stopwatch total;
  const auto start = std::chrono::steady_clock::now();
  for (const StereoFrame& f : frames) {
    if (realtime && &f != &frames.front()) {  // the first frame sets the clock
      const auto due =
          start + std::chrono::nanoseconds(f.timestamp_ns - frames.front().timestamp_ns);
      if (std::chrono::steady_clock::now() > due) {
        ++r.late_frames;
      } else {
        std::this_thread::sleep_until(due);
      }
    }
    twist::Stopwatch sw;
    auto res = (*sys)->Process(f);
    r.frame_latency_ms.push_back(sw.ElapsedMs());
    if (!res.ok()) {
      std::fprintf(stderr, "engine_bench: %s\n", std::string(res.status().message()).c_str());
      std::exit(2);
    }
    if (res->state != twist::TrackingState::kOk) ++r.lost;
    est.push_back({f.timestamp_ns, res->world_from_camera});
    double tracking = 0.0;
    for (const auto& t : res->timings) {
      r.stages[t.stage].push_back(t.ms);
      if (t.stage == "orb" || t.stage == "stereo" || t.stage == "track" || t.stage == "keyframe") {
        tracking += t.ms;
      }
    }
    r.stages["tracking_latency"].push_back(tracking);
    r.keyframes = res->num_keyframes;
    r.map_points = res->num_map_points;
  }
  (*sys)->Shutdown();  // joins the mapping thread: its work is counted
  r.wall_s = total.ElapsedMs() / 1000.0;
  std::vector<std::pair<int64_t, twist::geometry::SE3d>> keyframes;
  for (const twist::MapSnapshot::KeyFrame& kf : (*sys)->Snapshot().keyframes) {
    keyframes.push_back({kf.timestamp_ns, kf.world_from_camera});
  }
  r.cpu_ms_per_frame = (ProcessCpuMs() - cpu0) / frames.size();
  r.load_average = LoadAverage();
  r.fps = frames.size() / r.wall_s;
  r.rss_after_kb = CurrentRssKb();
  if (!gt.empty()) {
    std::vector<twist::geometry::SE3d> online;
    for (const auto& [t, pose] : est) online.push_back(pose);
    auto m = twist::io::EvaluateCamera(gt, online);
    if (m.ok()) {
      r.rpe_t = m->rpe_t;
      r.rpe_r = m->rpe_r_deg;
      r.ate = m->ate_rmse;
      r.path = m->gt_path_length > 0 ? m->est_path_length / m->gt_path_length : 0.0;
      r.ate_sim3 = m->ate_sim3_rmse;
    }
    auto refined =
        twist::io::EvaluateCamera(gt, twist::io::RefineCameraWithKeyFrames(est, keyframes));
    if (refined.ok()) {
      r.refined_rpe_t = refined->rpe_t;
      r.refined_rpe_r = refined->rpe_r_deg;
      r.refined_ate = refined->ate_rmse;
    }
  }
  return r;
}

// "median [min-max]" of one figure over the runs of a mode.
struct Spread {
  double median = 0, min = 0, max = 0;
};

Spread SpreadOf(const std::vector<RunResult>& runs,
                const std::string& mode,
                double RunResult::*field) {
  std::vector<double> v;
  for (const RunResult& r : runs) {
    if (r.mode == mode) v.push_back(r.*field);
  }
  if (v.empty()) return {};
  std::sort(v.begin(), v.end());
  // The median of an even count is the mean of the middle two.
  const double median =
      v.size() % 2 ? v[v.size() / 2] : 0.5 * (v[v.size() / 2 - 1] + v[v.size() / 2]);
  return {median, v.front(), v.back()};
}

// With --repeat: each mode's figures as median [min-max] over its runs,
// printed and appended to `json` as {"mode": {"figure": [median, min, max]}}.
void PrintSpreads(const std::vector<RunResult>& runs, std::ostringstream* json) {
  const std::pair<const char*, double RunResult::*> kFigures[] = {
      {"fps", &RunResult::fps},
      {"rpe_t", &RunResult::rpe_t},
      {"rpe_r_deg", &RunResult::rpe_r},
      {"ate", &RunResult::ate},
      {"path_ratio", &RunResult::path},
      {"ate_sim3", &RunResult::ate_sim3},
      {"refined_rpe_t", &RunResult::refined_rpe_t},
      {"refined_rpe_r_deg", &RunResult::refined_rpe_r},
      {"refined_ate", &RunResult::refined_ate},
  };
  *json << ", \"spread\": {";
  bool first_mode = true;
  for (const char* mode : {"sync", "background"}) {
    const int n = static_cast<int>(std::count_if(
        runs.begin(), runs.end(), [&](const RunResult& r) { return r.mode == mode; }));
    if (n < 2) continue;
    std::printf("\n[%s] median [min-max] over %d runs\n", mode, n);
    *json << (first_mode ? "" : ", ") << "\"" << mode << "\": {\"runs\": " << n;
    first_mode = false;
    for (const auto& [name, field] : kFigures) {
      const Spread s = SpreadOf(runs, mode, field);
      std::printf("  %-18s %.5g [%.5g-%.5g]\n", name, s.median, s.min, s.max);
      *json << ", \"" << name << "\": [" << s.median << ", " << s.min << ", " << s.max << "]";
    }
    *json << "}";
  }
  *json << "}";
}

}  // namespace

int main(int argc, char** argv) {
  std::string data = std::string(TWIST_SOURCE_DIR) + "/../shared/data/kitti_odometry_06_f0-50";
  std::string seq_name = "06", mode = "both", json_path;
  int num_features = 2000, repeat = 1;
  bool stereo_by_point_depth = false, realtime = false;
  double disparity_offset_px = 0.0;  // the rig's calibration (twistslam calibrate)
  for (int i = 1; i < argc; ++i) {
    const std::string a = argv[i];
    auto next = [&]() -> std::string {
      if (i + 1 >= argc) {
        std::fprintf(stderr, "engine_bench: %s needs a value\n", a.c_str());
        std::exit(2);
      }
      return argv[++i];
    };
    if (a == "--data")
      data = next();
    else if (a == "--seq")
      seq_name = next();
    else if (a == "--mode")
      mode = next();
    else if (a == "--features")
      num_features = std::stoi(next());
    else if (a == "--repeat")
      repeat = std::stoi(next());
    else if (a == "--json")
      json_path = next();
    else if (a == "--stereo-by-point-depth")
      stereo_by_point_depth = std::stoi(next()) != 0;
    else if (a == "--realtime")
      realtime = true;
    else if (a == "--disparity-offset")
      disparity_offset_px = std::stod(next());
    else {
      std::fprintf(stderr, "engine_bench: unknown argument %s\n", a.c_str());
      return 2;
    }
  }
  struct stat st;
  if (stat(data.c_str(), &st) != 0) {
    std::printf("engine_bench: data not found at %s, skipping\n", data.c_str());
    return 0;
  }
  auto seq = twist::io::OpenSequence(data, "kitti-odometry", seq_name);
  if (!seq.ok()) {
    std::fprintf(stderr, "engine_bench: %s\n", std::string(seq.status().message()).c_str());
    return 2;
  }
  std::vector<StereoFrame> frames;
  for (int64_t i = 0; i < (*seq)->size(); ++i) {
    auto f = (*seq)->ReadFrame(i);
    if (!f.ok()) {
      std::fprintf(stderr, "engine_bench: %s\n", std::string(f.status().message()).c_str());
      return 2;
    }
    frames.push_back(*std::move(f));
  }
  const std::vector<twist::geometry::SE3d> gt = (*seq)->has_gt_poses()
                                                    ? (*seq)->gt_world_from_camera()
                                                    : std::vector<twist::geometry::SE3d>{};

  twist::SessionConfig config;
  config.camera = (*seq)->camera();
  config.options.num_features = num_features;
  config.options.stereo_by_point_depth = stereo_by_point_depth;
  config.options.disparity_offset_px = disparity_offset_px;
  std::vector<RunResult> runs;
  for (int rep = 0; rep < repeat; ++rep) {
    if (mode == "sync" || mode == "both") {
      config.options.mapping_mode = twist::MappingMode::kSynchronous;
      runs.push_back(RunOnce(config, frames, gt, realtime));
    }
    if (mode == "background" || mode == "both") {
      config.options.mapping_mode = twist::MappingMode::kBackground;
      runs.push_back(RunOnce(config, frames, gt, realtime));
    }
  }
  const long peak_kb = PeakRssKb();

  const char* kStages[] = {
      "orb", "stereo", "track", "keyframe", "tracking_latency", "mapping", "ba", "total"};
  std::printf(
      "engine_bench: %s seq %s, %zu frames %dx%d, %d features%s%s, disparity offset %+.3f px\n",
      data.c_str(),
      seq_name.c_str(),
      frames.size(),
      config.camera.width,
      config.camera.height,
      num_features,
      stereo_by_point_depth ? ", stereo by point depth" : "",
      realtime ? ", frames paced at their timestamps" : ", frames back to back",
      disparity_offset_px);
  std::ostringstream json;
  json << "{\"frames\": " << frames.size() << ", \"features\": " << num_features
       << ", \"stereo_by_point_depth\": " << (stereo_by_point_depth ? "true" : "false")
       << ", \"realtime\": " << (realtime ? "true" : "false")
       << ", \"disparity_offset_px\": " << disparity_offset_px
       << ", \"peak_rss_mb\": " << peak_kb / 1024.0 << ", \"runs\": [";
  for (size_t k = 0; k < runs.size(); ++k) {
    const RunResult& r = runs[k];
    std::printf("\n[%s] %.2f frames/s end-to-end (%.2f s), lost %d, keyframes %d, points %d\n",
                r.mode.c_str(),
                r.fps,
                r.wall_s,
                r.lost,
                r.keyframes,
                r.map_points);
    std::printf(
        "  online  RPE_t %.5f m/frame  RPE_R %.4f deg/frame  ATE %.4f m  path %.5f x  "
        "ATE after Sim(3) %.4f m\n",
        r.rpe_t,
        r.rpe_r,
        r.ate,
        r.path,
        r.ate_sim3);
    std::printf("  refined RPE_t %.5f m/frame  RPE_R %.4f deg/frame  ATE %.4f m\n",
                r.refined_rpe_t,
                r.refined_rpe_r,
                r.refined_ate);
    if (realtime) std::printf("  %d frames taken after their due time\n", r.late_frames);
    std::printf("  CPU %.1f ms/frame (all threads), machine load average %.1f\n",
                r.cpu_ms_per_frame,
                r.load_average);
    std::printf("  %-18s %8s %8s %6s\n", "stage (ms)", "median", "p95", "n");
    json << (k ? ", " : "") << "{\"mode\": \"" << r.mode << "\", \"fps\": " << r.fps
         << ", \"wall_s\": " << r.wall_s << ", \"lost\": " << r.lost
         << ", \"keyframes\": " << r.keyframes << ", \"map_points\": " << r.map_points
         << ", \"rpe_t\": " << r.rpe_t << ", \"rpe_r_deg\": " << r.rpe_r << ", \"ate\": " << r.ate
         << ", \"path_ratio\": " << r.path << ", \"ate_sim3\": " << r.ate_sim3
         << ", \"refined_rpe_t\": " << r.refined_rpe_t
         << ", \"refined_rpe_r_deg\": " << r.refined_rpe_r << ", \"refined_ate\": " << r.refined_ate
         << ", \"late_frames\": " << r.late_frames
         << ", \"cpu_ms_per_frame\": " << r.cpu_ms_per_frame
         << ", \"load_average\": " << r.load_average
         << ", \"rss_growth_mb\": " << (r.rss_after_kb - r.rss_before_kb) / 1024.0
         << ", \"rss_per_keyframe_kb\": "
         << (r.keyframes ? static_cast<double>(r.rss_after_kb - r.rss_before_kb) / r.keyframes
                         : 0.0)
         << ", \"stages\": {";
    bool first = true;
    for (const char* s : kStages) {
      auto it = r.stages.find(s);
      if (it == r.stages.end()) continue;
      const double med = Percentile(it->second, 0.5), p95 = Percentile(it->second, 0.95);
      std::printf("  %-18s %8.2f %8.2f %6zu\n", s, med, p95, it->second.size());
      json << (first ? "" : ", ") << "\"" << s << "\": {\"median_ms\": " << med
           << ", \"p95_ms\": " << p95 << ", \"n\": " << it->second.size() << "}";
      first = false;
    }
    const double lat_med = Percentile(r.frame_latency_ms, 0.5),
                 lat_p95 = Percentile(r.frame_latency_ms, 0.95);
    std::printf(
        "  %-18s %8.2f %8.2f %6zu\n", "process_call", lat_med, lat_p95, r.frame_latency_ms.size());
    std::printf(
        "  memory: +%.1f MB during the run, %.1f kB per keyframe\n",
        (r.rss_after_kb - r.rss_before_kb) / 1024.0,
        r.keyframes ? static_cast<double>(r.rss_after_kb - r.rss_before_kb) / r.keyframes : 0.0);
    json << "}, \"process_call\": {\"median_ms\": " << lat_med << ", \"p95_ms\": " << lat_p95
         << "}}";
  }
  json << "]";
  PrintSpreads(runs, &json);
  json << "}";
  std::printf(
      "\npeak RSS %.1f MB (includes the %zu preloaded frames)\n", peak_kb / 1024.0, frames.size());
  std::printf("JSON %s\n", json.str().c_str());
  if (!json_path.empty()) {
    std::ofstream out(json_path);
    out << json.str() << "\n";
  }
  return 0;
}
