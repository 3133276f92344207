#include "slam/objects/flow_association.h"

#include <cmath>
#include <opencv2/imgproc.hpp>
#include <opencv2/video/tracking.hpp>
#include <string>
#include <vector>

namespace twist::objects {
namespace {

absl::StatusOr<cv::Mat> ToGray(const cv::Mat& image, const char* what) {
  if (image.empty()) return absl::InvalidArgumentError(std::string(what) + " image is empty");
  if (image.depth() != CV_8U) {
    return absl::InvalidArgumentError(std::string(what) + " image must be 8-bit");
  }
  if (image.channels() == 1) return image;
  if (image.channels() == 3) {
    cv::Mat gray;
    cv::cvtColor(image, gray, cv::COLOR_BGR2GRAY);
    return gray;
  }
  return absl::InvalidArgumentError(std::string(what) + " image must have 1 or 3 channels");
}

// What calcOpticalFlowPyrLK builds from an image (same window, levels and
// borders), plus the Scharr derivatives it would otherwise compute per call.
std::vector<cv::Mat> GrayPyramid(const cv::Mat& gray, const SparseFlowOptions& options) {
  std::vector<cv::Mat> pyramid;
  cv::buildOpticalFlowPyramid(gray,
                              pyramid,
                              cv::Size(options.window_size, options.window_size),
                              options.max_level,
                              /*withDerivatives=*/true);
  return pyramid;
}

bool Inside(const cv::Size& size, const Eigen::Vector2d& p, double border) {
  return p.x() >= border && p.y() >= border && p.x() <= size.width - 1 - border &&
         p.y() <= size.height - 1 - border;
}

}  // namespace

absl::Status SparseFlowOptions::Validate() const {
  if (window_size < 3 || window_size % 2 == 0) {
    return absl::InvalidArgumentError("sparse flow window_size must be odd and >= 3");
  }
  if (max_level < 0 || max_iterations < 1 || !(epsilon > 0.0)) {
    return absl::InvalidArgumentError(
        "sparse flow needs max_level >= 0, max_iterations >= 1, epsilon > 0");
  }
  if (!(max_forward_backward_px > 0.0)) {
    return absl::InvalidArgumentError("sparse flow max_forward_backward_px must be > 0");
  }
  return absl::OkStatus();
}

absl::StatusOr<std::vector<cv::Mat>> SparseFlowPyramid(const cv::Mat& image,
                                                       const SparseFlowOptions& options) {
  if (absl::Status s = options.Validate(); !s.ok()) return s;
  absl::StatusOr<cv::Mat> gray = ToGray(image, "sparse flow");
  if (!gray.ok()) return gray.status();
  return GrayPyramid(*gray, options);
}

absl::StatusOr<std::vector<std::optional<Eigen::Vector2d>>> TrackSparseFlow(
    const cv::Mat& prev,
    const cv::Mat& next,
    const std::vector<Eigen::Vector2d>& prev_points,
    const SparseFlowOptions& options,
    const std::vector<Eigen::Vector2d>* predicted) {
  if (absl::Status s = options.Validate(); !s.ok()) return s;
  absl::StatusOr<cv::Mat> g0 = ToGray(prev, "previous");
  if (!g0.ok()) return g0.status();
  absl::StatusOr<cv::Mat> g1 = ToGray(next, "current");
  if (!g1.ok()) return g1.status();
  if (g0->size() != g1->size()) {
    return absl::InvalidArgumentError("sparse flow: previous and current images differ in size");
  }
  return TrackSparseFlow(
      GrayPyramid(*g0, options), GrayPyramid(*g1, options), prev_points, options, predicted);
}

absl::StatusOr<std::vector<std::optional<Eigen::Vector2d>>> TrackSparseFlow(
    const std::vector<cv::Mat>& prev_pyramid,
    const std::vector<cv::Mat>& next_pyramid,
    const std::vector<Eigen::Vector2d>& prev_points,
    const SparseFlowOptions& options,
    const std::vector<Eigen::Vector2d>* predicted) {
  if (absl::Status s = options.Validate(); !s.ok()) return s;
  if (prev_pyramid.empty() || next_pyramid.empty()) {
    return absl::InvalidArgumentError("sparse flow: empty pyramid");
  }
  if (prev_pyramid[0].size() != next_pyramid[0].size()) {
    return absl::InvalidArgumentError("sparse flow: previous and current images differ in size");
  }
  if (predicted != nullptr && predicted->size() != prev_points.size()) {
    return absl::InvalidArgumentError("sparse flow: predicted and previous point counts differ");
  }
  std::vector<std::optional<Eigen::Vector2d>> out(prev_points.size());
  if (prev_points.empty()) return out;
  std::vector<cv::Point2f> p0, p1, back;
  p0.reserve(prev_points.size());
  for (const auto& p : prev_points)
    p0.emplace_back(static_cast<float>(p.x()), static_cast<float>(p.y()));
  int flags = 0;
  if (predicted != nullptr) {
    for (const auto& p : *predicted)
      p1.emplace_back(static_cast<float>(p.x()), static_cast<float>(p.y()));
    flags |= cv::OPTFLOW_USE_INITIAL_FLOW;
  }
  const cv::Size win(options.window_size, options.window_size);
  const cv::TermCriteria criteria(
      cv::TermCriteria::COUNT | cv::TermCriteria::EPS, options.max_iterations, options.epsilon);
  std::vector<uchar> status, status_back;
  std::vector<float> err;
  cv::calcOpticalFlowPyrLK(prev_pyramid,
                           next_pyramid,
                           p0,
                           p1,
                           status,
                           err,
                           win,
                           options.max_level,
                           criteria,
                           flags,
                           options.min_eigen_threshold);
  back = p0;  // the start is a good guess for the way back
  cv::calcOpticalFlowPyrLK(next_pyramid,
                           prev_pyramid,
                           p1,
                           back,
                           status_back,
                           err,
                           win,
                           options.max_level,
                           criteria,
                           cv::OPTFLOW_USE_INITIAL_FLOW,
                           options.min_eigen_threshold);
  for (size_t k = 0; k < prev_points.size(); ++k) {
    if (!status[k] || !status_back[k]) continue;
    const Eigen::Vector2d fwd(p1[k].x, p1[k].y);
    const Eigen::Vector2d bwd(back[k].x, back[k].y);
    if (!fwd.allFinite() || (bwd - prev_points[k]).norm() > options.max_forward_backward_px)
      continue;
    if (!Inside(next_pyramid[0].size(), fwd, options.border_px)) continue;
    out[k] = fwd;
  }
  return out;
}

absl::StatusOr<std::vector<std::optional<Eigen::Vector2d>>> TrackDenseFlow(
    const cv::Mat& flow, const std::vector<Eigen::Vector2d>& prev_points, double border_px) {
  if (flow.empty() || flow.type() != CV_32FC2) {
    return absl::InvalidArgumentError("dense flow must be a non-empty CV_32FC2 field (dx, dy)");
  }
  std::vector<std::optional<Eigen::Vector2d>> out(prev_points.size());
  for (size_t k = 0; k < prev_points.size(); ++k) {
    const Eigen::Vector2d& p = prev_points[k];
    if (!Inside(flow.size(), p, 0.0)) continue;
    const int x0 = std::min(static_cast<int>(std::floor(p.x())), flow.cols - 2);
    const int y0 = std::min(static_cast<int>(std::floor(p.y())), flow.rows - 2);
    const double ax = p.x() - x0, ay = p.y() - y0;
    const cv::Vec2f f00 = flow.at<cv::Vec2f>(y0, x0), f10 = flow.at<cv::Vec2f>(y0, x0 + 1);
    const cv::Vec2f f01 = flow.at<cv::Vec2f>(y0 + 1, x0), f11 = flow.at<cv::Vec2f>(y0 + 1, x0 + 1);
    Eigen::Vector2d d;
    for (int c = 0; c < 2; ++c) {
      d(c) = (1 - ax) * (1 - ay) * f00[c] + ax * (1 - ay) * f10[c] + (1 - ax) * ay * f01[c] +
             ax * ay * f11[c];
    }
    const Eigen::Vector2d q = p + d;
    if (!q.allFinite() || !Inside(flow.size(), q, border_px)) continue;
    out[k] = q;
  }
  return out;
}

absl::StatusOr<cv::Mat> ComputeDenseFlow(const cv::Mat& prev, const cv::Mat& next) {
  absl::StatusOr<cv::Mat> g0 = ToGray(prev, "previous");
  if (!g0.ok()) return g0.status();
  absl::StatusOr<cv::Mat> g1 = ToGray(next, "current");
  if (!g1.ok()) return g1.status();
  if (g0->size() != g1->size()) {
    return absl::InvalidArgumentError("dense flow: previous and current images differ in size");
  }
  cv::Mat flow;
  cv::calcOpticalFlowFarneback(*g0, *g1, flow, 0.5, 4, 21, 5, 7, 1.5, 0);
  return flow;
}

}  // namespace twist::objects
