// Engine benchmark on the KITTI clip: per-stage median / p95 (ORB, stereo
// matching, tracking, keyframe creation, local mapping, local BA), end-to-end
// frames/s in synchronous and background mapping modes, accuracy (RPE, ATE),
// peak RSS and memory per keyframe. Prints a table and JSON; never asserts.
//
//   engine_bench [--data DIR] [--seq 06] [--mode sync|background|both]
//                [--features N] [--repeat R] [--json FILE]
//                [--stereo-by-point-depth 0|1]
#include <sys/resource.h>
#include <sys/stat.h>

#include <algorithm>
#include <cstdio>
#include <cstring>
#include <fstream>
#include <map>
#include <sstream>
#include <string>
#include <vector>

#include "slam/common/timer.h"
#include "slam/io/metrics.h"
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
  double rpe_t = 0, rpe_r = 0, ate = 0;
  long rss_before_kb = 0, rss_after_kb = 0;
};

RunResult RunOnce(const twist::SessionConfig& config,
                  const std::vector<StereoFrame>& frames,
                  const std::vector<twist::geometry::SE3d>& gt) {
  RunResult r;
  r.mode = config.options.mapping_mode == twist::MappingMode::kBackground ? "background" : "sync";
  r.rss_before_kb = CurrentRssKb();
  auto sys = SlamSystem::Create(config);
  if (!sys.ok()) {
    std::fprintf(stderr, "engine_bench: %s\n", std::string(sys.status().message()).c_str());
    std::exit(2);
  }
  std::vector<twist::geometry::SE3d> est;
  const double cpu0 = ProcessCpuMs();
  twist::Stopwatch total;
  for (const StereoFrame& f : frames) {
    twist::Stopwatch sw;
    auto res = (*sys)->Process(f);
    r.frame_latency_ms.push_back(sw.ElapsedMs());
    if (!res.ok()) {
      std::fprintf(stderr, "engine_bench: %s\n", std::string(res.status().message()).c_str());
      std::exit(2);
    }
    if (res->state != twist::TrackingState::kOk) ++r.lost;
    est.push_back(res->world_from_camera);
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
  r.cpu_ms_per_frame = (ProcessCpuMs() - cpu0) / frames.size();
  r.load_average = LoadAverage();
  r.fps = frames.size() / r.wall_s;
  r.rss_after_kb = CurrentRssKb();
  if (!gt.empty()) {
    auto m = twist::io::EvaluateCamera(gt, est);
    if (m.ok()) {
      r.rpe_t = m->rpe_t;
      r.rpe_r = m->rpe_r_deg;
      r.ate = m->ate_rmse;
    }
  }
  return r;
}

}  // namespace

int main(int argc, char** argv) {
  std::string data = std::string(TWIST_SOURCE_DIR) + "/../shared/data/kitti_odometry_06_f0-50";
  std::string seq_name = "06", mode = "both", json_path;
  int num_features = 2000, repeat = 1;
  bool stereo_by_point_depth = false;
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
  std::vector<RunResult> runs;
  for (int rep = 0; rep < repeat; ++rep) {
    if (mode == "sync" || mode == "both") {
      config.options.mapping_mode = twist::MappingMode::kSynchronous;
      runs.push_back(RunOnce(config, frames, gt));
    }
    if (mode == "background" || mode == "both") {
      config.options.mapping_mode = twist::MappingMode::kBackground;
      runs.push_back(RunOnce(config, frames, gt));
    }
  }
  const long peak_kb = PeakRssKb();

  const char* kStages[] = {
      "orb", "stereo", "track", "keyframe", "tracking_latency", "mapping", "ba", "total"};
  std::printf("engine_bench: %s seq %s, %zu frames %dx%d, %d features%s\n",
              data.c_str(),
              seq_name.c_str(),
              frames.size(),
              config.camera.width,
              config.camera.height,
              num_features,
              stereo_by_point_depth ? ", stereo by point depth" : "");
  std::ostringstream json;
  json << "{\"frames\": " << frames.size() << ", \"features\": " << num_features
       << ", \"stereo_by_point_depth\": " << (stereo_by_point_depth ? "true" : "false")
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
        "  RPE_t %.4f m/frame  RPE_R %.4f deg/frame  ATE %.4f m\n", r.rpe_t, r.rpe_r, r.ate);
    std::printf("  CPU %.1f ms/frame (all threads), machine load average %.1f\n",
                r.cpu_ms_per_frame,
                r.load_average);
    std::printf("  %-18s %8s %8s %6s\n", "stage (ms)", "median", "p95", "n");
    json << (k ? ", " : "") << "{\"mode\": \"" << r.mode << "\", \"fps\": " << r.fps
         << ", \"wall_s\": " << r.wall_s << ", \"lost\": " << r.lost
         << ", \"keyframes\": " << r.keyframes << ", \"map_points\": " << r.map_points
         << ", \"rpe_t\": " << r.rpe_t << ", \"rpe_r_deg\": " << r.rpe_r << ", \"ate\": " << r.ate
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
  json << "]}";
  std::printf(
      "\npeak RSS %.1f MB (includes the %zu preloaded frames)\n", peak_kb / 1024.0, frames.size());
  std::printf("JSON %s\n", json.str().c_str());
  if (!json_path.empty()) {
    std::ofstream out(json_path);
    out << json.str() << "\n";
  }
  return 0;
}
