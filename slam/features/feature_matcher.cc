#include "slam/features/feature_matcher.h"

#include <algorithm>
#include <climits>
#include <cmath>

#include "slam/features/orb_extractor.h"

namespace twist::features {

KeypointGrid::KeypointGrid(const std::vector<cv::KeyPoint>& kps, int width, int height)
    : inv_cell_w_(static_cast<float>(kCols) / width),
      inv_cell_h_(static_cast<float>(kRows) / height),
      cells_(kCols * kRows) {
  for (int i = 0; i < static_cast<int>(kps.size()); ++i) {
    const int cx = static_cast<int>(kps[i].pt.x * inv_cell_w_);
    const int cy = static_cast<int>(kps[i].pt.y * inv_cell_h_);
    if (cx < 0 || cy < 0 || cx >= kCols || cy >= kRows) continue;
    cells_[cy * kCols + cx].push_back(i);
  }
}

std::vector<int> KeypointGrid::FeaturesInArea(const std::vector<cv::KeyPoint>& kps,
                                              float x,
                                              float y,
                                              float radius,
                                              int min_level,
                                              int max_level) const {
  std::vector<int> out;
  if (cells_.empty()) return out;
  const int x0 = std::max(0, static_cast<int>(std::floor((x - radius) * inv_cell_w_)));
  const int x1 = std::min(kCols - 1, static_cast<int>(std::floor((x + radius) * inv_cell_w_)));
  const int y0 = std::max(0, static_cast<int>(std::floor((y - radius) * inv_cell_h_)));
  const int y1 = std::min(kRows - 1, static_cast<int>(std::floor((y + radius) * inv_cell_h_)));
  if (x0 > x1 || y0 > y1) return out;
  for (int cy = y0; cy <= y1; ++cy) {
    for (int cx = x0; cx <= x1; ++cx) {
      for (int i : cells_[cy * kCols + cx]) {
        const cv::KeyPoint& kp = kps[i];
        if (min_level >= 0 && kp.octave < min_level) continue;
        if (max_level >= 0 && kp.octave > max_level) continue;
        if (std::fabs(kp.pt.x - x) < radius && std::fabs(kp.pt.y - y) < radius) out.push_back(i);
      }
    }
  }
  return out;
}

void OrientationFilter::Add(float angle_a_deg, float angle_b_deg, int match_index) {
  float rot = angle_a_deg - angle_b_deg;
  if (rot < 0.f) rot += 360.f;
  int bin = static_cast<int>(std::lround(rot * kBins / 360.f));
  if (bin >= kBins) bin = 0;
  bins_[bin].push_back(match_index);
}

std::vector<int> OrientationFilter::Rejected() const {
  int m1 = -1, m2 = -1, m3 = -1;
  auto size = [&](int b) { return b < 0 ? -1 : static_cast<int>(bins_[b].size()); };
  for (int b = 0; b < kBins; ++b) {
    const int s = static_cast<int>(bins_[b].size());
    if (s > size(m1)) {
      m3 = m2;
      m2 = m1;
      m1 = b;
    } else if (s > size(m2)) {
      m3 = m2;
      m2 = b;
    } else if (s > size(m3)) {
      m3 = b;
    }
  }
  if (size(m2) < 0.1 * size(m1)) m2 = -1;
  if (size(m3) < 0.1 * size(m1)) m3 = -1;
  std::vector<int> rejected;
  for (int b = 0; b < kBins; ++b) {
    if (b == m1 || b == m2 || b == m3) continue;
    rejected.insert(rejected.end(), bins_[b].begin(), bins_[b].end());
  }
  return rejected;
}

std::vector<std::pair<int, int>> MatchRatio(const cv::Mat& query,
                                            const cv::Mat& train,
                                            float ratio,
                                            int max_distance) {
  std::vector<int> train_owner(train.rows, -1), train_dist(train.rows, INT_MAX);
  std::vector<int> match(query.rows, -1);
  for (int q = 0; q < query.rows; ++q) {
    const uint8_t* dq = query.ptr<uint8_t>(q);
    int best = INT_MAX, second = INT_MAX, best_t = -1;
    for (int t = 0; t < train.rows; ++t) {
      const int d = DescriptorDistance(dq, train.ptr<uint8_t>(t));
      if (d < best) {
        second = best;
        best = d;
        best_t = t;
      } else if (d < second) {
        second = d;
      }
    }
    if (best_t < 0 || best > max_distance) continue;
    if (static_cast<float>(best) >= ratio * static_cast<float>(second)) continue;
    if (best < train_dist[best_t]) {
      if (train_owner[best_t] >= 0) match[train_owner[best_t]] = -1;
      train_owner[best_t] = q;
      train_dist[best_t] = best;
      match[q] = best_t;
    }
  }
  std::vector<std::pair<int, int>> out;
  for (int q = 0; q < query.rows; ++q) {
    if (match[q] >= 0) out.push_back({q, match[q]});
  }
  return out;
}

}  // namespace twist::features
