#include "slam/objects/object_ba.h"

#include <gtest/gtest.h>

#include <cstdio>

#include "tests/slam/objects/car_sequence.h"

namespace twist::objects {
namespace {

using namespace twist::objects::testing;  // NOLINT

// Tracker output refined by the dynamic BA over the whole window: the
// object's trajectory error (motion since its first frame) goes down.
TEST(ObjectBa, TrackerWindowRefinedByDynamicBa) {
  CarSequence seq(0.7, 21);
  ObjectTracker tracker(seq.camera(), ObjectTrackerOptions{});
  DynamicBaProblem problem;
  problem.camera = seq.camera();
  std::map<int64_t, int> keyframe_of_frame;
  std::vector<SE3d> gt;
  for (int i = 0; i < 15; ++i) {
    const ObjectFrameInput f = seq.Next(5, true);
    gt.push_back(seq.world_from_object());
    ASSERT_TRUE(tracker.Process(f).ok());
    BaKeyframe kf;
    kf.id = i;
    kf.timestamp_ns = f.timestamp_ns;
    kf.camera_from_world = f.camera_from_world;
    kf.fixed = true;  // camera poses from static tracking, held here
    keyframe_of_frame[f.frame_index] = static_cast<int>(problem.keyframes.size());
    problem.keyframes.push_back(kf);
  }
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
  ApplyBaToTrackedObjects(problem, links, &tracker);
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

}  // namespace
}  // namespace twist::objects
