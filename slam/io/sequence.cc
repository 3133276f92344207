#include "slam/io/sequence.h"

#include <glog/logging.h>

#include <algorithm>
#include <cctype>
#include <cstdio>
#include <filesystem>
#include <set>
#include <system_error>

#include "slam/io/file_util.h"
#include "slam/io/image_io.h"

namespace twist::io {
namespace {

std::string FrameFile(int64_t i) {
  char buf[32];
  std::snprintf(buf, sizeof(buf), "%06lld.png", static_cast<long long>(i));
  return buf;
}

bool AllDigits(const std::string& s) {
  return !s.empty() && std::all_of(s.begin(), s.end(), [](char c) { return std::isdigit(c); });
}

// Sequence folder name: the name as given if it exists, else zero-padded to
// `width` digits ("6" -> "06", "1" -> "0001").
std::string ResolveSequenceName(const std::string& parent, const std::string& seq, int width) {
  if (DirExists(JoinPath(parent, seq)) || !AllDigits(seq) ||
      static_cast<int>(seq.size()) >= width) {
    return seq;
  }
  return std::string(static_cast<size_t>(width) - seq.size(), '0') + seq;
}

// Number of frames in an image folder: NNNNNN.png files must be 0..N-1.
absl::StatusOr<int64_t> CountFrames(const std::string& dir) {
  if (!DirExists(dir)) return absl::NotFoundError(dir + ": no such directory");
  std::set<int64_t> indices;
  std::error_code ec;
  for (const auto& entry : std::filesystem::directory_iterator(dir, ec)) {
    const std::string name = entry.path().filename().string();
    if (name.size() < 5 || name.substr(name.size() - 4) != ".png") continue;
    const std::string stem = name.substr(0, name.size() - 4);
    int64_t index = 0;
    if (!AllDigits(stem) || !ParseInt64(stem, &index)) continue;
    indices.insert(index);
  }
  if (ec) return absl::FailedPreconditionError(dir + ": cannot list: " + ec.message());
  if (indices.empty()) return absl::NotFoundError(dir + ": no NNNNNN.png images");
  int64_t expected = 0;
  for (int64_t index : indices) {
    if (index != expected) {
      return absl::NotFoundError(JoinPath(dir, FrameFile(expected)) +
                                 ": missing (images must be numbered from 000000 without gaps)");
    }
    ++expected;
  }
  return expected;
}

std::vector<std::string> FramePaths(const std::string& dir, int64_t n) {
  std::vector<std::string> paths;
  paths.reserve(static_cast<size_t>(n));
  for (int64_t i = 0; i < n; ++i) paths.push_back(JoinPath(dir, FrameFile(i)));
  return paths;
}

absl::Status CheckAllExist(const std::vector<std::string>& paths, const std::string& what) {
  for (const std::string& p : paths) {
    if (!FileExists(p)) return absl::NotFoundError(p + ": missing " + what);
  }
  return absl::OkStatus();
}

absl::Status CountMismatch(const std::string& path,
                           size_t found,
                           int64_t frames,
                           const std::string& what) {
  return absl::InvalidArgumentError(path + ": " + std::to_string(found) + " " + what + " for " +
                                    std::to_string(frames) + " frames" +
                                    (static_cast<int64_t>(found) < frames ? " (truncated?)" : ""));
}

// Reads frame 0's left image to learn the image size, and checks that the
// principal point lies inside it.
absl::Status SetImageSize(const std::string& left0, geometry::StereoCamera* camera) {
  absl::StatusOr<cv::Mat> image = ReadImage8(left0);
  if (!image.ok()) return image.status();
  camera->width = image->cols;
  camera->height = image->rows;
  absl::Status s = camera->Validate();
  if (!s.ok()) {
    return absl::InvalidArgumentError(
        "calibration does not fit " + left0 + " (" + std::to_string(image->cols) + "x" +
        std::to_string(image->rows) + "): " + std::string(s.message()));
  }
  return absl::OkStatus();
}

absl::Status OpenOdometry(const std::string& dir,
                          const std::string& seq_in,
                          std::string* seq_out,
                          geometry::StereoCamera* camera,
                          std::vector<std::string>* left,
                          std::vector<std::string>* right,
                          std::vector<int64_t>* times,
                          std::vector<geometry::SE3d>* poses) {
  const std::string sequences = JoinPath(dir, "sequences");
  if (!DirExists(sequences)) {
    return absl::NotFoundError(sequences +
                               ": no such directory (expected the KITTI odometry "
                               "layout DIR/sequences/SS/...)");
  }
  const std::string seq = ResolveSequenceName(sequences, seq_in, 2);
  const std::string seq_dir = JoinPath(sequences, seq);
  if (!DirExists(seq_dir)) return absl::NotFoundError(seq_dir + ": no such directory");
  *seq_out = seq;
  auto calib = ReadKittiOdometryCalib(JoinPath(seq_dir, "calib.txt"));
  if (!calib.ok()) return calib.status();
  *camera = calib->camera;
  auto n = CountFrames(JoinPath(seq_dir, "image_0"));
  if (!n.ok()) return n.status();
  *left = FramePaths(JoinPath(seq_dir, "image_0"), *n);
  *right = FramePaths(JoinPath(seq_dir, "image_1"), *n);
  absl::Status s = CheckAllExist(*right, "right image");
  if (!s.ok()) return s;
  const std::string times_path = JoinPath(seq_dir, "times.txt");
  auto t = ReadTimes(times_path);
  if (!t.ok()) return t.status();
  if (static_cast<int64_t>(t->size()) != *n)
    return CountMismatch(times_path, t->size(), *n, "times");
  *times = std::move(*t);
  const std::string poses_path = JoinPath(JoinPath(dir, "poses"), seq + ".txt");
  if (FileExists(poses_path)) {
    auto p = ReadKittiPoses(poses_path);
    if (!p.ok()) return p.status();
    if (static_cast<int64_t>(p->size()) != *n)
      return CountMismatch(poses_path, p->size(), *n, "poses");
    *poses = std::move(*p);
  }
  return SetImageSize((*left)[0], camera);
}

}  // namespace

absl::StatusOr<DatasetFormat> ParseDatasetFormat(const std::string& name) {
  if (name == "kitti-odometry") return DatasetFormat::kKittiOdometry;
  if (name == "kitti-tracking") return DatasetFormat::kKittiTracking;
  return absl::InvalidArgumentError("unknown dataset format '" + name +
                                    "' (expected kitti-odometry or kitti-tracking)");
}

const char* DatasetFormatName(DatasetFormat format) {
  switch (format) {
    case DatasetFormat::kKittiOdometry:
      return "kitti-odometry";
    case DatasetFormat::kKittiTracking:
      return "kitti-tracking";
  }
  return "unknown";
}

cv::Mat MotsToPanoptic(const cv::Mat& mots) {
  CHECK_EQ(mots.type(), CV_16UC1);
  cv::Mat out(mots.size(), CV_16UC1);
  for (int y = 0; y < mots.rows; ++y) {
    const uint16_t* in = mots.ptr<uint16_t>(y);
    uint16_t* o = out.ptr<uint16_t>(y);
    for (int x = 0; x < mots.cols; ++x) {
      const int v = in[x];
      const int cls = v / 1000;
      const int inst = v % 1000;
      if (v == 10000 || v == 0) {
        o[x] = 0;
      } else if (cls == 1) {
        o[x] = static_cast<uint16_t>(26 * 1000 + inst);
      } else if (cls == 2) {
        o[x] = static_cast<uint16_t>(24 * 1000 + inst);
      } else {
        o[x] = static_cast<uint16_t>(v);
      }
    }
  }
  return out;
}

absl::StatusOr<std::unique_ptr<SequenceReader>> OpenSequence(const std::string& dir,
                                                             const std::string& format,
                                                             const std::string& seq) {
  absl::StatusOr<DatasetFormat> f = ParseDatasetFormat(format);
  if (!f.ok()) return f.status();
  return OpenSequence(dir, *f, seq);
}

absl::StatusOr<std::unique_ptr<SequenceReader>> OpenSequence(const std::string& dir_in,
                                                             DatasetFormat format,
                                                             const std::string& seq_in) {
  if (!DirExists(dir_in)) return absl::NotFoundError(dir_in + ": no such dataset directory");
  std::unique_ptr<SequenceReader> r(new SequenceReader());
  r->format_ = format;
  if (format == DatasetFormat::kKittiOdometry) {
    absl::Status s = OpenOdometry(dir_in,
                                  seq_in,
                                  &r->sequence_,
                                  &r->camera_,
                                  &r->left_paths_,
                                  &r->right_paths_,
                                  &r->timestamps_ns_,
                                  &r->gt_world_from_camera_);
    if (!s.ok()) return s;
    r->has_times_file_ = true;
    return r;
  }

  // kitti-tracking
  std::string dir = dir_in;
  if (!DirExists(JoinPath(dir, "image_02")) && DirExists(JoinPath(dir, "training/image_02"))) {
    dir = JoinPath(dir, "training");
  }
  const std::string image_02 = JoinPath(dir, "image_02");
  if (!DirExists(image_02)) {
    return absl::NotFoundError(image_02 +
                               ": no such directory (expected the KITTI tracking "
                               "layout DIR/image_02/SSSS/...)");
  }
  const std::string seq = ResolveSequenceName(image_02, seq_in, 4);
  r->sequence_ = seq;
  auto calib = ReadKittiTrackingCalib(JoinPath(JoinPath(dir, "calib"), seq + ".txt"));
  if (!calib.ok()) return calib.status();
  r->tracking_calib_ = *calib;
  r->camera_ = calib->camera;
  auto n = CountFrames(JoinPath(image_02, seq));
  if (!n.ok()) return n.status();
  r->left_paths_ = FramePaths(JoinPath(image_02, seq), *n);
  r->right_paths_ = FramePaths(JoinPath(JoinPath(dir, "image_03"), seq), *n);
  absl::Status s = CheckAllExist(r->right_paths_, "right image");
  if (!s.ok()) return s;

  const std::string panoptic_dir = JoinPath(JoinPath(dir, "panoptic"), seq);
  const std::string instances_dir = JoinPath(JoinPath(dir, "instances"), seq);
  if (DirExists(panoptic_dir)) {
    r->mask_paths_ = FramePaths(panoptic_dir, *n);
    s = CheckAllExist(r->mask_paths_, "panoptic mask");
    if (!s.ok()) return s;
  } else if (DirExists(instances_dir)) {
    r->mask_paths_ = FramePaths(instances_dir, *n);
    r->masks_are_mots_ = true;
    s = CheckAllExist(r->mask_paths_, "instance mask");
    if (!s.ok()) return s;
  }

  const std::string times_path = JoinPath(JoinPath(dir, "times"), seq + ".txt");
  if (FileExists(times_path)) {
    auto t = ReadTimes(times_path);
    if (!t.ok()) return t.status();
    if (static_cast<int64_t>(t->size()) != *n)
      return CountMismatch(times_path, t->size(), *n, "times");
    r->timestamps_ns_ = std::move(*t);
    r->has_times_file_ = true;
  } else {
    for (int64_t i = 0; i < *n; ++i) r->timestamps_ns_.push_back(i * kDefaultFramePeriodNs);
  }

  const std::string poses_path = JoinPath(JoinPath(dir, "poses"), seq + ".txt");
  if (FileExists(poses_path)) {
    auto p = ReadKittiPoses(poses_path);
    if (!p.ok()) return p.status();
    if (static_cast<int64_t>(p->size()) != *n)
      return CountMismatch(poses_path, p->size(), *n, "poses");
    r->gt_world_from_camera_ = std::move(*p);
  }

  const std::string labels_path = JoinPath(JoinPath(dir, "label_02"), seq + ".txt");
  if (FileExists(labels_path)) {
    auto labels = ReadKittiLabels(labels_path);
    if (!labels.ok()) return labels.status();
    r->labels_ = std::move(*labels);
    r->has_labels_ = true;
    for (size_t k = 0; k < r->labels_.size(); ++k) {
      r->labels_by_frame_[r->labels_[k].frame].push_back(k);
    }
  }

  const std::string objects_path = JoinPath(JoinPath(dir, "objects_gt"), seq + ".txt");
  if (FileExists(objects_path)) {
    auto objects = ReadObjectsGt(objects_path);
    if (!objects.ok()) return objects.status();
    for (const ObjectGtRow& row : *objects) {
      if (row.frame >= *n) {
        return absl::InvalidArgumentError(objects_path + ": frame " + std::to_string(row.frame) +
                                          " beyond the sequence's " + std::to_string(*n) +
                                          " frames");
      }
    }
    r->gt_objects_ = std::move(*objects);
    r->has_gt_objects_ = true;
  }

  const std::string classes_path = JoinPath(dir, "classes.txt");
  if (FileExists(classes_path)) {
    auto text = ReadTextFile(classes_path);
    if (!text.ok()) return text.status();
    r->class_table_text_ = std::move(*text);
  }

  s = SetImageSize(r->left_paths_[0], &r->camera_);
  if (!s.ok()) return s;
  return r;
}

absl::StatusOr<cv::Mat> SequenceReader::ReadMask(int64_t i) const {
  if (i < 0 || i >= size()) {
    return absl::OutOfRangeError("frame " + std::to_string(i) + " out of range [0, " +
                                 std::to_string(size()) + ")");
  }
  if (mask_paths_.empty()) return cv::Mat();
  const std::string& path = mask_paths_[static_cast<size_t>(i)];
  absl::StatusOr<cv::Mat> mask = ReadLabelImage16(path);
  if (!mask.ok()) return mask.status();
  absl::Status s =
      CheckSameSize(*mask, path, cv::Size(camera_.width, camera_.height), "the images");
  if (!s.ok()) return s;
  if (masks_are_mots_) return MotsToPanoptic(*mask);
  return mask;
}

absl::StatusOr<StereoFrame> SequenceReader::ReadFrame(int64_t i) const {
  if (i < 0 || i >= size()) {
    return absl::OutOfRangeError("frame " + std::to_string(i) + " out of range [0, " +
                                 std::to_string(size()) + ")");
  }
  const size_t k = static_cast<size_t>(i);
  StereoFrame frame;
  frame.index = i;
  frame.timestamp_ns = timestamps_ns_[k];
  const cv::Size size(camera_.width, camera_.height);
  absl::StatusOr<cv::Mat> left = ReadImage8(left_paths_[k]);
  if (!left.ok()) return left.status();
  absl::Status s = CheckSameSize(*left, left_paths_[k], size, "the first frame");
  if (!s.ok()) return s;
  absl::StatusOr<cv::Mat> right = ReadImage8(right_paths_[k]);
  if (!right.ok()) return right.status();
  s = CheckSameSize(*right, right_paths_[k], left->size(), "the left image");
  if (!s.ok()) return s;
  if (right->type() != left->type()) {
    return absl::InvalidArgumentError(
        right_paths_[k] + ": has " + std::to_string(right->channels()) +
        " channels but the left image has " + std::to_string(left->channels()));
  }
  frame.left = *left;
  frame.right = *right;
  absl::StatusOr<cv::Mat> mask = ReadMask(i);
  if (!mask.ok()) return mask.status();
  frame.panoptic = *mask;
  auto it = labels_by_frame_.find(i);
  if (it != labels_by_frame_.end()) {
    for (size_t idx : it->second) {
      const KittiLabel& l = labels_[idx];
      const int class_id = KittiTypeToClassId(l.type);
      if (l.is_dont_care() || class_id == 0) continue;
      DetectionBox box;
      box.class_id = class_id;
      box.instance_id = static_cast<int>(l.track_id);
      box.x_min = static_cast<float>(std::max(0.0, l.x1));
      box.y_min = static_cast<float>(std::max(0.0, l.y1));
      box.x_max = static_cast<float>(std::min<double>(camera_.width - 1, l.x2));
      box.y_max = static_cast<float>(std::min<double>(camera_.height - 1, l.y2));
      frame.boxes.push_back(box);
    }
  }
  return frame;
}

}  // namespace twist::io
