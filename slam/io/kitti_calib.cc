#include "slam/io/kitti_calib.h"

#include <Eigen/LU>
#include <cmath>
#include <vector>

#include "slam/io/file_util.h"

namespace twist::io {
namespace {

absl::StatusOr<Matrix34d> Get34(const std::map<std::string, std::vector<double>>& entries,
                                const std::string& path,
                                const std::vector<std::string>& keys,
                                bool* found) {
  for (const std::string& key : keys) {
    auto it = entries.find(key);
    if (it == entries.end()) continue;
    if (it->second.size() != 12) {
      return absl::InvalidArgumentError(path + ": entry " + key + " has " +
                                        std::to_string(it->second.size()) +
                                        " numbers, expected 12 (3x4 row-major)");
    }
    *found = true;
    Matrix34d m;
    for (int r = 0; r < 3; ++r) {
      for (int c = 0; c < 4; ++c) m(r, c) = it->second[r * 4 + c];
    }
    return m;
  }
  *found = false;
  return Matrix34d::Zero();
}

absl::StatusOr<Matrix34d> Require34(const std::map<std::string, std::vector<double>>& entries,
                                    const std::string& path,
                                    const std::string& key) {
  bool found = false;
  absl::StatusOr<Matrix34d> m = Get34(entries, path, {key}, &found);
  if (!m.ok()) return m.status();
  if (!found) return absl::InvalidArgumentError(path + ": missing entry " + key + ":");
  return m;
}

}  // namespace

absl::StatusOr<std::map<std::string, std::vector<double>>> ReadKittiCalibEntries(
    const std::string& path) {
  absl::StatusOr<std::string> text = ReadTextFile(path);
  if (!text.ok()) return text.status();
  std::map<std::string, std::vector<double>> entries;
  for (const TextLine& line : SplitLines(*text, /*skip_comments=*/true)) {
    const size_t colon = line.text.find(':');
    if (colon == std::string_view::npos || colon == 0) {
      return LineError(path, line.number, "expected 'KEY: numbers'");
    }
    std::string key(line.text.substr(0, colon));
    while (!key.empty() && (key.front() == ' ' || key.front() == '\t')) key.erase(0, 1);
    if (key.find_first_of(" \t") != std::string::npos) {
      return LineError(path, line.number, "key '" + key + "' contains whitespace");
    }
    TextLine rest{line.number, line.text.substr(colon + 1)};
    std::vector<double> values;
    absl::Status s = ParseNumberLine(path, rest, -1, &values);
    if (!s.ok()) return s;
    if (values.empty()) return LineError(path, line.number, "entry " + key + " has no numbers");
    if (entries.count(key)) return LineError(path, line.number, "duplicate entry " + key);
    entries[key] = std::move(values);
  }
  return entries;
}

absl::StatusOr<geometry::StereoCamera> StereoFromProjections(const Matrix34d& p_left,
                                                             const Matrix34d& p_right,
                                                             const std::string& what) {
  geometry::StereoCamera cam;
  cam.fx = p_left(0, 0);
  cam.fy = p_left(1, 1);
  cam.cx = p_left(0, 2);
  cam.cy = p_left(1, 2);
  if (!(cam.fx > 0) || !(cam.fy > 0)) {
    return absl::InvalidArgumentError(what + ": focal length must be positive (fx " +
                                      FormatDouble(cam.fx) + ", fy " + FormatDouble(cam.fy) + ")");
  }
  const Eigen::Matrix3d k_left = p_left.leftCols<3>();
  const Eigen::Matrix3d k_right = p_right.leftCols<3>();
  if ((k_left - k_right).cwiseAbs().maxCoeff() > 1e-6 * cam.fx) {
    return absl::InvalidArgumentError(what +
                                      ": left and right projection matrices have different "
                                      "intrinsics; the pair is not rectified");
  }
  cam.baseline = (p_left(0, 3) - p_right(0, 3)) / cam.fx;
  if (!(cam.baseline > 0)) {
    return absl::InvalidArgumentError(what + ": stereo baseline must be positive, got " +
                                      FormatDouble(cam.baseline) + " m");
  }
  return cam;
}

absl::StatusOr<KittiOdometryCalib> ReadKittiOdometryCalib(const std::string& path) {
  auto entries = ReadKittiCalibEntries(path);
  if (!entries.ok()) return entries.status();
  KittiOdometryCalib calib;
  auto p0 = Require34(*entries, path, "P0");
  if (!p0.ok()) return p0.status();
  auto p1 = Require34(*entries, path, "P1");
  if (!p1.ok()) return p1.status();
  calib.p0 = *p0;
  calib.p1 = *p1;
  auto cam = StereoFromProjections(calib.p0, calib.p1, path + " (P0/P1)");
  if (!cam.ok()) return cam.status();
  calib.camera = *cam;
  return calib;
}

absl::StatusOr<KittiTrackingCalib> ReadKittiTrackingCalib(const std::string& path) {
  auto entries = ReadKittiCalibEntries(path);
  if (!entries.ok()) return entries.status();
  KittiTrackingCalib calib;
  auto p2 = Require34(*entries, path, "P2");
  if (!p2.ok()) return p2.status();
  auto p3 = Require34(*entries, path, "P3");
  if (!p3.ok()) return p3.status();
  calib.p2 = *p2;
  calib.p3 = *p3;
  for (const char* key : {"R_rect", "R0_rect"}) {
    auto it = entries->find(key);
    if (it == entries->end()) continue;
    if (it->second.size() != 9) {
      return absl::InvalidArgumentError(path + ": entry " + key + " has " +
                                        std::to_string(it->second.size()) +
                                        " numbers, expected 9 (3x3 row-major)");
    }
    Eigen::Matrix3d r;
    for (int i = 0; i < 9; ++i) r(i / 3, i % 3) = it->second[i];
    calib.r_rect = r;
  }
  bool found = false;
  auto velo = Get34(*entries, path, {"Tr_velo_cam", "Tr_velo_to_cam"}, &found);
  if (!velo.ok()) return velo.status();
  if (found) calib.tr_velo_cam = *velo;
  auto imu = Get34(*entries, path, {"Tr_imu_velo", "Tr_imu_to_velo"}, &found);
  if (!imu.ok()) return imu.status();
  if (found) calib.tr_imu_velo = *imu;
  auto cam = StereoFromProjections(calib.p2, calib.p3, path + " (P2/P3)");
  if (!cam.ok()) return cam.status();
  calib.camera = *cam;
  const Eigen::Matrix3d k = calib.p2.leftCols<3>();
  calib.left_from_ref_translation = k.inverse() * calib.p2.col(3);
  return calib;
}

}  // namespace twist::io
