// Descriptor matching helpers: a spatial keypoint grid for guided (projection)
// search, the orientation-consistency filter and ratio-test matching.
#pragma once

#include <opencv2/core.hpp>
#include <utility>
#include <vector>

namespace twist::features {

// ORB-SLAM's descriptor thresholds (Hamming distance on 256 bits).
inline constexpr int kThresholdHigh = 100;
inline constexpr int kThresholdLow = 50;

// Buckets keypoints by image cell for fast radius queries.
class KeypointGrid {
 public:
  KeypointGrid() = default;
  KeypointGrid(const std::vector<cv::KeyPoint>& kps, int width, int height);

  // Indices of keypoints within the square of half-size `radius` around
  // (x, y) and with min_level <= octave <= max_level (-1: no bound).
  std::vector<int> FeaturesInArea(const std::vector<cv::KeyPoint>& kps,
                                  float x,
                                  float y,
                                  float radius,
                                  int min_level = -1,
                                  int max_level = -1) const;

 private:
  static constexpr int kCols = 64;
  static constexpr int kRows = 48;
  float inv_cell_w_ = 0.f, inv_cell_h_ = 0.f;
  std::vector<std::vector<int>> cells_;
};

// Rotation consistency: accumulates the keypoint angle differences of the
// candidate matches into 30 bins and keeps the matches of the three fullest
// bins (the 2nd/3rd only if they hold at least 10% of the 1st).
class OrientationFilter {
 public:
  void Add(float angle_a_deg, float angle_b_deg, int match_index);
  // Indices passed to Add() that fail the test.
  std::vector<int> Rejected() const;

 private:
  static constexpr int kBins = 30;
  std::vector<int> bins_[kBins];
};

// For each row of `query`, the best and second best rows of `train`; keeps
// the match when best <= max_distance and best < ratio * second. A train row
// claimed by several queries keeps only the closest. Returns (query, train)
// sorted by query.
std::vector<std::pair<int, int>> MatchRatio(const cv::Mat& query,
                                            const cv::Mat& train,
                                            float ratio,
                                            int max_distance);

}  // namespace twist::features
