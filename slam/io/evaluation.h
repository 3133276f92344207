// Evaluation of a run's output directory against a dataset sequence's ground
// truth: the engine behind `twistslam eval` (DESIGN.md §6, §7).
//
//   auto seq = OpenSequence(dir, "kitti-tracking", "0001");
//   auto eval = EvaluateRunDirectory(**seq, "/tmp/run", RunEvalOptions());
//   std::cout << FormatRunEvaluation(*eval);
//   WriteFileAtomic("metrics.json", RunEvaluationJson(*eval));
#pragma once

#include <optional>
#include <string>
#include <vector>

#include "absl/status/statusor.h"
#include "slam/io/metrics.h"
#include "slam/io/sequence.h"

namespace twist::io {

struct RunEvalOptions {
  ObjectEvalOptions objects;
  // Count mask pixels per object (reads every mask of the sequence) for the
  // visible-coverage variant; ignored when the sequence has no masks.
  bool count_mask_pixels = true;
  // The file of the run directory that holds the object tracks: objects.txt
  // (the per-frame poses) or objects_refined.txt (the trajectories as the
  // dynamic BA left them).
  std::string objects_file = "objects.txt";
  // The file that holds the camera poses: camera.txt (online) or
  // camera_refined.txt (corrected by the final map's keyframes).
  std::string camera_file = "camera.txt";
};

struct RunEvaluation {
  std::string dataset_format;
  std::string sequence;
  std::string est_dir;
  int64_t num_frames = 0;
  std::optional<CameraMetrics> camera;      // absent without ground-truth poses
  std::string camera_note;                  // why camera metrics are absent
  std::optional<ObjectEvaluation> objects;  // absent without object ground truth
  std::string objects_note;
  std::string objects_gt_source;  // "objects_gt" or "label_02 + poses"
  RunEvalOptions options;         // as used
  bool used_mask_pixels = false;  // visible coverage computed from the masks
};

// Ground-truth object poses from KITTI labels and ground-truth camera poses:
// world_from_object = world_from_left · (translate left_from_ref) · ref_from_object
// with the origin at the 3D box centre; DontCare and unknown types skipped;
// class from KittiTypeToClassId; track id from the label.
std::vector<ObjectGtRow> ObjectsGtFromLabels(const std::vector<KittiLabel>& labels,
                                             const std::vector<geometry::SE3d>& world_from_left,
                                             const Eigen::Vector3d& left_from_ref_translation);

// Reads OUTDIR/camera.txt (options.camera_file; when the sequence has ground-truth poses) and
// OUTDIR/objects.txt (when it has object ground truth) and computes the
// metrics. Fails, naming the file, when an output needed is missing or
// malformed, or has a different number of frames.
absl::StatusOr<RunEvaluation> EvaluateRunDirectory(const SequenceReader& sequence,
                                                   const std::string& est_dir,
                                                   const RunEvalOptions& options);

// Writes the sequence's own ground truth in the run-output format (camera.txt,
// camera_tum.txt, objects.txt with track id = instance id and the world twist
// of each step, ξ_i = Log(gt_wo(i) gt_wo(i−1)⁻¹)/Δt, or of the next step for
// an object's first frame). Evaluating it gives zeros: a self-check of the
// whole evaluation path. Fails without ground-truth camera poses.
absl::Status WriteGroundTruthAsRun(const SequenceReader& sequence, const std::string& dir);

std::string FormatRunEvaluation(const RunEvaluation& eval);
std::string RunEvaluationJson(const RunEvaluation& eval);

}  // namespace twist::io
