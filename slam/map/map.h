// The static map of one session: frames, keyframes, map points and the
// covisibility graph. Ids come from the map's own counters (no globals), and
// containers are ordered by id so that every iteration is deterministic.
//
// Concurrency: one coarse mutex (`mutex()`) guards the whole map; the tracker
// and the local mapper lock it around their reads and writes. Helpers below
// assume the caller holds it.
#pragma once

#include <Eigen/Core>
#include <array>
#include <atomic>
#include <cstdint>
#include <map>
#include <memory>
#include <mutex>
#include <opencv2/core.hpp>
#include <unordered_map>
#include <vector>

#include "slam/features/feature_matcher.h"
#include "slam/features/orb_extractor.h"
#include "slam/geometry/se3.h"
#include "slam/geometry/stereo_camera.h"

namespace twist::map {

using Descriptor = std::array<uint8_t, features::OrbExtractor::kDescriptorBytes>;

// The observations of one stereo image pair, immutable once built; shared by a
// frame and the keyframe made from it.
struct FrameFeatures {
  std::vector<cv::KeyPoint> keypoints;  // left image, level-0 pixels
  cv::Mat descriptors;                  // N x 32
  std::vector<float> u_right;           // -1: no stereo match
  std::vector<float> depth;             // -1: no stereo match
  std::vector<int32_t> labels;          // panoptic id under the keypoint (0 none)
  std::vector<uint8_t> is_static;       // usable by the static (camera) pipeline
  features::KeypointGrid grid;
  // Disparity offset (px) already added to every disparity in u_right/depth
  // (see Map::disparity_offset); 0 for features as measured.
  float disparity_offset = 0.f;

  int size() const { return static_cast<int>(keypoints.size()); }
  const uint8_t* descriptor(int i) const { return descriptors.ptr<uint8_t>(i); }
};

// A tracked frame: features, pose and the 3D points matched to its keypoints.
// `matched[i]` says `p_in_world[i]` holds the point matched to keypoint i; the
// point is a map point when point_ids[i] >= 0, otherwise a temporary
// (visual-odometry) point from the previous frame's stereo depth.
struct Frame {
  int64_t id = -1;
  int64_t timestamp_ns = 0;
  std::shared_ptr<const FrameFeatures> features;
  geometry::SE3d camera_from_world;
  std::vector<int64_t> point_ids;
  std::vector<Eigen::Vector3d> p_in_world;
  std::vector<uint8_t> matched;
  std::vector<uint8_t> outlier;
  int64_t reference_kf_id = -1;

  void ResetMatches();
  void SetMatch(int i, int64_t point_id, const Eigen::Vector3d& p);
  void ClearMatch(int i);
  int NumMapMatches() const;
  Eigen::Vector3d CameraCenter() const { return camera_from_world.Inverse().translation(); }
};

struct KeyFrame {
  int64_t id = -1;
  int64_t frame_id = -1;
  int64_t timestamp_ns = 0;
  std::shared_ptr<const FrameFeatures> features;
  geometry::SE3d camera_from_world;
  std::vector<int64_t> point_ids;            // map point per keypoint, -1 none
  std::map<int64_t, int> connections;        // covisible keyframe -> shared points
  std::vector<int64_t> ordered_connections;  // by weight desc, then id
  bool bad = false;

  Eigen::Vector3d CameraCenter() const { return camera_from_world.Inverse().translation(); }
  // Up to n best covisible keyframes (all when n < 0).
  std::vector<int64_t> BestCovisible(int n) const;
  // Number of map points observed by at least `min_obs` keyframes.
  int TrackedPoints(int min_obs, const class Map& map) const;
};

struct MapPoint {
  int64_t id = -1;
  Eigen::Vector3d p_in_world = Eigen::Vector3d::Zero();
  Descriptor descriptor{};
  Eigen::Vector3d normal = Eigen::Vector3d::UnitZ();  // mean viewing direction
  float min_distance = 0.f, max_distance = 0.f;       // scale invariance range
  std::map<int64_t, int> observations;                // keyframe -> keypoint index
  int64_t reference_kf_id = -1;
  int64_t first_kf_id = -1;
  int visible = 1;  // times predicted visible by the tracker
  int found = 1;    // times actually matched
  int32_t label = 0;
  bool bad = false;
  // Tracker bookkeeping (not persisted semantics, but saved for exact resume).
  int64_t last_local_map_frame = -1;

  float FoundRatio() const { return static_cast<float>(found) / static_cast<float>(visible); }
  // Predicted pyramid level for a point seen at `distance`.
  int PredictScale(float distance, const features::ScalePyramid& pyramid) const;
};

class Map {
 public:
  Map(const geometry::StereoCamera& camera, const features::ScalePyramid& pyramid);

  std::mutex& mutex() const { return mutex_; }
  // The map's lock for the tracking thread, whose latency the client sees:
  // while it waits, the mapper's yields between its steps
  // (YieldToPriorityWaiter) let it in. std::mutex is not fair, and a mapper
  // that unlocks and locks again would otherwise take it straight back.
  std::unique_lock<std::mutex> PriorityLock() const {
    priority_waiters_.fetch_add(1, std::memory_order_acq_rel);
    std::unique_lock<std::mutex> lock(mutex_);
    priority_waiters_.fetch_sub(1, std::memory_order_acq_rel);
    return lock;
  }
  // Called by the mapper between steps with `lock` (on mutex()) held: lets a
  // PriorityLock waiter take the map first. Holds the lock again on return.
  void YieldToPriorityWaiter(std::unique_lock<std::mutex>* lock) const;
  const geometry::StereoCamera& camera() const { return camera_; }
  const features::ScalePyramid& pyramid() const { return pyramid_; }

  KeyFrame* CreateKeyFrame(const Frame& frame);
  MapPoint* CreatePoint(const Eigen::Vector3d& p_in_world, const KeyFrame& reference_kf);

  KeyFrame* keyframe(int64_t id);
  const KeyFrame* keyframe(int64_t id) const;
  MapPoint* point(int64_t id);
  const MapPoint* point(int64_t id) const;
  // nullptr for bad/erased points.
  MapPoint* GoodPoint(int64_t id);

  const std::map<int64_t, std::unique_ptr<KeyFrame>>& keyframes() const { return keyframes_; }
  const std::map<int64_t, std::unique_ptr<MapPoint>>& points() const { return points_; }
  int NumGoodKeyFrames() const;
  int NumGoodPoints() const;

  // --- Graph maintenance (caller holds mutex()) ---
  void AddObservation(MapPoint* point, KeyFrame* kf, int kp_index);
  // Erases the point too when fewer than two observations remain (`point` is
  // then dangling: use ids after this call).
  void EraseObservation(MapPoint* point, int64_t kf_id);
  // Keeps the observation descriptor with the least median distance to the
  // others, and the mean viewing direction and distance range.
  void UpdatePointDescriptor(MapPoint* point);
  void UpdatePointNormalAndDepth(MapPoint* point);
  // Marks bad, removes all observations, erases the point.
  void ErasePoint(int64_t point_id);
  // Moves the observations of `old_id` into `new_id` and erases `old_id`.
  void ReplacePoint(int64_t old_id, int64_t new_id);
  void UpdateConnections(KeyFrame* kf);
  // Drops a keyframe's observations and graph edges, then erases it.
  void EraseKeyFrame(int64_t kf_id);

  // Counters (persisted for exact resume).
  int64_t next_keyframe_id() const { return next_kf_id_; }
  int64_t next_point_id() const { return next_point_id_; }
  void set_next_ids(int64_t kf, int64_t point) {
    next_kf_id_ = kf;
    next_point_id_ = point;
  }
  // Self-calibrated stereo disparity offset (px): true disparity = measured
  // disparity + offset, i.e. a horizontal principal-point difference between
  // the rectified cameras. Estimated by the local bundle adjustment.
  double disparity_offset() const { return disparity_offset_; }
  void set_disparity_offset(double offset) {
    disparity_offset_ = offset;
    ++disparity_offset_updates_;
  }
  int disparity_offset_updates() const { return disparity_offset_updates_; }

  // Restore path: inserts objects with given ids.
  KeyFrame* InsertKeyFrame(std::unique_ptr<KeyFrame> kf);
  MapPoint* InsertPoint(std::unique_ptr<MapPoint> p);

 private:
  geometry::StereoCamera camera_;
  features::ScalePyramid pyramid_;
  mutable std::mutex mutex_;
  mutable std::atomic<int> priority_waiters_{0};
  std::map<int64_t, std::unique_ptr<KeyFrame>> keyframes_;
  std::map<int64_t, std::unique_ptr<MapPoint>> points_;
  // points_ by id in constant time: the trackers and the mapper look points
  // up by id tens of thousands of times a frame, and a lookup in a tree of
  // ~10⁴-10⁵ points is a chain of cache misses. points_ keeps the ordered
  // iteration (saving, snapshots, the BA's order).
  std::unordered_map<int64_t, MapPoint*> point_index_;
  int num_bad_points_ = 0;  // points_ held with bad set (NumGoodPoints)
  double disparity_offset_ = 0.0;
  int disparity_offset_updates_ = 0;
  int64_t next_kf_id_ = 0;
  int64_t next_point_id_ = 0;
};

// The pose with its quaternion at a fixed point of normalisation: SE3's
// quaternion constructor renormalises, and renormalising is not always
// idempotent in floating point, so stored poses are canonicalised to make
// save -> load bit-exact (same results after a resume).
geometry::SE3d CanonicalPose(const geometry::SE3d& pose);

// Builds FrameFeatures' grid and returns a shared pointer (helper for tests
// and the system).
std::shared_ptr<FrameFeatures> FinalizeFeatures(FrameFeatures features, int width, int height);

// `features` with its disparities shifted so that the applied offset becomes
// `offset` (px): u_right and depth recomputed; stereo matches whose corrected
// disparity is not positive become monocular.
std::shared_ptr<const FrameFeatures> WithDisparityOffset(
    const std::shared_ptr<const FrameFeatures>& features,
    const geometry::StereoCamera& camera,
    float offset);

}  // namespace twist::map
