// Input of the engine: one rectified stereo frame with optional panoptic mask,
// optical flow and detection boxes.
#pragma once

#include <cstdint>
#include <vector>

#include <opencv2/core.hpp>

namespace twist {

// An axis-aligned detection box in left-image pixels.
struct DetectionBox {
  int class_id = 0;
  int instance_id = 0;
  float x_min = 0, y_min = 0, x_max = 0, y_max = 0;
};

struct StereoFrame {
  int64_t index = 0;         // client's frame index (informational)
  int64_t timestamp_ns = 0;  // strictly increasing within a session
  cv::Mat left;              // CV_8UC1 or CV_8UC3 (BGR), rectified
  cv::Mat right;             // same size and type as `left`
  // Optional panoptic mask of the left image: CV_16UC1 or CV_32SC1, pixel =
  // class_id * 1000 + instance_id (instance 0 for "stuff"). Empty = none.
  cv::Mat panoptic;
  // Optional dense optical flow previous-left -> this-left, CV_32FC2 (dx, dy).
  cv::Mat flow;
  std::vector<DetectionBox> boxes;  // optional
};

}  // namespace twist
