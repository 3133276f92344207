// ORB features on a scale pyramid with an even spatial distribution.
//
// Per pyramid level: FAST corners (OpenCV) with a high threshold, falling back
// to a low threshold in grid cells where the high one finds nothing; the
// corners are spread over the image with a quadtree (split the most crowded
// cell until there are enough cells, keep the strongest corner per cell);
// orientation by intensity centroid; a 256-bit steered BRIEF descriptor on the
// Gaussian-smoothed level image. The BRIEF test pattern is drawn once per
// extractor from a seeded generator (isotropic Gaussian, as BRIEF's G II), so
// the extractor has no global state and two extractors with the same seed
// produce identical descriptors.
#pragma once

#include <array>
#include <cstdint>
#include <opencv2/core.hpp>
#include <vector>

#include "absl/status/status.h"

namespace twist::features {

struct OrbOptions {
  int num_features = 2000;                // total over all levels
  int num_levels = 8;                     // pyramid levels
  double scale_factor = 1.2;              // level l is scaled by 1 / scale_factor^l
  int fast_threshold = 20;                // first FAST threshold
  int min_fast_threshold = 7;             // fallback threshold in cells without corners
  uint64_t pattern_seed = 0x0b5e55edULL;  // BRIEF test pattern seed
  // Corners of a favoured region (see Extract) come on top of each level's
  // budget instead of taking part of it.
  bool favoured_on_top = false;

  absl::Status Validate() const;
};

// Pyramid bookkeeping shared by frames, matchers and the optimizer.
struct ScalePyramid {
  std::vector<float> scale;  // scale_factor^l
  std::vector<float> inv_scale;
  std::vector<float> sigma2;  // scale^2 (pixel noise variance per level)
  std::vector<float> inv_sigma2;
  double scale_factor = 1.2;
  double log_scale_factor = 0.0;

  static ScalePyramid Create(int num_levels, double scale_factor);
  int num_levels() const { return static_cast<int>(scale.size()); }
};

// Region mask convention for Extract(): CV_8UC1, same size as the image;
// 0 = exclude, 1..127 = normal, 128..255 = favour: corners there win their
// cells in the distribution. With OrbOptions::favoured_on_top they are kept
// on top of the level's budget, which the other corners then get whole in a
// second spread without them (the object tracker's keypoints, favoured
// inside dynamic segments, do not take the camera's; docs/objects.md §48); a
// corner that only this second spread keeps has class_id kExtraKeypoint.
// Every other keypoint has class_id -1.
class OrbExtractor {
 public:
  static constexpr int kDescriptorBytes = 32;
  static constexpr int kExtraKeypoint = 1;

  explicit OrbExtractor(const OrbOptions& options);

  // `image` CV_8UC1. `region_mask` empty or CV_8UC1 of the same size.
  // Keypoints are in level-0 pixels, `octave` = level, `angle` in degrees,
  // `size` = patch diameter at that level; descriptors N x 32 CV_8UC1.
  // `levels` (optional) receives the pyramid images (level 0 = `image`).
  // `budget_scale` (in (0, 10]) multiplies every level's number of features.
  void Extract(const cv::Mat& image,
               const cv::Mat& region_mask,
               std::vector<cv::KeyPoint>* keypoints,
               cv::Mat* descriptors,
               std::vector<cv::Mat>* levels = nullptr,
               double budget_scale = 1.0) const;

  const OrbOptions& options() const { return options_; }
  const ScalePyramid& pyramid() const { return pyramid_; }

  // Level images: level 0 is `image` itself.
  void BuildPyramid(const cv::Mat& image, std::vector<cv::Mat>* levels) const;

 private:
  void ExtractLevel(const cv::Mat& level_image,
                    const cv::Mat& level_mask,
                    int level,
                    int target,
                    std::vector<cv::KeyPoint>* keypoints) const;
  void ComputeDescriptors(const cv::Mat& blurred,
                          const std::vector<cv::KeyPoint>& level_kps,
                          uint8_t* out) const;
  float IntensityCentroidAngle(const cv::Mat& image, const cv::Point2f& pt) const;

  OrbOptions options_;
  ScalePyramid pyramid_;
  std::vector<int> features_per_level_;
  std::vector<int> umax_;  // half-widths of the circular orientation patch
  // 256 tests, each two points (x1, y1, x2, y2) within radius kPatternRadius.
  std::vector<std::array<int8_t, 4>> pattern_;
  // pattern_ rotated by 360° * bin / kAngleBins (descriptor steering).
  static constexpr int kAngleBins = 90;
  std::vector<std::vector<std::array<int8_t, 4>>> rotated_pattern_;
};

// The 8-bit gray image the extractor reads: `image` itself (no copy) when it
// is one channel, else the BGR image converted.
cv::Mat ToGray(const cv::Mat& image);

// Hamming distance of two 32-byte descriptors.
int DescriptorDistance(const uint8_t* a, const uint8_t* b);
inline int DescriptorDistance(const cv::Mat& a, int row_a, const cv::Mat& b, int row_b) {
  return DescriptorDistance(a.ptr<uint8_t>(row_a), b.ptr<uint8_t>(row_b));
}

}  // namespace twist::features
