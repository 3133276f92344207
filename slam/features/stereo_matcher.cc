#include "slam/features/stereo_matcher.h"

#include <glog/logging.h>

#include <algorithm>
#include <cmath>
#include <cstdlib>
#include <vector>

namespace twist::features {
namespace {

// Mean of the (2w+1)² patch of `img` centred on integer (x, y).
double PatchMean(const cv::Mat& img, int x, int y, int w) {
  int sum = 0;
  for (int dy = -w; dy <= w; ++dy) {
    const uint8_t* row = img.ptr<uint8_t>(y + dy);
    for (int dx = -w; dx <= w; ++dx) sum += row[x + dx];
  }
  return static_cast<double>(sum) / ((2 * w + 1) * (2 * w + 1));
}

// Gauss-Newton on the horizontal position `x` of the right patch (row y):
// minimises the SSD of zero-mean patches, the right one sampled bilinearly
// with central-difference gradients. False when it leaves the image or the
// patch has no horizontal gradient.
bool RefineShiftGaussNewton(const cv::Mat& il,
                            int xl,
                            const cv::Mat& ir,
                            int y,
                            int w,
                            int iterations,
                            std::vector<double>* scratch,
                            double* x) {
  const int side = 2 * w + 1, n = side * side;
  scratch->resize(3 * static_cast<size_t>(n));
  double* left = scratch->data();
  double* val = left + n;
  double* grad = val + n;
  const double mean_l = PatchMean(il, xl, y, w);
  for (int dy = -w, k = 0; dy <= w; ++dy) {
    const uint8_t* pl = il.ptr<uint8_t>(y + dy) + xl;
    for (int dx = -w; dx <= w; ++dx, ++k) left[k] = pl[dx] - mean_l;
  }
  for (int it = 0; it < iterations; ++it) {
    const int x0 = static_cast<int>(std::floor(*x));
    const double t = *x - x0;
    if (x0 - w - 1 < 0 || x0 + w + 2 >= ir.cols) return false;
    double mean_v = 0.0, mean_g = 0.0;
    for (int dy = -w, k = 0; dy <= w; ++dy) {
      const uint8_t* row = ir.ptr<uint8_t>(y + dy);
      for (int dx = -w; dx <= w; ++dx, ++k) {
        const int xi = x0 + dx;
        val[k] = (1.0 - t) * row[xi] + t * row[xi + 1];
        grad[k] = 0.5 * ((1.0 - t) * (row[xi + 1] - row[xi - 1]) + t * (row[xi + 2] - row[xi]));
        mean_v += val[k];
        mean_g += grad[k];
      }
    }
    mean_v /= n;
    mean_g /= n;
    double h = 0.0, g = 0.0;
    for (int k = 0; k < n; ++k) {
      const double gk = grad[k] - mean_g;
      h += gk * gk;
      g += gk * ((val[k] - mean_v) - left[k]);
    }
    if (!(h > 1e-9)) return false;
    const double step = std::clamp(-g / h, -0.5, 0.5);
    *x += step;
    if (std::abs(step) < 1e-3) break;
  }
  return true;
}

}  // namespace

StereoMatchResult MatchStereo(const geometry::StereoCamera& camera,
                              const ScalePyramid& pyramid,
                              const std::vector<cv::KeyPoint>& left_kps,
                              const cv::Mat& left_desc,
                              const std::vector<cv::KeyPoint>& right_kps,
                              const cv::Mat& right_desc,
                              const std::vector<cv::Mat>& left_levels,
                              const std::vector<cv::Mat>& right_levels,
                              const StereoMatchOptions& options) {
  const int n = static_cast<int>(left_kps.size());
  StereoMatchResult result;
  result.u_right.assign(n, -1.f);
  result.depth.assign(n, -1.f);
  if (n == 0 || right_kps.empty()) return result;
  const int rows = left_levels[0].rows;

  // Row index of right keypoints over their band.
  std::vector<std::vector<int>> row_index(rows);
  for (int i = 0; i < static_cast<int>(right_kps.size()); ++i) {
    const cv::KeyPoint& kp = right_kps[i];
    const float r = static_cast<float>(options.row_band_sigmas) * pyramid.scale[kp.octave];
    const int lo = std::max(0, static_cast<int>(std::floor(kp.pt.y - r)));
    const int hi = std::min(rows - 1, static_cast<int>(std::ceil(kp.pt.y + r)));
    for (int y = lo; y <= hi; ++y) row_index[y].push_back(i);
  }

  const double max_disparity = camera.bf() / (options.min_depth_baselines * camera.baseline);
  const int w = options.sad_half_window;
  const int L = options.sad_search;
  std::vector<std::pair<int, int>> sad_of_match;  // (SAD, left index)
  sad_of_match.reserve(n);
  std::vector<float> sad_values(2 * L + 1);
  std::vector<double> scratch;

  for (int i = 0; i < n; ++i) {
    const cv::KeyPoint& kl = left_kps[i];
    const int y = cvRound(kl.pt.y);
    if (y < 0 || y >= rows) continue;
    const float ul = kl.pt.x;
    const float min_u = static_cast<float>(ul - max_disparity);
    const float max_u = ul;
    int best_dist = options.max_descriptor_distance + 1;
    int best_j = -1;
    const uint8_t* dl = left_desc.ptr<uint8_t>(i);
    for (int j : row_index[y]) {
      const cv::KeyPoint& kr = right_kps[j];
      if (kr.octave < kl.octave - 1 || kr.octave > kl.octave + 1) continue;
      if (kr.pt.x < min_u || kr.pt.x > max_u) continue;
      const int d = DescriptorDistance(dl, right_desc.ptr<uint8_t>(j));
      if (d < best_dist) {
        best_dist = d;
        best_j = j;
      }
    }
    if (best_j < 0 || best_dist > options.max_descriptor_distance) continue;

    // SAD refinement on the left keypoint's level.
    const int level = kl.octave;
    const cv::Mat& il = left_levels[level];
    const cv::Mat& ir = right_levels[level];
    // Level-0 <-> level pixel centres (see OrbExtractor::Extract).
    const float sx = static_cast<float>(left_levels[0].cols) / static_cast<float>(il.cols);
    const float sy = static_cast<float>(left_levels[0].rows) / static_cast<float>(il.rows);
    const int su = cvRound((ul + 0.5f) / sx - 0.5f);
    const int sv = cvRound((kl.pt.y + 0.5f) / sy - 0.5f);
    const int sur = cvRound((right_kps[best_j].pt.x + 0.5f) / sx - 0.5f);
    if (sv - w < 0 || sv + w >= il.rows || su - w < 0 || su + w >= il.cols) continue;
    if (sur - L - w < 0 || sur + L + w >= ir.cols) continue;
    const int center_l = il.at<uint8_t>(sv, su);
    int best_sad = INT32_MAX;
    int best_inc = 0;
    for (int inc = -L; inc <= L; ++inc) {
      const int center_r = ir.at<uint8_t>(sv, sur + inc);
      int sad = 0;
      for (int dy = -w; dy <= w; ++dy) {
        const uint8_t* pl = il.ptr<uint8_t>(sv + dy) + su - w;
        const uint8_t* pr = ir.ptr<uint8_t>(sv + dy) + sur + inc - w;
        for (int dx = 0; dx <= 2 * w; ++dx) {
          // Patches normalised by their centre intensity (brightness offset).
          sad += std::abs((pl[dx] - center_l) - (pr[dx] - center_r));
        }
      }
      sad_values[inc + L] = static_cast<float>(sad);
      if (sad < best_sad) {
        best_sad = sad;
        best_inc = inc;
      }
    }
    if (best_inc == -L || best_inc == L) continue;  // minimum on the border
    const float d1 = sad_values[best_inc + L - 1];
    const float d2 = sad_values[best_inc + L];
    const float d3 = sad_values[best_inc + L + 1];
    const float denom = 2.f * (d1 + d3 - 2.f * d2);
    if (denom <= 0.f) continue;
    float delta = (d1 - d3) / denom;
    if (delta < -1.f || delta > 1.f) continue;
    if (options.subpixel == SubpixelMethod::kSsdGaussNewton) {
      // From the SAD parabola's vertex: Gauss-Newton on the zero-mean SSD,
      // which is smooth in the shift (SAD is V-shaped around its minimum and
      // pulls the vertex to integers).
      double x = sur + best_inc + delta;
      if (!RefineShiftGaussNewton(
              il, su, ir, sv, w, options.gauss_newton_iterations, &scratch, &x)) {
        continue;
      }
      if (std::abs(x - (sur + best_inc)) > 1.5) continue;
      delta = static_cast<float>(x - (sur + best_inc));
    }
    const float ur = (static_cast<float>(sur + best_inc) + delta + 0.5f) * sx - 0.5f;
    float disparity = ul - ur + static_cast<float>(options.disparity_offset_px);
    if (disparity < 0.f || disparity >= max_disparity) continue;
    if (disparity <= 0.f) disparity = 0.01f;
    result.u_right[i] = ul - disparity;
    result.depth[i] = static_cast<float>(camera.bf() / disparity);
    sad_of_match.push_back({best_sad, i});
  }

  // Robust rejection of poor block matches.
  if (!sad_of_match.empty()) {
    std::vector<std::pair<int, int>> sorted;
    sorted.reserve(sad_of_match.size());
    for (const auto& m : sad_of_match) {
      if (left_kps[m.second].class_id != OrbExtractor::kExtraKeypoint) sorted.push_back(m);
    }
    if (sorted.empty()) sorted = sad_of_match;
    std::nth_element(sorted.begin(), sorted.begin() + sorted.size() / 2, sorted.end());
    const double median = sorted[sorted.size() / 2].first;
    const double th = options.sad_median_factor * median;
    for (const auto& [sad, i] : sad_of_match) {
      if (sad > th) {
        result.u_right[i] = -1.f;
        result.depth[i] = -1.f;
      } else {
        ++result.num_matches;
      }
    }
  }
  return result;
}

}  // namespace twist::features
