#include "slam/objects/masked_stereo.h"

#include <glog/logging.h>

#include <Eigen/Dense>
#include <algorithm>
#include <cmath>
#include <opencv2/imgproc.hpp>
#include <vector>

namespace twist::objects {

namespace {

std::optional<double> MaskedDisparityUncorrected(const cv::Mat& left,
                                                 const cv::Mat& right,
                                                 const cv::Mat& mask,
                                                 const Eigen::Vector2d& uv,
                                                 double initial_disparity,
                                                 double half_window,
                                                 const MaskedStereoOptions& options) {
  if (left.empty() || right.empty() || mask.empty() || left.type() != CV_8UC1 ||
      right.type() != CV_8UC1 || mask.type() != CV_8UC1 || left.size() != right.size() ||
      left.size() != mask.size() || !std::isfinite(initial_disparity)) {
    return std::nullopt;
  }
  const int h = std::clamp(
      static_cast<int>(std::lround(half_window)), options.min_half_window, options.max_half_window);
  const int cx = static_cast<int>(std::lround(uv.x()));
  const int cy = static_cast<int>(std::lround(uv.y()));
  const int d0 = static_cast<int>(std::lround(initial_disparity));
  const int s = options.search_px;
  // The left window and every right window of the search inside the image.
  if (cy - h < 0 || cy + h >= left.rows || cx - h < 0 || cx + h >= left.cols) return std::nullopt;
  if (cx - h - (d0 + s + 1) < 0 || cx + h - (d0 - s - 1) >= left.cols) return std::nullopt;
  if (d0 - s - 1 < 0) return std::nullopt;

  // Masked left pixels, zero-mean, with their right-image rows and their
  // offsets from the window's centre (looked up once, not per disparity or
  // iteration), side by side for the loops below.
  struct Pixel {
    const uint8_t* right_row;
    int x;
    double a;  // left grey level, then less its mean
    double dx, dy;
    double b = 0.0, slope = 0.0;  // the right image at the first estimate
  };
  const int side = 2 * h + 1;
  std::vector<Pixel> px;
  px.reserve(static_cast<size_t>(side * side));
  for (int y = cy - h; y <= cy + h; ++y) {
    const uint8_t* m = mask.ptr<uint8_t>(y);
    const uint8_t* l = left.ptr<uint8_t>(y);
    const uint8_t* r = right.ptr<uint8_t>(y);
    for (int x = cx - h; x <= cx + h; ++x) {
      if (m[x] == 0) continue;
      px.push_back({r,
                    x,
                    static_cast<double>(l[x]),
                    static_cast<double>(x - cx),
                    static_cast<double>(y - cy)});
    }
  }
  const int n = static_cast<int>(px.size());
  if (n < options.min_pixels || n < options.min_mask_share * side * side) return std::nullopt;
  double mean_a = 0.0;
  for (const Pixel& p : px) mean_a += p.a;
  mean_a /= n;
  double var_a = 0.0;
  for (Pixel& p : px) {
    p.a -= mean_a;
    var_a += p.a * p.a;
  }
  if (var_a / n < options.min_stddev * options.min_stddev) return std::nullopt;

  // ZNCC for the disparities d0 − s − 1 ... d0 + s + 1 (the outer two only
  // for the parabola).
  const int count = 2 * s + 3;
  std::vector<double> ncc(static_cast<size_t>(count), -1.0);
  for (int j = 0; j < count; ++j) {
    const int d = d0 - s - 1 + j;
    double sum_b = 0.0, sum_bb = 0.0, sum_ab = 0.0;
    for (const Pixel& p : px) {
      const double b = p.right_row[p.x - d];
      sum_b += b;
      sum_bb += b * b;
      sum_ab += p.a * b;
    }
    const double var_b = sum_bb - sum_b * sum_b / n;
    if (var_b <= 1e-9) continue;
    ncc[static_cast<size_t>(j)] = sum_ab / std::sqrt(var_a * var_b);
  }
  int best = 1;
  for (int j = 1; j + 1 < count; ++j) {
    if (ncc[static_cast<size_t>(j)] > ncc[static_cast<size_t>(best)]) best = j;
  }
  if (ncc[static_cast<size_t>(best)] < options.min_ncc) return std::nullopt;
  // On the search border: the true disparity may lie outside.
  if (best == 1 || best == count - 2) return std::nullopt;
  const double cm = ncc[static_cast<size_t>(best - 1)];
  const double c0 = ncc[static_cast<size_t>(best)];
  const double cp = ncc[static_cast<size_t>(best + 1)];
  const double denom = cm - 2.0 * c0 + cp;
  double offset = 0.0;
  if (denom < -1e-12) offset = std::clamp(0.5 * (cm - cp) / denom, -0.5, 0.5);
  const int d_int = d0 - s - 1 + best;
  double d = d_int + offset;
  if (options.gauss_newton_iterations <= 0) return d;

  // Gauss–Newton on the disparity plane d(x, y) = d + gx (x − cx) + gy (y − cy),
  // gain and offset of L(x, y) ≈ g·R(x − d(x, y), y) + o, with the right
  // image interpolated linearly. The parabola through correlation samples
  // leans towards integer disparities ("pixel locking", up to ~0.1 px), and
  // on a slanted surface (a car's side) a constant disparity over a masked
  // window, whose pixels may lie mostly on one side of the point, is the
  // disparity of the window's centroid rather than of the point.
  double g = 1.0, o = 0.0, gx = 0.0, gy = 0.0;
  // The right image at the pixel's current disparity (linear) and its
  // central-difference slope there; false off the image.
  const int right_cols = right.cols;
  auto sample = [&](const Pixel& p, double* b, double* slope) __attribute__((always_inline)) {
    const double x = p.x - d - gx * p.dx - gy * p.dy;
    // floor(x) < 1 exactly when x < 1; past that test truncation is the
    // floor (std::floor is a library call on the baseline x86-64 target,
    // the largest cost of this loop).
    if (!(x >= 1.0) || x >= right_cols) return false;
    const int x0 = static_cast<int>(x);
    if (x0 + 2 >= right_cols) return false;
    const double t = x - x0;
    const uint8_t* row = p.right_row;
    *b = (1.0 - t) * row[x0] + t * row[x0 + 1];
    *slope = 0.5 * ((1.0 - t) * (row[x0 + 1] - row[x0 - 1]) + t * (row[x0 + 2] - row[x0]));
    return true;
  };
  {
    // Initial gain and offset from the means and deviations at d. The
    // samples are kept: the first iteration reads the right image where
    // this pass did (the plane moves only after it).
    double sb = 0.0, sbb = 0.0;
    for (Pixel& p : px) {
      if (!sample(p, &p.b, &p.slope)) return std::nullopt;
      sb += p.b;
      sbb += p.b * p.b;
    }
    const double var_b = (sbb - sb * sb / n) / n;
    if (var_b <= 1e-9) return std::nullopt;
    g = std::sqrt(var_a / n / var_b);
    o = mean_a - g * sb / n;
  }
  using Vector5d = Eigen::Matrix<double, 5, 1>;
  using Matrix5d = Eigen::Matrix<double, 5, 5>;
  for (int it = 0; it < options.gauss_newton_iterations; ++it) {
    // The normal equations' lower triangle (LDLT reads no other) and
    // right-hand side, accumulated two entries at a time in packed pairs
    // (half the additions; each lane takes the same products and sums, in
    // the same order, as a scalar of its own would, so the result is bit
    // for bit the scalar one). j = (j0, j1, j2, j3, 1): h44 is the count,
    // h4k the sums of jk.
    using Pair = Eigen::Array2d;
    Pair h00_h10 = Pair::Zero(), h20_h30 = Pair::Zero(), h21_h31 = Pair::Zero(),
         h22_h32 = Pair::Zero(), h11_h33 = Pair::Zero(), h40_h41 = Pair::Zero(),
         h42_h43 = Pair::Zero(), r0_r1 = Pair::Zero(), r2_r3 = Pair::Zero();
    double r4 = 0.0;
    double b = 0.0, slope = 0.0;
    for (const Pixel& p : px) {
      if (it == 0) {
        b = p.b;
        slope = p.slope;
      } else if (!sample(p, &b, &slope)) {
        return std::nullopt;
      }
      const double r = g * b + o - (p.a + mean_a);
      const double j0 = -g * slope, j1 = -g * slope * p.dx, j2 = -g * slope * p.dy, j3 = b;
      const Pair j01(j0, j1), j23(j2, j3), j13(j1, j3);
      h00_h10 += j01 * j0;
      h20_h30 += j23 * j0;
      h21_h31 += j23 * j1;
      h22_h32 += j23 * j2;
      h11_h33 += j13 * j13;
      h40_h41 += j01;
      h42_h43 += j23;
      r0_r1 -= j01 * r;
      r2_r3 -= j23 * r;
      r4 -= r;
    }
    Matrix5d h_mat = Matrix5d::Zero();
    h_mat(0, 0) = h00_h10[0];
    h_mat(1, 0) = h00_h10[1];
    h_mat(1, 1) = h11_h33[0];
    h_mat(2, 0) = h20_h30[0];
    h_mat(2, 1) = h21_h31[0];
    h_mat(2, 2) = h22_h32[0];
    h_mat(3, 0) = h20_h30[1];
    h_mat(3, 1) = h21_h31[1];
    h_mat(3, 2) = h22_h32[1];
    h_mat(3, 3) = h11_h33[1];
    h_mat(4, 0) = h40_h41[0];
    h_mat(4, 1) = h40_h41[1];
    h_mat(4, 2) = h42_h43[0];
    h_mat(4, 3) = h42_h43[1];
    h_mat(4, 4) = n;
    const double r0 = r0_r1[0], r1 = r0_r1[1], r2 = r2_r3[0], r3 = r2_r3[1];
    Vector5d rhs;
    rhs << r0, r1, r2, r3, r4;
    // A weak prior towards zero slopes keeps the normal equations regular
    // when the texture cannot determine a slope (e.g. vertical stripes).
    h_mat(1, 1) += 25.0 * n;
    h_mat(2, 2) += 25.0 * n;
    rhs(1) -= 25.0 * n * gx;
    rhs(2) -= 25.0 * n * gy;
    const Vector5d step = h_mat.ldlt().solve(rhs);
    if (!step.allFinite()) return std::nullopt;
    d += std::clamp(step(0), -0.5, 0.5);
    gx += step(1);
    gy += step(2);
    g += step(3);
    o += step(4);
    if (std::abs(step(0)) < 1e-4) break;
  }
  // The plane at the point itself (uv is sub-pixel on pyramid levels > 0).
  d += gx * (uv.x() - cx) + gy * (uv.y() - cy);
  if (std::abs(d - d_int) > 1.0 || !(g > 0.0)) return std::nullopt;
  return d;
}

}  // namespace

std::optional<double> MaskedDisparity(const cv::Mat& left,
                                      const cv::Mat& right,
                                      const cv::Mat& mask,
                                      const Eigen::Vector2d& uv,
                                      double initial_disparity,
                                      double half_window,
                                      const MaskedStereoOptions& options) {
  // The search works on the images as they are; the rig's correction is
  // taken off the (corrected) initial value and added to the result.
  const double offset = options.disparity_offset_px;
  const std::optional<double> d = MaskedDisparityUncorrected(
      left, right, mask, uv, initial_disparity - offset, half_window, options);
  if (!d) return std::nullopt;
  return *d + offset;
}

int RemeasureBesideMask(const cv::Mat& left,
                        const cv::Mat& right,
                        const cv::Mat& dynamic,
                        int margin_px,
                        const std::vector<cv::KeyPoint>& keypoints,
                        const std::vector<double>& half_window_per_level,
                        double bf,
                        std::vector<float>* u_right,
                        std::vector<float>* depth,
                        const MaskedStereoOptions& options) {
  CHECK(dynamic.type() == CV_8UC1 && dynamic.size() == left.size());
  CHECK_EQ(u_right->size(), keypoints.size());
  CHECK_EQ(depth->size(), keypoints.size());
  if (margin_px <= 0 || cv::countNonZero(dynamic) == 0) return 0;
  cv::Mat still = dynamic == 0, near;
  const int side = 2 * margin_px + 1;
  cv::dilate(dynamic, near, cv::getStructuringElement(cv::MORPH_RECT, cv::Size(side, side)));
  int measured = 0;
  for (size_t i = 0; i < keypoints.size(); ++i) {
    if ((*u_right)[i] < 0.0f) continue;
    const cv::KeyPoint& kp = keypoints[i];
    const int x = std::clamp(cvRound(kp.pt.x), 0, left.cols - 1);
    const int y = std::clamp(cvRound(kp.pt.y), 0, left.rows - 1);
    if (still.at<uint8_t>(y, x) == 0 || near.at<uint8_t>(y, x) == 0) continue;
    CHECK(kp.octave >= 0 && kp.octave < static_cast<int>(half_window_per_level.size()));
    ++measured;
    const Eigen::Vector2d uv(kp.pt.x, kp.pt.y);
    const std::optional<double> d = MaskedDisparity(
        left, right, still, uv, uv.x() - (*u_right)[i], half_window_per_level[kp.octave], options);
    if (d && *d > 0.0) {
      (*u_right)[i] = static_cast<float>(uv.x() - *d);
      (*depth)[i] = static_cast<float>(bf / *d);
    } else {
      (*u_right)[i] = -1.0f;
      (*depth)[i] = -1.0f;
    }
  }
  return measured;
}

}  // namespace twist::objects
