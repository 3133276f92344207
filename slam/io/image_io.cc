#include "slam/io/image_io.h"

#include <opencv2/imgcodecs.hpp>
#include <opencv2/imgproc.hpp>

#include "slam/io/file_util.h"

namespace twist::io {
namespace {

std::string SizeText(const cv::Size& s) {
  return std::to_string(s.width) + "x" + std::to_string(s.height);
}

absl::StatusOr<cv::Mat> Decode(const std::string& path) {
  if (!FileExists(path)) {
    if (DirExists(path)) return absl::FailedPreconditionError(path + ": is a directory");
    return absl::NotFoundError(path + ": no such file");
  }
  cv::Mat image;
  try {
    image = cv::imread(path, cv::IMREAD_UNCHANGED);
  } catch (const cv::Exception& e) {
    return absl::DataLossError(path + ": cannot decode image (" + e.what() + ")");
  }
  if (image.empty()) {
    return absl::DataLossError(path + ": cannot decode image (truncated or not an image)");
  }
  return image;
}

const char* DepthName(int depth) {
  switch (depth) {
    case CV_8U:
      return "8-bit";
    case CV_8S:
      return "8-bit signed";
    case CV_16U:
      return "16-bit";
    case CV_16S:
      return "16-bit signed";
    case CV_32S:
      return "32-bit integer";
    case CV_32F:
      return "32-bit float";
    case CV_64F:
      return "64-bit float";
    default:
      return "unknown depth";
  }
}

}  // namespace

absl::StatusOr<cv::Mat> ReadImage8(const std::string& path) {
  absl::StatusOr<cv::Mat> image = Decode(path);
  if (!image.ok()) return image.status();
  if (image->depth() != CV_8U) {
    return absl::InvalidArgumentError(path + ": wrong bit depth: " + DepthName(image->depth()) +
                                      ", expected an 8-bit gray or colour image");
  }
  switch (image->channels()) {
    case 1:
    case 3:
      return image;
    case 4: {
      cv::Mat bgr;
      cv::cvtColor(*image, bgr, cv::COLOR_BGRA2BGR);
      return bgr;
    }
    default:
      return absl::InvalidArgumentError(path + ": " + std::to_string(image->channels()) +
                                        " channels, expected 1 (gray) or 3 (colour)");
  }
}

absl::StatusOr<cv::Mat> ReadLabelImage16(const std::string& path) {
  absl::StatusOr<cv::Mat> image = Decode(path);
  if (!image.ok()) return image.status();
  if (image->depth() != CV_16U) {
    return absl::InvalidArgumentError(path + ": wrong bit depth: " + DepthName(image->depth()) +
                                      ", expected a 16-bit label PNG (class*1000+instance)");
  }
  if (image->channels() != 1) {
    return absl::InvalidArgumentError(path + ": " + std::to_string(image->channels()) +
                                      " channels, expected a single-channel 16-bit label PNG");
  }
  return image;
}

absl::Status CheckSameSize(const cv::Mat& image,
                           const std::string& path,
                           const cv::Size& expected,
                           const std::string& what) {
  if (image.size() != expected) {
    return absl::InvalidArgumentError(path + ": wrong size " + SizeText(image.size()) +
                                      ", differs from " + what + " " + SizeText(expected));
  }
  return absl::OkStatus();
}

}  // namespace twist::io
