// One dataset sequence, read frame by frame, with its ground truth.
//
//   absl::StatusOr<std::unique_ptr<io::SequenceReader>> seq =
//       io::OpenSequence("/data/kitti", "kitti-tracking", "0001");
//   if (!seq.ok()) { ... seq.status().message() names the file and problem ... }
//   for (int64_t i = 0; i < (*seq)->size(); ++i) {
//     absl::StatusOr<StereoFrame> frame = (*seq)->ReadFrame(i);
//     ...
//   }
//
// Layouts (DESIGN.md §5, docs/formats.md):
//  kitti-odometry: DIR/sequences/SS/{image_0,image_1}/NNNNNN.png,
//                  DIR/sequences/SS/calib.txt (P0/P1), DIR/sequences/SS/times.txt,
//                  optional DIR/poses/SS.txt.
//  kitti-tracking: DIR/image_02/SSSS/NNNNNN.png, DIR/image_03/SSSS/NNNNNN.png,
//                  DIR/calib/SSSS.txt (P2/P3), optional DIR/label_02/SSSS.txt,
//                  DIR/panoptic/SSSS/NNNNNN.png (16-bit class*1000+instance),
//                  DIR/instances/SSSS/NNNNNN.png (KITTI MOTS), DIR/poses/SSSS.txt,
//                  DIR/times/SSSS.txt (else 10 Hz), DIR/classes.txt,
//                  DIR/objects_gt/SSSS.txt. DIR may also be the parent of
//                  `training/`.
// Opening checks the whole layout (counts, calibration, first image) so that
// a bad dataset fails before streaming starts; ReadFrame checks each file.
// The reader holds no mutable state: ReadFrame may be called concurrently.
#pragma once

#include <cstdint>
#include <map>
#include <memory>
#include <opencv2/core.hpp>
#include <optional>
#include <string>
#include <vector>

#include "absl/status/statusor.h"
#include "slam/common/stereo_frame.h"
#include "slam/geometry/se3.h"
#include "slam/geometry/stereo_camera.h"
#include "slam/io/kitti_calib.h"
#include "slam/io/kitti_labels.h"
#include "slam/io/trajectory_io.h"

namespace twist::io {

enum class DatasetFormat { kKittiOdometry, kKittiTracking };
// "kitti-odometry" | "kitti-tracking".
absl::StatusOr<DatasetFormat> ParseDatasetFormat(const std::string& name);
const char* DatasetFormatName(DatasetFormat format);

// The default frame period when a sequence has no times file (KITTI: 10 Hz).
inline constexpr int64_t kDefaultFramePeriodNs = 100'000'000;

class SequenceReader {
 public:
  DatasetFormat format() const { return format_; }
  // Sequence name as found on disk ("06", "0001").
  const std::string& sequence() const { return sequence_; }
  // Rectified stereo camera; width/height are those of the images.
  const geometry::StereoCamera& camera() const { return camera_; }
  int64_t size() const { return static_cast<int64_t>(left_paths_.size()); }
  const std::vector<int64_t>& timestamps_ns() const { return timestamps_ns_; }
  bool has_times_file() const { return has_times_file_; }

  // Loads frame i: left/right images (8-bit gray or BGR, same size and type
  // as the calibration's image size), the panoptic mask when present (or the
  // KITTI MOTS instance mask, classes mapped to Cityscapes ids) and, for
  // kitti-tracking with labels, the labelled 2D boxes of that frame (class
  // from KittiTypeToClassId, instance id = track id, DontCare skipped).
  absl::StatusOr<StereoFrame> ReadFrame(int64_t i) const;
  // Only the label mask of frame i (CV_16UC1), empty Mat when the sequence has none.
  absl::StatusOr<cv::Mat> ReadMask(int64_t i) const;
  bool has_masks() const { return !mask_paths_.empty(); }

  const std::string& left_path(int64_t i) const { return left_paths_[static_cast<size_t>(i)]; }
  const std::string& right_path(int64_t i) const { return right_paths_[static_cast<size_t>(i)]; }

  // Ground truth (each may be absent).
  bool has_gt_poses() const { return !gt_world_from_camera_.empty(); }
  const std::vector<geometry::SE3d>& gt_world_from_camera() const { return gt_world_from_camera_; }
  bool has_gt_objects() const { return has_gt_objects_; }
  const std::vector<ObjectGtRow>& gt_objects() const { return gt_objects_; }
  bool has_labels() const { return has_labels_; }
  const std::vector<KittiLabel>& labels() const { return labels_; }
  // Raw text of classes.txt (class table, see docs/config.md), "" if absent.
  const std::string& class_table_text() const { return class_table_text_; }
  // Full calibration of a kitti-tracking sequence.
  const std::optional<KittiTrackingCalib>& tracking_calib() const { return tracking_calib_; }

 private:
  friend absl::StatusOr<std::unique_ptr<SequenceReader>> OpenSequence(const std::string&,
                                                                      DatasetFormat,
                                                                      const std::string&);
  SequenceReader() = default;

  DatasetFormat format_ = DatasetFormat::kKittiOdometry;
  std::string sequence_;
  geometry::StereoCamera camera_;
  std::vector<std::string> left_paths_;
  std::vector<std::string> right_paths_;
  std::vector<std::string> mask_paths_;  // empty, or one per frame
  bool masks_are_mots_ = false;
  std::vector<int64_t> timestamps_ns_;
  bool has_times_file_ = false;
  std::vector<geometry::SE3d> gt_world_from_camera_;
  bool has_gt_objects_ = false;
  std::vector<ObjectGtRow> gt_objects_;
  bool has_labels_ = false;
  std::vector<KittiLabel> labels_;
  std::map<int64_t, std::vector<size_t>> labels_by_frame_;
  std::string class_table_text_;
  std::optional<KittiTrackingCalib> tracking_calib_;
};

absl::StatusOr<std::unique_ptr<SequenceReader>> OpenSequence(const std::string& dir,
                                                             DatasetFormat format,
                                                             const std::string& seq);
absl::StatusOr<std::unique_ptr<SequenceReader>> OpenSequence(const std::string& dir,
                                                             const std::string& format,
                                                             const std::string& seq);

// Maps a KITTI MOTS instance PNG (class 1 car, 2 pedestrian, 10000 ignore) to
// the panoptic convention with Cityscapes ids (car 26, person 24, 0 ignore).
// Values whose class is already > 2 are kept.
cv::Mat MotsToPanoptic(const cv::Mat& mots);

}  // namespace twist::io
