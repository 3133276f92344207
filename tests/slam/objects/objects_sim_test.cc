// Objects on rendered synthetic sequences (slam/sim): the real front end
// (ORB, stereo matching, panoptic segments, cluster association, road plane
// by RANSAC) feeding the object tracker with sparse Lucas–Kanade flow. The
// camera poses are the ground truth, so the figures isolate object tracking.
#include <glog/logging.h>
#include <gtest/gtest.h>

#include <algorithm>
#include <cstdio>
#include <cstdlib>
#include <map>
#include <random>
#include <tuple>

#include "slam/features/orb_extractor.h"
#include "slam/features/stereo_matcher.h"
#include "slam/objects/dynamic_ba.h"
#include "slam/objects/joint_frames.h"
#include "slam/objects/object_ba.h"
#include "slam/objects/object_tracker.h"
#include "slam/semantic/cluster_association.h"
#include "slam/semantic/panoptic.h"
#include "slam/semantic/plane_fitting.h"
#include "slam/sim/renderer.h"
#include "slam/sim/scenarios.h"
#include "tests/slam/objects/synthetic_objects.h"

namespace twist::objects {
namespace {

using geometry::SE3d;

// Window of the dynamic BA run after every frame (0: tracker only);
// TWIST_SIM_BA_WINDOW overrides it for experiments.
int BaWindow() {
  const char* w = std::getenv("TWIST_SIM_BA_WINDOW");
  return w != nullptr ? std::atoi(w) : 0;
}

struct TrackStats {
  int gt_track = 0;
  int class_id = 0;
  int frames_tracked = 0;
  int frames_visible = 0;  // GT mask >= 2000 px
  int frames_covered = 0;  // visible and tracked
  double ate_sum = 0.0;
  int ate_n = 0;
  double speed_err_sum = 0.0;
  double gt_speed_sum = 0.0;
  int speed_n = 0;
  // Steps in which the object turned by more than 1°: the rotation of the
  // estimated step about the true axis minus the true one, and the angle of
  // the step's rotation error.
  double turn_excess_sum = 0.0;
  double turn_error_sum = 0.0;
  int turn_n = 0;
  double turn_excess_deg() const { return turn_n > 0 ? turn_excess_sum / turn_n : 0.0; }
  double turn_error_deg() const { return turn_n > 0 ? turn_error_sum / turn_n : 0.0; }
  double ate() const { return ate_n > 0 ? ate_sum / ate_n : 0.0; }
  double speed_err_kmh() const { return speed_n > 0 ? 3.6 * speed_err_sum / speed_n : 0.0; }
  double gt_speed_kmh() const { return speed_n > 0 ? 3.6 * gt_speed_sum / speed_n : 0.0; }
  double coverage() const {
    return frames_visible > 0 ? static_cast<double>(frames_covered) / frames_visible : 0.0;
  }
};

std::map<int, TrackStats> RunScenario(
    const std::string& name,
    int frames,
    bool constrained,
    int ba_window,
    double patch_refresh_view_change_deg = ObjectTrackerOptions{}.patch_refresh_view_change_deg,
    bool masked_patches = ObjectTrackerOptions{}.masked_patches) {
  auto scenario = sim::MakeScenario(name, 7, frames);
  CHECK(scenario.ok()) << scenario.status();
  const geometry::StereoCamera cam = scenario->camera;
  sim::RenderOptions render_options;
  render_options.gray = true;
  sim::Renderer renderer(cam, render_options);
  features::OrbExtractor orb(features::OrbOptions{});
  semantic::ClusterAssociator clusters(semantic::ClusterAssociationOptions{});
  semantic::ClusterPlane::Options plane_options;
  plane_options.ransac.inlier_threshold_m = 0.05;
  semantic::ClusterPlane road(plane_options);
  std::mt19937_64 rng(1);
  std::vector<Eigen::Vector3d> road_points;
  ObjectTrackerOptions options;
  options.constrained = constrained && std::getenv("TWIST_SIM_FREE") == nullptr;
  // The camera is the ground truth here: its height does not drift, so a car
  // following the refitted road plane would only take the plane's refit
  // noise (docs/objects.md §37); the cars keep the plane they were created on.
  options.follow_parent_plane = false;
  options.patch_refresh_view_change_deg = patch_refresh_view_change_deg;
  options.masked_patches = masked_patches;
  if (const char* w = std::getenv("TWIST_SIM_WINDOW")) options.flow.window_size = std::atoi(w);
  if (std::getenv("TWIST_SIM_NOREFINE") != nullptr) options.refine_by_projection = false;
  if (const char* m = std::getenv("TWIST_SIM_MINSIGMA"))
    options.estimator.min_sigma_px = std::atof(m);
  if (const char* e = std::getenv("TWIST_SIM_EROSION")) options.mask_erosion_px = std::atof(e);
  ObjectTracker tracker(cam, options);

  std::map<int64_t, int> gt_of_object;                 // object id -> GT track id
  std::map<int64_t, std::pair<int, SE3d>> first_pose;  // object id -> (frame, est pose)
  std::map<int64_t, Eigen::Vector3d> prev_est_centre, prev_gt_centre;
  std::map<int64_t, std::pair<SE3d, SE3d>> prev_pose;  // object id -> (est, GT), last frame
  std::map<int, TrackStats> stats;
  std::vector<std::tuple<int64_t, int64_t, SE3d>>
      window;  // frame index, timestamp, camera_from_world

  for (int i = 0; i < frames; ++i) {
    const double t = scenario->TimeOf(i);
    const SE3d world_from_camera = scenario->WorldFromCamera(i);
    const sim::StereoRender r =
        renderer.RenderStereo(scenario->scene, t, world_from_camera, {}, {1.0, 0.0, 99});
    // Keypoints, favoured inside dynamic segments (paper §IV-D).
    const std::vector<semantic::Segment> segments =
        semantic::ExtractSegments(r.panoptic, 400, true);
    cv::Mat favour(r.left.size(), CV_8UC1, cv::Scalar(1));
    std::vector<semantic::Detection> dets;
    for (const auto& s : segments) {
      const int c = s.label.class_id;
      if (c != sim::kClassCar && c != sim::kClassDoor && c != sim::kClassPerson) continue;
      semantic::Detection d;
      d.label = s.label;
      d.box = cv::Rect2d(s.box);
      d.mask = semantic::SegmentMask(r.panoptic, s.label);
      favour.setTo(200, d.mask);
      dets.push_back(d);
    }
    std::vector<cv::KeyPoint> kl, kr;
    cv::Mat dl, dr;
    std::vector<cv::Mat> ll, lr;
    orb.Extract(r.left, favour, &kl, &dl, &ll);
    orb.Extract(r.right, cv::Mat(), &kr, &dr, &lr);
    const features::StereoMatchResult stereo =
        features::MatchStereo(cam, orb.pyramid(), kl, dl, kr, dr, ll, lr);
    ObjectFrameInput f;
    f.frame_index = i;
    f.timestamp_ns = static_cast<int64_t>(std::llround(t * 1e9));
    f.camera_from_world = world_from_camera.Inverse();
    f.left = r.left;
    f.keypoints.descriptors = dl;
    for (size_t k = 0; k < kl.size(); ++k) {
      f.keypoints.uv.emplace_back(kl[k].pt.x, kl[k].pt.y);
      f.keypoints.u_right.push_back(stereo.u_right[k]);
      // Road points for the plane.
      const auto label = semantic::LabelAt(r.panoptic, f.keypoints.uv.back());
      if (label && label->class_id == sim::kClassRoad && stereo.u_right[k] >= 0) {
        const auto p = cam.TriangulateStereo(kl[k].pt.x, kl[k].pt.y, stereo.u_right[k], 30.0);
        if (p) road_points.push_back(world_from_camera * *p);
      }
    }
    if (road_points.size() > 4000) road_points.erase(road_points.begin(), road_points.end() - 4000);
    road.Update(road_points, &rng);
    const semantic::AssociationResult assoc = clusters.Associate(dets);
    for (size_t d = 0; d < dets.size(); ++d) {
      ObjectDetectionInput in;
      in.cluster_id = assoc.cluster_of_detection[d];
      in.class_id = dets[d].label.class_id;
      in.instance_id = dets[d].label.instance_id;
      in.box = dets[d].box;
      in.mask = dets[d].mask;
      JointSpec spec;
      spec.anchor = world_from_camera.translation();
      if (in.class_id == sim::kClassDoor) {
        // The hinge is given (the paper does not estimate it either).
        for (const auto& obj : scenario->scene.objects) {
          if (obj.track_id == in.instance_id) {
            spec.type = joints::JointType::kRevolute;
            spec.axis_direction = obj.revolute.hinge_axis();
            spec.axis_point = obj.revolute.hinge_point();
          }
        }
      } else {
        spec.type = joints::JointType::kPlanar;
        if (road.has_plane()) spec.parent_plane = road.plane();
      }
      in.joint = ResolveJointOrFree(spec);
      f.detections.push_back(in);
    }
    auto results = tracker.Process(f);
    CHECK(results.ok()) << results.status();
    // Dynamic BA over the last `ba_window` frames (object poses and points;
    // the camera poses are the ground truth here and stay fixed).
    window.push_back({f.frame_index, f.timestamp_ns, f.camera_from_world});
    if (ba_window > 0 && static_cast<int>(window.size()) > ba_window) window.erase(window.begin());
    if (ba_window > 0 && static_cast<int>(window.size()) >= 3) {
      DynamicBaProblem problem;
      problem.camera = cam;
      std::map<int64_t, int> keyframe_of_frame;
      for (const auto& [index, ts, pose] : window) {
        BaKeyframe kf;
        kf.id = index;
        kf.timestamp_ns = ts;
        kf.camera_from_world = pose;
        kf.fixed = true;
        keyframe_of_frame[index] = static_cast<int>(problem.keyframes.size());
        problem.keyframes.push_back(kf);
      }
      const auto links =
          AddTrackedObjectsToBa(tracker, keyframe_of_frame, ObjectBaOptions{}, &problem);
      if (!links.empty()) {
        DynamicBaOptions ba_options;
        ba_options.max_iterations = 5;
        const auto summary = SolveDynamicBa(&problem, ba_options);
        CHECK(summary.ok()) << summary.status();
        if (summary->usable) {
          ApplyBaToTrackedObjects(problem, links, ObjectBaOptions{}, &tracker);
          for (ObjectResult& o : *results) {
            if (tracker.objects().count(o.id) > 0)
              o = ObjectTracker::ToResult(tracker.objects().at(o.id));
          }
        }
      }
    }

    // Metrics against the ground truth (DESIGN.md §6).
    std::map<int, int> gt_pixels;
    for (const auto& s : semantic::ExtractSegments(r.panoptic, 1, true))
      gt_pixels[s.label.instance_id] = s.num_pixels;
    std::map<int, bool> tracked_gt;
    for (const ObjectResult& o : *results) {
      if (gt_of_object.count(o.id) == 0) gt_of_object[o.id] = o.instance_id;
      const int gt_id = gt_of_object[o.id];
      const sim::SceneObject* gt = nullptr;
      for (const auto& obj : scenario->scene.objects) {
        if (obj.track_id == gt_id) gt = &obj;
      }
      if (gt == nullptr || o.state == ObjectState::kLost) continue;
      tracked_gt[gt_id] = true;
      TrackStats& st = stats[gt_id];
      st.gt_track = gt_id;
      st.class_id = gt->class_id;
      ++st.frames_tracked;
      if (first_pose.count(o.id) == 0) first_pose[o.id] = {i, o.world_from_object};
      const auto& [f0, est0] = first_pose[o.id];
      const SE3d gt0 = gt->WorldFromObject(scenario->TimeOf(f0));
      const SE3d gti = gt->WorldFromObject(t);
      const Eigen::Vector3d centre_local(0.0, -0.5 * gt->h, 0.0);
      const Eigen::Vector3d est_centre =
          (o.world_from_object * est0.Inverse() * gt0) * centre_local;
      const Eigen::Vector3d gt_centre = gti * centre_local;
      st.ate_sum += (est_centre - gt_centre).norm();
      if (std::getenv("TWIST_SIM_DEBUG") != nullptr && gt->class_id == sim::kClassDoor) {
        std::printf(
            "    frame %d obj %ld: est angle %.2f deg, gt angle %.2f deg, err %.3f m, inliers %d "
            "sigma %.2f pts %d\n",
            i,
            static_cast<long>(o.id),
            (o.world_from_object * est0.Inverse()).so3().Log().norm() * 57.2958,
            (gti * gt0.Inverse()).so3().Log().norm() * 57.2958,
            (est_centre - gt_centre).norm(),
            tracker.objects().at(o.id).last_num_inliers,
            tracker.objects().at(o.id).last_sigma_px,
            o.num_points);
      }
      ++st.ate_n;
      if (prev_est_centre.count(o.id) > 0 && i > f0) {
        const double est_speed =
            (est_centre - prev_est_centre[o.id]).norm() / scenario->frame_period;
        const double gt_speed = (gt_centre - prev_gt_centre[o.id]).norm() / scenario->frame_period;
        st.speed_err_sum += std::abs(est_speed - gt_speed);
        st.gt_speed_sum += gt_speed;
        ++st.speed_n;
      }
      if (prev_pose.count(o.id) > 0 && i > f0) {
        const SE3d est_step = o.world_from_object * prev_pose[o.id].first.Inverse();
        const SE3d gt_step = gti * prev_pose[o.id].second.Inverse();
        if (gt_step.so3().Log().norm() > M_PI / 180.0) {
          st.turn_excess_sum += testing::TurnExcessDeg(est_step, gt_step);
          st.turn_error_sum += testing::RotationErrorDeg(est_step, gt_step);
          ++st.turn_n;
        }
      }
      prev_pose[o.id] = {o.world_from_object, gti};
      prev_est_centre[o.id] = est_centre;
      prev_gt_centre[o.id] = gt_centre;
    }
    for (const auto& [gt_id, px] : gt_pixels) {
      if (px < 2000) continue;
      TrackStats& st = stats[gt_id];
      st.gt_track = gt_id;
      ++st.frames_visible;
      if (tracked_gt.count(gt_id) > 0) ++st.frames_covered;
    }
  }
  std::printf("[sim %s, %s, BA window %d] road plane: %s\n",
              name.c_str(),
              options.constrained ? "constrained" : "free",
              ba_window,
              road.has_plane() ? "fitted" : "none");
  for (const auto& [id, st] : stats) {
    std::printf(
        "  track %3d class %2d: tracked %2d frames, visible %2d, coverage %.2f, ATE %.3f m, "
        "speed error %.2f km/h (GT speed %.1f km/h), %d turning steps: excess %+.3f deg, "
        "error %.3f deg\n",
        id,
        st.class_id,
        st.frames_tracked,
        st.frames_visible,
        st.coverage(),
        st.ate(),
        st.speed_err_kmh(),
        st.gt_speed_kmh(),
        st.turn_n,
        st.turn_excess_deg(),
        st.turn_error_deg());
  }
  return stats;
}

TEST(ObjectsOnRenderedScenes, DrivingCars) {
  const auto stats = RunScenario("driving", 25, true, BaWindow());
  int moving = 0, parked = 0;
  double parked_speed_err = 0.0;
  for (const auto& [id, st] : stats) {
    if (st.class_id != sim::kClassCar || st.frames_visible < 10) continue;
    if (st.gt_speed_kmh() > 20.0 && st.frames_visible >= 20) {
      // The leading car, seen all along.
      EXPECT_GT(st.coverage(), 0.9) << "track " << id;
      EXPECT_LT(st.ate(), 0.15) << "track " << id;
      EXPECT_LT(st.speed_err_kmh(), 2.0) << "track " << id;
      ++moving;
    } else if (st.gt_speed_kmh() < 0.1) {
      // Parked cars passing by: tracked, and nearly still (frame-to-frame
      // speeds are noisy before the dynamic BA smooths them).
      EXPECT_GT(st.coverage(), 0.5) << "track " << id;
      parked_speed_err += st.speed_err_kmh();
      ++parked;
    }
  }
  EXPECT_GE(moving, 1);
  EXPECT_GE(parked, 3);
  std::printf("  mean speed error of parked cars: %.2f km/h\n",
              parked_speed_err / std::max(parked, 1));
  EXPECT_LT(parked_speed_err / std::max(parked, 1), 5.0);
}

// The revolute door (hinge given). Known weakness: the estimated opening
// lags the true one (see docs/objects.md), so the bound is loose.
TEST(ObjectsOnRenderedScenes, RevoluteDoor) {
  const auto stats = RunScenario("door", 30, true, BaWindow());
  bool door = false;
  for (const auto& [id, st] : stats) {
    if (st.class_id != sim::kClassDoor) continue;
    door = true;
    EXPECT_GT(st.coverage(), 0.6);
    EXPECT_LT(st.ate(), 0.5);
  }
  EXPECT_TRUE(door);
}

// Cars turning at 4° per frame, the objects' BA after every frame on the
// last 10: with the plain reference patches taken again as the view of
// their points turns by 5° (ObjectTrackerOptions::patch_refresh_view_change_deg,
// off by default), the steps' rotation error is lower than with the plain
// patches of the points' creation (docs/objects.md §43); so it is with the
// patches restricted to the car's mask (masked_patches, the default, §44).
TEST(ObjectsOnRenderedScenes, TurningCarsWithPatchesTakenAgain) {
  enum Patches { kCreation, kTakenAgain, kMasked };
  std::map<Patches, double> error_of, excess_of;
  for (Patches patches : {kCreation, kTakenAgain, kMasked}) {
    const auto stats = RunScenario(
        "turning_traffic", 40, true, 10, patches == kTakenAgain ? 5.0 : 0.0, patches == kMasked);
    double error = 0.0, excess = 0.0;
    int steps = 0;
    for (const auto& [id, st] : stats) {
      error += st.turn_error_sum;
      excess += st.turn_excess_sum;
      steps += st.turn_n;
    }
    ASSERT_GE(steps, 20);
    error_of[patches] = error / steps;
    excess_of[patches] = excess / steps;
    std::printf("  turning steps, patches %s: mean error %.3f deg, mean excess %+.3f deg\n",
                patches == kCreation     ? "of the creation"
                : patches == kTakenAgain ? "taken again"
                                         : "masked",
                error_of[patches],
                excess_of[patches]);
  }
  EXPECT_LT(error_of[kTakenAgain], error_of[kCreation]);
  EXPECT_LT(error_of[kTakenAgain], 0.6);
  EXPECT_LT(error_of[kMasked], error_of[kCreation]);
}

}  // namespace
}  // namespace twist::objects
