// Building wire frames from OpenCV images on the client side.
#pragma once

#include <cstdint>
#include <opencv2/core.hpp>

#include "absl/status/status.h"
#include "twistslam/v1/stream.pb.h"

namespace twist::client {

namespace pb = ::twistslam::v1;

// Encodes an image for the wire. RAW keeps the pixels as they are
// (CV_8UC1 -> GRAY8, CV_8UC3 -> BGR8, CV_16UC1 -> GRAY16, CV_32SC1 -> INT32,
// CV_32FC2 -> FLOAT32X2); PNG is lossless (8-bit gray/colour, 16-bit gray);
// JPEG (quality 95) only for 8-bit images. Other combinations ->
// InvalidArgument.
absl::Status EncodeImage(const cv::Mat& image, pb::ImageEncoding encoding, pb::Image* out);

struct FrameImages {
  int64_t index = 0;
  int64_t timestamp_ns = 0;
  cv::Mat left;  // CV_8UC1 or CV_8UC3
  cv::Mat right;
  cv::Mat panoptic;  // optional, CV_16UC1 or CV_32SC1
  cv::Mat flow;      // optional, CV_32FC2
};

// Images use `encoding`; the mask uses RAW for RAW and PNG otherwise (a
// 16-bit PNG; CV_32SC1 masks always go RAW); flow always RAW.
absl::Status MakeFrame(const FrameImages& images, pb::ImageEncoding encoding, pb::Frame* out);

}  // namespace twist::client
