// Helpers shared by the server, client and e2e tests: small deterministic
// frames and session requests.
#pragma once

#include <cstdint>
#include <opencv2/core.hpp>
#include <opencv2/imgproc.hpp>

#include "client/lib/frame_encoding.h"
#include "twistslam/v1/slam_service.pb.h"

namespace twist::testing {

namespace pb = ::twistslam::v1;

inline pb::CreateSessionRequest MakeCreateRequest(int width,
                                                  int height,
                                                  double fx = 100.0,
                                                  double baseline = 0.5) {
  pb::CreateSessionRequest request;
  request.set_name("test");
  pb::StereoCalibration* c = request.mutable_config()->mutable_calibration();
  c->set_fx(fx);
  c->set_fy(fx);
  c->set_cx(width / 2.0);
  c->set_cy(height / 2.0);
  c->set_baseline(baseline);
  c->set_width(width);
  c->set_height(height);
  return request;
}

// A textured gray image that depends on (seed, index).
inline cv::Mat TestImage(int width, int height, uint64_t seed, int64_t index) {
  cv::Mat image(height, width, CV_8UC1);
  cv::RNG rng(seed * 1000003ULL + static_cast<uint64_t>(index));
  rng.fill(image, cv::RNG::UNIFORM, 0, 256);
  cv::GaussianBlur(image, image, cv::Size(3, 3), 0);
  return image;
}

// A panoptic mask: road (7000) with one car instance (26001) box.
inline cv::Mat TestMask(int width, int height) {
  cv::Mat mask(height, width, CV_16UC1, cv::Scalar(7000));
  cv::rectangle(
      mask, cv::Rect(width / 4, height / 4, width / 4, height / 4), cv::Scalar(26001), cv::FILLED);
  return mask;
}

inline pb::Frame MakeTestFrame(int64_t index,
                               int width,
                               int height,
                               uint64_t seed = 1,
                               pb::ImageEncoding encoding = pb::IMAGE_ENCODING_RAW,
                               bool with_mask = false) {
  client::FrameImages images;
  images.index = index;
  images.timestamp_ns = 1'000'000'000 + index * 100'000'000;
  images.left = TestImage(width, height, seed, index);
  images.right = TestImage(width, height, seed + 7, index);
  if (with_mask) images.panoptic = TestMask(width, height);
  pb::Frame frame;
  client::MakeFrame(images, encoding, &frame).IgnoreError();
  return frame;
}

}  // namespace twist::testing
