// End to end: rendered synthetic scenes (slam/sim) through SlamSystem with
// panoptic masks; the objects of FrameResult are evaluated with slam/io
// metrics against the scene's ground truth (expressed in the engine's world,
// i.e. the first camera frame). The camera is estimated, not given.
#include <glog/logging.h>
#include <gtest/gtest.h>

#include <algorithm>
#include <cmath>
#include <cstdio>
#include <map>
#include <memory>
#include <string>
#include <vector>

#include "slam/io/metrics.h"
#include "slam/io/run_output.h"
#include "slam/sim/depth_truth.h"
#include "slam/sim/labels.h"
#include "slam/sim/renderer.h"
#include "slam/sim/scenarios.h"
#include "slam/system/slam_system.h"

namespace twist {
namespace {

using geometry::SE3d;

struct E2eRun {
  std::vector<FrameResult> results;
  std::vector<io::ObjectGtRow> gt;
  std::vector<io::ObjectTrackRow> est;
  std::vector<int64_t> timestamps;
  io::MaskPixelCounts pixels;
  std::vector<SE3d> gt_cameras;  // world_from_camera, first camera = identity
  io::ObjectEvaluation eval;
  MapSnapshot snapshot;  // after the last frame
};

E2eRun RunScenario(const std::string& name, int frames, bool constrained = true) {
  auto scenario = sim::MakeScenario(name, 7, frames);
  CHECK(scenario.ok()) << scenario.status();
  const sim::Scenario& sc = *scenario;
  sim::RenderOptions ro;
  ro.gray = true;
  sim::Renderer renderer(sc.camera, ro);
  SessionConfig config;
  config.camera = sc.camera;
  config.options.constrain_objects = constrained;
  auto sys = SlamSystem::Create(config);
  CHECK(sys.ok()) << sys.status();
  E2eRun run;
  const SE3d cam0_from_world = sc.WorldFromCamera(0).Inverse();
  for (int k = 0; k < frames; ++k) {
    const SE3d world_from_camera = sc.WorldFromCamera(k);
    sim::Exposure left, right;
    left.noise_seed = 2 * k + 1;
    right.noise_seed = 2 * k + 2;
    const sim::StereoRender r =
        renderer.RenderStereo(sc.scene, sc.TimeOf(k), world_from_camera, left, right);
    const StereoFrame f = sim::ScenarioStereoFrame(sc, k, r);
    absl::StatusOr<FrameResult> res = (*sys)->Process(f);
    CHECK(res.ok()) << res.status();
    for (const ObjectResult& o : res->objects) {
      if (o.state == ObjectState::kLost) continue;
      io::ObjectTrackRow row;
      row.frame = k;
      row.track_id = o.id;
      row.class_id = o.class_id;
      row.world_from_object = o.world_from_object;
      row.twist_in_world = o.twist_in_world;
      row.instance_id = o.instance_id;
      run.est.push_back(row);
    }
    for (const sim::FrameLabel& l : sim::ComputeFrameLabels(sc, renderer, k, r.panoptic)) {
      io::ObjectGtRow g;
      g.frame = k;
      g.track_id = l.track_id;
      g.class_id = l.class_id;
      g.world_from_object = cam0_from_world * l.world_from_object;
      run.gt.push_back(g);
    }
    io::CountMaskPixels(k, r.panoptic, &run.pixels);
    run.timestamps.push_back(f.timestamp_ns);
    run.gt_cameras.push_back(cam0_from_world * world_from_camera);
    run.results.push_back(*std::move(res));
  }
  run.snapshot = (*sys)->Snapshot();
  auto eval =
      io::EvaluateObjects(run.gt, run.est, run.timestamps, io::ObjectEvalOptions{}, &run.pixels);
  CHECK(eval.ok()) << eval.status();
  run.eval = *std::move(eval);
  std::vector<SE3d> est_cameras;
  for (const auto& r : run.results) est_cameras.push_back(r.world_from_camera);
  const auto cam = io::EvaluateCamera(run.gt_cameras, est_cameras);
  std::map<std::string, std::vector<double>> ms;
  for (const auto& r : run.results) {
    for (const auto& t : r.timings) ms[t.stage].push_back(t.ms);
  }
  std::string timing;
  for (const char* stage :
       {"objects", "objects_segments", "objects_track", "objects_ba", "total"}) {
    auto& v = ms[stage];
    if (v.empty()) continue;
    std::sort(v.begin(), v.end());
    timing += std::string(" ") + stage + " median " + std::to_string(v[v.size() / 2]) + " ms p95 " +
              std::to_string(v[(v.size() - 1) * 95 / 100]) + " ms;";
  }
  std::printf("[%s, %d frames, %s] camera ATE %.3f m;%s\n%s",
              name.c_str(),
              frames,
              constrained ? "constrained" : "free",
              cam.ok() ? cam->ate_rmse : -1.0,
              timing.c_str(),
              io::FormatObjectTable(run.eval).c_str());
  return run;
}

const io::ObjectMetrics* LongestTracked(const io::ObjectEvaluation& e, bool moving, int class_id) {
  const io::ObjectMetrics* best = nullptr;
  for (const auto& m : e.objects) {
    if (m.moving != moving || m.class_id != class_id || m.est_track_id < 0) continue;
    if (best == nullptr || m.tracked_frames > best->tracked_frames) best = &m;
  }
  return best;
}

TEST(ObjectsEndToEnd, DrivingCarsTrackedWithPlanarConstraint) {
  const E2eRun run = RunScenario("driving", 30);
  // Objects and cluster events come out of the engine.
  int created = 0, planes = 0;
  Eigen::Vector4d road = Eigen::Vector4d::Zero();
  for (const auto& r : run.results) {
    for (const auto& e : r.cluster_events) {
      created += e.type == ClusterEventType::kCreated;
      if (e.type == ClusterEventType::kPlaneUpdated) {
        ++planes;
        if (e.class_id == sim::kClassRoad && e.plane) road = *e.plane;
        ASSERT_TRUE(e.plane.has_value());
        EXPECT_NEAR(e.plane->norm(), 1.0, 1e-6);
      }
    }
  }
  EXPECT_GT(created, 0);
  EXPECT_GT(planes, 0);

  // The leading car (moving, seen all along).
  const io::ObjectMetrics* lead = LongestTracked(run.eval, true, sim::kClassCar);
  ASSERT_NE(lead, nullptr);
  // Measured (seed 7, 30 frames): ATE 0.20 m, RPE_R 0.26 deg/m, 1.0 km/h.
  EXPECT_GT(lead->tracked_frames, 20);
  EXPECT_LT(lead->ate, 0.3);
  EXPECT_LT(lead->rpe_r_deg_per_m, 0.5);
  EXPECT_LT(lead->speed_error_kmh, 2.0);
  // The car created later (ground-truth id 3, 9 frames tracked) turns by up
  // to 10° per frame in single steps without the constant-velocity filter of
  // the twist (docs/objects.md §13). Measured: RPE_R 0.34 deg/m and 1.8 km/h
  // with the filter, 3.4 deg/m and 6.0 km/h without.
  const io::ObjectMetrics* second = nullptr;
  for (const auto& m : run.eval.objects) {
    if (m.moving && m.class_id == sim::kClassCar && m.est_track_id >= 0 && &m != lead &&
        (second == nullptr || m.tracked_frames > second->tracked_frames)) {
      second = &m;
    }
  }
  ASSERT_NE(second, nullptr);
  EXPECT_GE(second->tracked_frames, 6);
  EXPECT_LT(second->rpe_r_deg_per_m, 1.0);
  EXPECT_LT(second->speed_error_kmh, 3.5);
  // Parked cars: tracked and nearly still (held stationary once their motion
  // is insignificant). Measured mean 0.27 km/h; 0.78 km/h when a step from
  // standstill faster than 4 m/s may start a held car (docs/objects.md §16).
  // The bound is the target.
  int parked = 0;
  double parked_speed = 0.0;
  for (const auto& m : run.eval.objects) {
    if (m.moving || m.class_id != sim::kClassCar || m.est_track_id < 0 || m.tracked_frames < 5 ||
        std::isnan(m.speed_error_kmh)) {
      continue;
    }
    parked_speed += m.speed_error_kmh;
    ++parked;
  }
  std::printf(
      "[driving] lead ATE %.3f m, RPE_R %.3f deg/m, speed error %.2f km/h; second RPE_R "
      "%.3f deg/m, speed error %.2f km/h; %d parked, mean speed error %.2f km/h\n",
      lead->ate,
      lead->rpe_r_deg_per_m,
      lead->speed_error_kmh,
      second->rpe_r_deg_per_m,
      second->speed_error_kmh,
      parked,
      parked_speed / std::max(parked, 1));
  EXPECT_GE(parked, 2);
  EXPECT_LT(parked_speed / std::max(parked, 1), 0.5);

  // Planar constraint: every planar track keeps its height above the road
  // (the component along its joint normal) and has no out-of-plane twist.
  std::map<int64_t, std::vector<const ObjectResult*>> tracks;
  for (const auto& r : run.results) {
    for (const auto& o : r.objects) {
      if (o.state != ObjectState::kLost && o.joint == "planar") tracks[o.id].push_back(&o);
    }
  }
  ASSERT_FALSE(tracks.empty());
  for (const auto& [id, samples] : tracks) {
    if (samples.size() < 5) continue;
    for (const ObjectResult* o : samples) {
      EXPECT_NEAR(o->twist_in_joint[2], 0.0, 1e-6) << "track " << id;
      EXPECT_NEAR(o->twist_in_joint[3], 0.0, 1e-6) << "track " << id;
      EXPECT_NEAR(o->twist_in_joint[4], 0.0, 1e-6) << "track " << id;
    }
  }
  // The lead car's GT height above the road is constant: so must be its
  // estimated one (measured to the last fitted road plane).
  ASSERT_GT(road.head<3>().norm(), 0.5);
  std::vector<double> heights;
  for (const auto& row : run.est) {
    if (row.track_id == lead->est_track_id) {
      heights.push_back(road.head<3>().dot(row.world_from_object.translation()) + road[3]);
    }
  }
  ASSERT_GT(heights.size(), 10u);
  const auto [lo, hi] = std::minmax_element(heights.begin(), heights.end());
  EXPECT_LT(*hi - *lo, 0.15);
}

// The map snapshot (GetMap) carries the clusters: the road's with the plane
// of its last "plane updated" event, and each dynamic one with the pose
// history of the object that holds it, whose newest pose is the one the
// last frame reported. Road points are labelled with the road's cluster.
TEST(ObjectsEndToEnd, TheMapSnapshotCarriesTheClusters) {
  const E2eRun run = RunScenario("driving", 20);
  const MapSnapshot& snap = run.snapshot;
  std::map<int64_t, Eigen::Vector4d> last_plane;
  for (const auto& r : run.results) {
    for (const auto& e : r.cluster_events) {
      if (e.type == ClusterEventType::kPlaneUpdated && e.plane) last_plane[e.cluster_id] = *e.plane;
    }
  }
  ASSERT_FALSE(last_plane.empty());
  int64_t road_cluster = -1;
  std::map<int64_t, const MapSnapshot::Cluster*> by_id;
  for (const MapSnapshot::Cluster& c : snap.clusters) {
    EXPECT_TRUE(by_id.emplace(c.id, &c).second) << "cluster " << c.id << " twice";
    EXPECT_EQ(c.is_dynamic, SessionConfig().classes.IsDynamic(c.class_id))
        << "cluster " << c.id << " class " << c.class_id;
    if (c.is_dynamic) {
      EXPECT_FALSE(c.plane.has_value());
    } else {
      EXPECT_TRUE(c.trajectory.empty());
    }
    if (c.class_id == sim::kClassRoad) road_cluster = c.id;
  }
  ASSERT_GE(road_cluster, 0);
  ASSERT_TRUE(by_id.at(road_cluster)->plane.has_value());
  ASSERT_TRUE(last_plane.count(road_cluster));
  EXPECT_EQ(*by_id.at(road_cluster)->plane, last_plane.at(road_cluster));

  // Every object tracked in the last frame ends one dynamic cluster's
  // trajectory (time-ordered, one sample per frame it was seen in).
  const FrameResult& last = run.results.back();
  int matched = 0;
  for (const ObjectResult& o : last.objects) {
    if (o.state != ObjectState::kTracked) continue;
    const MapSnapshot::Cluster* found = nullptr;
    for (const MapSnapshot::Cluster& c : snap.clusters) {
      if (!c.trajectory.empty() && c.trajectory.back().first == last.timestamp_ns &&
          (c.trajectory.back().second.translation() - o.world_from_object.translation()).norm() <
              1e-9) {
        found = &c;
      }
    }
    ASSERT_NE(found, nullptr) << "object " << o.id;
    EXPECT_EQ(found->class_id, o.class_id);
    EXPECT_TRUE(found->is_dynamic);
    for (size_t k = 1; k < found->trajectory.size(); ++k) {
      EXPECT_GT(found->trajectory[k].first, found->trajectory[k - 1].first);
    }
    ++matched;
  }
  EXPECT_GE(matched, 2);

  int road_points = 0;
  for (const MapSnapshot::Point& p : snap.points) {
    if (p.class_id == sim::kClassRoad) {
      EXPECT_EQ(p.cluster_id, road_cluster);
      ++road_points;
    } else if (p.class_id == sim::kClassCar) {
      EXPECT_EQ(p.cluster_id, -1);
    }
  }
  EXPECT_GT(road_points, 20);

  // The objects' whole trajectories: one per object reported, with a pose at
  // exactly the frames it was reported tracked or new, the last one as
  // reported (earlier ones as the dynamic BA refined them since).
  std::map<int64_t, std::map<int64_t, SE3d>> reported;  // id -> timestamp -> pose
  std::map<int64_t, int> class_of;
  for (const FrameResult& r : run.results) {
    for (const ObjectResult& o : r.objects) {
      if (o.state == ObjectState::kLost) continue;
      reported[o.id][r.timestamp_ns] = o.world_from_object;
      class_of[o.id] = o.class_id;
    }
  }
  ASSERT_EQ(snap.objects.size(), reported.size());
  double refined_by = 0.0;
  for (size_t k = 0; k < snap.objects.size(); ++k) {
    const MapSnapshot::Object& o = snap.objects[k];
    if (k > 0) {
      EXPECT_GT(o.id, snap.objects[k - 1].id);
    }
    ASSERT_TRUE(reported.count(o.id)) << "object " << o.id;
    EXPECT_EQ(o.class_id, class_of.at(o.id));
    const std::map<int64_t, SE3d>& online = reported.at(o.id);
    ASSERT_EQ(o.trajectory.size(), online.size()) << "object " << o.id;
    size_t j = 0;
    for (const auto& [t_ns, pose] : online) {
      EXPECT_EQ(o.trajectory[j].first, t_ns);
      const double d = (o.trajectory[j].second.translation() - pose.translation()).norm();
      EXPECT_LT(d, 1.0) << "object " << o.id << " at " << t_ns;
      refined_by = std::max(refined_by, d);
      ++j;
    }
  }
  EXPECT_GT(refined_by, 1e-6);  // the BA did move poses

  // The trajectories scored like the online poses, through the run output
  // writer (objects_refined.txt).
  io::RunOutputWriter writer;
  for (const FrameResult& r : run.results) writer.Add(r);
  std::vector<io::TimedObjectTrajectory> trajectories;
  for (const MapSnapshot::Object& o : snap.objects) {
    trajectories.push_back({o.id, o.class_id, o.instance_id, o.trajectory});
  }
  writer.SetRefinedObjects(trajectories);
  const std::vector<io::ObjectTrackRow> refined = writer.RefinedObjectRows();
  EXPECT_EQ(refined.size(), writer.ObjectRows().size());
  auto eval =
      io::EvaluateObjects(run.gt, refined, run.timestamps, io::ObjectEvalOptions{}, &run.pixels);
  ASSERT_TRUE(eval.ok()) << eval.status();
  std::printf("[driving, refined trajectories]\n%s", io::FormatObjectTable(*eval).c_str());
}

TEST(ObjectsEndToEnd, FollowBrakingAndDeterminism) {
  const E2eRun a = RunScenario("follow_braking", 20);
  const io::ObjectMetrics* lead = LongestTracked(a.eval, true, sim::kClassCar);
  ASSERT_NE(lead, nullptr);
  // Measured (seed 7, 20 frames): ATE 0.06 m, RPE_R 0.09 deg/m, 0.5 km/h.
  EXPECT_GT(lead->tracked_frames, 14);
  EXPECT_LT(lead->ate, 0.15);
  EXPECT_LT(lead->rpe_r_deg_per_m, 0.3);
  EXPECT_LT(lead->speed_error_kmh, 1.5);
  // Same input -> same output.
  const E2eRun b = RunScenario("follow_braking", 20);
  ASSERT_EQ(a.est.size(), b.est.size());
  for (size_t i = 0; i < a.est.size(); ++i) {
    EXPECT_EQ(a.est[i].track_id, b.est[i].track_id);
    EXPECT_EQ(a.est[i].world_from_object.translation(), b.est[i].world_from_object.translation());
  }
}

// The revolute door: the hinge is estimated (vertical axis in the wall at
// the door's edge nearest the camera), so the bounds are loose.
TEST(ObjectsEndToEnd, RevoluteDoor) {
  const E2eRun run = RunScenario("door", 30);
  const io::ObjectMetrics* door = nullptr;
  for (const auto& m : run.eval.objects) {
    if (m.class_id == sim::kClassDoor && m.est_track_id >= 0) door = &m;
  }
  ASSERT_NE(door, nullptr);
  // Measured (seed 7, 30 frames): 20 frames tracked, ATE 0.46 m.
  EXPECT_GT(door->tracked_frames, 10);
  EXPECT_LT(door->ate, 0.8);
}

// Switches, and a resume: the object stage is persisted by Save() (state
// format 4), so after Load() the objects continue exactly (same ids, states,
// poses and twists as the uninterrupted run).
TEST(ObjectsEndToEnd, SwitchesAndResume) {
  auto scenario = sim::MakeScenario("driving", 7, 8);
  ASSERT_TRUE(scenario.ok());
  sim::RenderOptions ro;
  ro.gray = true;
  sim::Renderer renderer(scenario->camera, ro);
  std::vector<StereoFrame> frames;
  for (int k = 0; k < 8; ++k) {
    const sim::StereoRender r = renderer.RenderStereo(
        scenario->scene, scenario->TimeOf(k), scenario->WorldFromCamera(k), {}, {1.0, 0.0, 99});
    frames.push_back(sim::ScenarioStereoFrame(*scenario, k, r));
  }
  auto run = [&](SessionConfig config, int save_at) {
    config.camera = scenario->camera;
    auto sys = SlamSystem::Create(config);
    CHECK(sys.ok()) << sys.status();
    std::unique_ptr<SlamSystem> s = *std::move(sys);
    std::vector<FrameResult> out;
    for (int k = 0; k < static_cast<int>(frames.size()); ++k) {
      if (k == save_at) {
        const std::string path = ::testing::TempDir() + "/objects_e2e_resume.bin";
        CHECK(s->Save(path).ok());
        auto loaded = SlamSystem::Load(path);
        CHECK(loaded.ok()) << loaded.status();
        s = *std::move(loaded);
      }
      auto r = s->Process(frames[k]);
      CHECK(r.ok()) << r.status();
      out.push_back(*std::move(r));
    }
    return out;
  };
  auto has_timing = [](const FrameResult& r) {
    for (const auto& t : r.timings) {
      if (t.stage == "objects") return true;
    }
    return false;
  };
  SessionConfig off;
  off.options.track_objects = false;
  for (const auto& r : run(off, -1)) {
    EXPECT_TRUE(r.objects.empty());
    EXPECT_TRUE(r.cluster_events.empty());
    EXPECT_FALSE(has_timing(r));
  }
  SessionConfig no_masks;
  no_masks.options.use_masks = false;
  for (const auto& r : run(no_masks, -1)) EXPECT_TRUE(r.objects.empty());

  const std::vector<FrameResult> full = run(SessionConfig(), -1);
  const std::vector<FrameResult> resumed = run(SessionConfig(), 4);
  ASSERT_FALSE(full.back().objects.empty());
  EXPECT_TRUE(has_timing(full.back()));
  // Both runs are identical, before and after the resume, to the last bit.
  ASSERT_EQ(full.size(), resumed.size());
  int tracked_after_resume = 0;
  for (size_t k = 0; k < full.size(); ++k) {
    ASSERT_EQ(full[k].objects.size(), resumed[k].objects.size()) << "frame " << k;
    for (size_t i = 0; i < full[k].objects.size(); ++i) {
      const ObjectResult& a = full[k].objects[i];
      const ObjectResult& b = resumed[k].objects[i];
      EXPECT_EQ(a.id, b.id) << "frame " << k;
      EXPECT_EQ(a.state, b.state) << "frame " << k;
      EXPECT_EQ(a.stationary, b.stationary) << "frame " << k;
      EXPECT_EQ(a.num_points, b.num_points) << "frame " << k;
      EXPECT_TRUE(a.world_from_object.matrix() == b.world_from_object.matrix()) << "frame " << k;
      EXPECT_TRUE(a.twist_in_world == b.twist_in_world) << "frame " << k;
      tracked_after_resume += k >= 4 && b.state == ObjectState::kTracked;
    }
  }
  EXPECT_GT(tracked_after_resume, 0);  // tracks continue (no restart as kNew)
}

}  // namespace
}  // namespace twist
