#include "slam/semantic/panoptic.h"

#include <glog/logging.h>

#include <cmath>
#include <map>
#include <string>

namespace twist::semantic {
namespace {

bool IsPanopticType(const cv::Mat& mask) {
  return mask.type() == CV_16UC1 || mask.type() == CV_32SC1;
}

// Calls fn(x, y, id) for every labelled pixel (of `roi`, when given).
template <typename Fn>
void ForEachPixel(const cv::Mat& mask, Fn&& fn, cv::Rect roi = cv::Rect()) {
  const cv::Rect full(0, 0, mask.cols, mask.rows);
  roi = roi.empty() ? full : (roi & full);
  if (mask.type() == CV_16UC1) {
    for (int y = roi.y; y < roi.y + roi.height; ++y) {
      const uint16_t* row = mask.ptr<uint16_t>(y);
      for (int x = roi.x; x < roi.x + roi.width; ++x) fn(x, y, static_cast<int64_t>(row[x]));
    }
  } else {
    for (int y = roi.y; y < roi.y + roi.height; ++y) {
      const int32_t* row = mask.ptr<int32_t>(y);
      for (int x = roi.x; x < roi.x + roi.width; ++x) {
        if (row[x] >= 0) fn(x, y, static_cast<int64_t>(row[x]));
      }
    }
  }
}

}  // namespace

absl::Status ValidatePanopticMask(const cv::Mat& mask, cv::Size expected_size) {
  if (mask.empty()) return absl::InvalidArgumentError("panoptic mask is empty");
  if (!IsPanopticType(mask)) {
    return absl::InvalidArgumentError("panoptic mask must be CV_16UC1 or CV_32SC1, got type " +
                                      std::to_string(mask.type()) + " with " +
                                      std::to_string(mask.channels()) + " channel(s)");
  }
  if (!expected_size.empty() && mask.size() != expected_size) {
    return absl::InvalidArgumentError("panoptic mask is " + std::to_string(mask.cols) + "x" +
                                      std::to_string(mask.rows) + " but the image is " +
                                      std::to_string(expected_size.width) + "x" +
                                      std::to_string(expected_size.height));
  }
  return absl::OkStatus();
}

int64_t PanopticIdAt(const cv::Mat& mask, int x, int y) {
  CHECK(IsPanopticType(mask)) << "panoptic mask must be CV_16UC1 or CV_32SC1";
  if (x < 0 || y < 0 || x >= mask.cols || y >= mask.rows) return -1;
  if (mask.type() == CV_16UC1) return mask.at<uint16_t>(y, x);
  const int32_t v = mask.at<int32_t>(y, x);
  return v < 0 ? -1 : v;
}

std::optional<PanopticLabel> LabelAt(const cv::Mat& mask, const Eigen::Vector2d& uv) {
  if (!std::isfinite(uv.x()) || !std::isfinite(uv.y())) return std::nullopt;
  const int x = static_cast<int>(std::lround(uv.x()));
  const int y = static_cast<int>(std::lround(uv.y()));
  const int64_t id = PanopticIdAt(mask, x, y);
  if (id < 0) return std::nullopt;
  return DecodePanopticId(id);
}

std::vector<std::optional<PanopticLabel>> LabelsAt(const cv::Mat& mask,
                                                   const std::vector<Eigen::Vector2d>& uvs) {
  std::vector<std::optional<PanopticLabel>> out;
  out.reserve(uvs.size());
  for (const Eigen::Vector2d& uv : uvs) out.push_back(LabelAt(mask, uv));
  return out;
}

std::vector<Segment> ExtractSegments(const cv::Mat& mask, int min_pixels, bool things_only) {
  CHECK(IsPanopticType(mask)) << "panoptic mask must be CV_16UC1 or CV_32SC1";
  struct Acc {
    int n = 0;
    int x0 = 1 << 30, y0 = 1 << 30, x1 = -1, y1 = -1;
  };
  std::map<int64_t, Acc> acc;
  // Labels come in runs along a row: one map look-up and update per run.
  auto add_run = [&](int x_first, int x_last, int y, int64_t id) {
    Acc& a = acc[id];
    a.n += x_last - x_first + 1;
    a.x0 = std::min(a.x0, x_first);
    a.y0 = std::min(a.y0, y);
    a.x1 = std::max(a.x1, x_last);
    a.y1 = std::max(a.y1, y);
  };
  ForEachLabelRun(mask, add_run);
  std::vector<Segment> out;
  for (const auto& [id, a] : acc) {
    const PanopticLabel label = DecodePanopticId(id);
    if (a.n < min_pixels) continue;
    if (things_only && label.instance_id == 0) continue;
    Segment s;
    s.label = label;
    s.num_pixels = a.n;
    s.box = cv::Rect(a.x0, a.y0, a.x1 - a.x0 + 1, a.y1 - a.y0 + 1);
    out.push_back(s);
  }
  return out;  // std::map keeps ids sorted, i.e. by (class, instance)
}

cv::Mat SegmentMask(const cv::Mat& mask, const PanopticLabel& label) {
  return SegmentMask(mask, label, cv::Rect());
}

cv::Mat SegmentMask(const cv::Mat& mask, const PanopticLabel& label, const cv::Rect& roi) {
  CHECK(IsPanopticType(mask)) << "panoptic mask must be CV_16UC1 or CV_32SC1";
  cv::Mat out(mask.size(), CV_8UC1, cv::Scalar(0));
  const int64_t target = MakePanopticId(label.class_id, label.instance_id);
  ForEachPixel(
      mask,
      [&](int x, int y, int64_t id) {
        if (id == target) out.at<uint8_t>(y, x) = 255;
      },
      roi);
  return out;
}

cv::Mat ClassMask(const cv::Mat& mask, int class_id) {
  CHECK(IsPanopticType(mask)) << "panoptic mask must be CV_16UC1 or CV_32SC1";
  // The ids of a class are one range: [class · divisor, class · divisor + divisor − 1].
  const double first = static_cast<double>(MakePanopticId(class_id, 0));
  cv::Mat out;
  cv::inRange(mask, cv::Scalar(first), cv::Scalar(first + kPanopticDivisor - 1), out);
  return out;
}

}  // namespace twist::semantic
