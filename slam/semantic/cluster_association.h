// Association of the current frame's panoptic detections with the existing
// semantic clusters (paper §IV-A; issue 5: "not by instance id alone").
//
// Real panoptic segmenters do not keep instance ids consistent from frame to
// frame, so a detection is matched to a cluster by
//   score = w_points · (share of the detection's matched map points that
//                       belong to the cluster)
//         + w_overlap · IoU(detection mask or box, cluster's predicted/previous
//                           mask or box)
//         + instance_bonus · [same instance id]
// over pairs of the same class, and the assignment maximising the total score
// is taken (Hungarian). Unmatched detections create clusters; clusters unseen
// for `lost_after_frames` frames become lost, and are removed after
// `remove_after_frames`.
#pragma once

#include <cstdint>
#include <map>
#include <opencv2/core.hpp>
#include <optional>
#include <unordered_set>
#include <vector>

#include "absl/status/status.h"
#include "slam/common/frame_result.h"
#include "slam/semantic/panoptic.h"

namespace twist::semantic {

double BoxIoU(const cv::Rect2d& a, const cv::Rect2d& b);
// IoU of two binary CV_8UC1 masks of the same size (non-zero = inside).
// `roi`, when non-empty, must contain every non-zero pixel of both masks
// (e.g. the union of their boxes): only it is scanned.
double MaskIoU(const cv::Mat& a, const cv::Mat& b, cv::Rect roi = cv::Rect());

// One instance segment of the current frame.
struct Detection {
  PanopticLabel label;  // class and the (possibly inconsistent) instance id
  cv::Rect2d box;       // pixels
  cv::Mat mask;         // optional CV_8UC1 full-image mask; empty = use the box
  // Map points whose keypoints in this frame fall inside the detection.
  std::vector<int64_t> point_ids;
};

enum class ClusterState { kNew = 0, kTracked = 1, kLost = 2 };

struct ClusterTrack {
  int64_t id = 0;
  int class_id = 0;
  int instance_id = 0;    // last instance id seen
  bool is_stuff = false;  // created from a "stuff" (instance 0) detection
  ClusterState state = ClusterState::kNew;
  cv::Rect2d last_box;
  cv::Mat last_mask;  // may be empty
  // Where the cluster is expected in the next frame (e.g. its points projected
  // with the motion model); set by the caller before Associate(), cleared after.
  std::optional<cv::Rect2d> predicted_box;
  cv::Mat predicted_mask;
  std::unordered_set<int64_t> point_ids;
  int frames_since_seen = 0;
  int num_frames_seen = 0;
};

struct ClusterAssociationOptions {
  double point_weight = 0.6;
  double overlap_weight = 0.4;
  double instance_bonus = 0.05;  // small: ids are a hint, not the truth
  double min_score = 0.2;        // weaker pairs are not associated
  int lost_after_frames = 3;     // unseen this many frames -> lost
  int remove_after_frames = 30;  // unseen this many frames -> removed
  // "Stuff" detections (instance 0) are associated by class only: one cluster
  // per stuff class.
  bool stuff_by_class = true;

  absl::Status Validate() const;
};

struct AssociationResult {
  // Cluster id per detection (same order as the input).
  std::vector<int64_t> cluster_of_detection;
  // Matching score per detection (0 for created clusters).
  std::vector<double> score_of_detection;
  std::vector<int64_t> created;
  std::vector<int64_t> lost;     // became lost in this frame
  std::vector<int64_t> removed;  // removed in this frame
  // The same as ClusterEvents (plane events come from the plane fitter).
  std::vector<ClusterEvent> events;
};

// Owns the cluster tracks of one session; ids are per instance (no globals).
class ClusterAssociator {
 public:
  explicit ClusterAssociator(const ClusterAssociationOptions& options);

  // Pairwise score (exposed for tests and debugging); 0 for different classes.
  double Score(const Detection& detection, const ClusterTrack& cluster) const;

  // Associates one frame's detections, updates the tracks (boxes, masks,
  // points, states) and returns what happened.
  AssociationResult Associate(const std::vector<Detection>& detections);

  // Tracks by id (includes lost ones until removed).
  const std::map<int64_t, ClusterTrack>& clusters() const { return clusters_; }
  ClusterTrack* Find(int64_t id);
  // The caller may predict where a cluster will be in the next frame.
  void SetPrediction(int64_t id, const cv::Rect2d& box, const cv::Mat& mask = cv::Mat());
  // Marks map points as members of a cluster (e.g. after triangulation).
  void AddPoints(int64_t id, const std::vector<int64_t>& point_ids);
  // Classes reported as dynamic in ClusterEvent::is_dynamic.
  void set_dynamic_classes(std::unordered_set<int> classes) {
    dynamic_classes_ = std::move(classes);
  }

  // Persistence (SlamSystem::Save/Load): the tracks and the id counter; the
  // options and dynamic classes come from the configuration.
  int64_t next_id() const { return next_id_; }
  void RestoreState(std::map<int64_t, ClusterTrack> clusters, int64_t next_id) {
    clusters_ = std::move(clusters);
    next_id_ = next_id;
  }

 private:
  ClusterAssociationOptions options_;
  std::map<int64_t, ClusterTrack> clusters_;
  std::unordered_set<int> dynamic_classes_;
  int64_t next_id_ = 1;
};

}  // namespace twist::semantic
