// Local mapping of the static map (ORB-SLAM2-style, no vocabulary):
//  - keyframe decision (NeedNewKeyFrame) from the tracker's statistics;
//  - keyframe creation with new points from close stereo keypoints;
//  - per new keyframe: observations, covisibility, culling of recent points,
//    new points by two-view triangulation with covisible keyframes
//    (epipolar-guided descriptor matching), fusion of duplicates with the
//    neighbours, local bundle adjustment with Ceres (SE3 manifold on 7-scalar
//    pose blocks, Huber, Schur complement) over the covisible keyframes, and
//    culling of redundant keyframes.
// The mapper locks the map's mutex itself; the bundle adjustment solves on a
// copy without holding it, so tracking can run meanwhile (background mode).
#pragma once

#include <atomic>
#include <condition_variable>
#include <cstdint>
#include <deque>
#include <functional>
#include <list>
#include <mutex>
#include <thread>
#include <vector>

#include "slam/map/map.h"

namespace twist::mapping {

struct MapperOptions {
  double close_depth_baselines = 40.0;  // ThDepth: stereo points created up to this
  // Local BA: an observation's u_right is used when the point is close in
  // that keyframe as the map holds it (true) or when the observation's own
  // stereo depth is close (false: the ThDepth test of new stereo points
  // applied to each observation). The latter keeps, for a point near ThDepth, only the
  // observations whose disparity came out too large, and the scale comes
  // out short: rendered static_street 1-3 camera ATE 0.0369 -> 0.0268 m with
  // true, but KITTI 06 f0-50 ATE 0.067 -> 0.081 m, whose path is already too
  // long (docs/math.md section 16).
  bool stereo_by_point_depth = false;
  int min_new_stereo_points = 100;      // at least this many closest stereo points
  int triangulation_neighbours = 10;
  int fusion_neighbours = 10;
  int local_ba_iterations = 10;      // after the first 5 robust iterations
  int num_threads = 1;               // Ceres threads
  double keyframe_redundancy = 0.9;  // cull keyframes with this share of redundant points
  int max_frames_between_keyframes = 10;
  // The local BA optimises the new keyframe and at most this many of its
  // covisible keyframes, the most covisible first (0: all of them, as
  // ORB-SLAM2). With a keyframe at every frame (KeyFrameDecisionInput::dense)
  // a point is seen by ~5 keyframes instead of ~3, every keyframe is
  // covisible with 20-40 others and the solve grows 4x; the 8 strongest give
  // the same accuracy on KITTI 06 (docs/math.md section 11).
  int max_local_ba_keyframes = 0;
  // Self-calibration of the stereo disparity offset (a horizontal
  // principal-point difference left by rectification) in the local BA, with
  // a zero-mean Gaussian prior of this standard deviation (px) at the first
  // bundle adjustment. Off: on KITTI 06 f0-50 it converges to 0.05-0.15 px
  // and shrinks the scale error (SAD: ATE 0.051 -> 0.030 m, path length
  // 1.003 -> 1.0016), but on rendered scenes, whose true offset is 0, it is
  // not precise enough and costs ATE in every clip tried (100 frames,
  // static_street / driving seeds 1-2: 0.016-0.031 -> 0.043-0.060 m with SAD,
  // up to 0.105 m with kSsdGaussNewton). See docs/math.md section 7. With
  // dense keyframes it fixes the scale on KITTI (ATE 0.064 -> 0.028 m) and
  // static_street, but costs the camera in intersection's turns (section 11).
  bool estimate_disparity_offset = false;
  double disparity_offset_prior_sigma = 0.5;
  // Later bundle adjustments: prior centred on the current estimate with
  // this standard deviation (px; random walk of a constant parameter).
  double disparity_offset_step_sigma = 0.02;
  // Only stereo observations up to this pyramid level inform the offset (the
  // others use the current estimate): disparities at levels 5-7 carry their
  // own +0.05..0.1 px bias on rendered scenes, which the offset absorbs
  // (static_street seed 2, an earlier matcher variant: -0.11 px with all
  // levels, 0.00 with level 0 only).
  int disparity_offset_max_level = 0;
};

// Inputs of the keyframe decision (ORB-SLAM2's NeedNewKeyFrame, stereo).
struct KeyFrameDecisionInput {
  int64_t frame_id = 0;
  int64_t last_keyframe_frame_id = 0;
  int64_t last_relocalization_frame_id = -1000000;
  int num_keyframes = 0;
  int num_inliers = 0;
  int reference_tracked_points = 0;  // points of the reference kf with >= min_obs observations
  int num_tracked_close = 0;
  int num_untracked_close = 0;
  bool mapper_idle = true;
  int mapper_queue = 0;
  // Dense keyframes in background mode: a frame also becomes a keyframe
  // while the mapper is busy if fewer than this many keyframes wait for it
  // (0: only when it is idle). The mapper adjusts a batch of waiting
  // keyframes with one bundle adjustment (MappingThread), so the frames the
  // busy mapper would have skipped are still refined.
  int max_mapper_queue = 0;
  int max_frames = 10;  // fps of the sequence (one keyframe per second at least)
  // Dense keyframes (SlamOptions::dense_keyframes): every tracked frame the
  // mapper can take becomes a keyframe, so that each frame's pose is refined
  // by the local BA with its own stereo points rather than kept as tracked.
  bool dense = false;
  // Dense keyframes in background mode: after this many frames without a
  // keyframe (0: no bound) tracking waits for room in the mapper's queue
  // and makes one (KeyFrameAfterWaiting). This bounds how far the map lags
  // behind in the stream's own time when frames come faster than the mapper
  // takes them (a recording replayed at once); at a live stream's pace the
  // mapper keeps up and nothing waits.
  int max_frames_without_keyframe = 0;
};
bool NeedNewKeyFrame(const KeyFrameDecisionInput& in);
// True when NeedNewKeyFrame says no only because the mapper's queue is full
// and max_frames_without_keyframe frames have passed: the caller waits for
// room (MappingThread::WaitForRoom) and makes the keyframe.
bool KeyFrameAfterWaiting(const KeyFrameDecisionInput& in);

struct MappingTimings {
  double process_ms = 0.0;  // observations, culling, triangulation, fusion
  bool bundle_adjusted = false;  // false: left to a newer keyframe's BA
  double ba_ms = 0.0;
  double culling_ms = 0.0;
  int ba_keyframes = 0;
  int ba_points = 0;
  int new_points = 0;
};

class LocalMapper {
 public:
  LocalMapper(const geometry::StereoCamera& camera,
              const features::ScalePyramid& pyramid,
              const MapperOptions& options);

  // Creates a keyframe from a tracked frame (locks the map): adds the frame's
  // inlier map points as observations and new points from close stereo
  // keypoints. `initial`: every stereo keypoint makes a point (first frame).
  map::KeyFrame* CreateKeyFrame(const map::Frame& frame, map::Map* map, bool initial);

  // The per-keyframe work (see header). Deterministic for a given map.
  // `abort` (optional) stops the bundle adjustment early. `skip_ba`
  // (optional) is asked once the keyframe's points are made, before its
  // bundle adjustment: true leaves the adjustment to a newer keyframe whose
  // window covers this one.
  MappingTimings ProcessKeyFrame(int64_t kf_id,
                                 map::Map* map,
                                 const std::atomic<bool>* abort = nullptr,
                                 const std::function<bool()>& skip_ba = nullptr);

  // Recently created points under probation (saved for exact resume).
  const std::list<int64_t>& recent_points() const { return recent_points_; }
  void set_recent_points(std::list<int64_t> p) { recent_points_ = std::move(p); }
  const MapperOptions& options() const { return options_; }

  // Local bundle adjustment around `kf_id` (exposed for tests). Returns the
  // number of optimised keyframes.
  int LocalBundleAdjustment(int64_t kf_id,
                            map::Map* map,
                            const std::atomic<bool>* abort,
                            MappingTimings* timings);

 private:
  void CullRecentPoints(const map::KeyFrame& kf, map::Map* map);
  // `lock` (held on entry and exit) is released briefly between neighbours.
  int TriangulateWithNeighbours(map::KeyFrame* kf,
                                map::Map* map,
                                std::unique_lock<std::mutex>* lock);
  void FuseWithNeighbours(map::KeyFrame* kf, map::Map* map, std::unique_lock<std::mutex>* lock);
  int Fuse(map::KeyFrame* kf, const std::vector<int64_t>& point_ids, map::Map* map, float radius);
  void CullKeyFrames(const map::KeyFrame& kf, map::Map* map);
  int WeightedObservations(const map::MapPoint& p, const map::Map& map) const;

  geometry::StereoCamera camera_;
  features::ScalePyramid pyramid_;
  MapperOptions options_;
  std::list<int64_t> recent_points_;
};

// Runs a LocalMapper on its own thread (MappingMode::kBackground): keyframes
// are queued by the tracking thread and processed in order. A keyframe that
// another one waits behind gets its points and fusion but no bundle
// adjustment of its own: the newest keyframe's adjustment optimises it with
// its most covisible neighbours, which the keyframes just before it are.
// So a bundle adjustment runs to the end instead of being cut short when a
// frame comes (it works on a copy, tracking never waits for it), and the
// mapper catches up with a batch of keyframes at the price of one.
//
// `niceness` > 0 lowers the thread's scheduling priority (its nice value):
// the tracking thread, whose latency the client sees, then comes first and
// the mapper works in the CPU time tracking leaves, which at a live stream's
// rate is the time between frames.
class MappingThread {
 public:
  explicit MappingThread(LocalMapper* mapper, map::Map* map, int niceness = 0);
  ~MappingThread();
  void Enqueue(int64_t kf_id);
  bool idle() const;
  int queue_size() const;
  // Blocks until fewer than `max_queue` keyframes wait (or the thread stops).
  void WaitForRoom(int max_queue);
  // Blocks until the queue is empty and nothing is being processed.
  void WaitIdle();
  void Shutdown();
  // Timings of processed keyframes since the last call.
  std::vector<MappingTimings> TakeTimings();

 private:
  void Run();

  LocalMapper* mapper_;
  map::Map* map_;
  const int niceness_;
  mutable std::mutex mutex_;
  std::condition_variable cv_;
  std::condition_variable idle_cv_;
  std::deque<int64_t> queue_;
  bool busy_ = false;
  bool stop_ = false;
  std::atomic<bool> abort_ba_{false};
  std::vector<MappingTimings> timings_;
  std::thread thread_;
};

}  // namespace twist::mapping
