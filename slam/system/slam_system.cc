// SlamSystem implementation: ORB extraction (left and right in parallel),
// row-band stereo matching, panoptic labels -> static keypoints, camera
// tracking, keyframe decision and local mapping (synchronous or on a
// per-session thread), snapshots and exact save/load.
#include "slam/system/slam_system.h"

#include <glog/logging.h>

#include <algorithm>
#include <cstdio>
#include <fstream>
#include <map>
#include <mutex>
#include <sstream>
#include <thread>

#include "slam/common/timer.h"
#include "slam/features/orb_extractor.h"
#include "slam/features/stereo_matcher.h"
#include "slam/map/map.h"
#include "slam/mapping/local_mapper.h"
#include "slam/objects/masked_stereo.h"
#include "slam/system/binary_io.h"
#include "slam/system/object_stage.h"
#include "slam/tracking/camera_tracker.h"

namespace twist {
namespace {

constexpr char kMagic[8] = {'T', 'W', 'S', 'L', 'A', 'M', 'S', '1'};
// 2: + object_ba_window_frames, object_ba_iterations, parked_objects_static
// and the parked-instance state. Version 1 files still load (defaults).
// 3: + the parked instances' camera-side check state.
// 4: + the object stage (clusters, planes, tracked objects, axis joints, RANSAC
// generator, BA window: ObjectStage::Write). Older files still load; their
// objects restart after the resume.
// 5: + each tracked object's twist covariance (the constant-velocity filter,
// ObjectTrackerOptions::acceleration_sigma_mps2). Version 4 files still load
// (the filter restarts at each object's next step).
// 6: + each object's settled poses (those older than its history) and the
// trajectories of removed objects (ObjectTracker::Trajectories). Older files
// load with trajectories that start at the history's first pose.
// 7: + each plane point's viewing ray and depth noise (the weighted plane
// refinement, semantic::RefinePlaneWeighted). Older files load with points of
// unknown noise (PlaneRefineOptions::unknown_sigma_m).
// 8: + each object point's stereo noise along its ray
// (ObjectPoint::sigma_in_object, estimated with each twist). Older files load
// with exact points.
// 9: + SlamOptions::dense_keyframes. Older files load with it off (the
// keyframe policy they were made with).
// 10: + a block before the trailer, its byte length last: the tracker's
// last inlier count (TrackerOptions::research_inlier_ratio). Older files load
// with none (no second local-map search on the first frame after loading).
// 11: + each object observation's disparity noise ratio
// (ObjectPointObservation::disparity_noise_ratio, the dynamic BA's stereo
// whitening). Older files load with 0: the BA window they bring weighs its
// disparities as before, until the window has slid past them.
// 12: + each plane class's camera-frame points and plane
// (ObjectStageOptions::camera_plane_frames). Older files load with none: the
// planar joints take the world fit until new frames bring enough points.
// 13: + each object point's view when its patch was taken
// (ObjectPoint::patch_view_in_object). Older files load with none: with
// ObjectTrackerOptions::patch_refresh_view_change_deg on, each patch is taken
// again at the point's next match.
// 14: + SlamOptions::extra_camera_keypoints. Older files load with it off.
// 15: + SlamOptions::stereo_by_point_depth. Older files load with it off.
// 16: + the object tracker's previous camera pose
// (ObjectTrackerOptions::approaching_growth_time_s). Older files load
// without: the first frame after loading takes the current camera pose.
// 17: + SlamOptions::disparity_offset_px (a double after
// stereo_by_point_depth). Older files load with 0.
constexpr uint32_t kFormatVersion = 17;
// Covisible keyframes in the local BA with dense keyframes (SlamOptions).
constexpr int kDenseLocalBaKeyFrames = 8;
// Dense keyframes in background mode: keyframes that may wait for the busy
// mapper (KeyFrameDecisionInput::max_mapper_queue). 0 made a keyframe of
// about every other frame at 10 frames/s, each bundle adjustment cut short
// by the next frame; with 2 the mapper adjusts the waiting ones in batches
// (docs/math.md section 23).
constexpr int kDenseKeyFrameQueue = 2;
// The mapping thread's nice value in background mode (MappingThread): the
// lowest, so that tracking never waits for CPU behind the mapper. Embedded
// runs as fast as they go (docs/math.md section 23): about 1.5 frames/s more
// than at nice 0 and ~20 % fewer keyframes, at a like camera RPE_t.
constexpr int kMappingThreadNiceness = 19;
// Dense keyframes in background mode: frames without a keyframe after which
// tracking waits for the mapper (KeyFrameDecisionInput). See math.md
// section 23 for KITTI 06 replayed at once with and without it.
constexpr int kMaxFramesWithoutKeyFrame = 5;
// With SlamOptions::extra_camera_keypoints the right image's budget grows by
// this many times the favoured (dynamic) share of the left image: favoured
// keypoints are extra to the left budget, and they win their cells, so they
// number about 1.5 times their area share (follow_braking: 1.44 at level 0,
// 1.6 over all levels).
constexpr double kFavouredKeypointsPerShare = 1.5;
// Static keypoints this close (px) to a dynamic segment have their stereo
// measured again on static pixels only (objects::RemeasureBesideMask) with
// SlamOptions::extra_camera_keypoints: with the favoured keypoints on top of
// the budget there are more of them beside the cars, and their blocks
// straddling a car drifted the camera (docs/objects.md §47-48).
constexpr int kStaticStereoBesideDynamicPx = 16;
// ObjectStageOptions::plane_dynamic_margin_px with extra_camera_keypoints:
// the extra road keypoints beside the cars slowed the planar cars down
// (docs/objects.md §47).
constexpr int kPlaneDynamicMarginPx = 24;

tracking::TrackerOptions TrackerOptionsFrom(const SlamOptions& o) {
  tracking::TrackerOptions t;
  t.close_depth_baselines = o.max_depth_baselines;
  return t;
}

mapping::MapperOptions MapperOptionsFrom(const SlamOptions& o) {
  mapping::MapperOptions m;
  m.close_depth_baselines = o.max_depth_baselines;
  m.local_ba_iterations = o.local_ba_iterations;
  m.num_threads = o.num_threads;
  m.max_local_ba_keyframes = o.dense_keyframes ? kDenseLocalBaKeyFrames : 0;
  m.stereo_by_point_depth = o.stereo_by_point_depth;
  return m;
}

absl::Status CheckImage(const cv::Mat& m, const char* name) {
  if (m.empty()) return absl::InvalidArgumentError(std::string(name) + " image is empty");
  if (m.type() != CV_8UC1 && m.type() != CV_8UC3) {
    return absl::InvalidArgumentError(std::string(name) +
                                      " image must be CV_8UC1 (gray) or CV_8UC3 (BGR), got type " +
                                      std::to_string(m.type()));
  }
  return absl::OkStatus();
}

// ---------------------------------------------------------- serialisation
void WriteFeatures(const map::FrameFeatures& f, system_io::BinaryWriter* w) {
  w->KeyPoints(f.keypoints);
  w->Mat(f.descriptors);
  w->PodVector(f.u_right);
  w->PodVector(f.depth);
  w->PodVector(f.labels);
  w->PodVector(f.is_static);
}

std::shared_ptr<map::FrameFeatures> ReadFeatures(system_io::BinaryReader* r,
                                                 const geometry::StereoCamera& cam) {
  map::FrameFeatures f;
  f.keypoints = r->KeyPoints();
  f.descriptors = r->Mat();
  f.u_right = r->PodVector<float>();
  f.depth = r->PodVector<float>();
  f.labels = r->PodVector<int32_t>();
  f.is_static = r->PodVector<uint8_t>();
  const size_t n = f.keypoints.size();
  if (!r->ok() || static_cast<size_t>(f.descriptors.rows) != n || f.u_right.size() != n ||
      f.depth.size() != n || f.labels.size() != n || f.is_static.size() != n ||
      (n > 0 && (f.descriptors.cols != 32 || f.descriptors.type() != CV_8UC1))) {
    r->Fail();
    return nullptr;
  }
  return map::FinalizeFeatures(std::move(f), cam.width, cam.height);
}

void WriteFrame(const map::Frame& fr, system_io::BinaryWriter* w) {
  w->Pod<uint8_t>(fr.features != nullptr);
  if (fr.features == nullptr) return;
  w->Pod(fr.id);
  w->Pod(fr.timestamp_ns);
  WriteFeatures(*fr.features, w);
  w->Pose(fr.camera_from_world);
  w->PodVector(fr.point_ids);
  w->Pod<uint64_t>(fr.p_in_world.size());
  for (const auto& p : fr.p_in_world) w->Bytes(p.data(), 3 * sizeof(double));
  w->PodVector(fr.matched);
  w->PodVector(fr.outlier);
  w->Pod(fr.reference_kf_id);
}

map::Frame ReadFrame(system_io::BinaryReader* r, const geometry::StereoCamera& cam) {
  map::Frame fr;
  if (r->Pod<uint8_t>() == 0) return fr;
  fr.id = r->Pod<int64_t>();
  fr.timestamp_ns = r->Pod<int64_t>();
  fr.features = ReadFeatures(r, cam);
  fr.camera_from_world = r->Pose();
  fr.point_ids = r->PodVector<int64_t>();
  const uint64_t n = r->Count(24);
  fr.p_in_world.resize(n);
  for (auto& p : fr.p_in_world) {
    for (int k = 0; k < 3; ++k) p[k] = r->Pod<double>();
  }
  fr.matched = r->PodVector<uint8_t>();
  fr.outlier = r->PodVector<uint8_t>();
  fr.reference_kf_id = r->Pod<int64_t>();
  const size_t m = fr.features ? fr.features->keypoints.size() : 0;
  if (fr.point_ids.size() != m || fr.p_in_world.size() != m || fr.matched.size() != m ||
      fr.outlier.size() != m) {
    r->Fail();
  }
  return fr;
}

void WriteConfig(const SessionConfig& c, system_io::BinaryWriter* w) {
  const auto& cam = c.camera;
  w->Pod(cam.fx);
  w->Pod(cam.fy);
  w->Pod(cam.cx);
  w->Pod(cam.cy);
  w->Pod(cam.baseline);
  w->Pod<int32_t>(cam.width);
  w->Pod<int32_t>(cam.height);
  w->String(c.classes.ToText());
  const auto& o = c.options;
  w->Pod<int32_t>(o.num_features);
  w->Pod<int32_t>(o.num_levels);
  w->Pod(o.scale_factor);
  w->Pod<int32_t>(o.fast_threshold);
  w->Pod(o.max_depth_baselines);
  w->Pod<int32_t>(static_cast<int32_t>(o.mapping_mode));
  w->Pod<int32_t>(o.local_ba_iterations);
  w->Pod<int32_t>(o.num_threads);
  w->Pod<uint8_t>(o.use_masks);
  w->Pod<uint8_t>(o.track_objects);
  w->Pod<uint8_t>(o.constrain_objects);
  w->Pod(o.temporal_window_s);
  w->Pod(o.seed);
  w->Pod<int32_t>(o.object_ba_window_frames);
  w->Pod<int32_t>(o.object_ba_iterations);
  w->Pod<uint8_t>(o.parked_objects_static);
  w->Pod<uint8_t>(o.dense_keyframes);
  w->Pod<uint8_t>(o.extra_camera_keypoints);
  w->Pod<uint8_t>(o.stereo_by_point_depth);
  w->Pod(o.disparity_offset_px);
}

absl::StatusOr<SessionConfig> ReadConfig(system_io::BinaryReader* r, uint32_t version) {
  SessionConfig c;
  auto& cam = c.camera;
  cam.fx = r->Pod<double>();
  cam.fy = r->Pod<double>();
  cam.cx = r->Pod<double>();
  cam.cy = r->Pod<double>();
  cam.baseline = r->Pod<double>();
  cam.width = r->Pod<int32_t>();
  cam.height = r->Pod<int32_t>();
  const std::string classes = r->String();
  auto& o = c.options;
  o.num_features = r->Pod<int32_t>();
  o.num_levels = r->Pod<int32_t>();
  o.scale_factor = r->Pod<double>();
  o.fast_threshold = r->Pod<int32_t>();
  o.max_depth_baselines = r->Pod<double>();
  o.mapping_mode = static_cast<MappingMode>(r->Pod<int32_t>());
  o.local_ba_iterations = r->Pod<int32_t>();
  o.num_threads = r->Pod<int32_t>();
  o.use_masks = r->Pod<uint8_t>() != 0;
  o.track_objects = r->Pod<uint8_t>() != 0;
  o.constrain_objects = r->Pod<uint8_t>() != 0;
  o.temporal_window_s = r->Pod<double>();
  o.seed = r->Pod<uint64_t>();
  if (version >= 2) {
    o.object_ba_window_frames = r->Pod<int32_t>();
    o.object_ba_iterations = r->Pod<int32_t>();
    o.parked_objects_static = r->Pod<uint8_t>() != 0;
  } else {
    // Version 1 engines ran neither the objects' BA nor parked instances.
    o.object_ba_window_frames = 0;
    o.parked_objects_static = false;
  }
  o.dense_keyframes = version >= 9 && r->Pod<uint8_t>() != 0;
  o.extra_camera_keypoints = version >= 14 && r->Pod<uint8_t>() != 0;
  o.stereo_by_point_depth = version >= 15 && r->Pod<uint8_t>() != 0;
  o.disparity_offset_px = version >= 17 ? r->Pod<double>() : 0.0;
  if (!r->ok()) return absl::DataLossError("state file truncated in the configuration");
  absl::StatusOr<joints::ClassTable> table = joints::ClassTable::FromText(classes);
  if (!table.ok()) {
    return absl::DataLossError("state file has an invalid class table: " +
                               std::string(table.status().message()));
  }
  c.classes = *std::move(table);
  return c;
}

// ---------------------------------------------------------- parked objects
// Instances of a-priori dynamic classes that the object stage reports as
// standing still (parked cars) help the camera like static points: once an
// instance has been tracked still (held stationary by the object tracker's
// likelihood-ratio test, or below kStillSpeed) for kParkFrames consecutive
// frames, its keypoints are static for tracking and mapping from the next
// frame on. It leaves the set as soon as the object stage sees it move (one
// tracked frame above kMovingSpeed), loses it, or stops reporting it. The
// state is per panoptic label (class * 1000 + instance): keypoints only carry
// labels. A parked instance's map points are ordinary static points; when it
// drives off, its keypoints are dynamic again and the tracker (which only
// matches static keypoints) no longer matches them; the stale points stay
// consistent with the keyframes that saw the car parked (only the mapper
// erases points). docs/objects.md §9 has the measurements.
struct ParkedLabel {
  int still_frames = 0;  // consecutive tracked frames below kStillSpeed
  bool parked = false;
  int64_t last_seen = 0;  // frame counter when last reported
  // Camera-side check while parked: share of the instance's stereo keypoints
  // that the camera tracker kept as inlier map matches (running mean), and
  // a frame counter before which the instance may not be parked again.
  double inlier_share = 0.0;
  int inlier_frames = 0;
  int64_t no_park_before = 0;

  // Back to "not parked", with the still-frame count and the camera-side
  // statistics restarted.
  void Unpark() {
    still_frames = 0;
    parked = false;
    inlier_share = 0.0;
    inlier_frames = 0;
  }
};
constexpr double kStillSpeed = 0.3;   // m/s (about 1 km/h)
constexpr double kMovingSpeed = 0.5;  // m/s
constexpr int kParkFrames = 5;
constexpr int64_t kForgetFrames = 10;
// A parked instance whose inlier share drops below this fraction of its
// running mean (with at least kMinParkedKeypoints stereo keypoints) is
// unparked at once, and not parked again for kNoParkFrames frames.
constexpr double kInlierDrop = 0.5;
constexpr int kMinParkedKeypoints = 8;
constexpr int64_t kNoParkFrames = 30;

bool IsParked(const std::map<int32_t, ParkedLabel>& parked, int32_t label) {
  auto it = parked.find(label);
  return it != parked.end() && it->second.parked;
}

void UpdateParked(const std::vector<ObjectResult>& objects,
                  int64_t frame,
                  std::map<int32_t, ParkedLabel>* parked) {
  for (const ObjectResult& o : objects) {
    if (o.instance_id <= 0) continue;
    ParkedLabel& p = (*parked)[o.class_id * 1000 + o.instance_id];
    p.last_seen = frame;
    if (o.state == ObjectState::kLost) {
      const int64_t no_park_before = p.no_park_before;
      p = ParkedLabel();
      p.last_seen = frame;
      p.no_park_before = no_park_before;
    } else if (o.state == ObjectState::kTracked) {
      // Still: the tracker's likelihood-ratio test holds the object
      // stationary (ObjectResult::stationary), or its speed is below
      // kStillSpeed.
      const bool still = o.stationary || o.speed_mps < kStillSpeed;
      if (!o.stationary && o.speed_mps > kMovingSpeed) {
        VLOG_IF(1, p.parked) << "frame " << frame << ": label " << o.class_id * 1000 + o.instance_id
                             << " moves (" << o.speed_mps << " m/s): no longer parked";
        p.Unpark();
      } else if (still) {
        p.still_frames = std::min(p.still_frames + 1, 1000);
        if (p.still_frames >= kParkFrames && !p.parked && frame >= p.no_park_before) {
          VLOG(1) << "frame " << frame << ": label " << o.class_id * 1000 + o.instance_id
                  << " parked";
          p.parked = true;
        }
      } else {
        p.still_frames = 0;  // in between: not parked yet, but not moving either
      }
    }
  }
  for (auto it = parked->begin(); it != parked->end();) {
    if (frame - it->second.last_seen > kForgetFrames) {
      it = parked->erase(it);
    } else {
      ++it;
    }
  }
}

// The object tracker holds a parked car's pose until its motion is
// significant and fast (ObjectTrackerOptions::stationary_leave_speed_mps),
// which lets a car that drives off stay "parked" for several frames. The
// camera sees it earlier: its stereo keypoints stop matching the map points
// it left behind (the tracker's robust pose optimisation drops them). After
// tracking, a parked instance whose share of inlier map matches falls below
// kInlierDrop of its running mean leaves the parked set.
void CheckParkedAgainstTracking(const map::Frame& frame,
                                int64_t frame_no,
                                std::map<int32_t, ParkedLabel>* parked) {
  if (frame.features == nullptr) return;
  const map::FrameFeatures& f = *frame.features;
  std::map<int32_t, std::pair<int, int>> counts;  // label -> (stereo keypoints, inliers)
  for (int i = 0; i < f.size(); ++i) {
    if (!(f.depth[i] > 0.f) || !IsParked(*parked, f.labels[i])) continue;
    std::pair<int, int>& c = counts[f.labels[i]];
    ++c.first;
    if (frame.matched[i] && frame.point_ids[i] >= 0) ++c.second;
  }
  for (const auto& [label, c] : counts) {
    if (c.first < kMinParkedKeypoints) continue;
    ParkedLabel& p = (*parked)[label];
    const double share = static_cast<double>(c.second) / static_cast<double>(c.first);
    if (p.inlier_frames >= 3 && share < kInlierDrop * p.inlier_share) {
      VLOG(1) << "frame " << frame_no << ": label " << label << " inlier share " << share
              << " (mean " << p.inlier_share << "): no longer parked";
      p.Unpark();
      p.no_park_before = frame_no + kNoParkFrames;
      continue;
    }
    p.inlier_share = p.inlier_frames == 0 ? share : 0.7 * p.inlier_share + 0.3 * share;
    ++p.inlier_frames;
  }
}

// ------------------------------------------------------------------ engine
class SlamSystemImpl final : public SlamSystem {
 public:
  explicit SlamSystemImpl(const SessionConfig& config)
      : config_(config),
        orb_(OrbOptionsFrom(config.options)),
        map_(config.camera, orb_.pyramid()),
        tracker_(config.camera, orb_.pyramid(), TrackerOptionsFrom(config.options)),
        mapper_(config.camera, orb_.pyramid(), MapperOptionsFrom(config.options)) {
    if (config_.options.mapping_mode == MappingMode::kBackground) {
      thread_ = std::make_unique<mapping::MappingThread>(&mapper_, &map_, kMappingThreadNiceness);
    }
    if (config_.options.track_objects && config_.options.use_masks) {
      ObjectStageOptions so;
      so.ba_window_frames = config_.options.object_ba_window_frames;
      so.ba_iterations = config_.options.object_ba_iterations;
      if (config_.options.extra_camera_keypoints)
        so.plane_dynamic_margin_px = kPlaneDynamicMarginPx;
      objects_ = std::make_unique<ObjectStage>(config_, so);
    }
  }
  ~SlamSystemImpl() override { Shutdown(); }

  absl::StatusOr<FrameResult> Process(const StereoFrame& frame) override;
  MapSnapshot Snapshot() const override;
  absl::Status Save(const std::string& path) const override;
  const SessionConfig& config() const override { return config_; }
  int64_t frames_processed() const override { return frames_processed_; }
  void Shutdown() override {
    if (thread_ != nullptr) thread_->Shutdown();
    shutdown_ = true;
  }

  absl::Status Restore(system_io::BinaryReader* r, uint32_t version);

 private:
  absl::Status ValidateInput(const StereoFrame& frame) const;
  // `left` and `right`: the frame's images in gray (the object stage gets the
  // same ones). `*dynamic` receives the dynamic segments' mask when the
  // extraction built it (extra_camera_keypoints), else it is left empty.
  std::shared_ptr<map::FrameFeatures> ExtractFeatures(const StereoFrame& frame,
                                                      const cv::Mat& left,
                                                      const cv::Mat& right,
                                                      cv::Mat* dynamic,
                                                      std::vector<StageTiming>* timings) const;

  SessionConfig config_;
  features::OrbExtractor orb_;
  map::Map map_;
  tracking::CameraTracker tracker_;
  mapping::LocalMapper mapper_;
  std::unique_ptr<mapping::MappingThread> thread_;
  std::unique_ptr<ObjectStage> objects_;  // dynamic objects (object_stage.h); null when off
  int64_t frames_processed_ = 0;
  bool has_last_timestamp_ = false;
  int64_t last_timestamp_ns_ = 0;
  int64_t first_timestamp_ns_ = 0;
  int max_frames_ = 10;  // frames per second, from the first two timestamps
  bool shutdown_ = false;
  // Parked instances (SlamOptions::parked_objects_static), by panoptic label.
  std::map<int32_t, ParkedLabel> parked_;
};

absl::Status SlamSystemImpl::ValidateInput(const StereoFrame& frame) const {
  if (absl::Status s = CheckImage(frame.left, "left"); !s.ok()) return s;
  if (absl::Status s = CheckImage(frame.right, "right"); !s.ok()) return s;
  if (frame.left.size() != frame.right.size() || frame.left.type() != frame.right.type()) {
    return absl::InvalidArgumentError("left and right images differ in size or type");
  }
  const auto& cam = config_.camera;
  if (frame.left.cols != cam.width || frame.left.rows != cam.height) {
    return absl::InvalidArgumentError("image size " + std::to_string(frame.left.cols) + "x" +
                                      std::to_string(frame.left.rows) +
                                      " differs from the calibration " + std::to_string(cam.width) +
                                      "x" + std::to_string(cam.height));
  }
  if (!frame.panoptic.empty()) {
    if (frame.panoptic.size() != frame.left.size()) {
      return absl::InvalidArgumentError("panoptic mask size differs from the image size");
    }
    if (frame.panoptic.type() != CV_16UC1 && frame.panoptic.type() != CV_32SC1) {
      return absl::InvalidArgumentError("panoptic mask must be CV_16UC1 or CV_32SC1");
    }
  }
  if (!frame.flow.empty() &&
      (frame.flow.size() != frame.left.size() || frame.flow.type() != CV_32FC2)) {
    return absl::InvalidArgumentError("optical flow must be CV_32FC2 of the image size");
  }
  if (has_last_timestamp_ && frame.timestamp_ns <= last_timestamp_ns_) {
    return absl::InvalidArgumentError("timestamp " + std::to_string(frame.timestamp_ns) +
                                      " ns is not after the previous frame's " +
                                      std::to_string(last_timestamp_ns_) + " ns");
  }
  return absl::OkStatus();
}

std::shared_ptr<map::FrameFeatures> SlamSystemImpl::ExtractFeatures(
    const StereoFrame& frame,
    const cv::Mat& left,
    const cv::Mat& right,
    cv::Mat* dynamic,
    std::vector<StageTiming>* timings) const {
  Stopwatch sw;
  map::FrameFeatures f;
  std::vector<cv::KeyPoint> right_kps;
  cv::Mat right_desc;
  std::vector<cv::Mat> left_levels, right_levels;
  // Keypoints favoured inside dynamic segments when objects are tracked; with
  // extra_camera_keypoints on top of the left image's budget, so the right
  // image's budget grows with them (the segments' keypoints come out at about
  // 1.5 times their share of the image: they win their cells,
  // docs/objects.md §48).
  const cv::Mat favour =
      objects_ != nullptr ? ObjectStage::FavourMask(frame.panoptic, config_.classes) : cv::Mat();
  const bool extra = !favour.empty() && config_.options.extra_camera_keypoints;
  if (extra) *dynamic = favour >= 128;
  const double right_budget = !extra
                                  ? 1.0
                                  : 1.0 + kFavouredKeypointsPerShare * cv::countNonZero(*dynamic) /
                                              static_cast<double>(favour.total());
  std::thread right_thread([&] {
    orb_.Extract(right, cv::Mat(), &right_kps, &right_desc, &right_levels, right_budget);
  });
  orb_.Extract(left, favour, &f.keypoints, &f.descriptors, &left_levels);
  right_thread.join();
  timings->push_back({"orb", sw.ElapsedMs()});
  sw.Restart();
  // The rig's disparity correction (SlamOptions::disparity_offset_px) goes
  // into every stereo measurement: the matcher's and the masked ones.
  features::StereoMatchOptions match_options;
  match_options.disparity_offset_px = config_.options.disparity_offset_px;
  objects::MaskedStereoOptions masked_options;
  masked_options.disparity_offset_px = config_.options.disparity_offset_px;
  features::StereoMatchResult st = features::MatchStereo(config_.camera,
                                                         orb_.pyramid(),
                                                         f.keypoints,
                                                         f.descriptors,
                                                         right_kps,
                                                         right_desc,
                                                         left_levels,
                                                         right_levels,
                                                         match_options);
  if (extra) {
    std::vector<double> half_window(orb_.pyramid().scale.size());
    for (size_t l = 0; l < half_window.size(); ++l) {
      half_window[l] = features::StereoBlockHalfPx(orb_.pyramid().scale[l]);
    }
    objects::RemeasureBesideMask(left,
                                 right,
                                 *dynamic,
                                 kStaticStereoBesideDynamicPx,
                                 f.keypoints,
                                 half_window,
                                 config_.camera.bf(),
                                 &st.u_right,
                                 &st.depth,
                                 masked_options);
  }
  f.u_right = std::move(st.u_right);
  f.depth = std::move(st.depth);
  // Panoptic labels; a-priori dynamic classes leave the static pipeline.
  const int n = static_cast<int>(f.keypoints.size());
  f.labels.assign(n, 0);
  f.is_static.assign(n, 1);
  if (!frame.panoptic.empty()) {
    for (int i = 0; i < n; ++i) {
      const int x = std::clamp(cvRound(f.keypoints[i].pt.x), 0, frame.panoptic.cols - 1);
      const int y = std::clamp(cvRound(f.keypoints[i].pt.y), 0, frame.panoptic.rows - 1);
      const int32_t label = frame.panoptic.type() == CV_16UC1
                                ? static_cast<int32_t>(frame.panoptic.at<uint16_t>(y, x))
                                : frame.panoptic.at<int32_t>(y, x);
      f.labels[i] = label;
      if (config_.options.use_masks && config_.classes.IsDynamic(label / 1000) &&
          !IsParked(parked_, label)) {
        f.is_static[i] = 0;
      }
    }
  }
  timings->push_back({"stereo", sw.ElapsedMs()});
  return map::FinalizeFeatures(std::move(f), config_.camera.width, config_.camera.height);
}

absl::StatusOr<FrameResult> SlamSystemImpl::Process(const StereoFrame& input) {
  if (shutdown_) return absl::FailedPreconditionError("the SLAM system has been shut down");
  if (absl::Status s = ValidateInput(input); !s.ok()) return s;
  Stopwatch total;
  FrameResult result;
  result.index = input.index;
  result.timestamp_ns = input.timestamp_ns;

  map::Frame frame;
  frame.id = frames_processed_;
  frame.timestamp_ns = input.timestamp_ns;
  const cv::Mat left_gray = features::ToGray(input.left);
  const cv::Mat right_gray = features::ToGray(input.right);
  cv::Mat dynamic;  // the dynamic segments, when the extraction built them
  frame.features = ExtractFeatures(input, left_gray, right_gray, &dynamic, &result.timings);
  frame.ResetMatches();

  if (frames_processed_ == 1 && input.timestamp_ns > first_timestamp_ns_) {
    const double fps = 1e9 / static_cast<double>(input.timestamp_ns - first_timestamp_ns_);
    max_frames_ = std::clamp(static_cast<int>(std::lround(fps)), 1, 100);
  }
  if (frames_processed_ == 0) first_timestamp_ns_ = input.timestamp_ns;

  Stopwatch sw;
  map::KeyFrame* new_kf = nullptr;
  TrackingState state;
  if (tracker_.state() == TrackingState::kNotInitialized) {
    state = TrackingState::kNotInitialized;
    if (tracker_.CanInitialize(frame)) {
      frame.camera_from_world = geometry::SE3d();
      new_kf = mapper_.CreateKeyFrame(frame, &map_, /*initial=*/true);
      {
        std::lock_guard<std::mutex> lock(map_.mutex());
        for (int i = 0; i < frame.features->size(); ++i) {
          if (new_kf->point_ids[i] >= 0) {
            frame.SetMatch(i, new_kf->point_ids[i], map_.point(new_kf->point_ids[i])->p_in_world);
          }
        }
      }
      tracker_.Initialize(frame, *new_kf);
      state = TrackingState::kOk;
    }
    result.timings.push_back({"track", sw.ElapsedMs()});
  } else {
    state = tracker_.Track(&frame, &map_);
    if (config_.options.parked_objects_static &&
        (state == TrackingState::kOk || state == TrackingState::kRelocalized)) {
      CheckParkedAgainstTracking(frame, frames_processed_, &parked_);
    }
    result.timings.push_back({"track", sw.ElapsedMs()});
    sw.Restart();
    if (state == TrackingState::kOk || state == TrackingState::kRelocalized) {
      mapping::KeyFrameDecisionInput in;
      {
        const std::unique_lock<std::mutex> lock = map_.PriorityLock();
        in.num_keyframes = map_.NumGoodKeyFrames();
        const map::KeyFrame* ref = map_.keyframe(tracker_.reference_kf_id());
        in.reference_tracked_points =
            ref ? ref->TrackedPoints(in.num_keyframes <= 2 ? 2 : 3, map_) : 0;
      }
      in.frame_id = frame.id;
      in.last_keyframe_frame_id = tracker_.last_keyframe_frame_id();
      in.last_relocalization_frame_id = tracker_.last_relocalization_frame_id();
      in.num_inliers = tracker_.stats().num_inliers;
      in.num_tracked_close = tracker_.stats().num_tracked_close;
      in.num_untracked_close = tracker_.stats().num_untracked_close;
      in.mapper_idle = thread_ == nullptr || thread_->idle();
      in.mapper_queue = thread_ == nullptr ? 0 : thread_->queue_size();
      in.max_mapper_queue = kDenseKeyFrameQueue;
      in.max_frames_without_keyframe = thread_ == nullptr ? 0 : kMaxFramesWithoutKeyFrame;
      in.max_frames = max_frames_;
      in.dense = config_.options.dense_keyframes;
      bool make_keyframe = mapping::NeedNewKeyFrame(in);
      if (!make_keyframe && mapping::KeyFrameAfterWaiting(in)) {
        Stopwatch wait;
        thread_->WaitForRoom(in.max_mapper_queue);
        result.timings.push_back({"mapping_wait", wait.ElapsedMs()});
        make_keyframe = true;
      }
      if (make_keyframe) {
        new_kf = mapper_.CreateKeyFrame(frame, &map_, /*initial=*/false);
        tracker_.OnKeyFrameCreated(frame, *new_kf);
      }
    }
    result.timings.push_back({"keyframe", sw.ElapsedMs()});
  }
  if (new_kf != nullptr) {
    const int64_t kf_id = new_kf->id;
    if (thread_ != nullptr) {
      thread_->Enqueue(kf_id);
    } else {
      const mapping::MappingTimings t = mapper_.ProcessKeyFrame(kf_id, &map_);
      result.timings.push_back({"mapping", t.process_ms});
      result.timings.push_back({"ba", t.ba_ms});
      result.timings.push_back({"kf_culling", t.culling_ms});
    }
  }
  if (thread_ != nullptr) {
    for (const auto& t : thread_->TakeTimings()) {
      result.timings.push_back({"mapping", t.process_ms});
      if (t.bundle_adjusted) result.timings.push_back({"ba", t.ba_ms});
    }
  }

  if (objects_ != nullptr && !input.panoptic.empty() &&
      (state == TrackingState::kOk || state == TrackingState::kRelocalized)) {
    sw.Restart();
    ObjectStageInput oi;
    oi.frame_index = input.index;
    oi.timestamp_ns = input.timestamp_ns;
    oi.left = left_gray;
    oi.right = right_gray;
    oi.panoptic = input.panoptic;
    oi.flow = input.flow;
    oi.dynamic = dynamic;
    oi.features = frame.features.get();
    oi.camera_from_world = frame.camera_from_world;
    // The input was validated above: a failure here is a bug, not bad input,
    // and must not leave the session half-updated.
    absl::StatusOr<ObjectStageOutput> o = objects_->Process(oi);
    if (o.ok()) {
      if (config_.options.parked_objects_static) {
        UpdateParked(o->objects, frames_processed_, &parked_);
      }
      result.objects = std::move(o->objects);
      result.cluster_events = std::move(o->cluster_events);
      for (const StageTiming& t : o->timings) result.timings.push_back(t);
      if (o->ba_ms > 0.0) result.timings.push_back({"objects_ba", o->ba_ms});
    } else {
      LOG(ERROR) << "object stage: " << o.status();
    }
    result.timings.push_back({"objects", sw.ElapsedMs()});
  }

  result.state = state;
  result.world_from_camera = frame.camera_from_world.Inverse();
  result.is_keyframe = new_kf != nullptr;
  result.num_tracked_points =
      state == TrackingState::kNotInitialized ? 0 : tracker_.stats().num_inliers;
  {
    const std::unique_lock<std::mutex> lock = map_.PriorityLock();
    result.num_map_points = map_.NumGoodPoints();
    result.num_keyframes = map_.NumGoodKeyFrames();
  }
  result.timings.push_back({"total", total.ElapsedMs()});
  ++frames_processed_;
  has_last_timestamp_ = true;
  last_timestamp_ns_ = input.timestamp_ns;
  return result;
}

MapSnapshot SlamSystemImpl::Snapshot() const {
  MapSnapshot s;
  std::lock_guard<std::mutex> lock(map_.mutex());
  s.points.reserve(map_.points().size());
  for (const auto& [id, p] : map_.points()) {
    if (p->bad) continue;
    MapSnapshot::Point q;
    q.p_in_world = p->p_in_world;
    q.class_id = p->label / 1000;
    s.points.push_back(q);
  }
  for (const auto& [id, kf] : map_.keyframes()) {
    s.keyframes.push_back({kf->id, kf->timestamp_ns, kf->camera_from_world.Inverse()});
  }
  if (objects_ != nullptr) objects_->AddToSnapshot(&s);
  return s;
}

absl::Status SlamSystemImpl::Save(const std::string& path) const {
  if (thread_ != nullptr) thread_->WaitIdle();
  system_io::BinaryWriter w;
  w.Bytes(kMagic, sizeof(kMagic));
  w.Pod(kFormatVersion);
  WriteConfig(config_, &w);
  w.Pod(frames_processed_);
  w.Pod<uint8_t>(has_last_timestamp_);
  w.Pod(last_timestamp_ns_);
  w.Pod(first_timestamp_ns_);
  w.Pod<int32_t>(max_frames_);
  {
    std::lock_guard<std::mutex> lock(map_.mutex());
    w.Pod(map_.next_keyframe_id());
    w.Pod(map_.next_point_id());
    w.Pod<uint64_t>(map_.keyframes().size());
    for (const auto& [id, kf] : map_.keyframes()) {
      w.Pod(kf->id);
      w.Pod(kf->frame_id);
      w.Pod(kf->timestamp_ns);
      WriteFeatures(*kf->features, &w);
      w.Pose(kf->camera_from_world);
      w.PodVector(kf->point_ids);
      w.Pod<uint64_t>(kf->connections.size());
      for (const auto& [o, wt] : kf->connections) {
        w.Pod(o);
        w.Pod<int32_t>(wt);
      }
      w.PodVector(kf->ordered_connections);
      w.Pod<uint8_t>(kf->bad);
    }
    w.Pod<uint64_t>(map_.points().size());
    for (const auto& [id, p] : map_.points()) {
      w.Pod(p->id);
      w.Bytes(p->p_in_world.data(), 3 * sizeof(double));
      w.Bytes(p->descriptor.data(), p->descriptor.size());
      w.Bytes(p->normal.data(), 3 * sizeof(double));
      w.Pod(p->min_distance);
      w.Pod(p->max_distance);
      w.Pod<uint64_t>(p->observations.size());
      for (const auto& [k, idx] : p->observations) {
        w.Pod(k);
        w.Pod<int32_t>(idx);
      }
      w.Pod(p->reference_kf_id);
      w.Pod(p->first_kf_id);
      w.Pod<int32_t>(p->visible);
      w.Pod<int32_t>(p->found);
      w.Pod(p->label);
      w.Pod<uint8_t>(p->bad);
      w.Pod(p->last_local_map_frame);
    }
  }
  const tracking::CameraTracker::State ts = tracker_.GetState();
  w.Pod<int32_t>(static_cast<int32_t>(ts.state));
  WriteFrame(ts.last_frame, &w);
  w.Pod<uint8_t>(ts.last_frame_is_keyframe);
  w.Pod<uint8_t>(ts.velocity.has_value());
  w.Pose(ts.velocity.value_or(geometry::SE3d()));
  w.Pose(ts.last_from_reference);
  w.Pod(ts.reference_kf_id);
  w.Pod(ts.last_kf_frame_id);
  w.Pod(ts.last_reloc_frame_id);
  const std::vector<int64_t> recent(mapper_.recent_points().begin(), mapper_.recent_points().end());
  w.PodVector(recent);
  w.Pod<uint64_t>(parked_.size());
  for (const auto& [label, p] : parked_) {
    w.Pod(label);
    w.Pod<int32_t>(p.still_frames);
    w.Pod<uint8_t>(p.parked);
    w.Pod(p.last_seen);
    w.Pod(p.inlier_share);
    w.Pod<int32_t>(p.inlier_frames);
    w.Pod(p.no_park_before);
  }
  w.Pod<uint8_t>(objects_ != nullptr);
  if (objects_ != nullptr) objects_->Write(&w);
  {
    // Format 10's block, its length last so that it can be found from the
    // end of the file.
    const size_t start = w.buffer().size();
    w.Pod<int32_t>(ts.last_inliers);
    w.Pod<uint64_t>(w.buffer().size() - start);
  }
  w.Bytes(kMagic, sizeof(kMagic));  // trailer: detects truncation

  const std::string tmp = path + ".tmp";
  {
    std::ofstream out(tmp, std::ios::binary | std::ios::trunc);
    if (!out) return absl::UnavailableError("cannot open " + tmp + " for writing");
    out.write(w.buffer().data(), static_cast<std::streamsize>(w.buffer().size()));
    out.flush();
    if (!out) {
      std::remove(tmp.c_str());
      return absl::UnavailableError("failed writing " + tmp);
    }
  }
  if (std::rename(tmp.c_str(), path.c_str()) != 0) {
    std::remove(tmp.c_str());
    return absl::UnavailableError("cannot rename " + tmp + " to " + path);
  }
  return absl::OkStatus();
}

absl::Status SlamSystemImpl::Restore(system_io::BinaryReader* r, uint32_t version) {
  frames_processed_ = r->Pod<int64_t>();
  has_last_timestamp_ = r->Pod<uint8_t>() != 0;
  last_timestamp_ns_ = r->Pod<int64_t>();
  first_timestamp_ns_ = r->Pod<int64_t>();
  max_frames_ = r->Pod<int32_t>();
  const int64_t next_kf = r->Pod<int64_t>();
  const int64_t next_point = r->Pod<int64_t>();
  const auto& cam = config_.camera;
  const uint64_t num_kfs = r->Count(64);
  for (uint64_t k = 0; k < num_kfs && r->ok(); ++k) {
    auto kf = std::make_unique<map::KeyFrame>();
    kf->id = r->Pod<int64_t>();
    kf->frame_id = r->Pod<int64_t>();
    kf->timestamp_ns = r->Pod<int64_t>();
    kf->features = ReadFeatures(r, cam);
    kf->camera_from_world = r->Pose();
    kf->point_ids = r->PodVector<int64_t>();
    const uint64_t nc = r->Count(12);
    for (uint64_t c = 0; c < nc && r->ok(); ++c) {
      const int64_t o = r->Pod<int64_t>();
      kf->connections[o] = r->Pod<int32_t>();
    }
    kf->ordered_connections = r->PodVector<int64_t>();
    kf->bad = r->Pod<uint8_t>() != 0;
    if (!r->ok() || kf->features == nullptr ||
        kf->point_ids.size() != kf->features->keypoints.size()) {
      return absl::DataLossError("state file has a corrupt keyframe");
    }
    map_.InsertKeyFrame(std::move(kf));
  }
  const uint64_t num_points = r->Count(100);
  for (uint64_t k = 0; k < num_points && r->ok(); ++k) {
    auto p = std::make_unique<map::MapPoint>();
    p->id = r->Pod<int64_t>();
    for (int c = 0; c < 3; ++c) p->p_in_world[c] = r->Pod<double>();
    for (auto& b : p->descriptor) b = r->Pod<uint8_t>();
    for (int c = 0; c < 3; ++c) p->normal[c] = r->Pod<double>();
    p->min_distance = r->Pod<float>();
    p->max_distance = r->Pod<float>();
    const uint64_t no = r->Count(12);
    for (uint64_t o = 0; o < no && r->ok(); ++o) {
      const int64_t kf = r->Pod<int64_t>();
      p->observations[kf] = r->Pod<int32_t>();
    }
    p->reference_kf_id = r->Pod<int64_t>();
    p->first_kf_id = r->Pod<int64_t>();
    p->visible = r->Pod<int32_t>();
    p->found = r->Pod<int32_t>();
    p->label = r->Pod<int32_t>();
    p->bad = r->Pod<uint8_t>() != 0;
    p->last_local_map_frame = r->Pod<int64_t>();
    if (!r->ok()) break;
    map_.InsertPoint(std::move(p));
  }
  map_.set_next_ids(next_kf, next_point);
  tracking::CameraTracker::State ts;
  ts.state = static_cast<TrackingState>(r->Pod<int32_t>());
  ts.last_frame = ReadFrame(r, cam);
  ts.last_frame_is_keyframe = r->Pod<uint8_t>() != 0;
  const bool has_velocity = r->Pod<uint8_t>() != 0;
  const geometry::SE3d velocity = r->Pose();
  if (has_velocity) ts.velocity = velocity;
  ts.last_from_reference = r->Pose();
  ts.reference_kf_id = r->Pod<int64_t>();
  ts.last_kf_frame_id = r->Pod<int64_t>();
  ts.last_reloc_frame_id = r->Pod<int64_t>();
  const std::vector<int64_t> recent = r->PodVector<int64_t>();
  if (version >= 2) {
    const uint64_t np = r->Count(17);
    for (uint64_t k = 0; k < np && r->ok(); ++k) {
      const int32_t label = r->Pod<int32_t>();
      ParkedLabel& p = parked_[label];
      p.still_frames = r->Pod<int32_t>();
      p.parked = r->Pod<uint8_t>() != 0;
      p.last_seen = r->Pod<int64_t>();
      if (version >= 3) {
        p.inlier_share = r->Pod<double>();
        p.inlier_frames = r->Pod<int32_t>();
        p.no_park_before = r->Pod<int64_t>();
      }
    }
  }
  if (version >= 4) {
    const bool has_objects = r->Pod<uint8_t>() != 0;
    if (r->ok() && has_objects != (objects_ != nullptr)) {
      return absl::DataLossError("state file: object state does not match the configuration");
    }
    if (r->ok() && has_objects) {
      if (absl::Status s = objects_->Read(r, version); !s.ok()) return s;
    }
  }
  if (version >= 10) {
    const size_t start = r->position();
    ts.last_inliers = r->Pod<int32_t>();
    const uint64_t length = r->Pod<uint64_t>();
    if (!r->ok() || length != r->position() - start - sizeof(uint64_t) || ts.last_inliers < 0) {
      return absl::DataLossError("state file has a corrupt tracking block");
    }
  }
  char trailer[8];
  for (char& c : trailer) c = r->Pod<char>();
  if (!r->ok() || std::memcmp(trailer, kMagic, 8) != 0 || !r->at_end()) {
    return absl::DataLossError("state file is truncated or corrupt");
  }
  // Cross-references must resolve.
  for (const auto& [id, kf] : map_.keyframes()) {
    for (int64_t pid : kf->point_ids) {
      if (pid >= 0 && map_.point(pid) == nullptr) {
        return absl::DataLossError("state file: keyframe references a missing point");
      }
    }
  }
  for (const auto& [id, p] : map_.points()) {
    for (const auto& [k, idx] : p->observations) {
      const map::KeyFrame* kf = map_.keyframe(k);
      if (kf == nullptr || idx < 0 || idx >= static_cast<int>(kf->point_ids.size())) {
        return absl::DataLossError("state file: point observation references a missing keyframe");
      }
    }
  }
  if (static_cast<int32_t>(ts.state) < 0 || static_cast<int32_t>(ts.state) > 3) {
    return absl::DataLossError("state file: invalid tracking state");
  }
  tracker_.SetState(std::move(ts));
  mapper_.set_recent_points(std::list<int64_t>(recent.begin(), recent.end()));
  return absl::OkStatus();
}

}  // namespace

absl::StatusOr<std::unique_ptr<SlamSystem>> SlamSystem::Create(const SessionConfig& config) {
  if (absl::Status s = config.Validate(); !s.ok()) return s;
  return std::unique_ptr<SlamSystem>(new SlamSystemImpl(config));
}

absl::StatusOr<std::unique_ptr<SlamSystem>> SlamSystem::Load(const std::string& path) {
  std::ifstream in(path, std::ios::binary);
  if (!in) return absl::NotFoundError("cannot open state file " + path);
  std::stringstream ss;
  ss << in.rdbuf();
  const std::string data = ss.str();
  system_io::BinaryReader r(data);
  char magic[8];
  for (char& c : magic) c = r.Pod<char>();
  if (!r.ok() || std::memcmp(magic, kMagic, 8) != 0) {
    return absl::DataLossError(path + " is not a TwistSLAM state file");
  }
  const uint32_t version = r.Pod<uint32_t>();
  if (version < 1 || version > kFormatVersion) {
    return absl::DataLossError(path + ": unsupported state format version " +
                               std::to_string(version));
  }
  absl::StatusOr<SessionConfig> config = ReadConfig(&r, version);
  if (!config.ok()) return config.status();
  if (absl::Status s = config->Validate(); !s.ok()) {
    return absl::DataLossError("state file has an invalid configuration: " +
                               std::string(s.message()));
  }
  auto sys = std::make_unique<SlamSystemImpl>(*config);
  if (absl::Status s = sys->Restore(&r, version); !s.ok()) {
    return absl::DataLossError(path + ": " + std::string(s.message()));
  }
  return std::unique_ptr<SlamSystem>(std::move(sys));
}

}  // namespace twist
