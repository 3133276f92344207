#include "server/rectifier.h"

#include <algorithm>
#include <cmath>
#include <opencv2/calib3d.hpp>
#include <opencv2/imgproc.hpp>

#include "absl/strings/str_cat.h"

namespace twist::server {
namespace {

absl::Status CheckCamera(const RawCameraModel& c, const char* which, int width, int height) {
  for (double v : {c.fx, c.fy, c.cx, c.cy}) {
    if (!std::isfinite(v))
      return absl::InvalidArgumentError(absl::StrCat(which, " camera: non-finite intrinsics"));
  }
  if (c.fx <= 0 || c.fy <= 0) {
    return absl::InvalidArgumentError(
        absl::StrCat(which, " camera: focal lengths must be positive"));
  }
  if (c.cx < 0 || c.cx >= width || c.cy < 0 || c.cy >= height) {
    return absl::InvalidArgumentError(
        absl::StrCat(which, " camera: principal point outside the image"));
  }
  const size_t n = c.distortion.size();
  if (n != 0 && n != 4 && n != 5 && n != 8) {
    return absl::InvalidArgumentError(
        absl::StrCat(which, " camera: ", n, " distortion coefficients; expected 0, 4, 5 or 8"));
  }
  for (double d : c.distortion) {
    if (!std::isfinite(d))
      return absl::InvalidArgumentError(absl::StrCat(which, " camera: non-finite distortion"));
  }
  return absl::OkStatus();
}

cv::Matx33d Intrinsics(const RawCameraModel& c) {
  return cv::Matx33d(c.fx, 0, c.cx, 0, c.fy, c.cy, 0, 0, 1);
}

cv::Mat Distortion(const RawCameraModel& c) {
  if (c.distortion.empty()) return cv::Mat::zeros(1, 4, CV_64F);
  return cv::Mat(c.distortion, /*copyData=*/true).reshape(1, 1);
}

}  // namespace

absl::StatusOr<StereoRectifier> StereoRectifier::Create(const RawStereoRig& rig) {
  if (rig.width <= 0 || rig.height <= 0) {
    return absl::InvalidArgumentError("unrectified rig: width and height must be positive");
  }
  if (absl::Status s = CheckCamera(rig.left, "left", rig.width, rig.height); !s.ok()) return s;
  if (absl::Status s = CheckCamera(rig.right, "right", rig.width, rig.height); !s.ok()) return s;
  const Eigen::Vector3d t = rig.right_from_left.translation();
  if (!t.allFinite() || t.norm() < 1e-6) {
    return absl::InvalidArgumentError(
        "unrectified rig: right_from_left translation (baseline) must be non-zero");
  }
  const Eigen::Matrix3d r = rig.right_from_left.rotation();
  cv::Matx33d r_cv;
  for (int i = 0; i < 3; ++i)
    for (int j = 0; j < 3; ++j) r_cv(i, j) = r(i, j);
  const cv::Vec3d t_cv(t.x(), t.y(), t.z());

  StereoRectifier out;
  const cv::Size size(rig.width, rig.height);
  const cv::Matx33d k1 = Intrinsics(rig.left), k2 = Intrinsics(rig.right);
  const cv::Mat d1 = Distortion(rig.left), d2 = Distortion(rig.right);
  cv::Mat r1, r2, p1, p2, q;
  try {
    cv::stereoRectify(k1,
                      d1,
                      k2,
                      d2,
                      size,
                      r_cv,
                      t_cv,
                      r1,
                      r2,
                      p1,
                      p2,
                      q,
                      cv::CALIB_ZERO_DISPARITY,
                      /*alpha=*/0.0,
                      size);
    cv::initUndistortRectifyMap(k1, d1, r1, p1, size, CV_16SC2, out.left_map1_, out.left_map2_);
    cv::initUndistortRectifyMap(k2, d2, r2, p2, size, CV_16SC2, out.right_map1_, out.right_map2_);
  } catch (const cv::Exception& e) {
    return absl::InvalidArgumentError(
        absl::StrCat("unrectified rig: rectification failed: ", e.what()));
  }
  geometry::StereoCamera& cam = out.rectified_;
  cam.fx = p1.at<double>(0, 0);
  cam.fy = p1.at<double>(1, 1);
  cam.cx = p1.at<double>(0, 2);
  cam.cy = p1.at<double>(1, 2);
  // P2 = [fx 0 cx -fx*b; ...] for a horizontal rig.
  cam.baseline = std::abs(p2.at<double>(0, 3) / p2.at<double>(0, 0));
  cam.width = rig.width;
  cam.height = rig.height;
  if (std::abs(p2.at<double>(1, 3)) > 1e-6 * std::abs(p2.at<double>(0, 3))) {
    return absl::InvalidArgumentError(
        "unrectified rig: the cameras are stacked vertically; only horizontal rigs are supported");
  }
  if (absl::Status s = cam.Validate(); !s.ok()) {
    return absl::InvalidArgumentError(
        absl::StrCat("unrectified rig: rectified camera invalid: ", s.message()));
  }
  out.k_left_ = k1;
  out.r_left_ = cv::Matx33d(r1);
  out.p_left_ = cv::Matx34d(p1);
  // Float maps for the mask: nearest-neighbour sampling must round, which the
  // fixed-point maps (truncation) do not.
  cv::initUndistortRectifyMap(k1, d1, r1, p1, size, CV_32FC1, out.mask_map_x_, out.mask_map_y_);
  out.dist_left_ = rig.left.distortion;
  return out;
}

void StereoRectifier::Rectify(StereoFrame* frame) const {
  cv::Mat left, right;
  cv::remap(frame->left, left, left_map1_, left_map2_, cv::INTER_LINEAR);
  cv::remap(frame->right, right, right_map1_, right_map2_, cv::INTER_LINEAR);
  frame->left = left;
  frame->right = right;
  if (!frame->panoptic.empty()) {
    cv::Mat mask;
    cv::remap(frame->panoptic, mask, mask_map_x_, mask_map_y_, cv::INTER_NEAREST);
    frame->panoptic = mask;
  }
  if (!frame->boxes.empty()) {
    std::vector<cv::Point2d> corners, rectified;
    for (const DetectionBox& b : frame->boxes) {
      corners.emplace_back(b.x_min, b.y_min);
      corners.emplace_back(b.x_max, b.y_min);
      corners.emplace_back(b.x_min, b.y_max);
      corners.emplace_back(b.x_max, b.y_max);
    }
    const cv::Mat dist = dist_left_.empty() ? cv::Mat() : cv::Mat(dist_left_, true).reshape(1, 1);
    cv::undistortPoints(corners, rectified, k_left_, dist, r_left_, p_left_);
    for (size_t i = 0; i < frame->boxes.size(); ++i) {
      DetectionBox& b = frame->boxes[i];
      float x0 = 1e30f, y0 = 1e30f, x1 = -1e30f, y1 = -1e30f;
      for (int k = 0; k < 4; ++k) {
        const cv::Point2d& p = rectified[4 * i + k];
        x0 = std::min(x0, static_cast<float>(p.x));
        y0 = std::min(y0, static_cast<float>(p.y));
        x1 = std::max(x1, static_cast<float>(p.x));
        y1 = std::max(y1, static_cast<float>(p.y));
      }
      b.x_min = std::clamp(x0, 0.0f, static_cast<float>(rectified_.width - 1));
      b.y_min = std::clamp(y0, 0.0f, static_cast<float>(rectified_.height - 1));
      b.x_max = std::clamp(x1, 0.0f, static_cast<float>(rectified_.width - 1));
      b.y_max = std::clamp(y1, 0.0f, static_cast<float>(rectified_.height - 1));
    }
  }
}

}  // namespace twist::server
