#include "slam/io/trajectory_io.h"

#include <Eigen/SVD>
#include <cinttypes>
#include <cmath>
#include <cstdio>
#include <limits>

#include "slam/io/file_util.h"

namespace twist::io {
namespace {

// Unit quaternion from 4 numbers (qx qy qz qw); fails when far from unit norm.
absl::Status ParseQuaternion(const std::string& path,
                             int line,
                             double qx,
                             double qy,
                             double qz,
                             double qw,
                             Eigen::Quaterniond* q) {
  const double norm = std::sqrt(qx * qx + qy * qy + qz * qz + qw * qw);
  if (!(std::abs(norm - 1.0) < 1e-3)) {
    return LineError(
        path, line, "quaternion (qx qy qz qw) has norm " + FormatDouble(norm) + ", expected 1");
  }
  *q = Eigen::Quaterniond(qw / norm, qx / norm, qy / norm, qz / norm);
  return absl::OkStatus();
}

void AppendPose7(const geometry::SE3d& pose, std::string* out) {
  const Eigen::Vector3d& t = pose.translation();
  Eigen::Quaterniond q = pose.unit_quaternion();
  if (q.w() < 0) q.coeffs() = -q.coeffs();  // canonical sign
  char buf[256];
  std::snprintf(buf,
                sizeof(buf),
                "%.9g %.9g %.9g %.9g %.9g %.9g %.9g",
                t.x(),
                t.y(),
                t.z(),
                q.x(),
                q.y(),
                q.z(),
                q.w());
  *out += buf;
}

absl::StatusOr<int64_t> IntField(const std::string& path,
                                 const TextLine& line,
                                 std::string_view token,
                                 const char* name) {
  int64_t v = 0;
  if (!ParseInt64(token, &v)) {
    return LineError(
        path, line.number, std::string(name) + " '" + std::string(token) + "' is not an integer");
  }
  return v;
}

absl::Status DoubleFields(const std::string& path,
                          const TextLine& line,
                          const std::vector<std::string_view>& fields,
                          size_t first,
                          size_t count,
                          double* out) {
  for (size_t i = 0; i < count; ++i) {
    if (!ParseDouble(fields[first + i], &out[i])) {
      return LineError(path,
                       line.number,
                       "field " + std::to_string(first + i + 1) + " '" +
                           std::string(fields[first + i]) + "' is not a finite number");
    }
  }
  return absl::OkStatus();
}

// The leading "frame track_id class tx ty tz qx qy qz qw" of objects.txt and
// objects_gt lines (fields 0..9).
absl::StatusOr<ObjectGtRow> ParseObjectPoseFields(const std::string& path,
                                                  const TextLine& line,
                                                  const std::vector<std::string_view>& f) {
  auto frame = IntField(path, line, f[0], "frame");
  if (!frame.ok()) return frame.status();
  auto track = IntField(path, line, f[1], "track_id");
  if (!track.ok()) return track.status();
  auto cls = IntField(path, line, f[2], "class");
  if (!cls.ok()) return cls.status();
  if (*frame < 0) return LineError(path, line.number, "negative frame index");
  double d[7];
  absl::Status s = DoubleFields(path, line, f, 3, 7, d);
  if (!s.ok()) return s;
  Eigen::Quaterniond q;
  s = ParseQuaternion(path, line.number, d[3], d[4], d[5], d[6], &q);
  if (!s.ok()) return s;
  ObjectGtRow row;
  row.frame = *frame;
  row.track_id = *track;
  row.class_id = static_cast<int>(*cls);
  row.world_from_object = geometry::SE3d(q, Eigen::Vector3d(d[0], d[1], d[2]));
  return row;
}

void AppendObjectPose(int64_t frame,
                      int64_t track_id,
                      int class_id,
                      const geometry::SE3d& world_from_object,
                      std::string* out) {
  char buf[96];
  std::snprintf(buf, sizeof(buf), "%" PRId64 " %" PRId64 " %d ", frame, track_id, class_id);
  *out += buf;
  AppendPose7(world_from_object, out);
}

}  // namespace

Eigen::Matrix3d NearestRotation(const Eigen::Matrix3d& m) {
  Eigen::JacobiSVD<Eigen::Matrix3d> svd(m, Eigen::ComputeFullU | Eigen::ComputeFullV);
  Eigen::Matrix3d d = Eigen::Matrix3d::Identity();
  if ((svd.matrixU() * svd.matrixV().transpose()).determinant() < 0) d(2, 2) = -1;
  return svd.matrixU() * d * svd.matrixV().transpose();
}

absl::StatusOr<std::vector<geometry::SE3d>> ReadKittiPoses(const std::string& path) {
  absl::StatusOr<std::string> text = ReadTextFile(path);
  if (!text.ok()) return text.status();
  std::vector<geometry::SE3d> poses;
  std::vector<double> v;
  for (const TextLine& line : SplitLines(*text)) {
    absl::Status s = ParseNumberLine(path, line, 12, &v);
    if (!s.ok()) return s;
    Eigen::Matrix3d r;
    Eigen::Vector3d t;
    for (int row = 0; row < 3; ++row) {
      for (int col = 0; col < 3; ++col) r(row, col) = v[row * 4 + col];
      t(row) = v[row * 4 + 3];
    }
    const double det = r.determinant();
    if (!(det > 0.5 && det < 1.5) ||
        (r.transpose() * r - Eigen::Matrix3d::Identity()).norm() > 0.1) {
      return LineError(path, line.number, "the 3x3 part is not a rotation matrix");
    }
    poses.emplace_back(NearestRotation(r), t);
  }
  if (poses.empty()) return absl::InvalidArgumentError(path + ": no poses (empty file)");
  return poses;
}

std::string FormatKittiPoses(const std::vector<geometry::SE3d>& world_from_camera) {
  std::string out;
  out.reserve(world_from_camera.size() * 160);
  char buf[64];
  for (const geometry::SE3d& pose : world_from_camera) {
    const Eigen::Matrix<double, 3, 4> m = pose.matrix3x4();
    for (int row = 0; row < 3; ++row) {
      for (int col = 0; col < 4; ++col) {
        std::snprintf(buf, sizeof(buf), "%.9e", m(row, col));
        if (row + col > 0) out += ' ';
        out += buf;
      }
    }
    out += '\n';
  }
  return out;
}

absl::Status WriteKittiPoses(const std::string& path,
                             const std::vector<geometry::SE3d>& world_from_camera) {
  return WriteFileAtomic(path, FormatKittiPoses(world_from_camera));
}

int64_t SecondsToNs(double seconds) { return static_cast<int64_t>(std::llround(seconds * 1e9)); }
double NsToSeconds(int64_t ns) { return static_cast<double>(ns) * 1e-9; }

absl::StatusOr<std::vector<int64_t>> ReadTimes(const std::string& path) {
  absl::StatusOr<std::string> text = ReadTextFile(path);
  if (!text.ok()) return text.status();
  std::vector<int64_t> times;
  std::vector<double> v;
  for (const TextLine& line : SplitLines(*text)) {
    absl::Status s = ParseNumberLine(path, line, 1, &v);
    if (!s.ok()) return s;
    if (v[0] < 0 || v[0] > 9.2e9) {
      return LineError(path, line.number, "time " + FormatDouble(v[0]) + " s out of range");
    }
    const int64_t ns = SecondsToNs(v[0]);
    if (!times.empty() && ns <= times.back()) {
      return LineError(path, line.number, "times must increase strictly");
    }
    times.push_back(ns);
  }
  if (times.empty()) return absl::InvalidArgumentError(path + ": no times (empty file)");
  return times;
}

std::string FormatTimes(const std::vector<int64_t>& timestamps_ns) {
  std::string out;
  char buf[48];
  for (int64_t ns : timestamps_ns) {
    // Exact decimal seconds with nanosecond digits.
    std::snprintf(buf,
                  sizeof(buf),
                  "%s%" PRId64 ".%09" PRId64 "\n",
                  ns < 0 ? "-" : "",
                  std::abs(ns) / 1000000000,
                  std::abs(ns) % 1000000000);
    out += buf;
  }
  return out;
}

absl::StatusOr<std::vector<StampedPose>> ReadTumTrajectory(const std::string& path) {
  absl::StatusOr<std::string> text = ReadTextFile(path);
  if (!text.ok()) return text.status();
  std::vector<StampedPose> poses;
  std::vector<double> v;
  for (const TextLine& line : SplitLines(*text, /*skip_comments=*/true)) {
    absl::Status s = ParseNumberLine(path, line, 8, &v);
    if (!s.ok()) return s;
    StampedPose p;
    p.timestamp_ns = SecondsToNs(v[0]);
    Eigen::Quaterniond q;
    s = ParseQuaternion(path, line.number, v[4], v[5], v[6], v[7], &q);
    if (!s.ok()) return s;
    p.world_from_camera = geometry::SE3d(q, Eigen::Vector3d(v[1], v[2], v[3]));
    poses.push_back(p);
  }
  if (poses.empty()) return absl::InvalidArgumentError(path + ": no poses (empty file)");
  return poses;
}

std::string FormatTumTrajectory(const std::vector<StampedPose>& poses) {
  std::string out;
  char buf[48];
  for (const StampedPose& p : poses) {
    const int64_t ns = p.timestamp_ns;
    std::snprintf(buf,
                  sizeof(buf),
                  "%s%" PRId64 ".%09" PRId64 " ",
                  ns < 0 ? "-" : "",
                  std::abs(ns) / 1000000000,
                  std::abs(ns) % 1000000000);
    out += buf;
    AppendPose7(p.world_from_camera, &out);
    out += '\n';
  }
  return out;
}

absl::Status WriteTumTrajectory(const std::string& path, const std::vector<StampedPose>& poses) {
  return WriteFileAtomic(path, FormatTumTrajectory(poses));
}

absl::StatusOr<std::vector<ObjectTrackRow>> ReadObjectTracks(const std::string& path) {
  absl::StatusOr<std::string> text = ReadTextFile(path);
  if (!text.ok()) return text.status();
  std::vector<ObjectTrackRow> rows;
  for (const TextLine& line : SplitLines(*text, /*skip_comments=*/true)) {
    const std::vector<std::string_view> f = SplitFields(line.text);
    if (f.size() != 16 && f.size() != 17) {
      return LineError(path,
                       line.number,
                       "expected 16 fields (frame track_id class tx ty tz qx qy qz qw vx vy vz "
                       "wx wy wz) or 17 (+ instance_id), found " +
                           std::to_string(f.size()));
    }
    absl::StatusOr<ObjectGtRow> pose = ParseObjectPoseFields(path, line, f);
    if (!pose.ok()) return pose.status();
    double twist[6];
    absl::Status s = DoubleFields(path, line, f, 10, 6, twist);
    if (!s.ok()) return s;
    ObjectTrackRow row;
    row.frame = pose->frame;
    row.track_id = pose->track_id;
    row.class_id = pose->class_id;
    row.world_from_object = pose->world_from_object;
    for (int i = 0; i < 6; ++i) row.twist_in_world(i) = twist[i];
    if (f.size() == 17) {
      auto inst = IntField(path, line, f[16], "instance_id");
      if (!inst.ok()) return inst.status();
      row.instance_id = *inst;
    }
    rows.push_back(row);
  }
  return rows;  // an empty file is valid: no object was tracked
}

std::string FormatObjectTracks(const std::vector<ObjectTrackRow>& rows) {
  std::string out;
  char buf[256];
  for (const ObjectTrackRow& r : rows) {
    AppendObjectPose(r.frame, r.track_id, r.class_id, r.world_from_object, &out);
    const geometry::Vector6d& x = r.twist_in_world;
    std::snprintf(
        buf, sizeof(buf), " %.9g %.9g %.9g %.9g %.9g %.9g", x(0), x(1), x(2), x(3), x(4), x(5));
    out += buf;
    if (r.instance_id >= 0) {
      std::snprintf(buf, sizeof(buf), " %" PRId64, r.instance_id);
      out += buf;
    }
    out += '\n';
  }
  return out;
}

absl::Status WriteObjectTracks(const std::string& path, const std::vector<ObjectTrackRow>& rows) {
  return WriteFileAtomic(path, FormatObjectTracks(rows));
}

absl::StatusOr<std::vector<ObjectGtRow>> ReadObjectsGt(const std::string& path) {
  absl::StatusOr<std::string> text = ReadTextFile(path);
  if (!text.ok()) return text.status();
  std::vector<ObjectGtRow> rows;
  for (const TextLine& line : SplitLines(*text, /*skip_comments=*/true)) {
    const std::vector<std::string_view> f = SplitFields(line.text);
    if (f.size() != 10) {
      return LineError(path,
                       line.number,
                       "expected 10 fields (frame track_id class tx ty tz qx qy qz qw), found " +
                           std::to_string(f.size()));
    }
    absl::StatusOr<ObjectGtRow> row = ParseObjectPoseFields(path, line, f);
    if (!row.ok()) return row.status();
    rows.push_back(*row);
  }
  return rows;
}

std::string FormatObjectsGt(const std::vector<ObjectGtRow>& rows) {
  std::string out;
  for (const ObjectGtRow& r : rows) {
    AppendObjectPose(r.frame, r.track_id, r.class_id, r.world_from_object, &out);
    out += '\n';
  }
  return out;
}

absl::Status WriteObjectsGt(const std::string& path, const std::vector<ObjectGtRow>& rows) {
  return WriteFileAtomic(path, FormatObjectsGt(rows));
}

}  // namespace twist::io
