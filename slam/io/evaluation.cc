#include "slam/io/evaluation.h"

#include <algorithm>
#include <filesystem>
#include <map>
#include <system_error>

#include "slam/io/file_util.h"
#include "slam/io/json_writer.h"

namespace twist::io {

std::vector<ObjectGtRow> ObjectsGtFromLabels(const std::vector<KittiLabel>& labels,
                                             const std::vector<geometry::SE3d>& world_from_left,
                                             const Eigen::Vector3d& left_from_ref_translation) {
  std::vector<ObjectGtRow> rows;
  const geometry::SE3d left_from_ref(geometry::SO3d(), left_from_ref_translation);
  for (const KittiLabel& l : labels) {
    const int class_id = KittiTypeToClassId(l.type);
    if (l.is_dont_care() || class_id == 0 || l.track_id < 0) continue;
    if (l.frame >= static_cast<int64_t>(world_from_left.size())) continue;
    ObjectGtRow row;
    row.frame = l.frame;
    row.track_id = l.track_id;
    row.class_id = class_id;
    row.world_from_object =
        world_from_left[static_cast<size_t>(l.frame)] * left_from_ref * l.RefFromObject();
    rows.push_back(row);
  }
  return rows;
}

absl::StatusOr<RunEvaluation> EvaluateRunDirectory(const SequenceReader& sequence,
                                                   const std::string& est_dir,
                                                   const RunEvalOptions& options) {
  if (!DirExists(est_dir)) return absl::NotFoundError(est_dir + ": no such output directory");
  RunEvaluation eval;
  eval.dataset_format = DatasetFormatName(sequence.format());
  eval.sequence = sequence.sequence();
  eval.est_dir = est_dir;
  eval.num_frames = sequence.size();
  eval.options = options;

  if (sequence.has_gt_poses()) {
    const std::string path = JoinPath(est_dir, options.camera_file);
    absl::StatusOr<std::vector<geometry::SE3d>> est = ReadKittiPoses(path);
    if (!est.ok()) return est.status();
    if (static_cast<int64_t>(est->size()) != sequence.size()) {
      return absl::InvalidArgumentError(path + ": " + std::to_string(est->size()) +
                                        " poses for a sequence of " +
                                        std::to_string(sequence.size()) + " frames");
    }
    absl::StatusOr<CameraMetrics> camera = EvaluateCamera(sequence.gt_world_from_camera(), *est);
    if (!camera.ok()) return camera.status();
    eval.camera = *camera;
  } else {
    eval.camera_note = "the sequence has no ground-truth camera poses";
  }

  std::vector<ObjectGtRow> gt_objects;
  if (sequence.has_gt_objects()) {
    gt_objects = sequence.gt_objects();
    eval.objects_gt_source = "objects_gt";
  } else if (sequence.has_labels() && sequence.has_gt_poses() && sequence.tracking_calib()) {
    gt_objects = ObjectsGtFromLabels(sequence.labels(),
                                     sequence.gt_world_from_camera(),
                                     sequence.tracking_calib()->left_from_ref_translation);
    eval.objects_gt_source = "label_02 + poses";
  }
  if (!eval.objects_gt_source.empty()) {
    const std::string path = JoinPath(est_dir, options.objects_file);
    absl::StatusOr<std::vector<ObjectTrackRow>> est = ReadObjectTracks(path);
    if (!est.ok()) return est.status();
    for (const ObjectTrackRow& row : *est) {
      if (row.frame >= sequence.size()) {
        return absl::InvalidArgumentError(path + ": frame " + std::to_string(row.frame) +
                                          " beyond the sequence's " +
                                          std::to_string(sequence.size()) + " frames");
      }
    }
    MaskPixelCounts counts;
    const bool use_counts = options.count_mask_pixels && sequence.has_masks();
    eval.used_mask_pixels = use_counts;
    if (use_counts) {
      for (int64_t i = 0; i < sequence.size(); ++i) {
        absl::StatusOr<cv::Mat> mask = sequence.ReadMask(i);
        if (!mask.ok()) return mask.status();
        CountMaskPixels(i, *mask, &counts);
      }
    }
    absl::StatusOr<ObjectEvaluation> objects = EvaluateObjects(gt_objects,
                                                               *est,
                                                               sequence.timestamps_ns(),
                                                               options.objects,
                                                               use_counts ? &counts : nullptr);
    if (!objects.ok()) return objects.status();
    eval.objects = *objects;
  } else {
    eval.objects_note =
        "the sequence has no object ground truth (objects_gt, or label_02 with poses)";
  }
  return eval;
}

absl::Status WriteGroundTruthAsRun(const SequenceReader& sequence, const std::string& dir) {
  if (!sequence.has_gt_poses()) {
    return absl::FailedPreconditionError("sequence " + sequence.sequence() +
                                         " has no ground-truth camera poses");
  }
  std::error_code ec;
  std::filesystem::create_directories(dir, ec);
  if (ec || !DirExists(dir)) return absl::FailedPreconditionError("cannot create directory " + dir);
  std::vector<ObjectGtRow> gt = sequence.gt_objects();
  if (!sequence.has_gt_objects() && sequence.has_labels() && sequence.tracking_calib()) {
    gt = ObjectsGtFromLabels(sequence.labels(),
                             sequence.gt_world_from_camera(),
                             sequence.tracking_calib()->left_from_ref_translation);
  }
  std::map<std::pair<int64_t, int64_t>, const ObjectGtRow*> by_key;
  for (const ObjectGtRow& row : gt) by_key[{row.track_id, row.frame}] = &row;
  const std::vector<int64_t>& stamps = sequence.timestamps_ns();
  std::vector<ObjectTrackRow> rows;
  for (const ObjectGtRow& g : gt) {
    ObjectTrackRow r;
    r.frame = g.frame;
    r.track_id = g.track_id;
    r.class_id = g.class_id;
    r.instance_id = g.track_id;
    r.world_from_object = g.world_from_object;
    auto prev = by_key.find({g.track_id, g.frame - 1});
    auto next = by_key.find({g.track_id, g.frame + 1});
    if (prev != by_key.end() && g.frame >= 1) {
      const double dt = NsToSeconds(stamps[g.frame] - stamps[g.frame - 1]);
      r.twist_in_world =
          (g.world_from_object * prev->second->world_from_object.Inverse()).Log() / dt;
    } else if (next != by_key.end() && g.frame + 1 < sequence.size()) {
      const double dt = NsToSeconds(stamps[g.frame + 1] - stamps[g.frame]);
      r.twist_in_world =
          (next->second->world_from_object * g.world_from_object.Inverse()).Log() / dt;
    }
    rows.push_back(r);
  }
  std::sort(rows.begin(), rows.end(), [](const ObjectTrackRow& a, const ObjectTrackRow& b) {
    return a.frame != b.frame ? a.frame < b.frame : a.track_id < b.track_id;
  });
  std::vector<StampedPose> tum;
  for (int64_t i = 0; i < sequence.size(); ++i) {
    tum.push_back({stamps[i], sequence.gt_world_from_camera()[i]});
  }
  absl::Status s = WriteKittiPoses(JoinPath(dir, "camera.txt"), sequence.gt_world_from_camera());
  if (!s.ok()) return s;
  s = WriteTumTrajectory(JoinPath(dir, "camera_tum.txt"), tum);
  if (!s.ok()) return s;
  return WriteObjectTracks(JoinPath(dir, "objects.txt"), rows);
}

std::string FormatRunEvaluation(const RunEvaluation& eval) {
  std::string out = "sequence " + eval.sequence + " (" + eval.dataset_format + ", " +
                    std::to_string(eval.num_frames) + " frames), estimate " + eval.est_dir + "\n";
  if (eval.camera) {
    if (eval.options.camera_file != "camera.txt")
      out += "camera from " + eval.options.camera_file + "\n";
    out += FormatCameraTable(*eval.camera);
  } else {
    out += "camera: not evaluated: " + eval.camera_note + "\n";
  }
  if (eval.objects) {
    out += "objects from " + eval.options.objects_file + "\n";
    out += FormatObjectTable(*eval.objects);
  } else {
    out += "objects: not evaluated: " + eval.objects_note + "\n";
  }
  return out;
}

std::string RunEvaluationJson(const RunEvaluation& eval) {
  JsonWriter w;
  w.BeginObject();
  w.Key("format").String(eval.dataset_format);
  w.Key("sequence").String(eval.sequence);
  w.Key("estimate").String(eval.est_dir);
  w.Key("num_frames").Int(eval.num_frames);
  w.Key("camera");
  if (eval.camera) {
    WriteCameraJson(*eval.camera, &w);
  } else {
    w.Null();
  }
  w.Key("objects");
  if (eval.objects) {
    WriteObjectsJson(*eval.objects, &w);
  } else {
    w.Null();
  }
  if (!eval.objects_gt_source.empty()) w.Key("objects_gt_source").String(eval.objects_gt_source);
  w.Key("options").BeginObject();
  w.Key("moving_speed_mps").Number(eval.options.objects.moving_speed_mps);
  w.Key("min_mask_pixels").Int(eval.options.objects.min_mask_pixels);
  w.Key("objects_file").String(eval.options.objects_file);
  w.Key("camera_file").String(eval.options.camera_file);
  w.Key("max_match_distance_m").Number(eval.options.objects.max_match_distance_m);
  w.Key("mask_pixels_counted").Bool(eval.used_mask_pixels);
  w.EndObject();
  w.EndObject();
  return w.str();
}

}  // namespace twist::io
