#include "slam/io/run_output.h"

#include <algorithm>
#include <filesystem>
#include <map>
#include <system_error>

#include "slam/io/file_util.h"
#include "slam/io/json_writer.h"

namespace twist::io {

void RunOutputWriter::Add(const FrameResult& result) {
  FrameRecord f;
  f.index = result.index;
  f.timestamp_ns = result.timestamp_ns;
  f.state = result.state;
  f.world_from_camera = result.world_from_camera;
  f.is_keyframe = result.is_keyframe;
  f.num_map_points = result.num_map_points;
  f.num_keyframes = result.num_keyframes;
  f.timings = result.timings;
  frames_.push_back(std::move(f));
  for (const ObjectResult& o : result.objects) {
    if (o.state == ObjectState::kLost) continue;
    ObjectTrackRow row;
    row.frame = result.index;
    row.track_id = o.id;
    row.class_id = o.class_id;
    row.world_from_object = o.world_from_object;
    row.twist_in_world = o.twist_in_world;
    row.instance_id = o.instance_id;
    objects_.push_back(row);
  }
}

std::vector<geometry::SE3d> RunOutputWriter::CameraPoses() const {
  std::vector<geometry::SE3d> poses;
  for (const FrameRecord& f : frames_) poses.push_back(f.world_from_camera);
  return poses;
}

std::vector<StampedPose> RunOutputWriter::CameraTum() const {
  std::vector<StampedPose> poses;
  for (const FrameRecord& f : frames_) poses.push_back({f.timestamp_ns, f.world_from_camera});
  return poses;
}

std::vector<ObjectTrackRow> RunOutputWriter::ObjectRows() const { return objects_; }

std::vector<geometry::SE3d> RefineCameraWithKeyFrames(
    const std::vector<std::pair<int64_t, geometry::SE3d>>& frames,
    const std::vector<std::pair<int64_t, geometry::SE3d>>& keyframes) {
  std::map<int64_t, size_t> frame_at;
  for (size_t i = 0; i < frames.size(); ++i) frame_at.emplace(frames[i].first, i);
  // (frame index, correction), in frame order.
  std::vector<std::pair<size_t, geometry::SE3d>> corrections;
  for (const auto& [t, world_from_camera] : keyframes) {
    const auto it = frame_at.find(t);
    if (it == frame_at.end()) continue;
    corrections.push_back({it->second, world_from_camera * frames[it->second].second.Inverse()});
  }
  std::sort(corrections.begin(), corrections.end(), [](const auto& a, const auto& b) {
    return a.first < b.first;
  });
  std::vector<geometry::SE3d> out;
  out.reserve(frames.size());
  size_t k = 0;  // the last correction at or before frame i (or the first)
  for (size_t i = 0; i < frames.size(); ++i) {
    if (corrections.empty()) {
      out.push_back(frames[i].second);
      continue;
    }
    while (k + 1 < corrections.size() && corrections[k + 1].first <= i) ++k;
    geometry::SE3d c = corrections[k].second;
    if (corrections[k].first < i && k + 1 < corrections.size()) {
      const auto& [a, ca] = corrections[k];
      const auto& [b, cb] = corrections[k + 1];
      const double s = static_cast<double>(i - a) / static_cast<double>(b - a);
      c = ca * geometry::SE3d::Exp(s * (ca.Inverse() * cb).Log());
    }
    out.push_back(c * frames[i].second);
  }
  return out;
}

void RunOutputWriter::SetRefinedKeyFrames(
    std::vector<std::pair<int64_t, geometry::SE3d>> keyframes) {
  refined_keyframes_ = std::move(keyframes);
}

std::vector<geometry::SE3d> RunOutputWriter::RefinedCameraPoses() const {
  std::vector<std::pair<int64_t, geometry::SE3d>> frames;
  frames.reserve(frames_.size());
  for (const FrameRecord& f : frames_) frames.push_back({f.timestamp_ns, f.world_from_camera});
  return RefineCameraWithKeyFrames(frames, refined_keyframes_.value_or(decltype(frames){}));
}

void RunOutputWriter::SetRefinedObjects(std::vector<TimedObjectTrajectory> trajectories) {
  refined_ = std::move(trajectories);
}

std::vector<ObjectTrackRow> RunOutputWriter::RefinedObjectRows() const {
  std::vector<ObjectTrackRow> rows;
  if (!refined_) return rows;
  std::map<int64_t, int64_t> frame_of_time;
  for (const FrameRecord& f : frames_) frame_of_time.emplace(f.timestamp_ns, f.index);
  for (const TimedObjectTrajectory& t : *refined_) {
    // The poses at the run's frames, in time order.
    struct AtFrame {
      int64_t frame;
      int64_t t_ns;
      const geometry::SE3d* pose;
    };
    std::vector<AtFrame> poses;
    for (const auto& [t_ns, pose] : t.poses) {
      const auto frame = frame_of_time.find(t_ns);
      if (frame != frame_of_time.end()) poses.push_back({frame->second, t_ns, &pose});
    }
    for (size_t i = 0; i < poses.size(); ++i) {
      ObjectTrackRow row;
      row.frame = poses[i].frame;
      row.track_id = t.track_id;
      row.class_id = t.class_id;
      row.world_from_object = *poses[i].pose;
      row.instance_id = t.instance_id;
      // Central difference over two rows either side (cut at the ends).
      constexpr size_t kHalfWindow = 2;
      const size_t a = i > kHalfWindow ? i - kHalfWindow : 0;
      const size_t b = std::min(poses.size() - 1, i + kHalfWindow);
      if (b > a && poses[b].t_ns > poses[a].t_ns) {
        row.twist_in_world = ((*poses[b].pose) * poses[a].pose->Inverse()).Log() /
                             (static_cast<double>(poses[b].t_ns - poses[a].t_ns) * 1e-9);
      }
      rows.push_back(row);
    }
  }
  std::stable_sort(rows.begin(), rows.end(), [](const ObjectTrackRow& a, const ObjectTrackRow& b) {
    return a.frame < b.frame || (a.frame == b.frame && a.track_id < b.track_id);
  });
  return rows;
}

std::string RunOutputWriter::SummaryJson(const RunInfo& info) const {
  JsonWriter w;
  w.BeginObject();
  w.Key("dataset").String(info.dataset);
  w.Key("format").String(info.format);
  w.Key("sequence").String(info.sequence);
  w.Key("mode").String(info.mode);
  w.Key("frames").Int(num_frames());
  w.Key("wall_time_s").Number(info.wall_time_s);
  std::map<std::string, int64_t> states;
  for (TrackingState s : {TrackingState::kNotInitialized,
                          TrackingState::kOk,
                          TrackingState::kLost,
                          TrackingState::kRelocalized}) {
    states[TrackingStateName(s)] = 0;
  }
  int64_t keyframes = 0;
  std::map<std::string, std::vector<double>> timings;
  for (const FrameRecord& f : frames_) {
    ++states[TrackingStateName(f.state)];
    keyframes += f.is_keyframe ? 1 : 0;
    for (const StageTiming& t : f.timings) timings[t.stage].push_back(t.ms);
  }
  w.Key("tracking_states").BeginObject();
  for (const auto& [name, n] : states) w.Key(name).Int(n);
  w.EndObject();
  w.Key("keyframes_inserted").Int(keyframes);
  w.Key("final_map_points").Int(frames_.empty() ? 0 : frames_.back().num_map_points);
  w.Key("final_keyframes").Int(frames_.empty() ? 0 : frames_.back().num_keyframes);
  std::map<int64_t, int64_t> track_lengths;
  for (const ObjectTrackRow& r : objects_) ++track_lengths[r.track_id];
  w.Key("object_tracks").Int(static_cast<int64_t>(track_lengths.size()));
  w.Key("object_rows").Int(static_cast<int64_t>(objects_.size()));
  w.Key("timings_ms").BeginObject();
  for (auto& [stage, values] : timings) {
    std::vector<double> v = values;
    std::sort(v.begin(), v.end());
    double mean = 0;
    for (double x : v) mean += x;
    mean /= static_cast<double>(v.size());
    w.Key(stage).BeginObject();
    w.Key("median").Number(v[v.size() / 2]);
    w.Key("mean").Number(mean);
    w.Key("p90").Number(v[std::min(v.size() - 1, v.size() * 9 / 10)]);
    w.Key("max").Number(v.back());
    w.EndObject();
  }
  w.EndObject();
  for (const auto& [key, value] : info.numbers) w.Key(key).Number(value);
  for (const auto& [key, value] : info.strings) w.Key(key).String(value);
  w.EndObject();
  return w.str();
}

absl::Status RunOutputWriter::Write(const std::string& dir, const RunInfo& info) const {
  std::error_code ec;
  std::filesystem::create_directories(dir, ec);
  if (ec || !DirExists(dir)) {
    return absl::FailedPreconditionError("cannot create output directory " + dir +
                                         (ec ? ": " + ec.message() : ""));
  }
  absl::Status s = WriteKittiPoses(JoinPath(dir, "camera.txt"), CameraPoses());
  if (!s.ok()) return s;
  s = WriteTumTrajectory(JoinPath(dir, "camera_tum.txt"), CameraTum());
  if (!s.ok()) return s;
  s = WriteObjectTracks(JoinPath(dir, "objects.txt"), objects_);
  if (!s.ok()) return s;
  if (refined_) {
    s = WriteObjectTracks(JoinPath(dir, "objects_refined.txt"), RefinedObjectRows());
    if (!s.ok()) return s;
  }
  if (refined_keyframes_) {
    s = WriteKittiPoses(JoinPath(dir, "camera_refined.txt"), RefinedCameraPoses());
    if (!s.ok()) return s;
  }
  return WriteFileAtomic(JoinPath(dir, "summary.json"), SummaryJson(info));
}

}  // namespace twist::io
