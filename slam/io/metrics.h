// Evaluation metrics of DESIGN.md §6 (paper §V); docs/formats.md gives the
// exact definitions.
//
// Camera: RPE over consecutive frames of E_i = (gt_i⁻¹ gt_{i+1})⁻¹ (est_i⁻¹ est_{i+1}):
// mean ‖t(E_i)‖ (m/frame) and mean angle(E_i) (°/frame); ATE = RMSE of camera
// positions after the rigid (SE(3), no scale) alignment est -> gt minimising
// it (Horn/Umeyama). All rotations are re-orthonormalised on read.
//
// Objects: for a ground-truth object matched to an estimated track whose first
// frame is f0, the ground-truth pose at f0 is propagated with the estimated
// motion, P(i) = est_wo(i) est_wo(f0)⁻¹ gt_wo(f0). Then
//   ATE            RMSE over tracked frames of ‖c(P(i)) − c(gt_wo(i))‖ (m; c = box centre)
//   RPE_t, RPE_R   Σ ‖t(E_i)‖ / D and Σ angle(E_i) / D over consecutive tracked frames,
//                  E_i = (gt_i⁻¹ gt_{i+1})⁻¹ (P_i⁻¹ P_{i+1}), D = ground-truth distance
//                  travelled by the box centre over those pairs (m/m, °/m)
//   coverage       tracked ground-truth frames / ground-truth frames (optionally only
//                  frames where the object shows ≥ N mask pixels)
//   speed error    mean |v_est(i) − v_gt(i)| in km/h, v_gt(i) = ‖c_gt(i) − c_gt(i−1)‖/Δt,
//                  v_est(i) = ‖Exp(ξ_i Δt)·c(P(i−1)) − c(P(i−1))‖/Δt with ξ_i the estimated
//                  world twist of frame i (per second)
// moving = mean ground-truth speed above a threshold.
#pragma once

#include <Eigen/Core>
#include <cmath>
#include <cstdint>
#include <map>
#include <opencv2/core.hpp>
#include <string>
#include <vector>

#include "absl/status/statusor.h"
#include "slam/geometry/se3.h"
#include "slam/io/trajectory_io.h"

namespace twist::io {

// Angle of a rotation in degrees (0..180), robust near 0.
double RotationAngleDeg(const geometry::SO3d& r);

// Rigid alignment (rotation + translation, no scale) gt ≈ R est + t
// minimising Σ‖gt_k − (R est_k + t)‖² (Umeyama 1991 with scale fixed to 1).
// Requires equal sizes ≥ 1; with < 3 non-collinear points the rotation is
// not unique and the solver's minimum-norm choice is returned.
geometry::SE3d AlignRigid(const std::vector<Eigen::Vector3d>& est,
                          const std::vector<Eigen::Vector3d>& gt);

// gt ≈ scale · rotation · est + translation.
struct Similarity {
  double scale = 1.0;
  Eigen::Matrix3d rotation = Eigen::Matrix3d::Identity();
  Eigen::Vector3d translation = Eigen::Vector3d::Zero();
};

// The same with the scale fitted too (Umeyama 1991). It is a diagnostic for
// a stereo system, whose scale is observable: ATE after it is the error left
// once a global scale error is taken out (docs/math.md §25).
Similarity AlignSimilarity(const std::vector<Eigen::Vector3d>& est,
                           const std::vector<Eigen::Vector3d>& gt);

struct CameraMetrics {
  int64_t num_frames = 0;
  int64_t num_pairs = 0;
  double rpe_t = 0;      // m/frame, mean over consecutive pairs
  double rpe_r_deg = 0;  // °/frame, mean
  double rpe_t_max = 0;
  double rpe_r_deg_max = 0;
  double ate_rmse = 0;  // m, after rigid alignment
  double ate_mean = 0;
  double ate_max = 0;
  // m, after a similarity alignment (AlignSimilarity), and the scale it
  // applied to the estimate (1 / the estimate's scale error)
  double ate_sim3_rmse = 0;
  double sim3_scale = 1;
  double gt_path_length = 0;  // m
  // m, the same sum over the estimate's consecutive poses: est / gt is the
  // scale error, which the ATE's rigid alignment leaves in (docs/math.md §21)
  double est_path_length = 0;
  geometry::SE3d alignment;            // gt_from_est used for the ATE
  std::vector<double> rpe_t_per_pair;  // size num_pairs
  std::vector<double> rpe_r_deg_per_pair;
  std::vector<double> ate_per_frame;  // size num_frames
};

// Fails when the sizes differ or are 0.
absl::StatusOr<CameraMetrics> EvaluateCamera(
    const std::vector<geometry::SE3d>& gt_world_from_camera,
    const std::vector<geometry::SE3d>& est_world_from_camera);

struct ObjectEvalOptions {
  double moving_speed_mps = 0.5;  // moving when the mean GT speed exceeds this
  // Frames where the object shows at least this many mask pixels count for
  // the visible-coverage variant (needs pixel counts).
  int64_t min_mask_pixels = 2000;  // issue #5: coverage over frames with >= 2000 px
  // Fallback association without instance ids: nearest GT box centre at the
  // track's first frame within this distance.
  double max_match_distance_m = 3.0;
};

// (frame, panoptic id = class*1000 + instance) -> pixel count.
using MaskPixelCounts = std::map<std::pair<int64_t, int64_t>, int64_t>;

// Where the frames an object shows itself in (visible coverage) but its
// evaluated track misses lie: before the first frame of every track
// associated with it (not created yet), covered by another of its tracks (a
// fragment), between its tracks' first and last frames with no track (lost
// for a while), or after their last frame.
struct VisibleMisses {
  int64_t before_first = 0;
  int64_t other_fragment = 0;
  int64_t gap = 0;
  int64_t after_last = 0;
  VisibleMisses& operator+=(const VisibleMisses& o);
};

struct ObjectMetrics {
  int64_t gt_track_id = 0;
  int class_id = 0;
  bool moving = false;
  double gt_mean_speed_kmh = 0;
  int64_t gt_frames = 0;
  int64_t est_track_id = -1;  // -1: never tracked
  int num_est_tracks = 0;     // estimated tracks associated with this object (fragments)
  int64_t first_frame = -1;   // f0
  int64_t tracked_frames = 0;
  double coverage = 0;
  int64_t visible_gt_frames = -1;  // -1: no pixel counts
  int64_t visible_tracked_frames = -1;
  double visible_coverage = NAN;
  // With pixel counts.
  VisibleMisses visible_misses;
  double ate = NAN;       // m
  double distance_m = 0;  // GT distance over the evaluated pairs
  int64_t num_pairs = 0;
  double rpe_t_per_m = NAN;          // m/m (NaN when distance < 1e-3 m)
  double rpe_r_deg_per_m = NAN;      // °/m
  double rpe_t_per_frame = NAN;      // m/frame
  double rpe_r_deg_per_frame = NAN;  // °/frame
  int64_t speed_samples = 0;
  double speed_error_kmh = NAN;       // from the estimated twists
  double speed_error_pose_kmh = NAN;  // from finite differences of the propagated poses
  // Accumulators for pooled aggregates.
  double sum_sq_ate = 0;
  double sum_rpe_t = 0;
  double sum_rpe_r_deg = 0;
  double sum_speed_error_kmh = 0;
};

struct ObjectAggregate {
  int num_objects = 0;
  int num_tracked = 0;
  int64_t gt_frames = 0;
  int64_t tracked_frames = 0;
  double coverage = NAN;  // tracked_frames / gt_frames
  double visible_coverage = NAN;
  // Summed over the objects.
  VisibleMisses visible_misses;
  double ate = NAN;          // pooled RMSE over all tracked frames
  double rpe_t_per_m = NAN;  // Σ errors / Σ distance
  double rpe_r_deg_per_m = NAN;
  double speed_error_kmh = NAN;  // mean over all samples
};

// The aggregate of one class's moving or static objects (issue #5 states
// its targets for moving and parked *cars*; pedestrians, also moving, are
// reported apart).
struct ClassAggregate {
  int class_id = 0;
  bool moving = false;
  ObjectAggregate aggregate;
};

struct ObjectEvaluation {
  std::vector<ObjectMetrics> objects;  // one per GT object, by track id
  ObjectAggregate all, moving, static_objects;
  std::vector<ClassAggregate> by_class;  // by class id, moving before static
  int num_est_tracks = 0;
  int num_unmatched_est_tracks = 0;  // false positives / unassociated
};

absl::StatusOr<ObjectEvaluation> EvaluateObjects(const std::vector<ObjectGtRow>& gt,
                                                 const std::vector<ObjectTrackRow>& est,
                                                 const std::vector<int64_t>& timestamps_ns,
                                                 const ObjectEvalOptions& options,
                                                 const MaskPixelCounts* pixel_counts = nullptr);

// Pixel count of every panoptic id present in a CV_16UC1 / CV_32SC1 mask,
// keyed (frame, id), added to *counts.
void CountMaskPixels(int64_t frame, const cv::Mat& mask, MaskPixelCounts* counts);

// Human-readable tables.
std::string FormatCameraTable(const CameraMetrics& m);
std::string FormatObjectTable(const ObjectEvaluation& e);

class JsonWriter;
void WriteCameraJson(const CameraMetrics& m, JsonWriter* w);  // writes an object value
void WriteObjectsJson(const ObjectEvaluation& e, JsonWriter* w);

}  // namespace twist::io
