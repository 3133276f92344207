// Object tracking and dynamic bundle adjustment timings on synthetic cars
// (tests/slam/objects/car_sequence.h: planar cars on a road, 60 points each,
// 0.5 px keypoint noise, the client's dense flow).
//
// For 1 and 5 simultaneous cars it runs the object tracker over --frames
// frames and, every frame once the window is full, a dynamic BA over the last
// --window frames (camera poses free except the oldest, 300 static points,
// every tracked car), then prints median and p95 of
//   - tracking time per object (ObjectTracker::Process / number of objects),
//   - tracking time per frame,
//   - dynamic BA time (solve only, and build + solve),
// plus the sparse Lucas–Kanade time for 60 points on a textured 1241x376
// image, and one JSON document (stdout, or --json FILE).
//
// Then the whole engine (SlamSystem, synchronous mode, default options: ORB,
// stereo, camera tracking, mapping, object stage with its dynamic BA) on a
// rendered scenario (slam/sim, full KITTI-size images, --engine-frames
// frames): median and p95 of the per-frame total time and of the process
// CPU time spent in Process() (all threads; robust to a loaded machine), the
// frame rate they sustain, and how many objects were
// tracked per frame (issue #5: keep up with 10 frames/s with up to 5 tracked
// objects), and the per-frame time split between the frames with at most
// --engine-objects-split (5) tracked objects and the others.
// --engine-frames 0 skips it.
//
//   objects_bench [--frames N] [--window W] [--ba-iterations K] [--json FILE]
//                 [--engine-scenario NAME] [--engine-frames N] [--engine-seed S]
//                 [--engine-object-ba W]   (object_ba_window_frames; default: the option's)
//                 [--engine-objects-split N]
//                 [--engine-extra-keypoints 0|1] (SlamOptions::extra_camera_keypoints;
//                                 default: the option's)
#include <time.h>

#include <algorithm>
#include <cmath>
#include <cstdio>
#include <cstdlib>
#include <fstream>
#include <opencv2/imgproc.hpp>
#include <random>
#include <sstream>
#include <string>
#include <vector>

#include "absl/status/statusor.h"
#include "slam/common/timer.h"
#include "slam/objects/dynamic_ba.h"
#include "slam/objects/flow_association.h"
#include "slam/objects/masked_stereo.h"
#include "slam/objects/object_ba.h"
#include "slam/objects/object_tracker.h"
#include "slam/sim/depth_truth.h"
#include "slam/sim/renderer.h"
#include "slam/semantic/panoptic.h"
#include "slam/sim/scenarios.h"
#include "slam/system/slam_system.h"
#include "tests/slam/objects/car_sequence.h"

namespace {

using twist::geometry::SE3d;
using namespace twist::objects;           // NOLINT
using namespace twist::objects::testing;  // NOLINT

// CPU time of the calling thread (the machine may be shared: wall time alone
// over-states the cost under contention).
double ThreadCpuMs() {
  timespec ts;
  clock_gettime(CLOCK_THREAD_CPUTIME_ID, &ts);
  return ts.tv_sec * 1e3 + ts.tv_nsec * 1e-6;
}

// CPU time of the whole process (all threads: the engine extracts the right
// image's ORB on a second thread).
double ProcessCpuMs() {
  timespec ts;
  clock_gettime(CLOCK_PROCESS_CPUTIME_ID, &ts);
  return ts.tv_sec * 1e3 + ts.tv_nsec * 1e-6;
}

double Percentile(std::vector<double> v, double p) {
  if (v.empty()) return 0.0;
  std::sort(v.begin(), v.end());
  const size_t i =
      std::min(v.size() - 1, static_cast<size_t>(p * static_cast<double>(v.size() - 1) + 0.5));
  return v[i];
}

double Mean(const std::vector<double>& v) {
  double m = 0.0;
  for (double x : v) m += x / static_cast<double>(v.size());
  return m;
}

std::string Stats(const std::vector<double>& v) {
  std::ostringstream s;
  s << "{\"median\": " << Percentile(v, 0.5) << ", \"p95\": " << Percentile(v, 0.95)
    << ", \"n\": " << v.size() << "}";
  return s.str();
}

// Merges the frames of several car sequences (same camera motion).
ObjectFrameInput Merge(std::vector<ObjectFrameInput> frames) {
  ObjectFrameInput out = frames[0];
  for (size_t k = 1; k < frames.size(); ++k) {
    const ObjectFrameInput& f = frames[k];
    out.keypoints.uv.insert(out.keypoints.uv.end(), f.keypoints.uv.begin(), f.keypoints.uv.end());
    out.keypoints.u_right.insert(
        out.keypoints.u_right.end(), f.keypoints.u_right.begin(), f.keypoints.u_right.end());
    out.keypoints.descriptors.push_back(f.keypoints.descriptors);
    out.detections.insert(out.detections.end(), f.detections.begin(), f.detections.end());
    for (int y = 0; y < f.flow.rows; ++y) {
      for (int x = 0; x < f.flow.cols; ++x) {
        const cv::Vec2f v = f.flow.at<cv::Vec2f>(y, x);
        if (v[0] != 0.0f || v[1] != 0.0f) out.flow.at<cv::Vec2f>(y, x) = v;
      }
    }
  }
  return out;
}

struct RunResult {
  std::vector<double> track_ms_per_object, track_ms_per_frame, ba_solve_ms, ba_total_ms;
  std::vector<double> track_cpu_ms_per_object, ba_solve_cpu_ms;
  int ba_terms_static = 0, ba_terms_dynamic = 0, ba_terms_cv = 0;
};

RunResult Run(int num_cars, int frames, int window, int ba_iterations) {
  std::vector<CarSequence> cars;
  const double lateral[5] = {3.0, -3.0, 6.5, -6.5, 0.0};
  for (int c = 0; c < num_cars; ++c)
    cars.emplace_back(0.5, 100 + static_cast<uint64_t>(c), lateral[c], 60);
  ObjectTracker tracker(cars[0].camera(), ObjectTrackerOptions{});
  // Static street points for the BA.
  std::mt19937_64 rng(7);
  std::uniform_real_distribution<double> uz(8.0, 60.0), uy(-4.0, 1.6), ux(-7.0, 7.0);
  std::normal_distribution<double> noise(0.0, 0.5);
  std::vector<Eigen::Vector3d> street;
  for (int j = 0; j < 300; ++j) {
    street.push_back(j % 3 == 0 ? Eigen::Vector3d(ux(rng), 1.65, uz(rng))
                                : Eigen::Vector3d(j % 3 == 1 ? -9.0 : 9.0, uy(rng), uz(rng)));
  }
  std::vector<ObjectFrameInput> history;
  RunResult r;
  for (int i = 0; i < frames; ++i) {
    std::vector<ObjectFrameInput> parts;
    for (int c = 0; c < num_cars; ++c)
      parts.push_back(cars[static_cast<size_t>(c)].Next(c + 1, true));
    ObjectFrameInput frame = Merge(std::move(parts));
    twist::Stopwatch sw;
    const double cpu0 = ThreadCpuMs();
    const auto results = tracker.Process(frame);
    const double ms = sw.ElapsedMs();
    const double cpu_ms = ThreadCpuMs() - cpu0;
    if (!results.ok()) {
      std::fprintf(
          stderr, "tracking failed: %s\n", std::string(results.status().message()).c_str());
      std::exit(1);
    }
    if (i > 0) {
      r.track_ms_per_frame.push_back(ms);
      r.track_ms_per_object.push_back(ms / num_cars);
      r.track_cpu_ms_per_object.push_back(cpu_ms / num_cars);
    }
    frame.flow = cv::Mat();  // keep the history light
    frame.left = cv::Mat();
    history.push_back(std::move(frame));
    if (static_cast<int>(history.size()) < window) continue;
    // Dynamic BA over the last `window` frames.
    twist::Stopwatch total;
    DynamicBaProblem problem;
    problem.camera = cars[0].camera();
    std::map<int64_t, int> keyframe_of_frame;
    const size_t first = history.size() - static_cast<size_t>(window);
    for (size_t k = first; k < history.size(); ++k) {
      BaKeyframe kf;
      kf.id = history[k].frame_index;
      kf.timestamp_ns = history[k].timestamp_ns;
      kf.camera_from_world = history[k].camera_from_world;
      kf.fixed = k == first;
      keyframe_of_frame[history[k].frame_index] = static_cast<int>(problem.keyframes.size());
      problem.keyframes.push_back(kf);
    }
    for (size_t j = 0; j < street.size(); ++j) {
      BaStaticPoint sp;
      sp.id = static_cast<int64_t>(j);
      sp.point_in_world = street[j];
      problem.points.push_back(sp);
      for (size_t k = 0; k < problem.keyframes.size(); ++k) {
        Eigen::Vector3d uvr;
        if (!problem.camera.ProjectStereoChecked(
                problem.keyframes[k].camera_from_world * street[j], &uvr, nullptr, 1.0) ||
            !problem.camera.InImage(uvr.head<2>(), 5) || uvr.z() < 0) {
          continue;
        }
        BaObservation o;
        o.keyframe = static_cast<int>(k);
        o.point = static_cast<int>(j);
        o.uv = uvr.head<2>() + Eigen::Vector2d(noise(rng), noise(rng));
        o.u_right = uvr.z() + noise(rng);
        problem.observations.push_back(o);
      }
    }
    const auto links =
        AddTrackedObjectsToBa(tracker, keyframe_of_frame, ObjectBaOptions{}, &problem);
    DynamicBaOptions options;
    options.max_iterations = ba_iterations;
    twist::Stopwatch solve;
    const double solve_cpu0 = ThreadCpuMs();
    const auto summary = SolveDynamicBa(&problem, options);
    const double solve_ms = solve.ElapsedMs();
    r.ba_solve_cpu_ms.push_back(ThreadCpuMs() - solve_cpu0);
    if (!summary.ok()) {
      std::fprintf(stderr, "BA failed: %s\n", std::string(summary.status().message()).c_str());
      std::exit(1);
    }
    ApplyBaToTrackedObjects(problem, links, ObjectBaOptions{}, &tracker);
    r.ba_solve_ms.push_back(solve_ms);
    r.ba_total_ms.push_back(total.ElapsedMs());
    r.ba_terms_static = summary->num_static_terms;
    r.ba_terms_dynamic = summary->num_dynamic_terms;
    r.ba_terms_cv = summary->num_const_velocity_terms;
  }
  return r;
}

struct EngineResult {
  std::vector<double> total_ms, objects_ms, objects_ba_ms;
  std::vector<double> process_cpu_ms;  // CPU time of the whole process during Process()
  std::vector<double> num_tracked;     // objects tracked (not lost) per frame
  int max_tracked = 0;
  int frames = 0;
  int lost_frames = 0;
  int object_ba_window = 0;
  // Wall time of the whole stream, frames fed back to back (rendered
  // beforehand) and the background mapping drained by Shutdown().
  double stream_s = 0.0;
};

// A rendered scenario's frames, rendered once for all the engine runs.
struct EngineStream {
  twist::geometry::StereoCamera camera;
  std::vector<twist::StereoFrame> frames;
};

absl::StatusOr<EngineStream> RenderStream(const std::string& scenario_name,
                                          int frames,
                                          uint64_t seed) {
  auto scenario = twist::sim::MakeScenario(scenario_name, seed, frames);
  if (!scenario.ok()) return scenario.status();
  twist::sim::RenderOptions ro;
  ro.gray = true;
  twist::sim::Renderer renderer(scenario->camera, ro);
  EngineStream stream;
  stream.camera = scenario->camera;
  for (int k = 0; k < frames; ++k) {
    twist::sim::Exposure left, right;
    left.noise_seed = 2 * static_cast<uint64_t>(k) + 1;
    right.noise_seed = 2 * static_cast<uint64_t>(k) + 2;
    const twist::sim::StereoRender img = renderer.RenderStereo(
        scenario->scene, scenario->TimeOf(k), scenario->WorldFromCamera(k), left, right);
    stream.frames.push_back(twist::sim::ScenarioStereoFrame(*scenario, k, img));
  }
  return stream;
}

// The whole engine (default SlamOptions, but for the objects' BA window and
// extra_camera_keypoints) on `stream`, with the mapping in
// Process() (synchronous, as the tests run it) or in its own thread
// (background, as the service runs it).
absl::StatusOr<EngineResult> RunEngine(const EngineStream& stream,
                                       int object_ba_window,
                                       bool extra_camera_keypoints,
                                       twist::MappingMode mapping) {
  twist::SessionConfig config;
  config.camera = stream.camera;
  config.options.extra_camera_keypoints = extra_camera_keypoints;
  if (object_ba_window >= 0) config.options.object_ba_window_frames = object_ba_window;
  config.options.mapping_mode = mapping;
  auto sys = twist::SlamSystem::Create(config);
  if (!sys.ok()) return sys.status();
  EngineResult r;
  r.object_ba_window = config.options.object_ba_window_frames;
  twist::Stopwatch wall;
  for (const twist::StereoFrame& f : stream.frames) {
    const double cpu0 = ProcessCpuMs();
    auto out = (*sys)->Process(f);
    r.process_cpu_ms.push_back(ProcessCpuMs() - cpu0);
    if (!out.ok()) return out.status();
    ++r.frames;
    if (out->state == twist::TrackingState::kLost) ++r.lost_frames;
    double objects_ms = 0.0, ba_ms = 0.0;
    for (const twist::StageTiming& t : out->timings) {
      if (t.stage == "total") r.total_ms.push_back(t.ms);
      if (t.stage == "objects") objects_ms = t.ms;
      if (t.stage == "objects_ba") ba_ms = t.ms;
    }
    r.objects_ms.push_back(objects_ms);
    r.objects_ba_ms.push_back(ba_ms);
    int tracked = 0;
    for (const twist::ObjectResult& o : out->objects)
      tracked += o.state != twist::ObjectState::kLost;
    r.num_tracked.push_back(tracked);
    r.max_tracked = std::max(r.max_tracked, tracked);
  }
  (*sys)->Shutdown();
  r.stream_s = wall.ElapsedMs() * 1e-3;
  return r;
}

}  // namespace

int main(int argc, char** argv) {
  int frames = 40;
  int window = 10;
  int ba_iterations = 5;
  std::string json_path;
  std::string engine_scenario = "driving";
  int engine_frames = 60;
  uint64_t engine_seed = 1;
  int engine_object_ba = -1;  // -1: SlamOptions default
  bool extra_keypoints = twist::SlamOptions().extra_camera_keypoints;
  int split = 5;              // tracked objects per frame (issue #5's "up to 5")
  for (int i = 1; i < argc; ++i) {
    const std::string a = argv[i];
    const bool has_value = i + 1 < argc;
    if (a == "--frames" && has_value) {
      frames = std::atoi(argv[++i]);
    } else if (a == "--window" && has_value) {
      window = std::atoi(argv[++i]);
    } else if (a == "--ba-iterations" && has_value) {
      ba_iterations = std::atoi(argv[++i]);
    } else if (a == "--json" && has_value) {
      json_path = argv[++i];
    } else if (a == "--engine-scenario" && has_value) {
      engine_scenario = argv[++i];
    } else if (a == "--engine-frames" && has_value) {
      engine_frames = std::atoi(argv[++i]);
    } else if (a == "--engine-object-ba" && has_value) {
      engine_object_ba = std::atoi(argv[++i]);
    } else if (a == "--engine-objects-split" && has_value) {
      split = std::atoi(argv[++i]);
    } else if (a == "--engine-extra-keypoints" && has_value) {
      extra_keypoints = std::atoi(argv[++i]) != 0;
    } else if (a == "--engine-seed" && has_value) {
      engine_seed = static_cast<uint64_t>(std::atoll(argv[++i]));
    } else {
      std::fprintf(
          stderr,
          "usage: objects_bench [--frames N] [--window W] [--ba-iterations K] [--json FILE]\n"
          "                     [--engine-scenario NAME] [--engine-frames N] [--engine-seed S]\n"
          "                     [--engine-object-ba W] [--engine-objects-split N]\n"
          "                     [--engine-extra-keypoints 0|1]\n");
      return 2;
    }
  }
  if (frames < 2 || window < 3 || window > frames || ba_iterations < 1 || split < 0) {
    std::fprintf(stderr,
                 "objects_bench: need frames >= 2, 3 <= window <= frames, ba-iterations >= 1, "
                 "engine-objects-split >= 0\n");
    return 2;
  }
  std::ostringstream json;
  json << "{\"frames\": " << frames << ", \"window\": " << window
       << ", \"ba_iterations\": " << ba_iterations;
  for (int cars : {1, 5}) {
    const RunResult r = Run(cars, frames, window, ba_iterations);
    std::printf(
        "%d object(s): tracking %.2f ms/object (p95 %.2f; CPU %.2f, p95 %.2f), %.2f ms/frame (p95 "
        "%.2f); "
        "dynamic BA solve %.1f ms (p95 %.1f; CPU %.1f, p95 %.1f), build+solve %.1f ms (p95 %.1f) "
        "[%d static, %d dynamic, %d const-velocity terms]\n",
        cars,
        Percentile(r.track_ms_per_object, 0.5),
        Percentile(r.track_ms_per_object, 0.95),
        Percentile(r.track_cpu_ms_per_object, 0.5),
        Percentile(r.track_cpu_ms_per_object, 0.95),
        Percentile(r.track_ms_per_frame, 0.5),
        Percentile(r.track_ms_per_frame, 0.95),
        Percentile(r.ba_solve_ms, 0.5),
        Percentile(r.ba_solve_ms, 0.95),
        Percentile(r.ba_solve_cpu_ms, 0.5),
        Percentile(r.ba_solve_cpu_ms, 0.95),
        Percentile(r.ba_total_ms, 0.5),
        Percentile(r.ba_total_ms, 0.95),
        r.ba_terms_static,
        r.ba_terms_dynamic,
        r.ba_terms_cv);
    json << ", \"objects_" << cars
         << "\": {\"track_ms_per_object\": " << Stats(r.track_ms_per_object)
         << ", \"track_cpu_ms_per_object\": " << Stats(r.track_cpu_ms_per_object)
         << ", \"track_ms_per_frame\": " << Stats(r.track_ms_per_frame)
         << ", \"ba_solve_ms\": " << Stats(r.ba_solve_ms)
         << ", \"ba_solve_cpu_ms\": " << Stats(r.ba_solve_cpu_ms)
         << ", \"ba_build_solve_ms\": " << Stats(r.ba_total_ms)
         << ", \"ba_static_terms\": " << r.ba_terms_static
         << ", \"ba_dynamic_terms\": " << r.ba_terms_dynamic
         << ", \"ba_const_velocity_terms\": " << r.ba_terms_cv << "}";
  }
  // Sparse LK on a textured image: 60 points, like one car without client flow.
  {
    std::mt19937_64 rng(3);
    std::uniform_int_distribution<int> u(0, 255);
    cv::Mat img(376, 1241, CV_8UC1);
    for (int y = 0; y < img.rows; ++y) {
      for (int x = 0; x < img.cols; ++x) img.at<uint8_t>(y, x) = static_cast<uint8_t>(u(rng));
    }
    cv::GaussianBlur(img, img, cv::Size(0, 0), 1.5);
    cv::Mat next;
    const cv::Mat m = (cv::Mat_<double>(2, 3) << 1, 0, 4.3, 0, 1, -1.7);
    cv::warpAffine(img, next, m, img.size(), cv::INTER_LINEAR, cv::BORDER_REFLECT);
    std::vector<Eigen::Vector2d> pts;
    std::uniform_real_distribution<double> px(100, 1100), py(50, 320);
    for (int k = 0; k < 60; ++k) pts.emplace_back(px(rng), py(rng));
    std::vector<double> lk;
    for (int rep = 0; rep < 30; ++rep) {
      twist::Stopwatch sw;
      const auto t = TrackSparseFlow(img, next, pts, SparseFlowOptions{});
      lk.push_back(sw.ElapsedMs());
      if (!t.ok()) return 1;
    }
    std::printf("sparse LK (forward-backward), 60 points, 1241x376: %.2f ms (p95 %.2f)\n",
                Percentile(lk, 0.5),
                Percentile(lk, 0.95));
    json << ", \"sparse_flow_60_points_ms\": " << Stats(lk);
  }
  // Masked stereo (MaskedDisparity: the objects' points, the road's points
  // and the static keypoints beside the cars are measured with it, ~800
  // times a frame on 'driving'): every 6th pixel of the cars of a rendered
  // frame, from the true disparity rounded, 8 px half-windows.
  {
    auto scenario = twist::sim::MakeScenario("driving", 1, 20);
    if (!scenario.ok()) return 1;
    twist::sim::RenderOptions ro;
    ro.gray = true;
    const twist::sim::Renderer renderer(scenario->camera, ro);
    const twist::sim::StereoRender img = twist::sim::RenderScenarioFrame(renderer, *scenario, 10);
    const cv::Mat cars = twist::semantic::ClassMask(img.panoptic, 26);
    const double bf = scenario->camera.fx * scenario->camera.baseline;
    std::vector<std::pair<Eigen::Vector2d, double>> queries;
    for (int y = 20; y + 20 < cars.rows; y += 6) {
      for (int x = 40; x + 40 < cars.cols; x += 6) {
        const float z = img.depth.at<float>(y, x);
        if (cars.at<uint8_t>(y, x) == 0 || !(z > 0.f) || !std::isfinite(z)) continue;
        queries.emplace_back(Eigen::Vector2d(x, y), std::round(bf / z));
      }
    }
    std::vector<double> per_call_us;
    int measured = 0;
    for (int rep = 0; rep < 15; ++rep) {
      measured = 0;
      const double cpu0 = ThreadCpuMs();
      for (const auto& [uv, d0] : queries)
        measured += MaskedDisparity(img.left, img.right, cars, uv, d0, 8.0).has_value();
      per_call_us.push_back((ThreadCpuMs() - cpu0) * 1e3 / std::max<size_t>(1, queries.size()));
    }
    std::printf("masked stereo, %zu points on the cars of a rendered frame (%d measured): %.2f "
                "us/point of thread CPU (p95 %.2f)\n",
                queries.size(),
                measured,
                Percentile(per_call_us, 0.5),
                Percentile(per_call_us, 0.95));
    json << ", \"masked_disparity_us_per_point\": " << Stats(per_call_us);
  }
  absl::StatusOr<EngineStream> stream = EngineStream{};
  if (engine_frames > 0) stream = RenderStream(engine_scenario, engine_frames, engine_seed);
  if (!stream.ok()) {
    std::fprintf(
        stderr, "objects_bench: engine scenario: %s\n", stream.status().ToString().c_str());
    return 1;
  }
  for (const auto& [mapping, mode_name] :
       {std::pair{twist::MappingMode::kSynchronous, "synchronous"},
        std::pair{twist::MappingMode::kBackground, "background"}}) {
    if (engine_frames <= 0) break;
    const absl::StatusOr<EngineResult> e =
        RunEngine(*stream, engine_object_ba, extra_keypoints, mapping);
    if (!e.ok()) {
      std::fprintf(stderr, "objects_bench: engine run: %s\n", e.status().ToString().c_str());
      return 1;
    }
    const double mean_total = Mean(e->total_ms), mean_tracked = Mean(e->num_tracked);
    const double median = Percentile(e->total_ms, 0.5);
    std::printf(
        "engine on '%s', %s mapping (%d frames, object BA window %d%s): stream %.1f frames/s "
        "(wall, frames back to back); total %.1f ms/frame (p95 %.1f, mean "
        "%.1f) "
        "= %.1f frames/s at the median, %.1f at the mean; objects stage %.1f ms (p95 %.1f), of "
        "which dynamic BA %.1f ms (p95 %.1f); process CPU %.1f ms/frame (p95 %.1f, = %.1f "
        "frames/s on one core); tracked objects per frame mean %.1f, max %d; %d lost frames\n",
        engine_scenario.c_str(),
        mode_name,
        e->frames,
        e->object_ba_window,
        extra_keypoints ? ", extra camera keypoints" : ", no extra camera keypoints",
        e->stream_s > 0.0 ? e->frames / e->stream_s : 0.0,
        median,
        Percentile(e->total_ms, 0.95),
        mean_total,
        median > 0.0 ? 1000.0 / median : 0.0,
        mean_total > 0.0 ? 1000.0 / mean_total : 0.0,
        Percentile(e->objects_ms, 0.5),
        Percentile(e->objects_ms, 0.95),
        Percentile(e->objects_ba_ms, 0.5),
        Percentile(e->objects_ba_ms, 0.95),
        Percentile(e->process_cpu_ms, 0.5),
        Percentile(e->process_cpu_ms, 0.95),
        Percentile(e->process_cpu_ms, 0.5) > 0.0 ? 1000.0 / Percentile(e->process_cpu_ms, 0.5)
                                                 : 0.0,
        mean_tracked,
        e->max_tracked,
        e->lost_frames);
    // Issue #5 asks for 10 frames/s with up to 5 tracked objects: the
    // Process() wall time of the frames with at most `split` objects against
    // the others. With the mapping in its own thread the stream runs at
    // about 1000 / mean ms when that thread keeps up.
    std::vector<double> few_ms, many_ms;
    for (size_t k = 0; k < e->total_ms.size(); ++k) {
      (e->num_tracked[k] <= split ? few_ms : many_ms).push_back(e->total_ms[k]);
    }
    std::printf(
        "  frames with <= %d tracked objects: %zu, Process %.1f ms median, %.1f mean (= %.1f "
        "frames/s); with more: %zu, %.1f median, %.1f mean (= %.1f frames/s)\n",
        split,
        few_ms.size(),
        Percentile(few_ms, 0.5),
        Mean(few_ms),
        few_ms.empty() ? 0.0 : 1000.0 / Mean(few_ms),
        many_ms.size(),
        Percentile(many_ms, 0.5),
        Mean(many_ms),
        many_ms.empty() ? 0.0 : 1000.0 / Mean(many_ms));
    json << ", \"engine_" << mode_name << "\": {\"scenario\": \"" << engine_scenario
         << "\", \"frames\": " << e->frames
         << ", \"extra_camera_keypoints\": " << (extra_keypoints ? "true" : "false")
         << ", \"stream_frames_per_s\": " << (e->stream_s > 0.0 ? e->frames / e->stream_s : 0.0)
         << ", \"total_ms\": " << Stats(e->total_ms) << ", \"mean_total_ms\": " << mean_total
         << ", \"objects_ms\": " << Stats(e->objects_ms)
         << ", \"objects_ba_ms\": " << Stats(e->objects_ba_ms)
         << ", \"process_cpu_ms\": " << Stats(e->process_cpu_ms)
         << ", \"mean_tracked_objects\": " << mean_tracked
         << ", \"max_tracked_objects\": " << e->max_tracked << ", \"objects_split\": " << split
         << ", \"total_ms_at_most_split\": " << Stats(few_ms)
         << ", \"total_ms_above_split\": " << Stats(many_ms) << "}";
  }
  json << "}\n";
  if (json_path.empty()) {
    std::printf("%s", json.str().c_str());
  } else {
    std::ofstream(json_path) << json.str();
  }
  return 0;
}
