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

namespace {

// The patch searches' integer search half-width (pixels).
int SearchRadius(const ProjectionSearchOptions& options) {
  return static_cast<int>(std::ceil(options.patch_search_radius_px));
}

// The patch searches' input: an 8-bit image and a square CV_32F patch.
// Returns the patch's half size.
int CheckSearchInput(const cv::Mat& image, const cv::Mat& patch) {
  CHECK_EQ(image.type(), CV_8UC1);
  CHECK_EQ(patch.type(), CV_32F);
  CHECK_EQ(patch.rows, patch.cols);
  return patch.rows / 2;
}

// A patch search's correlation at every integer offset (dx, dy) within
// options.patch_search_radius_px of `predicted` whose (2h+1)² window lies
// inside the image. One bilinear region covers every offset: the window of
// offset (dx, dy) is its sub-block at (r + dx, r + dy), the patch
// ExtractPatch would take at predicted + (dx, dy) (up to the float rounding
// of the centre). `score(region, r, dx, dy)` gives an offset's correlation, or
// nullopt to leave it unscored (−2 in the grid).
struct OffsetScores {
  cv::Mat scores;  // CV_64F, (2r + 1)², offset (dx, dy) at (r + dy, r + dx)
  int r = 0;
  double best = -2.0;
  int bx = 0, by = 0;

  // The best offset's sub-pixel position (ParabolaPeakOffset), or nullopt
  // when its correlation is below min_ncc.
  std::optional<Eigen::Vector2d> Vertex(const Eigen::Vector2d& predicted, double min_ncc) const {
    if (best < min_ncc) return std::nullopt;
    return predicted + (Eigen::Vector2d(bx, by) + ParabolaPeakOffset(scores, bx + r, by + r));
  }
};

template <typename Score>
OffsetScores ScoreOffsets(const cv::Mat& image,
                          int h,
                          const Eigen::Vector2d& predicted,
                          const ProjectionSearchOptions& options,
                          Score&& score) {
  const int side = 2 * h + 1;
  OffsetScores out;
  const int r = out.r = SearchRadius(options);
  cv::Mat region;
  cv::getRectSubPix(
      image,
      cv::Size(side + 2 * r, side + 2 * r),
      cv::Point2f(static_cast<float>(predicted.x()), static_cast<float>(predicted.y())),
      region,
      CV_32F);
  out.scores = cv::Mat(2 * r + 1, 2 * r + 1, CV_64F, cv::Scalar(-2.0));
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
      const std::optional<double> v = score(region, r, dx, dy);
      if (!v) continue;
      out.scores.at<double>(dy + r, dx + r) = *v;
      if (*v > out.best) {
        out.best = *v;
        out.bx = dx;
        out.by = dy;
      }
    }
  }
  return out;
}

// Bilinear sample of an 8-bit image; (x, y) at least one pixel inside.
double Bilinear(const cv::Mat& image, double x, double y) {
  const int x0 = static_cast<int>(std::floor(x));
  const int y0 = static_cast<int>(std::floor(y));
  const double ax = x - x0, ay = y - y0;
  const uint8_t* r0 = image.ptr<uint8_t>(y0) + x0;
  const uint8_t* r1 = image.ptr<uint8_t>(y0 + 1) + x0;
  return (1.0 - ay) * ((1.0 - ax) * r0[0] + ax * r0[1]) + ay * ((1.0 - ax) * r1[0] + ax * r1[1]);
}

// Whether every pixel a bilinear sample at (x, y) reads, widened by
// `margin` pixels (the sample's gradient), is on the mask; true without one.
bool OnMask(const cv::Mat& mask, double x, double y, int margin = 0) {
  if (mask.empty()) return true;
  const int x0 = static_cast<int>(std::floor(x)) - margin;
  const int y0 = static_cast<int>(std::floor(y)) - margin;
  const int x1 = static_cast<int>(std::floor(x)) + 1 + margin;
  const int y1 = static_cast<int>(std::floor(y)) + 1 + margin;
  if (x0 < 0 || y0 < 0 || x1 >= mask.cols || y1 >= mask.rows) return false;
  for (int yy = y0; yy <= y1; ++yy) {
    const uint8_t* row = mask.ptr<uint8_t>(yy);
    for (int xx = x0; xx <= x1; ++xx) {
      if (row[xx] == 0) return false;
    }
  }
  return true;
}

// Gauss–Newton on (shift, gain, offset) minimising
// Σ (gain · I(uv + x) + offset − T(x))² over the patch pixels `used`
// (row-major indices); nullopt when it does not converge.
std::optional<Eigen::Vector2d> RefineShift(const cv::Mat& image,
                                           const cv::Mat& patch,
                                           const std::vector<int>& used,
                                           Eigen::Vector2d uv,
                                           int iterations) {
  const int h = patch.rows / 2;
  const int side = patch.rows;
  double gain = 1.0, offset = 0.0;
  {
    // Start from the gain and offset that match the means and deviations.
    double st = 0, stt = 0, si = 0, sii = 0;
    for (int i : used) {
      const double t = patch.at<float>(i / side, i % side);
      const double v = Bilinear(image, uv.x() + i % side - h, uv.y() + i / side - h);
      st += t;
      stt += t * t;
      si += v;
      sii += v * v;
    }
    const double n = static_cast<double>(used.size());
    const double vt = stt / n - (st / n) * (st / n), vi = sii / n - (si / n) * (si / n);
    if (vt <= 1e-6 || vi <= 1e-6) return std::nullopt;
    gain = std::sqrt(vt / vi);
    offset = st / n - gain * si / n;
  }
  for (int it = 0; it < iterations; ++it) {
    Eigen::Matrix4d hess = Eigen::Matrix4d::Zero();
    Eigen::Vector4d grad = Eigen::Vector4d::Zero();
    for (int i : used) {
      const double x = uv.x() + i % side - h, y = uv.y() + i / side - h;
      if (x < 1.0 || y < 1.0 || x > image.cols - 3 || y > image.rows - 3) return std::nullopt;
      const double v = Bilinear(image, x, y);
      const double gx = 0.5 * (Bilinear(image, x + 1, y) - Bilinear(image, x - 1, y));
      const double gy = 0.5 * (Bilinear(image, x, y + 1) - Bilinear(image, x, y - 1));
      const Eigen::Vector4d j(gain * gx, gain * gy, v, 1.0);
      const double r = gain * v + offset - patch.at<float>(i / side, i % side);
      hess += j * j.transpose();
      grad += j * r;
    }
    const Eigen::Vector4d step = hess.ldlt().solve(-grad);
    if (!step.allFinite()) return std::nullopt;
    uv += step.head<2>();
    gain += step(2);
    offset += step(3);
    if (step.head<2>().norm() < 1e-3) break;
  }
  return uv;
}

}  // namespace

cv::Mat ExtractMaskedPatch(const cv::Mat& image,
                           const cv::Mat& mask,
                           const Eigen::Vector2d& uv,
                           int half_size,
                           double min_share) {
  CHECK(mask.type() == CV_8UC1 && mask.size() == image.size());
  cv::Mat patch = ExtractPatch(image, uv, half_size);
  if (patch.empty()) return patch;
  cv::Mat off(patch.size(), CV_8UC1, cv::Scalar(0));
  for (int y = 0; y < patch.rows; ++y) {
    for (int x = 0; x < patch.cols; ++x) {
      if (!OnMask(mask, uv.x() + x - half_size, uv.y() + y - half_size)) off.at<uint8_t>(y, x) = 1;
    }
  }
  const double on = static_cast<double>(patch.total()) - cv::countNonZero(off);
  if (on >= std::max(4.0, min_share * static_cast<double>(patch.total()))) {
    patch.setTo(std::numeric_limits<float>::quiet_NaN(), off);
  }
  return patch;
}

std::optional<Eigen::Vector2d> PatchSearch(const cv::Mat& image,
                                           const cv::Mat& patch,
                                           const Eigen::Vector2d& predicted,
                                           const ProjectionSearchOptions& options) {
  if (patch.empty()) return std::nullopt;
  const int h = CheckSearchInput(image, patch);
  const int side = 2 * h + 1;
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
  const OffsetScores found =
      ScoreOffsets(image, h, predicted, options, [&](const cv::Mat& region, int r, int dx, int dy) {
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
        return std::optional<double>(
            sigma_a < 1e-6 || sigma_b < 1e-6 ? 0.0 : sum_ab / (n * sigma_a * sigma_b));
      });
  return found.Vertex(predicted, options.min_ncc);
}

std::optional<Eigen::Vector2d> MaskedPatchSearch(const cv::Mat& image,
                                                 const cv::Mat& patch,
                                                 const cv::Mat& mask,
                                                 const Eigen::Vector2d& predicted,
                                                 const ProjectionSearchOptions& options) {
  if (patch.empty()) return std::nullopt;
  const int h = CheckSearchInput(image, patch);
  CHECK(mask.empty() || (mask.type() == CV_8UC1 && mask.size() == image.size()));
  const int side = 2 * h + 1;
  const double min_pixels = std::max(4.0, options.min_masked_patch_share * side * side);
  // Which pixels of the search region (ScoreOffsets) lie on the object, once
  // for every offset's window.
  const int rr = SearchRadius(options);
  cv::Mat on_object(side + 2 * rr, side + 2 * rr, CV_8UC1);
  for (int i = 0; i < on_object.rows; ++i) {
    for (int j = 0; j < on_object.cols; ++j) {
      on_object.at<uint8_t>(i, j) =
          OnMask(mask, predicted.x() + (j - rr - h), predicted.y() + (i - rr - h)) ? 1 : 0;
    }
  }
  const OffsetScores found =
      ScoreOffsets(image, h, predicted, options, [&](const cv::Mat& region, int r, int dx, int dy) {
        double n = 0, sa = 0, saa = 0, sb = 0, sbb = 0, sab = 0;
        for (int y = 0; y < side; ++y) {
          const float* ref = patch.ptr<float>(y);
          const float* row = region.ptr<float>(r + dy + y) + (r + dx);
          const uint8_t* on = on_object.ptr<uint8_t>(r + dy + y) + (r + dx);
          for (int x = 0; x < side; ++x) {
            const double a = ref[x];
            if (std::isnan(a) || !on[x]) continue;
            const double b = row[x];
            n += 1;
            sa += a;
            saa += a * a;
            sb += b;
            sbb += b * b;
            sab += a * b;
          }
        }
        if (n < min_pixels) return std::optional<double>();
        const double va = saa - sa * sa / n, vb = sbb - sb * sb / n;
        return std::optional<double>(
            va < 1e-6 || vb < 1e-6 ? 0.0 : (sab - sa * sb / n) / std::sqrt(va * vb));
      });
  const std::optional<Eigen::Vector2d> vertex = found.Vertex(predicted, options.min_ncc);
  if (!vertex || options.patch_gauss_newton_iterations <= 0) return vertex;
  std::vector<int> used;
  const Eigen::Vector2d peak = predicted + Eigen::Vector2d(found.bx, found.by);
  for (int y = 0; y < side; ++y) {
    for (int x = 0; x < side; ++x) {
      if (!std::isnan(patch.at<float>(y, x)) && OnMask(mask, peak.x() + x - h, peak.y() + y - h, 1))
        used.push_back(y * side + x);
    }
  }
  const auto refined =
      RefineShift(image, patch, used, *vertex, options.patch_gauss_newton_iterations);
  return refined && (*refined - *vertex).norm() <= 1.0 ? *refined : vertex;
}

}  // namespace twist::objects
