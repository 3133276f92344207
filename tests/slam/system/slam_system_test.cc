// SlamSystem on rendered synthetic streets (slam/sim, exact ground truth):
// input validation, determinism, exact save/load resume, accuracy, and the
// background mapping mode.
#include "slam/system/slam_system.h"

#include <glog/logging.h>
#include <gtest/gtest.h>
#include <unistd.h>

#include <cstdio>
#include <cstring>
#include <fstream>
#include <memory>
#include <opencv2/imgproc.hpp>

#include "slam/io/metrics.h"
#include "slam/sim/renderer.h"
#include "slam/sim/scenarios.h"
#include "tests/slam/system/sim_clip.h"

namespace twist {
namespace {

TEST(SlamSystem, RejectsBadInputAndKeepsItsState) {
  const Clip& clip = SmallClip();
  auto sys = SlamSystem::Create(clip.config);
  ASSERT_TRUE(sys.ok()) << sys.status();
  ASSERT_TRUE((*sys)->Process(clip.frames[0]).ok());
  const StereoFrame& good = clip.frames[1];
  auto expect_invalid = [&](StereoFrame f, const char* what) {
    auto r = (*sys)->Process(f);
    EXPECT_EQ(r.status().code(), absl::StatusCode::kInvalidArgument) << what;
    EXPECT_EQ((*sys)->frames_processed(), 1) << what;
  };
  StereoFrame f = good;
  f.left = cv::Mat();
  expect_invalid(f, "empty left");
  f = good;
  f.right = good.right(cv::Rect(0, 0, good.right.cols - 2, good.right.rows)).clone();
  expect_invalid(f, "size mismatch");
  f = good;
  cv::cvtColor(good.right, f.right, cv::COLOR_GRAY2BGR);
  expect_invalid(f, "type mismatch");
  f = good;
  cv::resize(good.left, f.left, cv::Size(), 0.5, 0.5);
  cv::resize(good.right, f.right, cv::Size(), 0.5, 0.5);
  expect_invalid(f, "size differs from calibration");
  f = good;
  f.left.convertTo(f.left, CV_16UC1);
  f.right.convertTo(f.right, CV_16UC1);
  expect_invalid(f, "16-bit images");
  f = good;
  f.panoptic = cv::Mat(10, 10, CV_16UC1, cv::Scalar(0));
  expect_invalid(f, "mask size");
  f = good;
  f.panoptic = cv::Mat(good.left.size(), CV_8UC1, cv::Scalar(0));
  expect_invalid(f, "mask type");
  f = good;
  f.timestamp_ns = clip.frames[0].timestamp_ns;
  expect_invalid(f, "repeated timestamp");
  // The session still works, and gives what a fresh session gives.
  auto r1 = (*sys)->Process(good);
  ASSERT_TRUE(r1.ok());
  auto fresh = SlamSystem::Create(clip.config);
  ASSERT_TRUE((*fresh)->Process(clip.frames[0]).ok());
  auto r2 = (*fresh)->Process(good);
  ASSERT_TRUE(r2.ok());
  EXPECT_TRUE(SamePose(r1->world_from_camera, r2->world_from_camera));
  (*sys)->Shutdown();
  EXPECT_EQ((*sys)->Process(clip.frames[2]).status().code(), absl::StatusCode::kFailedPrecondition);
}

TEST(SlamSystem, InvalidConfigurationIsRejected) {
  SessionConfig config = SmallClip().config;
  config.options.num_features = 10;
  EXPECT_EQ(SlamSystem::Create(config).status().code(), absl::StatusCode::kInvalidArgument);
  config = SmallClip().config;
  config.camera.baseline = -1;
  EXPECT_EQ(SlamSystem::Create(config).status().code(), absl::StatusCode::kInvalidArgument);
}

TEST(SlamSystem, SynchronousModeIsDeterministic) {
  const Clip& clip = SmallClip();
  auto a = SlamSystem::Create(clip.config);
  auto b = SlamSystem::Create(clip.config);
  for (size_t k = 0; k < clip.frames.size(); ++k) {
    auto ra = (*a)->Process(clip.frames[k]);
    auto rb = (*b)->Process(clip.frames[k]);
    ASSERT_TRUE(ra.ok() && rb.ok());
    EXPECT_EQ(ra->state, rb->state);
    EXPECT_TRUE(SamePose(ra->world_from_camera, rb->world_from_camera)) << "frame " << k;
    EXPECT_EQ(ra->num_map_points, rb->num_map_points);
    EXPECT_EQ(ra->is_keyframe, rb->is_keyframe);
  }
}

inline bool SameObjects(const FrameResult& a, const FrameResult& b) {
  if (a.objects.size() != b.objects.size()) return false;
  for (size_t k = 0; k < a.objects.size(); ++k) {
    const ObjectResult& x = a.objects[k];
    const ObjectResult& y = b.objects[k];
    if (x.id != y.id || x.state != y.state || !SamePose(x.world_from_object, y.world_from_object) ||
        std::memcmp(x.twist_in_world.data(), y.twist_in_world.data(), 6 * sizeof(double)) != 0) {
      return false;
    }
  }
  return true;
}

TEST(SlamSystem, SynchronousModeIsDeterministicWithObjectsAndDynamicBa) {
  // Moving and parked cars, the objects' dynamic BA (on by default) and the
  // parked-instance logic (switched on): two sessions fed the same frames, interleaved
  // (so their heaps differ), agree to the last bit, camera and objects.
  static const Clip* clip = new Clip(MakeClip("follow_braking", 24, 0.5));
  SessionConfig config = clip->config;
  ASSERT_GT(config.options.object_ba_window_frames, 0);  // on by default
  config.options.parked_objects_static = true;
  auto a = SlamSystem::Create(config);
  auto b = SlamSystem::Create(config);
  ASSERT_TRUE(a.ok() && b.ok());
  int ba_frames = 0, object_rows = 0;
  for (size_t k = 0; k < clip->frames.size(); ++k) {
    auto ra = (*a)->Process(clip->frames[k]);
    std::vector<std::unique_ptr<char[]>> junk;  // shift b's allocations
    for (int j = 0; j < 50; ++j) junk.push_back(std::make_unique<char[]>(64 + 40 * j));
    auto rb = (*b)->Process(clip->frames[k]);
    ASSERT_TRUE(ra.ok() && rb.ok());
    EXPECT_EQ(ra->state, rb->state);
    EXPECT_TRUE(SamePose(ra->world_from_camera, rb->world_from_camera)) << "frame " << k;
    EXPECT_EQ(ra->num_map_points, rb->num_map_points) << "frame " << k;
    EXPECT_TRUE(SameObjects(*ra, *rb)) << "frame " << k;
    object_rows += static_cast<int>(ra->objects.size());
    for (const StageTiming& t : ra->timings) ba_frames += t.stage == "objects_ba";
  }
  EXPECT_GT(object_rows, 20);
  EXPECT_GT(ba_frames, 10);  // the dynamic BA did run
}

TEST(SlamSystem, ObjectOptionsAreValidatedAndSaved) {
  SessionConfig config = SmallClip().config;
  config.options.object_ba_window_frames = 2;
  EXPECT_EQ(SlamSystem::Create(config).status().code(), absl::StatusCode::kInvalidArgument);
  config.options.object_ba_window_frames = 0;
  EXPECT_TRUE(SlamSystem::Create(config).ok());
  config.options.object_ba_iterations = 0;
  EXPECT_EQ(SlamSystem::Create(config).status().code(), absl::StatusCode::kInvalidArgument);
  config.options.object_ba_window_frames = 7;
  config.options.object_ba_iterations = 3;
  config.options.parked_objects_static = true;
  auto sys = SlamSystem::Create(config);
  ASSERT_TRUE(sys.ok());
  ASSERT_TRUE((*sys)->Process(SmallClip().frames[0]).ok());
  const std::string path = TempPath("options_state");
  ASSERT_TRUE((*sys)->Save(path).ok());
  auto loaded = SlamSystem::Load(path);
  ASSERT_TRUE(loaded.ok()) << loaded.status();
  EXPECT_EQ((*loaded)->config().options.object_ba_window_frames, 7);
  EXPECT_EQ((*loaded)->config().options.object_ba_iterations, 3);
  EXPECT_TRUE((*loaded)->config().options.parked_objects_static);
  std::remove(path.c_str());
}

// The objects are not persisted (they restart after a resume), so the resume
// is bit-exact only when the camera does not depend on them: without the
// parked-instance logic (the default). With it, see the next test.
TEST(SlamSystem, SaveLoadResumesWithIdenticalResults) {
  const Clip& clip = SmallClip();
  const size_t split = 13;
  SessionConfig config = clip.config;
  config.options.parked_objects_static = false;
  auto full = SlamSystem::Create(config);
  std::vector<FrameResult> expected;
  for (const auto& f : clip.frames) expected.push_back(*(*full)->Process(f));

  auto first = SlamSystem::Create(config);
  for (size_t k = 0; k < split; ++k) ASSERT_TRUE((*first)->Process(clip.frames[k]).ok());
  const std::string path = TempPath("slam_state");
  ASSERT_TRUE((*first)->Save(path).ok());
  auto resumed = SlamSystem::Load(path);
  ASSERT_TRUE(resumed.ok()) << resumed.status();
  EXPECT_EQ((*resumed)->frames_processed(), static_cast<int64_t>(split));
  const MapSnapshot s1 = (*first)->Snapshot(), s2 = (*resumed)->Snapshot();
  ASSERT_EQ(s1.points.size(), s2.points.size());
  ASSERT_EQ(s1.keyframes.size(), s2.keyframes.size());
  // Timestamps must keep increasing after the resume.
  EXPECT_FALSE((*resumed)->Process(clip.frames[split - 1]).ok());
  for (size_t k = split; k < clip.frames.size(); ++k) {
    auto r = (*resumed)->Process(clip.frames[k]);
    ASSERT_TRUE(r.ok());
    EXPECT_EQ(r->state, expected[k].state) << k;
    EXPECT_TRUE(SamePose(r->world_from_camera, expected[k].world_from_camera)) << "frame " << k;
    EXPECT_EQ(r->num_map_points, expected[k].num_map_points) << k;
    EXPECT_EQ(r->num_keyframes, expected[k].num_keyframes) << k;
  }
  std::remove(path.c_str());
}

TEST(SlamSystem, SaveLoadWithParkedObjectsKeepsTracking) {
  // static_street is lined with parked cars: with parked_objects_static their
  // points join the static pipeline. The parked set is saved, the objects
  // restart after Load, so the resumed run is close to (not bit-identical
  // with) the uninterrupted one.
  const Clip& clip = SmallClip();
  const size_t split = 15;
  SessionConfig config = clip.config;
  config.options.parked_objects_static = true;
  auto full = SlamSystem::Create(config);
  std::vector<FrameResult> expected;
  for (const auto& f : clip.frames) expected.push_back(*(*full)->Process(f));
  auto first = SlamSystem::Create(config);
  for (size_t k = 0; k < split; ++k) ASSERT_TRUE((*first)->Process(clip.frames[k]).ok());
  const std::string path = TempPath("slam_state_parked");
  ASSERT_TRUE((*first)->Save(path).ok());
  auto resumed = SlamSystem::Load(path);
  ASSERT_TRUE(resumed.ok()) << resumed.status();
  std::vector<geometry::SE3d> est;
  for (size_t k = 0; k < split; ++k) est.push_back(expected[k].world_from_camera);
  for (size_t k = split; k < clip.frames.size(); ++k) {
    auto r = (*resumed)->Process(clip.frames[k]);
    ASSERT_TRUE(r.ok());
    EXPECT_EQ(r->state, TrackingState::kOk) << k;
    EXPECT_LT(
        (r->world_from_camera.translation() - expected[k].world_from_camera.translation()).norm(),
        0.05)
        << "frame " << k;
    est.push_back(r->world_from_camera);
  }
  auto m = io::EvaluateCamera(clip.gt, est);
  ASSERT_TRUE(m.ok());
  EXPECT_LE(m->ate_rmse, 2 * kMaxStaticStreetAte);
  std::remove(path.c_str());
}

TEST(SlamSystem, LoadRejectsMissingAndCorruptFiles) {
  EXPECT_EQ(SlamSystem::Load(TempPath("does_not_exist")).status().code(),
            absl::StatusCode::kNotFound);
  const std::string garbage = TempPath("garbage");
  {
    std::ofstream out(garbage, std::ios::binary);
    out << "not a state file at all";
  }
  EXPECT_EQ(SlamSystem::Load(garbage).status().code(), absl::StatusCode::kDataLoss);
  // A valid file cut short.
  const Clip& clip = SmallClip();
  auto sys = SlamSystem::Create(clip.config);
  for (int k = 0; k < 4; ++k) ASSERT_TRUE((*sys)->Process(clip.frames[k]).ok());
  const std::string path = TempPath("state_full");
  ASSERT_TRUE((*sys)->Save(path).ok());
  std::ifstream in(path, std::ios::binary);
  std::string data((std::istreambuf_iterator<char>(in)), std::istreambuf_iterator<char>());
  {
    std::ofstream out(garbage, std::ios::binary);
    out.write(data.data(), static_cast<std::streamsize>(data.size() / 2));
  }
  EXPECT_EQ(SlamSystem::Load(garbage).status().code(), absl::StatusCode::kDataLoss);
  std::remove(garbage.c_str());
  std::remove(path.c_str());
}

TEST(SlamSystem, BackgroundMappingTracksTheStreet) {
  const Clip& clip = SmallClip();
  SessionConfig config = clip.config;
  config.options.mapping_mode = MappingMode::kBackground;
  auto sys = SlamSystem::Create(config);
  ASSERT_TRUE(sys.ok());
  std::vector<geometry::SE3d> est;
  for (const auto& f : clip.frames) {
    auto r = (*sys)->Process(f);
    ASSERT_TRUE(r.ok());
    EXPECT_EQ(r->state, TrackingState::kOk);
    est.push_back(r->world_from_camera);
  }
  // Save waits for the mapping thread, then the file loads.
  const std::string path = TempPath("bg_state");
  ASSERT_TRUE((*sys)->Save(path).ok());
  EXPECT_TRUE(SlamSystem::Load(path).ok());
  std::remove(path.c_str());
  (*sys)->Shutdown();
  (*sys)->Shutdown();
  auto m = io::EvaluateCamera(clip.gt, est);
  ASSERT_TRUE(m.ok());
  EXPECT_LE(m->ate_rmse, 2 * kMaxStaticStreetAte);
}

}  // namespace
}  // namespace twist
