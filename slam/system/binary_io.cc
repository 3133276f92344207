#include "slam/system/binary_io.h"

#include <cmath>

namespace twist::system_io {

namespace {
bool SameParams(const geometry::SE3d& T, const double p[7]) {
  double q[7];
  T.ToParams(q);
  return std::memcmp(q, p, sizeof(q)) == 0;
}
}  // namespace

geometry::SE3d PoseFromParamsExact(const double p[7]) {
  const geometry::SE3d plain = geometry::SE3d::FromParams(p);
  if (SameParams(plain, p)) return plain;
  double c[7];
  std::memcpy(c, p, sizeof(c));
  for (int k = 1; k <= 16; ++k) {
    for (int sign = -1; sign <= 1; sign += 2) {
      const double s = 1.0 + sign * k * std::ldexp(1.0, -53);
      for (int i = 0; i < 4; ++i) c[i] = p[i] * s;
      const geometry::SE3d T = geometry::SE3d::FromParams(c);
      if (SameParams(T, p)) return T;
    }
  }
  for (int i = 0; i < 4; ++i) {
    for (int sign = -1; sign <= 1; sign += 2) {
      std::memcpy(c, p, sizeof(c));
      c[i] = std::nextafter(p[i], sign * 10.0);
      const geometry::SE3d T = geometry::SE3d::FromParams(c);
      if (SameParams(T, p)) return T;
    }
  }
  return plain;
}

void BinaryWriter::Mat(const cv::Mat& m) {
  const cv::Mat c = m.isContinuous() ? m : m.clone();
  Pod<int32_t>(c.rows);
  Pod<int32_t>(c.cols);
  Pod<int32_t>(c.type());
  if (!c.empty()) Bytes(c.data, c.total() * c.elemSize());
}

void BinaryWriter::KeyPoints(const std::vector<cv::KeyPoint>& kps) {
  Pod<uint64_t>(kps.size());
  for (const cv::KeyPoint& k : kps) {
    Pod(k.pt.x);
    Pod(k.pt.y);
    Pod(k.size);
    Pod(k.angle);
    Pod(k.response);
    Pod<int32_t>(k.octave);
    Pod<int32_t>(k.class_id);
  }
}

void BinaryWriter::Pose(const geometry::SE3d& T) {
  double p[7];
  T.ToParams(p);
  Bytes(p, sizeof(p));
}

std::string BinaryReader::String() {
  const uint64_t n = Pod<uint64_t>();
  if (!ok_ || n > data_.size() - pos_) {
    ok_ = false;
    return {};
  }
  std::string s = data_.substr(pos_, n);
  pos_ += n;
  return s;
}

cv::Mat BinaryReader::Mat() {
  const int rows = Pod<int32_t>();
  const int cols = Pod<int32_t>();
  const int type = Pod<int32_t>();
  if (!ok_ || rows < 0 || cols < 0 || type < 0 || type > CV_64FC4) {
    ok_ = false;
    return {};
  }
  if (rows == 0 || cols == 0) return cv::Mat(rows, cols, type);
  const size_t elem = CV_ELEM_SIZE(type);
  const size_t bytes = static_cast<size_t>(rows) * cols * elem;
  if (!Need(bytes)) return {};
  cv::Mat m(rows, cols, type);
  std::memcpy(m.data, data_.data() + pos_, bytes);
  pos_ += bytes;
  return m;
}

std::vector<cv::KeyPoint> BinaryReader::KeyPoints() {
  const uint64_t n = Count(28);
  std::vector<cv::KeyPoint> kps;
  kps.reserve(n);
  for (uint64_t i = 0; i < n && ok_; ++i) {
    cv::KeyPoint k;
    k.pt.x = Pod<float>();
    k.pt.y = Pod<float>();
    k.size = Pod<float>();
    k.angle = Pod<float>();
    k.response = Pod<float>();
    k.octave = Pod<int32_t>();
    k.class_id = Pod<int32_t>();
    kps.push_back(k);
  }
  return kps;
}

geometry::SE3d BinaryReader::Pose() {
  double p[7];
  for (double& v : p) v = Pod<double>();
  if (!ok_) return geometry::SE3d();
  return PoseFromParamsExact(p);
}

}  // namespace twist::system_io
