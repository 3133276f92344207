// Minimal little-endian binary serialisation used by SlamSystem::Save/Load.
// Values are written as raw bytes (doubles round-trip exactly), containers
// with a 64-bit length prefix. The reader never trusts lengths: it fails
// (ok() == false) instead of allocating more than the remaining input.
#pragma once

#include <cstdint>
#include <cstring>
#include <opencv2/core.hpp>
#include <string>
#include <type_traits>
#include <vector>

#include "slam/geometry/se3.h"

namespace twist::system_io {

class BinaryWriter {
 public:
  template <typename T>
  void Pod(const T& v) {
    static_assert(std::is_trivially_copyable_v<T>);
    const char* p = reinterpret_cast<const char*>(&v);
    buffer_.append(p, sizeof(T));
  }
  void Bytes(const void* data, size_t n) { buffer_.append(static_cast<const char*>(data), n); }
  void String(const std::string& s) {
    Pod<uint64_t>(s.size());
    Bytes(s.data(), s.size());
  }
  template <typename T>
  void PodVector(const std::vector<T>& v) {
    static_assert(std::is_trivially_copyable_v<T>);
    Pod<uint64_t>(v.size());
    if (!v.empty()) Bytes(v.data(), v.size() * sizeof(T));
  }
  void Mat(const cv::Mat& m);
  void KeyPoints(const std::vector<cv::KeyPoint>& kps);
  void Pose(const geometry::SE3d& T);
  const std::string& buffer() const { return buffer_; }

 private:
  std::string buffer_;
};

class BinaryReader {
 public:
  explicit BinaryReader(const std::string& data) : data_(data) {}
  template <typename T>
  T Pod() {
    static_assert(std::is_trivially_copyable_v<T>);
    T v{};
    if (!Need(sizeof(T))) return v;
    std::memcpy(&v, data_.data() + pos_, sizeof(T));
    pos_ += sizeof(T);
    return v;
  }
  std::string String();
  template <typename T>
  std::vector<T> PodVector() {
    const uint64_t n = Pod<uint64_t>();
    std::vector<T> v;
    if (!ok_ || n > (data_.size() - pos_) / sizeof(T)) {
      ok_ = false;
      return v;
    }
    v.resize(n);
    if (n > 0) std::memcpy(v.data(), data_.data() + pos_, n * sizeof(T));
    pos_ += n * sizeof(T);
    return v;
  }
  cv::Mat Mat();
  std::vector<cv::KeyPoint> KeyPoints();
  geometry::SE3d Pose();
  uint64_t Count(size_t min_bytes_per_item) {
    const uint64_t n = Pod<uint64_t>();
    if (!ok_ || n > (data_.size() - pos_) / std::max<size_t>(min_bytes_per_item, 1)) ok_ = false;
    return ok_ ? n : 0;
  }
  bool ok() const { return ok_; }
  bool at_end() const { return pos_ == data_.size(); }
  size_t position() const { return pos_; }
  void Fail() { ok_ = false; }

 private:
  bool Need(size_t n) {
    if (!ok_ || data_.size() - pos_ < n) {
      ok_ = false;
      return false;
    }
    return true;
  }
  const std::string& data_;
  size_t pos_ = 0;
  bool ok_ = true;
};

}  // namespace twist::system_io
