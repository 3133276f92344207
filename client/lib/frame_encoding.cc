#include "client/lib/frame_encoding.h"

#include <opencv2/imgcodecs.hpp>
#include <vector>

#include "absl/strings/str_cat.h"

namespace twist::client {

absl::Status EncodeImage(const cv::Mat& image, pb::ImageEncoding encoding, pb::Image* out) {
  out->Clear();
  if (image.empty()) return absl::InvalidArgumentError("cannot encode an empty image");
  if (encoding == pb::IMAGE_ENCODING_RAW) {
    pb::PixelFormat format;
    switch (image.type()) {
      case CV_8UC1:
        format = pb::PIXEL_FORMAT_GRAY8;
        break;
      case CV_8UC3:
        format = pb::PIXEL_FORMAT_BGR8;
        break;
      case CV_16UC1:
        format = pb::PIXEL_FORMAT_GRAY16;
        break;
      case CV_32SC1:
        format = pb::PIXEL_FORMAT_INT32;
        break;
      case CV_32FC2:
        format = pb::PIXEL_FORMAT_FLOAT32X2;
        break;
      default:
        return absl::InvalidArgumentError(
            absl::StrCat("no RAW pixel format for OpenCV type ", image.type()));
    }
    out->set_encoding(pb::IMAGE_ENCODING_RAW);
    out->set_width(image.cols);
    out->set_height(image.rows);
    out->set_pixel_format(format);
    const size_t row = image.cols * image.elemSize();
    out->set_stride(static_cast<int32_t>(row));
    std::string* data = out->mutable_data();
    data->resize(row * image.rows);
    for (int r = 0; r < image.rows; ++r) std::memcpy(&(*data)[r * row], image.ptr(r), row);
    return absl::OkStatus();
  }
  const bool png = encoding == pb::IMAGE_ENCODING_PNG;
  if (!png && encoding != pb::IMAGE_ENCODING_JPEG)
    return absl::InvalidArgumentError("unknown image encoding");
  const bool ok_type =
      image.type() == CV_8UC1 || image.type() == CV_8UC3 || (png && image.type() == CV_16UC1);
  if (!ok_type) {
    return absl::InvalidArgumentError(
        absl::StrCat("cannot encode OpenCV type ", image.type(), " as ", png ? "PNG" : "JPEG"));
  }
  std::vector<uchar> buffer;
  const std::vector<int> params = png ? std::vector<int>{cv::IMWRITE_PNG_COMPRESSION, 1}
                                      : std::vector<int>{cv::IMWRITE_JPEG_QUALITY, 95};
  if (!cv::imencode(png ? ".png" : ".jpg", image, buffer, params)) {
    return absl::InternalError("image encoding failed");
  }
  out->set_encoding(encoding);
  out->set_data(buffer.data(), buffer.size());
  return absl::OkStatus();
}

absl::Status MakeFrame(const FrameImages& images, pb::ImageEncoding encoding, pb::Frame* out) {
  out->Clear();
  out->set_index(images.index);
  out->set_timestamp_ns(images.timestamp_ns);
  if (absl::Status s = EncodeImage(images.left, encoding, out->mutable_left()); !s.ok()) return s;
  if (absl::Status s = EncodeImage(images.right, encoding, out->mutable_right()); !s.ok()) return s;
  if (!images.panoptic.empty()) {
    const pb::ImageEncoding mask_encoding =
        (encoding == pb::IMAGE_ENCODING_RAW || images.panoptic.type() != CV_16UC1)
            ? pb::IMAGE_ENCODING_RAW
            : pb::IMAGE_ENCODING_PNG;
    if (absl::Status s = EncodeImage(images.panoptic, mask_encoding, out->mutable_panoptic());
        !s.ok())
      return s;
  }
  if (!images.flow.empty()) {
    if (absl::Status s = EncodeImage(images.flow, pb::IMAGE_ENCODING_RAW, out->mutable_flow());
        !s.ok())
      return s;
  }
  return absl::OkStatus();
}

}  // namespace twist::client
