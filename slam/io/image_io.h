// Image loading with checks and clear errors (file named, problem stated).
#pragma once

#include <opencv2/core.hpp>
#include <string>

#include "absl/status/statusor.h"

namespace twist::io {

// 8-bit gray (CV_8UC1) or colour (CV_8UC3, BGR) image. A 4-channel PNG is
// returned as BGR; 16-bit images are rejected ("wrong bit depth").
absl::StatusOr<cv::Mat> ReadImage8(const std::string& path);

// 16-bit single-channel label image (panoptic or KITTI MOTS instance PNG),
// returned as CV_16UC1. An 8-bit or multi-channel file is rejected.
absl::StatusOr<cv::Mat> ReadLabelImage16(const std::string& path);

// Fails with "<path>: size WxH differs from <what> WxH" when sizes differ.
absl::Status CheckSameSize(const cv::Mat& image,
                           const std::string& path,
                           const cv::Size& expected,
                           const std::string& what);

}  // namespace twist::io
