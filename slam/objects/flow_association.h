// Frame-to-frame association of object keypoints by optical flow (paper
// §IV-D: the paper uses RAFT; here classical OpenCV flow, or a dense flow
// field supplied by the client with the frame).
#pragma once

#include <Eigen/Core>
#include <opencv2/core.hpp>
#include <optional>
#include <vector>

#include "absl/status/status.h"
#include "absl/status/statusor.h"

namespace twist::objects {

struct SparseFlowOptions {
  int window_size = 21;  // pixels, odd
  int max_level = 3;     // pyramid levels above the base image
  int max_iterations = 30;
  double epsilon = 0.01;
  double min_eigen_threshold = 1e-4;
  // Forward-backward check: a track is kept when tracking it back from the
  // new position lands within this distance of where it started.
  double max_forward_backward_px = 1.0;
  double border_px = 2.0;  // tracks ending closer to the border are dropped

  absl::Status Validate() const;
};

// Pyramidal Lucas–Kanade (cv::calcOpticalFlowPyrLK) from `prev` to `next`
// (8-bit gray or BGR, same size) with a forward-backward check. `predicted`,
// when given (same size as prev_points; e.g. the points projected with the
// constant-velocity motion), seeds the search. nullopt for lost tracks.
absl::StatusOr<std::vector<std::optional<Eigen::Vector2d>>> TrackSparseFlow(
    const cv::Mat& prev,
    const cv::Mat& next,
    const std::vector<Eigen::Vector2d>& prev_points,
    const SparseFlowOptions& options,
    const std::vector<Eigen::Vector2d>* predicted = nullptr);

// The pyramid TrackSparseFlow builds from an image (8-bit gray or BGR), with
// its derivatives: the objects of one frame share one per image instead of
// building both images' pyramids on every call.
absl::StatusOr<std::vector<cv::Mat>> SparseFlowPyramid(const cv::Mat& image,
                                                       const SparseFlowOptions& options);

// TrackSparseFlow on pyramids from SparseFlowPyramid (same options): the same
// result as on their images.
absl::StatusOr<std::vector<std::optional<Eigen::Vector2d>>> TrackSparseFlow(
    const std::vector<cv::Mat>& prev_pyramid,
    const std::vector<cv::Mat>& next_pyramid,
    const std::vector<Eigen::Vector2d>& prev_points,
    const SparseFlowOptions& options,
    const std::vector<Eigen::Vector2d>* predicted = nullptr);

// Uses a dense flow field prev -> next (CV_32FC2, (dx, dy) per pixel of the
// previous image), sampled bilinearly at each point. nullopt when the point is
// outside the field, the flow is not finite, or the target leaves the image
// (minus border_px).
absl::StatusOr<std::vector<std::optional<Eigen::Vector2d>>> TrackDenseFlow(
    const cv::Mat& flow, const std::vector<Eigen::Vector2d>& prev_points, double border_px = 2.0);

// Dense Farnebäck flow prev -> next (8-bit, converted to gray if needed), for
// clients that send no flow but want the dense path.
absl::StatusOr<cv::Mat> ComputeDenseFlow(const cv::Mat& prev, const cv::Mat& next);

}  // namespace twist::objects
