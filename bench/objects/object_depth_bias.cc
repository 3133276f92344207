// Depth bias of the object points (issue #5): runs generated scenarios
// through the engine's front end (ORB with favoured dynamic segments, stereo
// matching) and the object stage, with ground-truth camera poses, and
// compares every object observation with the renderer's exact depth.
//
// For every inlier observation of a tracked object in a frame it reports, as
// signed ratio (z / z_true − 1) and metres (z − z_true):
//   meas   the observation's own stereo depth bf / (u − u_right);
//   model  the depth of the object point as the tracker holds it
//          (camera_from_world · world_from_object · p_o);
// where z_true is the rendered depth at the keypoint (the pixel the point is
// observed at). The rows split the observations by: creation frame vs later
// frames, distance of the keypoint to the instance mask's border, ORB pyramid
// level, depth, moving vs parked (ground truth), and whether the 9×9 window
// around the keypoint lies on one plane of the depth buffer (a block matcher
// has one true disparity there) or straddles a depth edge.
//
// Later observations are also compared with the true projection of the
// physical point they were created on: "along" (mean, then median) is the
// error along that point's true image motion since the previous frame
// (> 0: the observation is ahead of the point), "ddisp+" the disparity error
// signed by the true disparity's change (> 0: the change is overestimated).
// The steps table's "turn excess" is the estimated minus the true rotation
// of a step about the true axis (> 0: the object turned too far), and its
// "turning" row the steps whose true rotation exceeds 1°.
//
//   object_depth_bias [--scenario driving,follow_braking] [--frames 100]
//                     [--seed 1] [--ba 10] [--masked-stereo 1] [--json FILE]
// --masked-stereo 0 gives the object stage no right image, so object depths
// are the engine matcher's (ObjectTrackerOptions::masked_stereo has no effect).
#include <glog/logging.h>

#include <algorithm>
#include <cmath>
#include <cstdio>
#include <cstdlib>
#include <cstring>
#include <functional>
#include <map>
#include <set>
#include <sstream>
#include <string>
#include <unordered_map>
#include <vector>

#include <Eigen/Geometry>
#include <opencv2/imgproc.hpp>

#include "slam/features/orb_extractor.h"
#include "slam/features/stereo_matcher.h"
#include "slam/map/map.h"
#include "slam/sim/depth_truth.h"
#include "slam/sim/renderer.h"
#include "slam/sim/scenarios.h"
#include "slam/sim/writer.h"
#include "slam/system/object_stage.h"
#include "slam/system/slam_options.h"

namespace twist {
namespace {

using geometry::SE3d;

struct Sample {
  bool creation = false;
  bool parked = false;
  bool planar = false;  // 9×9 window on one depth plane
  bool stereo = false;
  int level = 0;
  double border_px = 0.0;
  double z_true = 0.0;
  double z_meas = 0.0;   // 0 when mono
  double z_model = 0.0;
  int object_age = 0;    // frames since the object was created
  // Later frames: the observation against the true projection of the
  // physical point the object point was created on (the rendered surface
  // under its creation pixel, carried by the true object motion).
  bool has_truth_proj = false;
  double du = 0.0, dv = 0.0;  // observed − true pixel
  double ddisp = 0.0;         // observed − true disparity (stereo only)
  double expansion = 0.0;     // (observed − true) along the ray from the object's image centre,
                              // divided by the true distance to that centre
  double true_scale_step = 0.0;  // true image scale change since the previous frame (ratio − 1)
  double along = 0.0;  // (observed − true) along the true image motion since the previous frame
  bool has_along = false;
  double ddisp_along = 0.0;  // ddisp signed by the true disparity's change since the previous frame
  bool has_ddisp_along = false;
  bool turning = false;  // the object turned by more than 1° over the step
};

double Median(std::vector<double> v) {
  if (v.empty()) return std::nan("");
  std::nth_element(v.begin(), v.begin() + static_cast<long>(v.size() / 2), v.end());
  return v[v.size() / 2];
}

double Mean(const std::vector<double>& v) {
  if (v.empty()) return std::nan("");
  double s = 0.0;
  for (double x : v) s += x;
  return s / static_cast<double>(v.size());
}

// One frame step of a tracked object, against the ground truth: the
// estimated world motion of the step, M = P(i) P(i−1)⁻¹, and the true one
// applied to the true box centre at i−1; the error split along the ray from
// the camera to the object ("radial", + = away from the camera) and across it.
struct Step {
  bool parked = false;
  bool stationary = false;
  double distance = 0.0;    // camera -> true box centre (m)
  double rel_radial = 0.0;  // true change of that distance over the step (m)
  double err_radial = 0.0;  // estimated − true box centre displacement, along the ray (m)
  double err_lateral = 0.0;
  double speed_err_kmh = 0.0;  // |reported speed − true speed|
  double rot_err_deg = 0.0;    // angle of the step's rotation error
  double turn_deg = 0.0;       // the true step's rotation angle
  double turn_excess_deg = 0.0;  // estimated − true rotation about the true axis
};

struct Row {
  std::string name;
  std::vector<double> meas_ratio, meas_m, model_ratio, model_m;
  void Add(const Sample& s) {
    if (s.stereo) {
      meas_ratio.push_back(s.z_meas / s.z_true - 1.0);
      meas_m.push_back(s.z_meas - s.z_true);
    }
    model_ratio.push_back(s.z_model / s.z_true - 1.0);
    model_m.push_back(s.z_model - s.z_true);
  }
};

void PrintRows(const std::string& title, const std::vector<Row>& rows, std::ostringstream* json) {
  std::printf("\n%s\n", title.c_str());
  std::printf("  %-26s %7s %9s %9s %8s | %7s %9s %9s %8s\n",
              "group",
              "n_meas",
              "med %",
              "mean %",
              "med m",
              "n_model",
              "med %",
              "mean %",
              "med m");
  for (const Row& r : rows) {
    if (r.model_ratio.empty()) continue;
    std::printf("  %-26s %7zu %+9.2f %+9.2f %+8.3f | %7zu %+9.2f %+9.2f %+8.3f\n",
                r.name.c_str(),
                r.meas_ratio.size(),
                100.0 * Median(r.meas_ratio),
                100.0 * Mean(r.meas_ratio),
                Median(r.meas_m),
                r.model_ratio.size(),
                100.0 * Median(r.model_ratio),
                100.0 * Mean(r.model_ratio),
                Median(r.model_m));
    *json << "{\"table\":\"" << title << "\",\"group\":\"" << r.name
          << "\",\"n_meas\":" << r.meas_ratio.size()
          << ",\"meas_median_ratio\":" << Median(r.meas_ratio)
          << ",\"meas_median_m\":" << Median(r.meas_m) << ",\"n_model\":" << r.model_ratio.size()
          << ",\"model_median_ratio\":" << Median(r.model_ratio)
          << ",\"model_median_m\":" << Median(r.model_m) << "},\n";
  }
}

void Report(const std::string& scenario, const std::vector<Sample>& samples, std::ostringstream* json) {
  auto split = [&](const std::string& title,
                   const std::vector<std::pair<std::string, std::function<bool(const Sample&)>>>&
                       groups) {
    std::vector<Row> rows;
    for (const auto& [name, pred] : groups) {
      Row r;
      r.name = name;
      for (const Sample& s : samples)
        if (pred(s)) r.Add(s);
      rows.push_back(std::move(r));
    }
    PrintRows(scenario + ": " + title, rows, json);
  };
  split("all / creation vs later",
        {{"all", [](const Sample&) { return true; }},
         {"creation frame", [](const Sample& s) { return s.creation; }},
         {"later frames", [](const Sample& s) { return !s.creation; }},
         {"later, object age 1-3", [](const Sample& s) { return !s.creation && s.object_age <= 3; }},
         {"later, object age 4-10",
          [](const Sample& s) { return !s.creation && s.object_age > 3 && s.object_age <= 10; }},
         {"later, object age > 10", [](const Sample& s) { return !s.creation && s.object_age > 10; }}});
  split("moving vs parked",
        {{"moving, creation", [](const Sample& s) { return !s.parked && s.creation; }},
         {"moving, later", [](const Sample& s) { return !s.parked && !s.creation; }},
         {"parked, creation", [](const Sample& s) { return s.parked && s.creation; }},
         {"parked, later", [](const Sample& s) { return s.parked && !s.creation; }}});
  split("distance to the mask border (creation)",
        {{"border < 3 px", [](const Sample& s) { return s.creation && s.border_px < 3; }},
         {"border 3-6 px",
          [](const Sample& s) { return s.creation && s.border_px >= 3 && s.border_px < 6; }},
         {"border 6-10 px",
          [](const Sample& s) { return s.creation && s.border_px >= 6 && s.border_px < 10; }},
         {"border 10-20 px",
          [](const Sample& s) { return s.creation && s.border_px >= 10 && s.border_px < 20; }},
         {"border >= 20 px", [](const Sample& s) { return s.creation && s.border_px >= 20; }}});
  std::vector<std::pair<std::string, std::function<bool(const Sample&)>>> levels;
  for (int l = 0; l < 8; ++l) {
    levels.push_back({"level " + std::to_string(l) + " (creation)",
                      [l](const Sample& s) { return s.creation && s.level == l; }});
  }
  levels.push_back({"patch match (later)", [](const Sample& s) { return !s.creation && s.level < 0; }});
  for (int l = 0; l < 8; ++l) {
    levels.push_back({"level " + std::to_string(l) + " (later)",
                      [l](const Sample& s) { return !s.creation && s.level == l; }});
  }
  split("pyramid level", levels);
  split("depth (creation)",
        {{"z < 10 m", [](const Sample& s) { return s.creation && s.z_true < 10; }},
         {"z 10-20 m", [](const Sample& s) { return s.creation && s.z_true >= 10 && s.z_true < 20; }},
         {"z 20-30 m", [](const Sample& s) { return s.creation && s.z_true >= 20 && s.z_true < 30; }},
         {"z >= 30 m", [](const Sample& s) { return s.creation && s.z_true >= 30; }}});
  split("planar window vs depth edge (creation)",
        {{"planar 9x9 window", [](const Sample& s) { return s.creation && s.planar; }},
         {"depth edge in window", [](const Sample& s) { return s.creation && !s.planar; }}});
}

void ReportObservations(const std::string& scenario, const std::vector<Sample>& samples) {
  std::printf("\n%s: later observations against the true projection of their creation point\n",
              scenario.c_str());
  std::printf("  %-28s %6s %8s %8s %8s %9s %10s %10s %8s %8s %8s %8s\n",
              "group",
              "n",
              "med du",
              "med dv",
              "med |d|",
              "med ddisp",
              "expansion",
              "true scale",
              "along",
              "med al",
              "ddisp+",
              "med dd+");
  auto row = [&](const std::string& name, const std::function<bool(const Sample&)>& pred) {
    std::vector<double> du, dv, dn, dd, ex, ts, al, da;
    for (const Sample& s : samples) {
      if (!s.has_truth_proj || !pred(s)) continue;
      du.push_back(s.du);
      dv.push_back(s.dv);
      dn.push_back(std::hypot(s.du, s.dv));
      if (s.stereo) dd.push_back(s.ddisp);
      if (s.expansion != 0.0) ex.push_back(s.expansion);
      ts.push_back(s.true_scale_step);
      if (s.has_along) al.push_back(s.along);
      if (s.has_ddisp_along) da.push_back(s.ddisp_along);
    }
    if (du.empty()) return;
    std::printf(
        "  %-28s %6zu %+8.3f %+8.3f %8.3f %+9.3f %+10.4f %+10.4f %+8.3f %+8.3f %+8.3f %+8.3f\n",
        name.c_str(),
        du.size(),
        Median(du),
        Median(dv),
        Median(dn),
        Median(dd),
        Median(ex),
        Median(ts),
        Mean(al),
        Median(al),
        Mean(da),
        Median(da));
  };
  row("all", [](const Sample&) { return true; });
  row("keypoint match", [](const Sample& s) { return s.level >= 0; });
  row("patch match", [](const Sample& s) { return s.level < 0; });
  row("moving", [](const Sample& s) { return !s.parked; });
  row("moving, keypoint", [](const Sample& s) { return !s.parked && s.level >= 0; });
  row("moving, patch", [](const Sample& s) { return !s.parked && s.level < 0; });
  row("parked", [](const Sample& s) { return s.parked; });
  row("parked, keypoint", [](const Sample& s) { return s.parked && s.level >= 0; });
  row("parked, patch", [](const Sample& s) { return s.parked && s.level < 0; });
  row("approaching (scale > 2 %)", [](const Sample& s) { return s.true_scale_step > 0.02; });
  row("approaching, keypoint", [](const Sample& s) { return s.true_scale_step > 0.02 && s.level >= 0; });
  row("approaching, patch", [](const Sample& s) { return s.true_scale_step > 0.02 && s.level < 0; });
  row("turning", [](const Sample& s) { return s.turning; });
  row("turning, keypoint", [](const Sample& s) { return s.turning && s.level >= 0; });
  row("turning, patch", [](const Sample& s) { return s.turning && s.level < 0; });
  row("border < 6 px", [](const Sample& s) { return s.border_px < 6; });
  row("border >= 6 px", [](const Sample& s) { return s.border_px >= 6; });
  for (int a : {1, 3, 6, 10, 20}) {
    row("object age <= " + std::to_string(a), [a](const Sample& s) { return s.object_age <= a; });
  }
}

void ReportSteps(const std::string& scenario, const std::vector<Step>& steps) {
  std::printf("\n%s: object steps against the ground truth (reported poses and speeds)\n",
              scenario.c_str());
  std::printf("  %-30s %6s %12s %12s %12s %12s %10s %10s %10s\n",
              "group",
              "n",
              "radial m/fr",
              "|lateral| m",
              "rad/relrad",
              "speed km/h",
              "rot deg",
              "stationary",
              "turn excess");
  auto row = [&](const std::string& name, const std::function<bool(const Step&)>& pred) {
    std::vector<double> rad, lat, ratio, spd, rot, exc;
    int still = 0;
    for (const Step& s : steps) {
      if (!pred(s)) continue;
      rad.push_back(s.err_radial);
      lat.push_back(std::abs(s.err_lateral));
      if (std::abs(s.rel_radial) > 0.3) ratio.push_back(s.err_radial / s.rel_radial);
      spd.push_back(s.speed_err_kmh);
      rot.push_back(s.rot_err_deg);
      exc.push_back(s.turn_excess_deg);
      still += s.stationary ? 1 : 0;
    }
    if (rad.empty()) return;
    std::printf("  %-30s %6zu %+12.4f %12.4f %+12.4f %12.3f %10.3f %10d %+10.3f\n",
                name.c_str(),
                rad.size(),
                Mean(rad),
                Mean(lat),
                Median(ratio),
                Mean(spd),
                Mean(rot),
                still,
                Mean(exc));
  };
  row("moving", [](const Step& s) { return !s.parked; });
  row("moving, approaching", [](const Step& s) { return !s.parked && s.rel_radial < -0.3; });
  row("moving, receding", [](const Step& s) { return !s.parked && s.rel_radial > 0.3; });
  row("moving, turning > 1 deg/fr", [](const Step& s) { return !s.parked && s.turn_deg > 1.0; });
  row("moving, z < 15 m", [](const Step& s) { return !s.parked && s.distance < 15; });
  row("moving, z 15-30 m", [](const Step& s) { return !s.parked && s.distance >= 15 && s.distance < 30; });
  row("moving, z >= 30 m", [](const Step& s) { return !s.parked && s.distance >= 30; });
  row("parked", [](const Step& s) { return s.parked; });
  row("parked, not held", [](const Step& s) { return s.parked && !s.stationary; });
  row("parked, z < 15 m", [](const Step& s) { return s.parked && s.distance < 15; });
  row("parked, z 15-30 m", [](const Step& s) { return s.parked && s.distance >= 15 && s.distance < 30; });
  row("parked, z >= 30 m", [](const Step& s) { return s.parked && s.distance >= 30; });
}

int Run(const std::string& name,
        int frames,
        uint32_t seed,
        int ba_window,
        bool masked,
        std::ostringstream* json) {
  absl::StatusOr<sim::Scenario> scenario = sim::MakeScenario(name, seed, frames);
  CHECK(scenario.ok()) << scenario.status();
  const geometry::StereoCamera& cam = scenario->camera;
  sim::Renderer renderer(cam, sim::RenderOptions{});
  SessionConfig config;
  config.camera = cam;
  const SlamOptions& so = config.options;
  features::OrbExtractor orb(OrbOptionsFrom(so));
  ObjectStageOptions stage_options;
  stage_options.ba_window_frames = ba_window;
  stage_options.ba_iterations = so.object_ba_iterations;
  ObjectStage stage(config, stage_options);

  std::vector<Sample> samples;
  std::vector<Step> steps;
  std::map<int64_t, std::pair<int, SE3d>> prev_pose;  // object id -> (frame, world_from_object)
  std::map<int64_t, std::pair<SE3d, SE3d>> first_pose;  // object id -> (est, gt) at its first frame
  const bool trace = std::getenv("TWIST_DEPTH_TRACE") != nullptr;
  std::map<int64_t, std::set<int64_t>> seen;  // object id -> point ids seen before
  std::map<int64_t, int64_t> created_at;       // object id -> frame
  std::map<std::pair<int64_t, int64_t>, Eigen::Vector3d> truth_point;  // (object, point) -> GT object frame
  const double bf = cam.bf();
  for (int i = 0; i < frames; ++i) {
    const sim::StereoRender r = sim::RenderScenarioFrame(renderer, *scenario, i);
    cv::Mat left, right;
    if (r.left.channels() == 3) {
      cv::cvtColor(r.left, left, cv::COLOR_BGR2GRAY);
      cv::cvtColor(r.right, right, cv::COLOR_BGR2GRAY);
    } else {
      left = r.left;
      right = r.right;
    }
    map::FrameFeatures f;
    std::vector<cv::KeyPoint> right_kps;
    cv::Mat right_desc;
    std::vector<cv::Mat> left_levels, right_levels;
    orb.Extract(right, cv::Mat(), &right_kps, &right_desc, &right_levels);
    orb.Extract(left,
                ObjectStage::FavourMask(r.panoptic, config.classes),
                &f.keypoints,
                &f.descriptors,
                &left_levels);
    features::StereoMatchResult st = features::MatchStereo(
        cam, orb.pyramid(), f.keypoints, f.descriptors, right_kps, right_desc, left_levels, right_levels);
    f.u_right = std::move(st.u_right);
    f.depth = std::move(st.depth);
    const int n = f.size();
    f.labels.assign(n, 0);
    f.is_static.assign(n, 1);
    std::unordered_map<uint64_t, int> level_of;
    for (const cv::KeyPoint& k : f.keypoints) {
      uint32_t bx, by;
      std::memcpy(&bx, &k.pt.x, 4);
      std::memcpy(&by, &k.pt.y, 4);
      level_of[(static_cast<uint64_t>(bx) << 32) | by] = k.octave;
    }
    const std::shared_ptr<map::FrameFeatures> features =
        map::FinalizeFeatures(std::move(f), cam.width, cam.height);

    const double t = scenario->TimeOf(i);
    const SE3d world_from_camera = scenario->WorldFromCamera(i);
    ObjectStageInput in;
    in.frame_index = i;
    in.timestamp_ns = static_cast<int64_t>(std::llround(t * 1e9));
    in.left = left;
    if (masked) in.right = right;
    in.panoptic = r.panoptic;
    in.features = features.get();
    in.camera_from_world = world_from_camera.Inverse();
    absl::StatusOr<ObjectStageOutput> out = stage.Process(in);
    CHECK(out.ok()) << out.status();

    for (const ObjectResult& res : out->objects) {
      if (res.state != ObjectState::kTracked) continue;
      const sim::SceneObject* gt = nullptr;
      for (const sim::SceneObject& s : scenario->scene.objects)
        if (s.track_id == res.instance_id && s.class_id == res.class_id) gt = &s;
      auto prev = prev_pose.find(res.id);
      if (gt != nullptr && prev != prev_pose.end() && prev->second.first == i - 1) {
        const double t0 = scenario->TimeOf(i - 1);
        const SE3d gt0 = gt->WorldFromObject(t0), gt1 = gt->WorldFromObject(t);
        const Eigen::Vector3d centre_in_object(0.0, -0.5 * gt->h, 0.0);
        const Eigen::Vector3d c0 = gt0 * centre_in_object, c1 = gt1 * centre_in_object;
        const Eigen::Vector3d c1_est = res.world_from_object * prev->second.second.Inverse() * c0;
        const Eigen::Vector3d cam = world_from_camera.translation();
        const Eigen::Vector3d ray = (c1 - cam).normalized();
        Step st;
        const double gt_speed = (c1 - c0).norm() / (t - t0);
        st.parked = gt_speed < 0.05;
        st.stationary = res.stationary;
        st.distance = (c1 - cam).norm();
        st.rel_radial = st.distance - (c0 - scenario->WorldFromCamera(i - 1).translation()).norm();
        const Eigen::Vector3d e = c1_est - c1;
        st.err_radial = e.dot(ray);
        st.err_lateral = (e - st.err_radial * ray).norm();
        st.speed_err_kmh = 3.6 * std::abs(res.speed_mps - gt_speed);
        const SE3d m_est = res.world_from_object * prev->second.second.Inverse();
        const SE3d m_gt = gt1 * gt0.Inverse();
        st.rot_err_deg = Eigen::AngleAxisd(m_gt.rotation().transpose() * m_est.rotation()).angle() * 180.0 / M_PI;
        const Eigen::AngleAxisd aa_gt(m_gt.rotation());
        const Eigen::AngleAxisd aa_est(m_est.rotation());
        st.turn_deg = aa_gt.angle() * 180.0 / M_PI;
        st.turn_excess_deg =
            ((aa_est.angle() * aa_est.axis()).dot(aa_gt.axis()) - aa_gt.angle()) * 180.0 / M_PI;
        steps.push_back(st);
      }
      prev_pose[res.id] = {static_cast<int>(i), res.world_from_object};
      if (gt != nullptr && trace) {
        if (!first_pose.count(res.id)) first_pose[res.id] = {res.world_from_object, gt->WorldFromObject(t)};
        const auto& [e0, g0] = first_pose[res.id];
        const Eigen::Vector3d centre_in_object(0.0, -0.5 * gt->h, 0.0);
        const Eigen::Vector3d c_true = gt->WorldFromObject(t) * centre_in_object;
        const Eigen::Vector3d c_est = res.world_from_object * e0.Inverse() * g0 * centre_in_object;
        const Eigen::Vector3d cam = world_from_camera.translation();
        const Eigen::Vector3d ray = (c_true - cam).normalized();
        std::printf("TRACE %s obj %lld gt %d frame %d dist %.2f cum_radial %+.3f cum_lat %.3f speed %.2f/%.2f pts %d\n",
                    name.c_str(), static_cast<long long>(res.id), gt->track_id, i, (c_true - cam).norm(),
                    (c_est - c_true).dot(ray), ((c_est - c_true) - (c_est - c_true).dot(ray) * ray).norm(),
                    res.speed_mps, (gt->WorldFromObject(t + 0.05).translation() - gt->WorldFromObject(t - 0.05).translation()).norm() / 0.1,
                    res.num_points);
      }
    }
    for (const auto& [id, o] : stage.tracker().objects()) {
      if (o.history.empty() || o.history.back().frame_index != i) continue;
      if (!created_at.count(id)) created_at[id] = i;
      const sim::SceneObject* gt = nullptr;
      for (const sim::SceneObject& s : scenario->scene.objects)
        if (s.track_id == o.instance_id && s.class_id == o.class_id) gt = &s;
      if (gt == nullptr) continue;
      const double gt_speed =
          (gt->WorldFromObject(t + 0.05).translation() - gt->WorldFromObject(t - 0.05).translation())
              .norm() /
          0.1;
      cv::Mat mask = r.panoptic == gt->panoptic();
      cv::Mat border;
      cv::distanceTransform(mask, border, cv::DIST_L2, 3);
      const SE3d camera_from_object = in.camera_from_world * o.history.back().world_from_object;
      std::unordered_map<int64_t, const objects::ObjectPoint*> point_of;
      for (const objects::ObjectPoint& p : o.points) point_of[p.id] = &p;
      std::set<int64_t>& seen_points = seen[id];
      for (const objects::ObjectPointObservation& ob : o.history.back().observations) {
        auto it = point_of.find(ob.point_id);
        if (it == point_of.end()) continue;
        const int x = static_cast<int>(std::lround(ob.uv.x()));
        const int y = static_cast<int>(std::lround(ob.uv.y()));
        if (x < 0 || y < 0 || x >= r.depth.cols || y >= r.depth.rows) continue;
        Sample s;
        s.creation = seen_points.insert(ob.point_id).second;
        const SE3d gt_wo = gt->WorldFromObject(t);
        const SE3d camera_from_gt = in.camera_from_world * gt_wo;
        const Eigen::Vector3d centre_c = camera_from_gt * Eigen::Vector3d(0.0, -0.5 * gt->h, 0.0);
        if (!s.creation) {
          auto tp = truth_point.find({id, ob.point_id});
          if (tp != truth_point.end()) {
            const Eigen::Vector3d pc = camera_from_gt * tp->second;
            if (pc.z() > 0.5 && centre_c.z() > 0.5) {
              const Eigen::Vector2d uv_true(cam.fx * pc.x() / pc.z() + cam.cx,
                                            cam.fy * pc.y() / pc.z() + cam.cy);
              const Eigen::Vector2d centre_uv(cam.fx * centre_c.x() / centre_c.z() + cam.cx,
                                              cam.fy * centre_c.y() / centre_c.z() + cam.cy);
              s.has_truth_proj = true;
              s.du = ob.uv.x() - uv_true.x();
              s.dv = ob.uv.y() - uv_true.y();
              const Eigen::Vector2d rel = uv_true - centre_uv;
              if (rel.norm() > 5.0) s.expansion = (ob.uv - uv_true).dot(rel) / rel.squaredNorm();
              const SE3d prev_camera_from_gt =
                  scenario->WorldFromCamera(i - 1).Inverse() * gt->WorldFromObject(scenario->TimeOf(i - 1));
              s.true_scale_step = (prev_camera_from_gt * Eigen::Vector3d(0.0, -0.5 * gt->h, 0.0)).z() /
                                      centre_c.z() - 1.0;
              if (ob.u_right >= 0.0) s.ddisp = (ob.uv.x() - ob.u_right) - bf / pc.z();
              const Eigen::Vector3d pp = prev_camera_from_gt * tp->second;
              if (pp.z() > 0.5) {
                const Eigen::Vector2d uv_prev(cam.fx * pp.x() / pp.z() + cam.cx,
                                              cam.fy * pp.y() / pp.z() + cam.cy);
                const Eigen::Vector2d m = uv_true - uv_prev;
                if (m.norm() > 1.0) {
                  s.along = (ob.uv - uv_true).dot(m.normalized());
                  s.has_along = true;
                }
                const double dd_true = bf / pc.z() - bf / pp.z();
                if (ob.u_right >= 0.0 && std::abs(dd_true) > 0.05) {
                  s.ddisp_along = s.ddisp * (dd_true > 0 ? 1.0 : -1.0);
                  s.has_ddisp_along = true;
                }
              }
              s.turning =
                  Eigen::AngleAxisd((gt_wo.rotation().transpose() *
                                     gt->WorldFromObject(scenario->TimeOf(i - 1)).rotation()))
                      .angle() > 1.0 * M_PI / 180.0;
            }
          }
        }
        s.parked = gt_speed < 0.05;
        s.object_age = static_cast<int>(i - created_at[id]);
        const auto plane = sim::PlanarDisparity(r.depth, bf, ob.uv.x(), ob.uv.y(), 4);
        s.planar = plane.has_value();
        s.z_true = plane ? bf / plane->disparity : r.depth.at<float>(y, x);
        if (!std::isfinite(s.z_true) || s.z_true <= 0.0) continue;
        s.border_px = border.at<float>(y, x);
        const float fx = static_cast<float>(ob.uv.x()), fy = static_cast<float>(ob.uv.y());
        uint32_t bx, by;
        std::memcpy(&bx, &fx, 4);
        std::memcpy(&by, &fy, 4);
        auto lv = level_of.find((static_cast<uint64_t>(bx) << 32) | by);
        s.level = lv == level_of.end() ? -1 : lv->second;  // -1: patch match (not a keypoint)
        s.stereo = ob.u_right >= 0.0 && ob.uv.x() - ob.u_right > 0.0;
        if (s.stereo) s.z_meas = bf / (ob.uv.x() - ob.u_right);
        s.z_model = (camera_from_object * it->second->point_in_object).z();
        if (s.creation) {
          const Eigen::Vector3d ray((ob.uv.x() - cam.cx) / cam.fx, (ob.uv.y() - cam.cy) / cam.fy, 1.0);
          truth_point[{id, ob.point_id}] =
              (in.camera_from_world * gt->WorldFromObject(t)).Inverse() * (s.z_true * ray);
        }
        samples.push_back(s);
        if (trace && s.creation) {
          std::printf("CREATE obj %lld frame %d age %d z %.2f err %+.3f planar %d border %.1f level %d\n",
                      static_cast<long long>(id), i, s.object_age, s.z_true, s.z_model - s.z_true,
                      s.planar ? 1 : 0, s.border_px, s.level);
        }
      }
    }
  }
  Report(name, samples, json);
  ReportObservations(name, samples);
  ReportSteps(name, steps);
  return 0;
}

}  // namespace
}  // namespace twist

int main(int argc, char** argv) {
  google::InitGoogleLogging(argv[0]);
  std::string scenarios = "driving,follow_braking";
  int frames = 100;
  uint32_t seed = 1;
  int ba = twist::SlamOptions().object_ba_window_frames;
  std::string json_path;
  bool masked = true;
  for (int a = 1; a + 1 < argc; a += 2) {
    const std::string k = argv[a], v = argv[a + 1];
    if (k == "--scenario") {
      scenarios = v;
    } else if (k == "--frames") {
      frames = std::atoi(v.c_str());
    } else if (k == "--seed") {
      seed = static_cast<uint32_t>(std::atoi(v.c_str()));
    } else if (k == "--ba") {
      ba = std::atoi(v.c_str());
    } else if (k == "--masked-stereo") {
      masked = std::atoi(v.c_str()) != 0;
    } else if (k == "--json") {
      json_path = v;
    } else {
      std::fprintf(stderr, "unknown option %s\n", k.c_str());
      return 2;
    }
  }
  std::ostringstream json;
  json << "[\n";
  std::stringstream list(scenarios);
  std::string name;
  while (std::getline(list, name, ',')) twist::Run(name, frames, seed, ba, masked, &json);
  json << "{}]\n";
  if (!json_path.empty()) {
    FILE* f = std::fopen(json_path.c_str(), "w");
    if (f != nullptr) {
      std::fputs(json.str().c_str(), f);
      std::fclose(f);
    }
  }
  return 0;
}
