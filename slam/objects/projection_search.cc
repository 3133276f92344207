#include "slam/objects/projection_search.h"

#include <glog/logging.h>

#include <algorithm>
#include <cmath>
#include <cstring>
#include <limits>
#include <opencv2/core.hpp>
#include <opencv2/imgproc.hpp>
#include <unordered_map>
#include <vector>

namespace twist::objects {

int HammingDistance(const cv::Mat& a, const cv::Mat& b) {
  DCHECK_EQ(a.cols, b.cols);
  const uint8_t* pa = a.ptr<uint8_t>(0);
  const uint8_t* pb = b.ptr<uint8_t>(0);
  const int n = a.cols * static_cast<int>(a.elemSize());
  int d = 0;
  int k = 0;
  for (; k + 8 <= n; k += 8) {
    uint64_t x, y;
    std::memcpy(&x, pa + k, 8);
    std::memcpy(&y, pb + k, 8);
    d += __builtin_popcountll(x ^ y);
  }
  for (; k < n; ++k) d += __builtin_popcount(static_cast<unsigned>(pa[k] ^ pb[k]));
  return d;
}

std::vector<int> SearchByProjection(const geometry::StereoCamera& camera,
                                    const geometry::SE3d& camera_from_object,
                                    const std::vector<Eigen::Vector3d>& points_in_object,
                                    const std::vector<cv::Mat>& descriptors,
                                    const std::vector<bool>& skip,
                                    const FrameKeypoints& keypoints,
                                    const ProjectionSearchOptions& options) {
  const size_t n = points_in_object.size();
  CHECK_EQ(descriptors.size(), n);
  CHECK_EQ(skip.size(), n);
  std::vector<int> match(n, -1);
  const int num_kp = static_cast<int>(keypoints.uv.size());
  if (num_kp == 0 || keypoints.descriptors.rows != num_kp) return match;
  // Bucket the keypoints on a grid of radius-sized cells.
  const double cell = std::max(4.0, options.radius_px);
  std::unordered_map<int64_t, std::vector<int>> grid;
  auto pack = [](int x, int y) {
    return (static_cast<int64_t>(x) << 32) ^ static_cast<int64_t>(static_cast<uint32_t>(y));
  };
  for (int i = 0; i < num_kp; ++i) {
    const Eigen::Vector2d& q = keypoints.uv[static_cast<size_t>(i)];
    grid[pack(static_cast<int>(std::floor(q.x() / cell)),
              static_cast<int>(std::floor(q.y() / cell)))]
        .push_back(i);
  }
  std::vector<int> owner(static_cast<size_t>(num_kp), -1);
  std::vector<int> owner_dist(static_cast<size_t>(num_kp), std::numeric_limits<int>::max());
  const double r2 = options.radius_px * options.radius_px;
  for (size_t k = 0; k < n; ++k) {
    if (skip[k] || descriptors[k].empty()) continue;
    Eigen::Vector2d uv;
    if (!camera.ProjectChecked(camera_from_object * points_in_object[k], &uv, nullptr, 0.1))
      continue;
    if (!camera.InImage(uv)) continue;
    int best = -1, best_d = std::numeric_limits<int>::max(),
        second_d = std::numeric_limits<int>::max();
    const int gx = static_cast<int>(std::floor(uv.x() / cell));
    const int gy = static_cast<int>(std::floor(uv.y() / cell));
    for (int dy = -1; dy <= 1; ++dy) {
      for (int dx = -1; dx <= 1; ++dx) {
        auto it = grid.find(pack(gx + dx, gy + dy));
        if (it == grid.end()) continue;
        for (int i : it->second) {
          if ((keypoints.uv[static_cast<size_t>(i)] - uv).squaredNorm() > r2) continue;
          const int d = HammingDistance(descriptors[k], keypoints.descriptors.row(i));
          if (d < best_d) {
            second_d = best_d;
            best_d = d;
            best = i;
          } else if (d < second_d) {
            second_d = d;
          }
        }
      }
    }
    if (best < 0 || best_d > options.max_hamming) continue;
    if (second_d < std::numeric_limits<int>::max() && best_d > options.ratio * second_d) continue;
    const size_t b = static_cast<size_t>(best);
    if (best_d >= owner_dist[b]) continue;
    if (owner[b] >= 0) match[static_cast<size_t>(owner[b])] = -1;
    owner[b] = static_cast<int>(k);
    owner_dist[b] = best_d;
    match[k] = best;
  }
  return match;
}

cv::Mat ExtractPatch(const cv::Mat& image, const Eigen::Vector2d& uv, int half_size) {
  CHECK_EQ(image.type(), CV_8UC1);
  const int size = 2 * half_size + 1;
  if (uv.x() - half_size < 0 || uv.y() - half_size < 0 || uv.x() + half_size > image.cols - 1 ||
      uv.y() + half_size > image.rows - 1) {
    return cv::Mat();
  }
  cv::Mat patch;
  cv::getRectSubPix(image,
                    cv::Size(size, size),
                    cv::Point2f(static_cast<float>(uv.x()), static_cast<float>(uv.y())),
                    patch,
                    CV_32F);
  return patch;
}

double Ncc(const cv::Mat& a, const cv::Mat& b) {
  CHECK_EQ(a.type(), CV_32F);
  CHECK(a.size() == b.size() && a.type() == b.type());
  cv::Scalar ma, sa, mb, sb;
  cv::meanStdDev(a, ma, sa);
  cv::meanStdDev(b, mb, sb);
  if (sa[0] < 1e-6 || sb[0] < 1e-6) return 0.0;
  cv::Mat da = a - ma[0], db = b - mb[0];
  return da.dot(db) / (static_cast<double>(a.total()) * sa[0] * sb[0]);
}

Eigen::Vector2d ParabolaPeakOffset(const cv::Mat& scores, int cx, int cy) {
  CHECK_EQ(scores.type(), CV_64F);
  // 1D parabola through the neighbours along each axis.
  auto refine = [](double l, double c, double rr) {
    const double den = l - 2.0 * c + rr;
    if (l < -1.5 || rr < -1.5 || std::abs(den) < 1e-12) return 0.0;
    return std::clamp(0.5 * (l - rr) / den, -0.5, 0.5);
  };
  const double c = scores.at<double>(cy, cx);
  double ox = 0.0, oy = 0.0;
  if (cx > 0 && cx < scores.cols - 1)
    ox = refine(scores.at<double>(cy, cx - 1), c, scores.at<double>(cy, cx + 1));
  if (cy > 0 && cy < scores.rows - 1)
    oy = refine(scores.at<double>(cy - 1, cx), c, scores.at<double>(cy + 1, cx));
  return Eigen::Vector2d(ox, oy);
}

std::optional<Eigen::Vector2d> PatchSearch(const cv::Mat& image,
                                           const cv::Mat& patch,
                                           const Eigen::Vector2d& predicted,
                                           const ProjectionSearchOptions& options) {
  if (patch.empty()) return std::nullopt;
  CHECK_EQ(image.type(), CV_8UC1);
  CHECK_EQ(patch.type(), CV_32F);
  CHECK_EQ(patch.rows, patch.cols);
  const int h = patch.rows / 2;
  const int side = 2 * h + 1;
  const int r = static_cast<int>(std::ceil(options.patch_search_radius_px));
  const int w = 2 * r + 1;
  // The template zero-mean once, as Ncc does for every offset.
  const int n = side * side;
  std::vector<double> centred(static_cast<size_t>(n));
  double mean_a = 0.0;
  for (int y = 0; y < side; ++y) {
    const float* row = patch.ptr<float>(y);
    for (int x = 0; x < side; ++x) mean_a += row[x];
  }
  mean_a /= n;
  double var_a = 0.0;
  for (int y = 0; y < side; ++y) {
    const float* row = patch.ptr<float>(y);
    for (int x = 0; x < side; ++x) {
      const double v = row[x] - mean_a;
      centred[static_cast<size_t>(y * side + x)] = v;
      var_a += v * v;
    }
  }
  const double sigma_a = std::sqrt(var_a / n);
  // One bilinear region covering every offset: the window of offset (dx, dy)
  // is its sub-block at (r + dx, r + dy), the patch ExtractPatch would take
  // at predicted + (dx, dy) (up to the float rounding of the centre).
  cv::Mat region;
  cv::getRectSubPix(
      image,
      cv::Size(side + 2 * r, side + 2 * r),
      cv::Point2f(static_cast<float>(predicted.x()), static_cast<float>(predicted.y())),
      region,
      CV_32F);
  cv::Mat scores(w, w, CV_64F, cv::Scalar(-2.0));
  double best = -2.0;
  int bx = 0, by = 0;
  for (int dy = -r; dy <= r; ++dy) {
    for (int dx = -r; dx <= r; ++dx) {
      if (dx * dx + dy * dy >
          options.patch_search_radius_px * options.patch_search_radius_px + 1e-9)
        continue;
      // ExtractPatch's bounds: the whole patch inside the image.
      const Eigen::Vector2d uv = predicted + Eigen::Vector2d(dx, dy);
      if (uv.x() - h < 0 || uv.y() - h < 0 || uv.x() + h > image.cols - 1 ||
          uv.y() + h > image.rows - 1)
        continue;
      // Zero-mean NCC with population deviations (Ncc).
      double sum_b = 0.0, sum_bb = 0.0, sum_ab = 0.0;
      for (int y = 0; y < side; ++y) {
        const float* row = region.ptr<float>(r + dy + y) + (r + dx);
        const double* a = centred.data() + y * side;
        for (int x = 0; x < side; ++x) {
          const double b = row[x];
          sum_b += b;
          sum_bb += b * b;
          sum_ab += a[x] * b;
        }
      }
      const double mean_b = sum_b / n;
      const double sigma_b = std::sqrt(std::max(0.0, sum_bb / n - mean_b * mean_b));
      const double score =
          sigma_a < 1e-6 || sigma_b < 1e-6 ? 0.0 : sum_ab / (n * sigma_a * sigma_b);
      scores.at<double>(dy + r, dx + r) = score;
      if (score > best) {
        best = score;
        bx = dx;
        by = dy;
      }
    }
  }
  if (best < options.min_ncc) return std::nullopt;
  return predicted + (Eigen::Vector2d(bx, by) + ParabolaPeakOffset(scores, bx + r, by + r));
}

}  // namespace twist::objects
