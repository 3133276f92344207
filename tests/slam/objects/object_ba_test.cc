#include "slam/objects/object_ba.h"

#include <gtest/gtest.h>

#include <Eigen/Eigenvalues>
#include <cmath>
#include <cstdio>
#include <map>

#include "tests/slam/objects/car_sequence.h"

namespace twist::objects {
namespace {

using namespace twist::objects::testing;  // NOLINT

// Frame `frame_index` as keyframe `id` of `problem` (camera pose fixed: from
// static tracking, held here).
void AddKeyframe(int64_t frame_index,
                 int64_t id,
                 int64_t timestamp_ns,
                 const SE3d& camera_from_world,
                 DynamicBaProblem* problem,
                 std::map<int64_t, int>* keyframe_of_frame) {
  BaKeyframe kf;
  kf.id = id;
  kf.timestamp_ns = timestamp_ns;
  kf.camera_from_world = camera_from_world;
  kf.fixed = true;
  (*keyframe_of_frame)[frame_index] = static_cast<int>(problem->keyframes.size());
  problem->keyframes.push_back(kf);
}
void AddKeyframe(const ObjectFrameInput& f,
                 int64_t id,
                 DynamicBaProblem* problem,
                 std::map<int64_t, int>* keyframe_of_frame) {
  AddKeyframe(f.frame_index, id, f.timestamp_ns, f.camera_from_world, problem, keyframe_of_frame);
}

// The frames seen so far (timestamp, camera pose), and the object stage's
// window over them: the last `window` frames as keyframes of a new problem.
struct SeenFrames {
  std::map<int64_t, std::pair<int64_t, SE3d>> frames;
  void Add(const ObjectFrameInput& f) {
    frames[f.frame_index] = {f.timestamp_ns, f.camera_from_world};
  }
  DynamicBaProblem Window(const geometry::StereoCamera& camera,
                          int window,
                          std::map<int64_t, int>* keyframe_of_frame) const {
    DynamicBaProblem problem;
    problem.camera = camera;
    const int64_t newest = frames.rbegin()->first;
    for (auto it = frames.lower_bound(newest - window + 1); it != frames.end(); ++it) {
      AddKeyframe(
          it->first, it->first, it->second.first, it->second.second, &problem, keyframe_of_frame);
    }
    return problem;
  }
};

// Tracks the car of `seq` for `frames` frames, with every frame a keyframe
// of `problem` (camera poses fixed: from static tracking, held here); the
// true object poses go to `gt`.
void TrackWindow(CarSequence* seq,
                 int frames,
                 ObjectTracker* tracker,
                 DynamicBaProblem* problem,
                 std::map<int64_t, int>* keyframe_of_frame,
                 std::vector<SE3d>* gt) {
  problem->camera = seq->camera();
  for (int i = 0; i < frames; ++i) {
    const ObjectFrameInput f = seq->Next(5, true);
    gt->push_back(seq->world_from_object());
    ASSERT_TRUE(tracker->Process(f).ok());
    AddKeyframe(f, i, problem, keyframe_of_frame);
  }
}

// Tracks the car of `seq` over 14 frames, every frame a keyframe of
// `problem`: detected in frames 0-5 and 8-13, hidden in 6-7. With
// `new_points` it shows points 0-39 before the gap and 60-99 after
// (`seq` needs 100 points). The true poses go to `gt`.
void TrackAcrossAGap(CarSequence* seq,
                     bool new_points,
                     ObjectTracker* tracker,
                     DynamicBaProblem* problem,
                     std::map<int64_t, int>* keyframe_of_frame,
                     std::map<int64_t, SE3d>* gt) {
  problem->camera = seq->camera();
  for (int i = 0; i < 14; ++i) {
    if (new_points) seq->set_shown_range(i < 6 ? 0 : 60, i < 6 ? 40 : 100);
    const ObjectFrameInput f = seq->Next(5, i < 6 || i >= 8);
    (*gt)[f.frame_index] = seq->world_from_object();
    ASSERT_TRUE(tracker->Process(f).ok());
    AddKeyframe(f, i, problem, keyframe_of_frame);
  }
}

// Error of the object's motion from its first recorded frame to its
// current pose.
double MotionErrorSinceFirstFrame(const TrackedObject& o, const std::map<int64_t, SE3d>& gt) {
  const ObjectPoseSample& first = o.history.front();
  return TranslationError(o.world_from_object * first.world_from_object.Inverse(),
                          gt.at(o.history.back().frame_index) * gt.at(first.frame_index).Inverse());
}

// Largest error of the object's motion since its first recorded frame.
double MaxTrajectoryError(const TrackedObject& o, const std::map<int64_t, SE3d>& gt) {
  const SE3d est0 = o.history.front().world_from_object;
  const SE3d gt0 = gt.at(o.history.front().frame_index);
  double max_error = 0.0;
  for (const ObjectPoseSample& sample : o.history) {
    max_error = std::max(max_error,
                         TranslationError(sample.world_from_object * est0.Inverse(),
                                          gt.at(sample.frame_index) * gt0.Inverse()));
  }
  return max_error;
}

// Solves `problem` (it must converge to a usable solution) and writes the
// result back into `tracker`.
void SolveAndApply(DynamicBaProblem* problem,
                   const std::vector<ObjectBaLink>& links,
                   const ObjectBaOptions& options,
                   ObjectTracker* tracker,
                   const DynamicBaOptions& ba_options = DynamicBaOptions{}) {
  const auto summary = SolveDynamicBa(problem, ba_options);
  ASSERT_TRUE(summary.ok() && summary->usable);
  ApplyBaToTrackedObjects(*problem, links, options, tracker);
}

// Tracker output refined by the dynamic BA over the whole window: the
// object's trajectory error (motion since its first frame) goes down.
TEST(ObjectBa, TrackerWindowRefinedByDynamicBa) {
  CarSequence seq(0.7, 21);
  ObjectTracker tracker(seq.camera(), ObjectTrackerOptions{});
  DynamicBaProblem problem;
  std::map<int64_t, int> keyframe_of_frame;
  std::vector<SE3d> gt;
  TrackWindow(&seq, 15, &tracker, &problem, &keyframe_of_frame, &gt);
  ASSERT_EQ(tracker.objects().size(), 1u);
  const int64_t id = tracker.objects().begin()->first;
  auto drift = [&](const TrackedObject& o) {
    double sum = 0.0, rot = 0.0;
    const SE3d est0 = o.history.front().world_from_object;
    for (size_t i = 1; i < o.history.size(); ++i) {
      const SE3d est_motion = o.history[i].world_from_object * est0.Inverse();
      const SE3d gt_motion = gt[i] * gt[0].Inverse();
      sum += TranslationError(est_motion, gt_motion);
      rot += RotationErrorDeg(est_motion, gt_motion);
    }
    return std::make_pair(sum / (o.history.size() - 1), rot / (o.history.size() - 1));
  };
  const auto before = drift(tracker.objects().at(id));
  const std::vector<ObjectBaLink> links =
      AddTrackedObjectsToBa(tracker, keyframe_of_frame, ObjectBaOptions{}, &problem);
  ASSERT_EQ(links.size(), 1u);
  EXPECT_EQ(problem.objects[0].frames.size(), 15u);
  EXPECT_TRUE(problem.objects[0].frames[0].fixed);
  const auto summary = SolveDynamicBa(&problem, DynamicBaOptions{});
  ASSERT_TRUE(summary.ok() && summary->usable);
  ApplyBaToTrackedObjects(problem, links, ObjectBaOptions{}, &tracker);
  const auto after = drift(tracker.objects().at(id));
  std::printf(
      "[tracker + dynamic BA] mean trajectory error %.3f m / %.3f deg -> %.3f m / %.3f deg (%d "
      "dynamic terms)\n",
      before.first,
      before.second,
      after.first,
      after.second,
      summary->num_dynamic_terms);
  EXPECT_LT(after.first, 0.7 * before.first);
  EXPECT_LT(after.second, before.second);
  // The tracker continues from the refined state.
  const auto next = tracker.Process(seq.Next(5, true));
  ASSERT_TRUE(next.ok());
  EXPECT_EQ((*next)[0].state, ObjectState::kTracked);
}

// The step twist written back is the mean over the last twist_steps steps of
// the refined poses, exactly; over 6 noisy sequences it follows the car's true
// speed more closely than the last step alone.
TEST(ObjectBa, TheWrittenBackTwistIsTheMeanOfTheLastSteps) {
  double speed_error[3] = {0.0, 0.0, 0.0};
  for (int steps : {1, 2}) {
    for (uint64_t seed = 1; seed <= 6; ++seed) {
      // Steps as noisy as before the disparity's own noise (§34), which
      // makes them accurate to 8 mm here: averaging is for noisy steps.
      CarSequence seq(0.7, 300 + seed);
      seq.set_independent_right_noise(true);
      ObjectTrackerOptions tracker_options;
      tracker_options.step_disparity_noise = false;
      ObjectTracker tracker(seq.camera(), tracker_options);
      DynamicBaProblem problem;
      std::map<int64_t, int> keyframe_of_frame;
      std::vector<SE3d> gt;
      TrackWindow(&seq, 10, &tracker, &problem, &keyframe_of_frame, &gt);
      ASSERT_EQ(tracker.objects().size(), 1u);
      ObjectBaOptions options;
      options.twist_steps = steps;
      const auto links = AddTrackedObjectsToBa(tracker, keyframe_of_frame, options, &problem);
      SolveAndApply(&problem, links, options, &tracker);
      const TrackedObject& o = tracker.objects().begin()->second;
      const size_t n = o.history.size();
      ASSERT_EQ(n, 10u);
      const Vector6d expected = o.joint.WorldProjector() *
                                (o.history[n - 1].world_from_object *
                                 o.history[n - 1 - steps].world_from_object.Inverse())
                                    .Log() /
                                steps;
      EXPECT_LT((o.twist_step - expected).norm(), 1e-12) << "seed " << seed;
      const Eigen::Vector3d c = gt.back().translation();
      const double true_speed = (seq.step().head<3>() + seq.step().tail<3>().cross(c)).norm();
      const double speed = (o.twist_step.head<3>() + o.twist_step.tail<3>().cross(c)).norm();
      speed_error[steps] += std::abs(speed - true_speed) / 6.0;
    }
  }
  std::printf("[written-back twist] mean speed error per step: 1 step %.3f m, 2 steps %.3f m\n",
              speed_error[1],
              speed_error[2]);
  EXPECT_LT(speed_error[2], speed_error[1]);
}

// A parked car's frames in which the tracker held it (and the frame each hold
// started from) enter the BA fixed: the refined trajectory keeps it still.
// A lost object is left out of the BA (no new observations; refining its
// tail again and again under a sliding gauge only drifts it).
TEST(ObjectBa, HeldFramesStayAndLostObjectsAreLeftOut) {
  CarSequence parked(0.5, 21);
  parked.set_step(Vector6d::Zero());
  ObjectTracker tracker(parked.camera(), ObjectTrackerOptions{});
  DynamicBaProblem problem;
  std::map<int64_t, int> keyframe_of_frame;
  std::vector<SE3d> gt;
  TrackWindow(&parked, 12, &tracker, &problem, &keyframe_of_frame, &gt);
  ASSERT_EQ(tracker.objects().size(), 1u);
  const TrackedObject& o = tracker.objects().begin()->second;
  ASSERT_EQ(o.history.size(), 12u);
  int held = 0;
  for (const ObjectPoseSample& s : o.history) held += s.held;
  ASSERT_GE(held, 9);
  const std::vector<SE3d> before = [&] {
    std::vector<SE3d> poses;
    for (const ObjectPoseSample& s : o.history) poses.push_back(s.world_from_object);
    return poses;
  }();
  const auto links = AddTrackedObjectsToBa(tracker, keyframe_of_frame, ObjectBaOptions{}, &problem);
  ASSERT_EQ(links.size(), 1u);
  const BaObject& ba = problem.objects[0];
  ASSERT_EQ(ba.frames.size(), 12u);
  for (size_t k = 0; k < 12; ++k) {
    const bool next_held = k + 1 < 12 && o.history[k + 1].held;
    EXPECT_EQ(ba.frames[k].fixed, k == 0 || o.history[k].held || next_held) << "frame " << k;
  }
  SolveAndApply(&problem, links, ObjectBaOptions{}, &tracker);
  const TrackedObject& after = tracker.objects().begin()->second;
  for (size_t k = 0; k < 12; ++k) {
    const bool next_held = k + 1 < 12 && after.history[k + 1].held;
    if (!after.history[k].held && !next_held) continue;
    EXPECT_EQ(after.history[k].world_from_object.translation(), before[k].translation()) << k;
    if (after.history[k].held) {
      EXPECT_EQ(after.history[k].world_from_object.translation(),
                after.history[k - 1].world_from_object.translation())
          << k;
    }
  }

  // A moving car tracked for 8 frames, then undetected: lost, left out.
  CarSequence moving(0.5, 22);
  ObjectTracker tracker2(moving.camera(), ObjectTrackerOptions{});
  DynamicBaProblem problem2;
  std::map<int64_t, int> keyframe_of_frame2;
  std::vector<SE3d> gt2;
  TrackWindow(&moving, 8, &tracker2, &problem2, &keyframe_of_frame2, &gt2);
  EXPECT_EQ(
      AddTrackedObjectsToBa(tracker2, keyframe_of_frame2, ObjectBaOptions{}, &problem2).size(), 1u);
  problem2.objects.clear();
  ASSERT_TRUE(tracker2.Process(moving.Next(5, false)).ok());
  ASSERT_EQ(tracker2.objects().begin()->second.state, ObjectState::kLost);
  EXPECT_TRUE(
      AddTrackedObjectsToBa(tracker2, keyframe_of_frame2, ObjectBaOptions{}, &problem2).empty());
}

// A car tracked for 6 frames, lost for 2, re-acquired and tracked for 6
// more: no constant-velocity term spans the gap (it would take the 3 steps
// across it for one), and the re-acquired pose is kept.
TEST(ObjectBa, NoConstantVelocityTermSpansAGap) {
  CarSequence seq(0.3, 23);
  ObjectTracker tracker(seq.camera(), ObjectTrackerOptions{});
  DynamicBaProblem problem;
  std::map<int64_t, int> keyframe_of_frame;
  std::map<int64_t, SE3d> gt;
  TrackAcrossAGap(&seq, false, &tracker, &problem, &keyframe_of_frame, &gt);
  ASSERT_EQ(tracker.objects().size(), 1u);
  const int64_t id = tracker.objects().begin()->first;
  ASSERT_EQ(tracker.objects().at(id).history.size(), 12u);  // re-acquired at frame 8
  const auto links = AddTrackedObjectsToBa(tracker, keyframe_of_frame, ObjectBaOptions{}, &problem);
  ASSERT_EQ(links.size(), 1u);
  const std::vector<BaObjectFrame>& frames = problem.objects[0].frames;
  ASSERT_EQ(frames.size(), 12u);
  for (size_t k = 0; k < frames.size(); ++k) {
    EXPECT_EQ(frames[k].follows_previous, k != 6) << "frame " << k;
    EXPECT_EQ(frames[k].fixed, k == 0 || k == 6) << "frame " << k;
  }
  const auto summary = SolveDynamicBa(&problem, DynamicBaOptions{});
  ASSERT_TRUE(summary.ok() && summary->usable);
  EXPECT_EQ(summary->num_const_velocity_terms, 8);  // 4 + 4 (10 across the gap)
  ApplyBaToTrackedObjects(problem, links, ObjectBaOptions{}, &tracker);
  const double max_error = MaxTrajectoryError(tracker.objects().at(id), gt);
  std::printf("[BA over a 2-frame gap] max trajectory error %.3f m\n", max_error);
  EXPECT_LT(max_error, 0.15);
}

// The same gap, the car continued on points it had not shown before
// (ObjectTrackerOptions::max_continuation_gap_frames): no point ties the two
// parts, so the first frame after the gap, fixed, is their only gauge. With a
// term across the gap and that frame free, as before §24, the BA drags the
// poses after the gap back by more than a metre.
TEST(ObjectBa, AContinuedTrackKeepsItsPoseAfterTheGap) {
  for (bool as_before : {false, true}) {
    CarSequence seq(0.3, 23, 3.0, 120);
    ObjectTracker tracker(seq.camera(), ObjectTrackerOptions{});
    DynamicBaProblem problem;
    std::map<int64_t, int> keyframe_of_frame;
    std::map<int64_t, SE3d> gt;
    TrackAcrossAGap(&seq, true, &tracker, &problem, &keyframe_of_frame, &gt);
    ASSERT_EQ(tracker.objects().size(), 1u);
    const int64_t id = tracker.objects().begin()->first;
    const TrackedObject& o = tracker.objects().at(id);
    ASSERT_EQ(o.history.size(), 12u);  // continued at frame 8
    int64_t last_old = -1;             // the points are all new
    for (const ObjectPoseSample& sample : o.history) {
      if (sample.frame_index >= 8) continue;
      for (const ObjectPointObservation& obs : sample.observations)
        last_old = std::max(last_old, obs.point_id);
    }
    for (const ObjectPoint& p : o.points) EXPECT_GT(p.id, last_old);
    const auto links =
        AddTrackedObjectsToBa(tracker, keyframe_of_frame, ObjectBaOptions{}, &problem);
    ASSERT_EQ(links.size(), 1u);
    BaObjectFrame& after_gap = problem.objects[0].frames.at(6);
    EXPECT_FALSE(after_gap.follows_previous);
    EXPECT_TRUE(after_gap.fixed);
    if (as_before) {
      after_gap.follows_previous = true;
      after_gap.fixed = false;
    }
    SolveAndApply(&problem, links, ObjectBaOptions{}, &tracker);
    const double max_error = MaxTrajectoryError(o, gt);
    std::printf("[continued track in the BA, %s] max trajectory error %.3f m\n",
                as_before ? "term across the gap, pose free" : "now",
                max_error);
    if (as_before) {
      EXPECT_GT(max_error, 0.5);
    } else {
      EXPECT_LT(max_error, 0.15);
    }
  }
}

// A car tracked with the dynamic BA after every frame, as the object stage
// runs it, whose measurement fails (1 m aside) in frame 11 of 14: the tracker
// refuses that step and coasts on its prediction (from the refined state),
// keeping no observation. While that frame is the newest, nothing but the
// motion priors would place it, by extrapolation (here the constant-
// acceleration prior on translation, with the constant-velocity one on
// rotation only): ObjectBaOptions::fix_coasted_newest_frame keeps the
// tracker's prediction, exactly, and it is the better guess. In the next
// windows the frame is free again, interpolated between measured ones.
TEST(ObjectBa, CoastedFramesStayWhereTheTrackerPutThem) {
  const int kGlitch = 11;
  std::map<bool, std::pair<double, double>> error_of;  // fix -> at the coast, at the end
  for (bool fix : {true, false}) {
    double sum_error_at_coast = 0.0, sum_error_end = 0.0;
    const int kSeeds = 6;
    for (int seed = 0; seed < kSeeds; ++seed) {
      CarSequence seq(0.7, 60 + static_cast<uint64_t>(seed));
      ObjectTracker tracker(seq.camera(), ObjectTrackerOptions{});
      DynamicBaProblem problem;
      problem.camera = seq.camera();
      std::map<int64_t, int> keyframe_of_frame;
      std::map<int64_t, SE3d> gt;
      ObjectBaOptions options;
      options.fix_coasted_newest_frame = fix;
      DynamicBaOptions ba;
      ba.const_velocity_sqrt_weight.head<3>().setZero();
      ba.const_acceleration_sqrt_weight << 40, 40, 40, 0, 0, 0;
      // Error of the motion since the object's first frame, at its newest.
      auto motion_error = [&](const TrackedObject& o) {
        const ObjectPoseSample& first = o.history.front();
        return TranslationError(
            o.world_from_object * first.world_from_object.Inverse(),
            gt.at(o.history.back().frame_index) * gt.at(first.frame_index).Inverse());
      };
      for (int i = 0; i < 14; ++i) {
        seq.set_measurement_glitch(i == kGlitch ? SE3d(geometry::SO3d(), Eigen::Vector3d(1.0, 0, 0))
                                                : SE3d());
        const ObjectFrameInput f = seq.Next(5, true);
        gt[f.frame_index] = seq.world_from_object();
        ASSERT_TRUE(tracker.Process(f).ok());
        AddKeyframe(f, i, &problem, &keyframe_of_frame);
        ASSERT_EQ(tracker.objects().size(), 1u);
        const TrackedObject& o = tracker.objects().begin()->second;
        if (o.history.size() < 3) continue;
        const size_t n = o.history.size();
        const bool coasted = o.history.back().observations.empty();
        ASSERT_EQ(coasted, i == kGlitch) << "frame " << i;
        const SE3d predicted = o.world_from_object;
        problem.objects.clear();
        const auto links = AddTrackedObjectsToBa(tracker, keyframe_of_frame, options, &problem);
        ASSERT_EQ(links.size(), 1u);
        ASSERT_EQ(problem.objects[0].frames.size(), n);
        EXPECT_EQ(problem.objects[0].frames[n - 1].fixed, coasted && fix) << "frame " << i;
        SolveAndApply(&problem, links, options, &tracker, ba);
        if (coasted && fix) {
          EXPECT_LT((o.world_from_object.translation() - predicted.translation()).norm(), 1e-12);
          EXPECT_LT(RotationErrorDeg(o.world_from_object, predicted), 1e-9);
        }
        if (coasted) sum_error_at_coast += motion_error(o);
        if (i == 13) sum_error_end += motion_error(o);
      }
    }
    std::printf(
        "[coasted frame %s] mean error of the motion to the current pose: at the coast %.3f m, "
        "2 frames later %.3f m\n",
        fix ? "fixed" : "free",
        sum_error_at_coast / kSeeds,
        sum_error_end / kSeeds);
    error_of[fix] = {sum_error_at_coast / kSeeds, sum_error_end / kSeeds};
  }
  EXPECT_LT(error_of[true].first, 0.9 * error_of[false].first);
  EXPECT_NEAR(error_of[true].second, error_of[false].second, 0.005);
}
// A car braking from 8 m/s at 2 m/s² (0.02 m per frame squared), tracked over
// 36 frames with the dynamic BA after every frame on the last 10 frames, as
// the object stage runs it. Once the window slides along the track, its
// second frame is fixed too (ObjectBaOptions::keep_velocity_at_gauge); without
// that, the constant-velocity prior's pull on the frame next to the gauge
// adds up from window to window and the car falls behind.
TEST(ObjectBa, ASlidingWindowKeepsTheVelocityAtItsGauge) {
  const int kFrames = 36, kWindow = 10;
  std::map<bool, double> error_of;
  for (bool keep : {true, false}) {
    double sum_error = 0.0;
    const int kSeeds = 4;
    for (int seed = 0; seed < kSeeds; ++seed) {
      CarSequence seq(0.5, 80 + static_cast<uint64_t>(seed));
      const Vector6d step0 = seq.step();
      ObjectTracker tracker(seq.camera(), ObjectTrackerOptions{});
      ObjectBaOptions options;
      options.keep_velocity_at_gauge = keep;
      // Points free (no prior): inherited points held keep the velocity
      // too (one fixed frame 0.126 -> 0.029 m, two 0.019 -> 0.025 m).
      options.inherited_point_prior = false;
      std::map<int64_t, SE3d> gt;
      SeenFrames seen;
      for (int i = 0; i < kFrames; ++i) {
        seq.set_step(step0 * (0.8 - 0.02 * i) / 0.8);
        const ObjectFrameInput f = seq.Next(5, true);
        gt[f.frame_index] = seq.world_from_object();
        seen.Add(f);
        ASSERT_TRUE(tracker.Process(f).ok());
        ASSERT_EQ(tracker.objects().size(), 1u);
        std::map<int64_t, int> keyframe_of_frame;
        DynamicBaProblem problem = seen.Window(seq.camera(), kWindow, &keyframe_of_frame);
        const auto links = AddTrackedObjectsToBa(tracker, keyframe_of_frame, options, &problem);
        if (links.empty()) continue;
        const TrackedObject& o = tracker.objects().begin()->second;
        const bool slid = o.history.front().frame_index < f.frame_index - kWindow + 1;
        ASSERT_GE(problem.objects[0].frames.size(), 3u);
        EXPECT_TRUE(problem.objects[0].frames[0].fixed);
        EXPECT_EQ(problem.objects[0].frames[1].fixed, keep && slid) << "frame " << i;
        SolveAndApply(&problem, links, options, &tracker);
      }
      const TrackedObject& o = tracker.objects().begin()->second;
      ASSERT_EQ(o.history.back().frame_index, kFrames - 1);
      sum_error += MotionErrorSinceFirstFrame(o, gt);
    }
    error_of[keep] = sum_error / kSeeds;
    std::printf(
        "[braking car, sliding BA windows, %s] error of the motion after %d frames %.3f m\n",
        keep ? "2 fixed frames" : "1 fixed frame",
        kFrames,
        error_of[keep]);
  }
  EXPECT_LT(error_of[true], 0.6 * error_of[false]);
}

// A car whose points turn over (one new point seen and one lost per frame,
// as when the camera comes to see other corners of it), refined by the BA
// after every frame on the last 10 frames. Points the window inherits from
// earlier windows (observations before it) get a prior there
// (ObjectBaOptions::inherited_point_prior), or are held with
// hold_points_seen_before_window; solved again from the window alone they
// follow its sliding gauge, and the car's motion drifts further from the
// truth.
//
// The BA runs with Huber on the objects' terms, as when the prior was
// introduced. With Tukey's biweight (the default) this drift is decided by
// single runaway tracker steps at the points' turnover (seed 1: 0.03 ->
// 0.83 m in free and prior alike, docs/objects.md section 67), not by the
// prior; on the 24 rendered object runs the prior still lowers the cars'
// ATE under Tukey (0.0960 -> 0.0877 m).
TEST(ObjectBa, ASlidingWindowKeepsWhatItsInheritedPointsWereSeenAs) {
  const int kFrames = 30, kWindow = 10, kShown = 30;
  enum Variant { kFree, kPrior, kHeld };
  std::map<Variant, double> error_of;
  DynamicBaOptions huber;
  huber.dynamic_tukey_c = 0.0;
  for (Variant variant : {kFree, kPrior, kHeld}) {
    double sum_error = 0.0;
    const int kSeeds = 12;
    for (int seed = 0; seed < kSeeds; ++seed) {
      CarSequence seq(0.7, 500 + static_cast<uint64_t>(seed), 3.0, kShown + kFrames);
      seq.set_step(0.4 * seq.step());  // 3.2 m/s
      ObjectTracker tracker(seq.camera(), ObjectTrackerOptions{});
      ObjectBaOptions options;
      options.inherited_point_prior = variant == kPrior;
      options.hold_points_seen_before_window = variant == kHeld ? 4 : 0;
      std::map<int64_t, SE3d> gt;
      SeenFrames seen;
      for (int i = 0; i < kFrames; ++i) {
        seq.set_shown_range(static_cast<size_t>(i), static_cast<size_t>(i + kShown));
        const ObjectFrameInput f = seq.Next(5, true);
        gt[f.frame_index] = seq.world_from_object();
        seen.Add(f);
        ASSERT_TRUE(tracker.Process(f).ok());
        ASSERT_EQ(tracker.objects().size(), 1u) << "frame " << i << " seed " << seed;
        std::map<int64_t, int> keyframe_of_frame;
        DynamicBaProblem problem = seen.Window(seq.camera(), kWindow, &keyframe_of_frame);
        const auto links = AddTrackedObjectsToBa(tracker, keyframe_of_frame, options, &problem);
        if (links.empty()) continue;
        // Observations before the window = all of the point's inlier
        // observations less those in the window's frames.
        const TrackedObject& o = tracker.objects().begin()->second;
        const BaObject& ba = problem.objects[0];
        ASSERT_EQ(ba.fixed_points.size(), ba.points_in_object.size());
        ASSERT_EQ(ba.point_prior_sqrt_information.size(), ba.points_in_object.size());
        std::map<int64_t, int> in_window;
        for (const BaObservation& obs : ba.observations) ++in_window[links[0].point_ids[obs.point]];
        int inherited = 0;
        for (size_t k = 0; k < ba.points_in_object.size(); ++k) {
          const int64_t id = links[0].point_ids[k];
          int before = 0;
          for (const ObjectPoint& p : o.points) {
            if (p.id == id) before = p.num_observations - in_window[id];
          }
          inherited += before > 0 ? 1 : 0;
          EXPECT_EQ(ba.fixed_points[k], variant == kHeld && before >= 4) << "frame " << i;
          const Eigen::Matrix3d& a = ba.point_prior_sqrt_information[k];
          EXPECT_EQ(a.isZero(), variant != kPrior || before == 0) << "frame " << i;
          if (!a.isZero()) {
            // Symmetric positive definite (sqrt(before) times one stereo
            // observation's square-root information).
            EXPECT_LT((a - a.transpose()).norm(), 1e-9 * a.norm());
            EXPECT_GT(a.selfadjointView<Eigen::Lower>().eigenvalues().minCoeff(), 0.0);
          }
        }
        if (i >= 2 * kWindow) {
          EXPECT_GT(inherited, 0) << "frame " << i;
        }
        SolveAndApply(&problem, links, options, &tracker, huber);
      }
      const TrackedObject& o = tracker.objects().begin()->second;
      ASSERT_EQ(o.history.back().frame_index, kFrames - 1);
      sum_error += MotionErrorSinceFirstFrame(o, gt);
    }
    error_of[variant] = sum_error / kSeeds;
  }
  std::printf(
      "[car with turning-over points, sliding BA windows] error of the motion after %d frames: "
      "free %.3f m, prior %.3f m, held %.3f m\n",
      kFrames,
      error_of[kFree],
      error_of[kPrior],
      error_of[kHeld]);
  EXPECT_LT(error_of[kPrior], error_of[kFree]);
  EXPECT_LT(error_of[kHeld], error_of[kFree]);
}

// A car turning at 4° per frame from its first frame (exact flow, 0.5 px
// keypoint noise; 12 steps, 48°), its reported pose after every frame: with
// the BA on the last 10 frames after each one, the reported steps' rotation
// error is 0.6 times the tracker's alone (0.163 against 0.271° per step),
// and neither turns the car too far or too little on average (−0.007 and
// −0.102°). On the rendered turning cars the reported steps turned 0.14°
// per step too far with the BA (docs/objects.md §42); not here.
TEST(ObjectBa, ASlidingWindowFollowsATurningCar) {
  std::map<bool, double> mean_excess, mean_error;
  for (bool with_ba : {false, true}) {
    double sum_excess = 0.0, sum_error = 0.0;
    int steps = 0;
    for (int seed = 0; seed < 10; ++seed) {
      CarSequence seq(0.5, 900 + static_cast<uint64_t>(seed));
      Vector6d turning;  // per frame, in the car's frame (joint axes)
      turning << 0.0, 0.8, 0.0, 0.0, 0.0, 0.07;
      seq.set_step(seq.world_from_object().Adjoint() * turning);
      ObjectTrackerOptions tracker_options;
      tracker_options.young_turn_prior_poses = 0;  // it turns from its first frame
      ObjectTracker tracker(seq.camera(), tracker_options);
      const ObjectBaOptions options;
      SeenFrames seen;
      SE3d last_reported, last_true;
      for (int i = 0; i < 13; ++i) {
        const ObjectFrameInput f = seq.Next(5, true);
        seen.Add(f);
        ASSERT_TRUE(tracker.Process(f).ok());
        ASSERT_EQ(tracker.objects().size(), 1u) << "seed " << seed << " frame " << i;
        if (with_ba) {
          std::map<int64_t, int> keyframe_of_frame;
          DynamicBaProblem problem = seen.Window(seq.camera(), 10, &keyframe_of_frame);
          const auto links = AddTrackedObjectsToBa(tracker, keyframe_of_frame, options, &problem);
          if (!links.empty()) {
            SolveAndApply(&problem, links, options, &tracker);
          }
        }
        const TrackedObject& o = tracker.objects().begin()->second;
        ASSERT_NE(o.state, ObjectState::kLost) << "seed " << seed << " frame " << i;
        if (i >= 3) {  // past the first steps' start from rest
          const double excess = TurnExcessDeg(o.world_from_object * last_reported.Inverse(),
                                              seq.world_from_object() * last_true.Inverse());
          sum_excess += excess;
          sum_error += std::abs(excess);
          ++steps;
        }
        last_reported = o.world_from_object;
        last_true = seq.world_from_object();
      }
    }
    mean_excess[with_ba] = sum_excess / steps;
    mean_error[with_ba] = sum_error / steps;
    std::printf(
        "[turning car, 4 deg/frame, %s] reported steps: mean turn excess %+.3f deg, mean "
        "|error| %.3f deg\n",
        with_ba ? "BA after every frame" : "tracker alone",
        mean_excess[with_ba],
        mean_error[with_ba]);
  }
  EXPECT_LT(mean_error[true], 0.75 * mean_error[false]);
  EXPECT_LT(std::abs(mean_excess[true]), 0.15);
  EXPECT_LT(std::abs(mean_excess[false]), 0.15);
}

// The camera's height estimate drifts by 5 mm per frame (the tracker gets
// the drifting poses; the road plane under the car was fitted when the car
// was created). Tracked with the BA after every frame on the last 10 frames:
// held to its plane, the car can only match its image height by moving in
// depth; with a soft freedom along the plane's normal
// (ObjectBaOptions::soft_normal_step_sigma_m) the BA lifts it instead. The
// tracker keeps the plane it created the car on
// (ObjectTrackerOptions::follow_parent_plane off): following the drifting
// plane, the default, leaves the car 0.010 m off with σ = 0 (§37).
TEST(ObjectBa, ASoftNormalKeepsACarUnderADriftingCameraAtItsDepth) {
  const int kFrames = 30, kWindow = 10;
  std::map<double, double> error_of;  // σ -> mean error under the camera at the end
  for (double sigma : {0.01, 0.0}) {
    double sum_error = 0.0;
    const int kSeeds = 4;
    for (int seed = 0; seed < kSeeds; ++seed) {
      CarSequence seq(0.5, 90 + static_cast<uint64_t>(seed));
      seq.set_camera_height_drift(0.005);
      ObjectTrackerOptions tracker_options;
      tracker_options.follow_parent_plane = false;
      ObjectTracker tracker(seq.camera(), tracker_options);
      ObjectBaOptions options;
      options.soft_normal_step_sigma_m = sigma;
      Eigen::Vector3d centre_true = Eigen::Vector3d::Zero();
      for (const Eigen::Vector3d& p : seq.points()) centre_true += p / seq.points().size();
      Eigen::Vector3d centre_in_object = Eigen::Vector3d::Zero();
      SeenFrames seen;
      double error = 0.0;
      for (int i = 0; i < kFrames; ++i) {
        const ObjectFrameInput f = seq.Next(5, true);
        seen.Add(f);
        ASSERT_TRUE(tracker.Process(f).ok());
        ASSERT_EQ(tracker.objects().size(), 1u);
        std::map<int64_t, int> keyframe_of_frame;
        DynamicBaProblem problem = seen.Window(seq.camera(), kWindow, &keyframe_of_frame);
        const auto links = AddTrackedObjectsToBa(tracker, keyframe_of_frame, options, &problem);
        if (!links.empty()) {
          EXPECT_EQ(problem.objects[0].soft_normal_step_sigma_m, sigma);
          const auto summary = SolveDynamicBa(&problem, DynamicBaOptions{});
          ASSERT_TRUE(summary.ok() && summary->usable);
          EXPECT_EQ(summary->num_normal_step_terms > 0, sigma > 0.0);
          ApplyBaToTrackedObjects(problem, links, options, &tracker);
        }
        const SE3d camera_from_object =
            seq.camera_from_world_given() * tracker.objects().begin()->second.world_from_object;
        const Eigen::Vector3d truth =
            seq.camera_from_world_true() * (seq.world_from_object() * centre_true);
        if (i == 0) centre_in_object = camera_from_object.Inverse() * truth;
        error = (camera_from_object * centre_in_object - truth).norm();
      }
      sum_error += error;
    }
    error_of[sigma] = sum_error / kSeeds;
    std::printf(
        "[camera height drifting 5 mm/frame, BA windows, soft normal sigma %.2f m] error "
        "of the car under the camera after %d frames %.3f m\n",
        sigma,
        kFrames,
        error_of[sigma]);
  }
  EXPECT_LT(error_of[0.01], 0.6 * error_of[0.0]);
}

}  // namespace
}  // namespace twist::objects
