// Panoptic mask decoding (DESIGN.md §3): pixel id = class_id * 1000 + instance_id,
// instance 0 for "stuff". Masks are CV_16UC1 or CV_32SC1 images of the left
// camera; negative CV_32SC1 values mean "no label".
#pragma once

#include <Eigen/Core>
#include <cstdint>
#include <opencv2/core.hpp>
#include <optional>
#include <type_traits>
#include <vector>

#include "absl/status/status.h"

namespace twist::semantic {

inline constexpr int kPanopticDivisor = 1000;

struct PanopticLabel {
  int class_id = 0;
  int instance_id = 0;  // 0 for "stuff" classes

  bool operator==(const PanopticLabel& o) const {
    return class_id == o.class_id && instance_id == o.instance_id;
  }
  bool operator!=(const PanopticLabel& o) const { return !(*this == o); }
  bool operator<(const PanopticLabel& o) const {
    return class_id != o.class_id ? class_id < o.class_id : instance_id < o.instance_id;
  }
};

inline int ClassOf(int64_t panoptic_id) { return static_cast<int>(panoptic_id / kPanopticDivisor); }
inline int InstanceOf(int64_t panoptic_id) {
  return static_cast<int>(panoptic_id % kPanopticDivisor);
}
inline int64_t MakePanopticId(int class_id, int instance_id) {
  return static_cast<int64_t>(class_id) * kPanopticDivisor + instance_id;
}
inline PanopticLabel DecodePanopticId(int64_t panoptic_id) {
  return PanopticLabel{ClassOf(panoptic_id), InstanceOf(panoptic_id)};
}

// OK for a non-empty single-channel CV_16UC1 / CV_32SC1 image; when
// expected_size is non-empty the mask must have that size.
absl::Status ValidatePanopticMask(const cv::Mat& mask, cv::Size expected_size = cv::Size());

// Raw panoptic id at integer pixel (x, y); -1 outside the image or for a
// negative (void) CV_32SC1 value. CHECKs the mask type.
int64_t PanopticIdAt(const cv::Mat& mask, int x, int y);

// Label at a sub-pixel keypoint: pixel centres are at integer coordinates
// (OpenCV keypoint convention), so (u, v) reads pixel (round(u), round(v)).
// nullopt outside the image or on a void pixel.
std::optional<PanopticLabel> LabelAt(const cv::Mat& mask, const Eigen::Vector2d& uv);

// Labels of many keypoints at once (same rules as LabelAt).
std::vector<std::optional<PanopticLabel>> LabelsAt(const cv::Mat& mask,
                                                   const std::vector<Eigen::Vector2d>& uvs);

// Calls fn(x_first, x_last, y, id) for every run of pixels with one panoptic
// id along a row (x_first..x_last inclusive), rows top to bottom; negative
// (void) CV_32SC1 runs are skipped. The mask must be CV_16UC1 or CV_32SC1.
template <typename Fn>
void ForEachLabelRun(const cv::Mat& mask, Fn&& fn) {
  auto rows = [&](auto zero) {
    using T = decltype(zero);
    for (int y = 0; y < mask.rows; ++y) {
      const T* row = mask.ptr<T>(y);
      for (int x = 0; x < mask.cols;) {
        const T id = row[x];
        int end = x + 1;
        while (end < mask.cols && row[end] == id) ++end;
        bool labelled = true;
        if constexpr (std::is_signed_v<T>) labelled = id >= 0;
        if (labelled) fn(x, end - 1, y, static_cast<int64_t>(id));
        x = end;
      }
    }
  };
  if (mask.type() == CV_16UC1) {
    rows(uint16_t{0});
  } else {
    rows(int32_t{0});
  }
}

// One segment of the mask: every pixel with the same panoptic id.
struct Segment {
  PanopticLabel label;
  int num_pixels = 0;
  cv::Rect box;  // tight bounding box, pixels
};

// Segments of the mask, sorted by (class, instance). Segments with fewer than
// min_pixels pixels are dropped. With things_only, "stuff" (instance 0) is
// skipped.
std::vector<Segment> ExtractSegments(const cv::Mat& mask,
                                     int min_pixels = 1,
                                     bool things_only = false);

// Binary CV_8UC1 mask (255 inside) of the pixels carrying `label`.
cv::Mat SegmentMask(const cv::Mat& mask, const PanopticLabel& label);
// The same mask, looking for `label` only inside `roi` (empty: everywhere):
// with a Segment's tight box from ExtractSegments, the same result.
cv::Mat SegmentMask(const cv::Mat& mask, const PanopticLabel& label, const cv::Rect& roi);
// Binary CV_8UC1 mask (255 inside) of the pixels of class `class_id`, any
// instance.
cv::Mat ClassMask(const cv::Mat& mask, int class_id);

}  // namespace twist::semantic
