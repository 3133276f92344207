#include "slam/system/binary_io.h"

#include <cmath>

namespace twist::system_io {

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
  // Written by ToParams: finite, with a unit quaternion; anything else is a
  // corrupt file (normalising garbage would hide it).
  double q_norm_sq = 0.0;
  for (int i = 0; i < 7; ++i) {
    if (!std::isfinite(p[i])) {
      Fail();
      return geometry::SE3d();
    }
    if (i < 4) q_norm_sq += p[i] * p[i];
  }
  if (std::abs(q_norm_sq - 1.0) > 1e-6) {
    Fail();
    return geometry::SE3d();
  }
  // Exact: a resumed session continues bit for bit.
  return geometry::SE3d::FromParamsExact(p);
}

}  // namespace twist::system_io
