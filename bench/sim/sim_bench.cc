// Render time of the synthetic generator: for every scenario, renders
// `--frames` stereo frames (left + right + panoptic mask, plus the labels) at
// 1242x375 and prints the median and p95 time per frame, then one JSON line.
// Also reports (untimed) the fewest ORB keypoints of a left image (cv::ORB,
// 5000 max) and the share of object pixels in the masks.
//
//   sim_bench [--frames N] [--threads T] [--scenario NAME] [--json FILE]
#include <algorithm>
#include <cstdio>
#include <cstdlib>
#include <cstring>
#include <fstream>
#include <opencv2/features2d.hpp>
#include <opencv2/imgproc.hpp>
#include <string>
#include <vector>

#include "slam/common/timer.h"
#include "slam/sim/labels.h"
#include "slam/sim/renderer.h"
#include "slam/sim/scenarios.h"
#include "slam/sim/writer.h"

namespace {

double Percentile(std::vector<double> v, double p) {
  if (v.empty()) return 0.0;
  std::sort(v.begin(), v.end());
  const size_t i =
      std::min(v.size() - 1, static_cast<size_t>(p * static_cast<double>(v.size() - 1) + 0.5));
  return v[i];
}

}  // namespace

int main(int argc, char** argv) {
  int frames = 20;
  int threads = 2;
  std::string only, json_path;
  for (int i = 1; i < argc; ++i) {
    const std::string a = argv[i];
    const bool has_value = i + 1 < argc;
    if (a == "--frames" && has_value) {
      frames = std::atoi(argv[++i]);
    } else if (a == "--threads" && has_value) {
      threads = std::atoi(argv[++i]);
    } else if (a == "--scenario" && has_value) {
      only = argv[++i];
    } else if (a == "--json" && has_value) {
      json_path = argv[++i];
    } else {
      std::fprintf(stderr,
                   "usage: sim_bench [--frames N] [--threads T] [--scenario NAME] [--json FILE]\n");
      return 2;
    }
  }
  if (frames < 1) frames = 1;
  std::string json = "{\"benchmark\":\"sim_render\",\"width\":1242,\"height\":375,\"threads\":" +
                     std::to_string(threads) + ",\"frames\":" + std::to_string(frames) +
                     ",\"scenarios\":[";
  std::printf("%-30s %10s %10s %10s %10s %9s %9s %9s\n",
              "scenario",
              "render_med",
              "render_p95",
              "labels_med",
              "frame_med",
              "orb_min",
              "dyn_med",
              "dyn_max");
  bool first = true;
  for (const twist::sim::ScenarioInfo& info : twist::sim::ListScenarios()) {
    if (!only.empty() && info.name != only) continue;
    absl::StatusOr<twist::sim::Scenario> sc = twist::sim::MakeScenario(info.name, 1, frames);
    if (!sc.ok()) {
      std::fprintf(stderr, "%s\n", std::string(sc.status().message()).c_str());
      return 1;
    }
    twist::sim::RenderOptions options;
    options.num_threads = threads;
    const twist::sim::Renderer renderer(sc->camera, options);
    std::vector<double> render_ms, label_ms, total_ms, orb, dynamic_share;
    cv::Ptr<cv::ORB> detector = cv::ORB::create(5000);
    twist::sim::RenderScratch scratch;
    twist::sim::StereoRender r;
    for (int i = 0; i < frames; ++i) {
      twist::sim::Exposure left, right;
      twist::sim::FrameExposures(*sc, i, &left, &right);
      twist::Stopwatch watch;
      renderer.RenderStereo(
          sc->scene, sc->TimeOf(i), sc->WorldFromCamera(i), left, right, &scratch, &r);
      render_ms.push_back(watch.ElapsedMs());
      twist::Stopwatch label_watch;
      const auto labels = twist::sim::ComputeFrameLabels(*sc, renderer, i, r.panoptic);
      label_ms.push_back(label_watch.ElapsedMs());
      total_ms.push_back(watch.ElapsedMs());
      // Texture richness and share of dynamic (object) pixels, not timed.
      cv::Mat gray;
      cv::cvtColor(r.left, gray, cv::COLOR_BGR2GRAY);
      std::vector<cv::KeyPoint> keypoints;
      detector->detect(gray, keypoints);
      orb.push_back(static_cast<double>(keypoints.size()));
      int64_t dynamic = 0;
      for (int y = 0; y < r.panoptic.rows; ++y) {
        const uint16_t* row = r.panoptic.ptr<uint16_t>(y);
        for (int x = 0; x < r.panoptic.cols; ++x) dynamic += row[x] % 1000 != 0 ? 1 : 0;
      }
      dynamic_share.push_back(static_cast<double>(dynamic) /
                              static_cast<double>(r.panoptic.total()));
    }
    const double med = Percentile(render_ms, 0.5), p95 = Percentile(render_ms, 0.95);
    std::printf("%-30s %8.1fms %8.1fms %8.1fms %8.1fms %9.0f %8.1f%% %8.1f%%\n",
                info.name.c_str(),
                med,
                p95,
                Percentile(label_ms, 0.5),
                Percentile(total_ms, 0.5),
                Percentile(orb, 0.0),
                100.0 * Percentile(dynamic_share, 0.5),
                100.0 * Percentile(dynamic_share, 1.0));
    char buf[1024];
    std::snprintf(buf,
                  sizeof(buf),
                  "%s{\"scenario\":\"%s\",\"render_ms_median\":%.2f,\"render_ms_p95\":%.2f,"
                  "\"labels_ms_median\":%.2f,\"frame_ms_median\":%.2f,\"frame_ms_p95\":%.2f,"
                  "\"orb_keypoints_min\":%.0f,\"orb_keypoints_median\":%.0f,"
                  "\"dynamic_pixel_share_median\":%.4f,\"dynamic_pixel_share_max\":%.4f}",
                  first ? "" : ",",
                  info.name.c_str(),
                  med,
                  p95,
                  Percentile(label_ms, 0.5),
                  Percentile(total_ms, 0.5),
                  Percentile(total_ms, 0.95),
                  Percentile(orb, 0.0),
                  Percentile(orb, 0.5),
                  Percentile(dynamic_share, 0.5),
                  Percentile(dynamic_share, 1.0));
    json += buf;
    first = false;
  }
  json += "]}";
  std::printf("%s\n", json.c_str());
  if (!json_path.empty()) std::ofstream(json_path) << json << "\n";
  return 0;
}
