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
    if (x.id != y.id || x.class_id != y.class_id || x.instance_id != y.instance_id ||
        x.state != y.state || x.stationary != y.stationary || x.joint != y.joint ||
        x.num_points != y.num_points || !SamePose(x.world_from_object, y.world_from_object) ||
        std::memcmp(x.twist_in_world.data(), y.twist_in_world.data(), 6 * sizeof(double)) != 0 ||
        std::memcmp(x.twist_in_joint.data(), y.twist_in_joint.data(), 6 * sizeof(double)) != 0 ||
        std::memcmp(&x.speed_mps, &y.speed_mps, sizeof(double)) != 0) {
      return false;
    }
  }
  return true;
}

inline bool SameClusterEvents(const FrameResult& a, const FrameResult& b) {
  if (a.cluster_events.size() != b.cluster_events.size()) return false;
  for (size_t k = 0; k < a.cluster_events.size(); ++k) {
    const ClusterEvent& x = a.cluster_events[k];
    const ClusterEvent& y = b.cluster_events[k];
    if (x.type != y.type || x.cluster_id != y.cluster_id || x.class_id != y.class_id ||
        x.instance_id != y.instance_id || x.is_dynamic != y.is_dynamic ||
        x.plane.has_value() != y.plane.has_value() ||
        (x.plane && std::memcmp(x.plane->data(), y.plane->data(), 4 * sizeof(double)) != 0)) {
      return false;
    }
  }
  return true;
}

// Moving and parked cars (the follow_braking scene), shared by the object tests.
const Clip& CarsClip() {
  static const Clip* clip = new Clip(MakeClip("follow_braking", 24, 0.5));
  return *clip;
}

TEST(SlamSystem, SynchronousModeIsDeterministicWithObjectsAndDynamicBa) {
  // Moving and parked cars, the objects' dynamic BA (on by default) and the
  // parked-instance logic (switched on): two sessions fed the same frames, interleaved
  // (so their heaps differ), agree to the last bit, camera and objects.
  const Clip* clip = &CarsClip();
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
    EXPECT_TRUE(SameClusterEvents(*ra, *rb)) << "frame " << k;
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
  config.options.object_ba_iterations = 3;
  for (double bad : {2.5, -2.01, std::nan("")}) {
    config.options.disparity_offset_px = bad;
    const absl::Status s = SlamSystem::Create(config).status();
    EXPECT_EQ(s.code(), absl::StatusCode::kInvalidArgument) << bad;
    EXPECT_NE(std::string(s.message()).find("disparity_offset_px"), std::string::npos) << bad;
  }
  config.options.disparity_offset_px = 0.0;
  config.options.object_ba_window_frames = 7;
  config.options.object_ba_iterations = 3;
  config.options.parked_objects_static = false;   // not the default
  config.options.dense_keyframes = false;         // not the default
  config.options.extra_camera_keypoints = false;  // not the default
  config.options.stereo_by_point_depth = true;    // not the default
  config.options.disparity_offset_px = 0.125;     // not the default
  auto sys = SlamSystem::Create(config);
  ASSERT_TRUE(sys.ok());
  ASSERT_TRUE((*sys)->Process(SmallClip().frames[0]).ok());
  const std::string path = TempPath("options_state");
  ASSERT_TRUE((*sys)->Save(path).ok());
  auto loaded = SlamSystem::Load(path);
  ASSERT_TRUE(loaded.ok()) << loaded.status();
  EXPECT_EQ((*loaded)->config().options.object_ba_window_frames, 7);
  EXPECT_EQ((*loaded)->config().options.object_ba_iterations, 3);
  EXPECT_FALSE((*loaded)->config().options.parked_objects_static);
  EXPECT_FALSE((*loaded)->config().options.dense_keyframes);
  EXPECT_FALSE((*loaded)->config().options.extra_camera_keypoints);
  EXPECT_TRUE((*loaded)->config().options.stereo_by_point_depth);
  EXPECT_EQ((*loaded)->config().options.disparity_offset_px, 0.125);
  std::remove(path.c_str());
}

// Camera only (parked-instance logic off); objects: SaveLoadResumesObjectsExactly.
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
  // points join the static pipeline. The parked set and the objects are
  // saved, so the resumed run is bit-identical with the uninterrupted one.
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
    EXPECT_TRUE(SamePose(r->world_from_camera, expected[k].world_from_camera)) << "frame " << k;
    EXPECT_TRUE(SameObjects(*r, expected[k])) << "frame " << k;
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

// Writes `bytes` to `path` (replacing it).
void WriteBytes(const std::string& path, const std::string& bytes) {
  std::ofstream out(path, std::ios::binary | std::ios::trunc);
  out.write(bytes.data(), static_cast<std::streamsize>(bytes.size()));
}

// The bytes of the file at `path`.
std::string ReadBytes(const std::string& path) {
  std::ifstream in(path, std::ios::binary);
  return std::string((std::istreambuf_iterator<char>(in)), std::istreambuf_iterator<char>());
}

// Sets the format version of the state file `bytes` (after its 8-byte magic).
void SetVersion(uint32_t version, std::string* bytes) {
  std::memcpy(&(*bytes)[8], &version, sizeof(version));
}

// The object stage is persisted (state format 4): a session saved after N
// frames and loaded into a new system continues exactly like the original,
// camera and objects (ids, states, poses, twists, stationarity, cluster and
// plane events), with the objects' BA and the parked-instance logic on.
TEST(SlamSystem, SaveLoadResumesObjectsExactly) {
  const Clip& clip = CarsClip();
  const size_t split = 12;
  SessionConfig config = clip.config;
  config.options.parked_objects_static = true;
  auto first = SlamSystem::Create(config);
  ASSERT_TRUE(first.ok());
  int objects_before = 0;
  for (size_t k = 0; k < split; ++k) {
    auto r = (*first)->Process(clip.frames[k]);
    ASSERT_TRUE(r.ok());
    objects_before += static_cast<int>(r->objects.size());
  }
  ASSERT_GT(objects_before, 5);  // objects are tracked when the state is saved
  const std::string path = TempPath("slam_state_objects");
  ASSERT_TRUE((*first)->Save(path).ok());
  auto resumed = SlamSystem::Load(path);
  ASSERT_TRUE(resumed.ok()) << resumed.status();
  // Saving the loaded system gives the same bytes (nothing is lost or added).
  const std::string path2 = TempPath("slam_state_objects_again");
  ASSERT_TRUE((*resumed)->Save(path2).ok());
  {
    const std::string da = ReadBytes(path), db = ReadBytes(path2);
    size_t first_diff = 0, num_diff = 0;
    for (size_t i = 0; i < std::min(da.size(), db.size()); ++i) {
      if (da[i] != db[i] && num_diff++ == 0) first_diff = i;
    }
    EXPECT_TRUE(da == db) << da.size() << " vs " << db.size() << " bytes, " << num_diff
                          << " differ from offset " << first_diff;
  }
  int rows = 0, moving = 0, stationary = 0;
  for (size_t k = split; k < clip.frames.size(); ++k) {
    auto ra = (*first)->Process(clip.frames[k]);
    auto rb = (*resumed)->Process(clip.frames[k]);
    ASSERT_TRUE(ra.ok() && rb.ok());
    EXPECT_EQ(ra->state, rb->state) << "frame " << k;
    EXPECT_TRUE(SamePose(ra->world_from_camera, rb->world_from_camera)) << "frame " << k;
    EXPECT_EQ(ra->num_map_points, rb->num_map_points) << "frame " << k;
    EXPECT_TRUE(SameObjects(*ra, *rb)) << "frame " << k;
    EXPECT_TRUE(SameClusterEvents(*ra, *rb)) << "frame " << k;
    for (const ObjectResult& o : ra->objects) {
      ++rows;
      moving += o.speed_mps > 2.0;
      stationary += o.stationary;
    }
  }
  // The resumed part does exercise moving and parked objects.
  EXPECT_GT(rows, 10);
  EXPECT_GT(moving, 0);
  EXPECT_GT(stationary, 0);
  std::remove(path.c_str());
  std::remove(path2.c_str());
}

// Every truncation of a state file with objects, and every version newer than
// the engine's, is a DataLoss status (never a crash or a silent success).
TEST(SlamSystem, LoadRejectsTruncatedObjectState) {
  const Clip& clip = CarsClip();
  SessionConfig config = clip.config;
  config.options.parked_objects_static = true;
  auto sys = SlamSystem::Create(config);
  ASSERT_TRUE(sys.ok());
  for (int k = 0; k < 8; ++k) ASSERT_TRUE((*sys)->Process(clip.frames[k]).ok());
  const std::string path = TempPath("state_objects_full");
  ASSERT_TRUE((*sys)->Save(path).ok());
  const std::string data = ReadBytes(path);
  ASSERT_GT(data.size(), 1000u);
  const std::string cut = TempPath("state_objects_cut");
  auto write = [&](const std::string& bytes) { WriteBytes(cut, bytes); };
  // Cuts all over the file, and densely in its tail (the object state).
  std::vector<size_t> sizes;
  for (int k = 1; k < 40; ++k) sizes.push_back(data.size() * k / 40);
  for (size_t k = 1; k <= 600 && k < data.size(); k += 7) sizes.push_back(data.size() - k);
  for (size_t n : sizes) {
    write(data.substr(0, n));
    EXPECT_EQ(SlamSystem::Load(cut).status().code(), absl::StatusCode::kDataLoss) << n;
  }
  // A trailing extra byte.
  write(data + "x");
  EXPECT_EQ(SlamSystem::Load(cut).status().code(), absl::StatusCode::kDataLoss);
  // A future version.
  std::string future = data;
  SetVersion(99, &future);
  write(future);
  EXPECT_EQ(SlamSystem::Load(cut).status().code(), absl::StatusCode::kDataLoss);
  // Byte flips in the tail never crash (a flipped double may still load).
  for (size_t k = 9; k <= 2000 && k < data.size(); k += 13) {
    std::string flipped = data;
    flipped[data.size() - k] = static_cast<char>(flipped[data.size() - k] ^ 0xA5);
    write(flipped);
    const auto r = SlamSystem::Load(cut);
    EXPECT_TRUE(r.ok() || r.status().code() == absl::StatusCode::kDataLoss) << r.status();
  }
  // The intact file loads.
  write(data);
  EXPECT_TRUE(SlamSystem::Load(cut).ok());
  std::remove(cut.c_str());
  std::remove(path.c_str());
}

// The offset of SlamOptions::dense_keyframes in a state file (format 9+): the
// first byte where two fresh sessions that differ only in it differ.
size_t DenseKeyFramesOffset(SessionConfig config) {
  std::string bytes[2];
  for (int dense = 0; dense < 2; ++dense) {
    config.options.dense_keyframes = dense != 0;
    auto sys = SlamSystem::Create(config);
    EXPECT_TRUE(sys.ok());
    const std::string path = TempPath("state_dense_offset");
    EXPECT_TRUE((*sys)->Save(path).ok());
    bytes[dense] = ReadBytes(path);
    std::remove(path.c_str());
  }
  size_t k = 0;
  while (k < bytes[0].size() && bytes[0][k] == bytes[1][k]) ++k;
  return k;
}

// A format-15 file with objects (before the tracker's previous camera pose
// was saved) loads, and with the default options the resumed session
// continues exactly as the uninterrupted one: the pose only serves
// ObjectTrackerOptions::approaching_growth_time_s, off by default. Format 16
// appended it (a flag byte and a pose) at the end of the object stage, just
// before format 10's block (an int32 and its uint64 length) and the trailer.
TEST(SlamSystem, LoadsObjectStateFormat15) {
  const Clip& clip = CarsClip();
  const size_t split = 8;
  auto first = SlamSystem::Create(clip.config);
  ASSERT_TRUE(first.ok());
  for (size_t k = 0; k < split; ++k) ASSERT_TRUE((*first)->Process(clip.frames[k]).ok());
  const std::string path = TempPath("state_objects_v16");
  ASSERT_TRUE((*first)->Save(path).ok());
  std::string data = ReadBytes(path);
  std::remove(path.c_str());
  // Format 17's disparity offset (8 bytes after the options' last flag).
  const size_t dense_at = DenseKeyFramesOffset(clip.config);
  data.erase(dense_at + 3, sizeof(double));
  const size_t tail = 4 + 8 + 8;  // format 10's block and the trailer
  const size_t added = 1 + 7 * sizeof(double);
  ASSERT_GT(data.size(), tail + added);
  ASSERT_EQ(data[data.size() - tail - added], '\x01');  // a previous camera pose
  data.erase(data.size() - tail - added, added);
  SetVersion(15, &data);
  const std::string older = TempPath("state_objects_v15");
  WriteBytes(older, data);
  auto resumed = SlamSystem::Load(older);
  std::remove(older.c_str());
  ASSERT_TRUE(resumed.ok()) << resumed.status();
  int rows = 0;
  for (size_t k = split; k < clip.frames.size(); ++k) {
    auto ra = (*first)->Process(clip.frames[k]);
    auto rb = (*resumed)->Process(clip.frames[k]);
    ASSERT_TRUE(ra.ok() && rb.ok());
    EXPECT_TRUE(SamePose(ra->world_from_camera, rb->world_from_camera)) << "frame " << k;
    EXPECT_TRUE(SameObjects(*ra, *rb)) << "frame " << k;
    rows += static_cast<int>(ra->objects.size());
  }
  EXPECT_GT(rows, 10);
  // Declared as format 16, the same bytes lack the pose: rejected.
  SetVersion(16, &data);
  WriteBytes(older, data);
  EXPECT_EQ(SlamSystem::Load(older).status().code(), absl::StatusCode::kDataLoss);
  std::remove(older.c_str());
}

// A format-3 file (written before the objects were saved) still loads. Without
// the object stage a format-11 (= 10) file less its last block (before the trailer)
// and its dense_keyframes byte is a format-4 file (formats 5 to 8 only add to
// the object state), and a format-3 file plus one flag byte before the
// trailer, so one is made from the other.
TEST(SlamSystem, LoadsFormatVersion3) {
  const Clip& clip = SmallClip();
  SessionConfig config = clip.config;
  config.options.track_objects = false;
  // Older files load with dense keyframes and the camera's extra keypoints
  // off: the session they resume must have had them off to continue
  // identically.
  config.options.dense_keyframes = false;
  config.options.extra_camera_keypoints = false;
  const size_t dense_at = DenseKeyFramesOffset(config);
  auto sys = SlamSystem::Create(config);
  ASSERT_TRUE(sys.ok());
  for (int k = 0; k < 6; ++k) ASSERT_TRUE((*sys)->Process(clip.frames[k]).ok());
  const std::string path = TempPath("state_v4");
  ASSERT_TRUE((*sys)->Save(path).ok());
  std::string data = ReadBytes(path);
  uint32_t version = 0;
  std::memcpy(&version, &data[8], sizeof(version));
  ASSERT_EQ(version, 17u);
  // `bytes` declared as format `as` loads; returns its options.
  auto options_as = [](std::string bytes, uint32_t as) {
    SetVersion(as, &bytes);
    const std::string older = TempPath("state_older");
    WriteBytes(older, bytes);
    auto loaded = SlamSystem::Load(older);
    std::remove(older.c_str());
    EXPECT_TRUE(loaded.ok()) << loaded.status();
    return loaded.ok() ? (*loaded)->config().options : SlamOptions();
  };
  // Format 17 adds SlamOptions::disparity_offset_px, the 8 bytes after
  // stereo_by_point_depth; without them the file is a format-16 one.
  data.erase(dense_at + 3, sizeof(double));
  EXPECT_EQ(options_as(data, 16).disparity_offset_px, 0.0);
  // Format 16 only adds to the object stage: without it the file is a
  // format-15 one.
  EXPECT_FALSE(options_as(data, 15).dense_keyframes);  // loads, its options as saved
  // Format 15 adds SlamOptions::stereo_by_point_depth, the byte after
  // extra_camera_keypoints; without it the file is a format-14 one.
  ASSERT_EQ(data[dense_at + 2], '\0');
  data.erase(dense_at + 2, 1);
  EXPECT_FALSE(options_as(data, 14).stereo_by_point_depth);
  // Format 14 adds SlamOptions::extra_camera_keypoints, the byte after
  // dense_keyframes; without it the file is a format-13 one.
  ASSERT_EQ(data[dense_at + 1], '\0');
  data.erase(dense_at + 1, 1);
  EXPECT_FALSE(options_as(data, 13).extra_camera_keypoints);
  // Without the object stage a format-13 file is a format-10 one (formats 11
  // to 13 only add to the object stage). Format 10's block ends with its
  // length, before the 8-byte trailer.
  uint64_t block = 0;
  std::memcpy(&block, &data[data.size() - 16], sizeof(block));
  ASSERT_LT(block + 16, data.size());
  data.erase(data.size() - 16 - block, block + 8);  // format 9 from here on
  ASSERT_EQ(data[data.size() - 9], '\0');           // "no object stage"
  {
    std::string v9 = data;
    SetVersion(9, &v9);
    const std::string path9 = TempPath("state_v9");
    WriteBytes(path9, v9);
    EXPECT_TRUE(SlamSystem::Load(path9).ok());
    // Declared as format 10, the same bytes lack the block: rejected.
    SetVersion(10, &v9);
    WriteBytes(path9, v9);
    EXPECT_EQ(SlamSystem::Load(path9).status().code(), absl::StatusCode::kDataLoss);
    std::remove(path9.c_str());
  }
  ASSERT_LT(dense_at, data.size());
  ASSERT_EQ(data[dense_at], '\0');
  data.erase(dense_at, 1);  // format 8 from here on
  {
    std::string v4 = data;
    SetVersion(4, &v4);
    const std::string path4 = TempPath("state_v4_declared");
    WriteBytes(path4, v4);
    EXPECT_TRUE(SlamSystem::Load(path4).ok());
    std::remove(path4.c_str());
  }
  std::string v3 = data.substr(0, data.size() - 9) + data.substr(data.size() - 8);
  SetVersion(3, &v3);
  const std::string path3 = TempPath("state_v3");
  WriteBytes(path3, v3);
  auto loaded = SlamSystem::Load(path3);
  ASSERT_TRUE(loaded.ok()) << loaded.status();
  for (size_t k = 6; k < 10; ++k) {
    auto a = (*sys)->Process(clip.frames[k]);
    auto b = (*loaded)->Process(clip.frames[k]);
    ASSERT_TRUE(a.ok() && b.ok());
    EXPECT_TRUE(SamePose(a->world_from_camera, b->world_from_camera)) << "frame " << k;
  }
  // The same bytes declared as format 4 lack the flag: rejected.
  SetVersion(4, &v3);
  WriteBytes(path3, v3);
  EXPECT_EQ(SlamSystem::Load(path3).status().code(), absl::StatusCode::kDataLoss);
  std::remove(path.c_str());
  std::remove(path3.c_str());
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
  const std::string data = ReadBytes(path);
  WriteBytes(garbage, data.substr(0, data.size() / 2));
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
  const std::vector<geometry::SE3d> est = TrackClip(**sys, clip);
  ASSERT_EQ(est.size(), clip.frames.size());
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
