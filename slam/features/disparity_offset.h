// Calibration of a stereo rig's disparity offset from a sequence with known
// camera motion (docs/math.md section 21).
//
// A rectified rig whose right principal point sits delta pixels off the left
// one (a residual of the rectification that no single stereo pair reveals)
// measures every disparity delta too small, so every depth bf / d is too far
// by a share that grows with the depth, and the trajectory comes out too
// long. With the true relative motion between two frames, a point seen with
// stereo in both has a depth in the first that, moved by the motion, must
// give the disparity measured in the second: only the right delta makes
// the two agree. KITTI's odometry rig reads +0.09...+0.11 px that way,
// the project's renderer -0.01...0 px.
//
//   std::vector<features::StereoKeypoints> views = ...;  // per frame
//   std::vector<features::DisparityPair> pairs =
//       features::CollectDisparityPairs(camera, pyramid, views, world_from_camera, {});
//   features::DisparityOffsetFit fit = features::FitDisparityOffset(camera, pairs);
//   // fit.offset_px: add to every measured disparity (SlamOptions::disparity_offset_px)
#pragma once

#include <opencv2/core.hpp>
#include <vector>

#include "slam/features/orb_extractor.h"
#include "slam/features/stereo_matcher.h"
#include "slam/geometry/se3.h"
#include "slam/geometry/stereo_camera.h"

namespace twist::features {

// One frame's left keypoints and their stereo matches (MatchStereo).
struct StereoKeypoints {
  std::vector<cv::KeyPoint> keypoints;
  cv::Mat descriptors;
  std::vector<float> u_right;  // -1 when unmatched
};

// ORB on both images of a rectified gray pair and MatchStereo, as the engine
// extracts a frame without masks.
StereoKeypoints ExtractStereoKeypoints(const OrbExtractor& orb,
                                       const geometry::StereoCamera& camera,
                                       const cv::Mat& left_gray,
                                       const cv::Mat& right_gray,
                                       const StereoMatchOptions& options = {});

// A keypoint matched between frames i and j, with stereo in both.
struct DisparityPair {
  Eigen::Vector2d uv_i, uv_j;  // left pixels
  double disparity_i = 0.0, disparity_j = 0.0;
  int level = 0;             // the larger of the two keypoints' levels
  double level_scale = 1.0;  // its scale
  int frame_i = 0;           // index into the views
  geometry::SE3d j_from_i;   // known relative motion
};

struct DisparityPairOptions {
  std::vector<int> gaps = {1, 2, 3, 4, 5};  // frame pairs (i, i + gap)
  float ratio = 0.8f;                       // descriptor ratio test
  int max_descriptor_distance = 50;
  // A pair is kept when frame i's measured depth, moved by the motion,
  // projects within this many pixels x level scale of frame j's keypoint
  // and its disparity within this many pixels x level scale of frame j's
  // (moving objects and wrong matches fail).
  double max_reprojection_px = 3.0;
  double max_disparity_px = 3.0;
  // The offset those checks correct the measured disparities by. Checked
  // uncorrected, a rig with a large offset loses the pairs its offset moves
  // most (the far ones), and the survivors read too little of it:
  // CalibrateDisparityOffset checks again at each fit.
  double check_offset_px = 0.0;
};

struct DisparityPairStats {
  int matched = 0;   // stereo in both frames
  int rejected = 0;  // failed the motion check
};

// Pairs over every (i, i + gap) of `views`; `world_from_camera[i]` is view
// i's left camera pose (the shorter of the two lists bounds the frames used).
std::vector<DisparityPair> CollectDisparityPairs(
    const geometry::StereoCamera& camera,
    const ScalePyramid& pyramid,
    const std::vector<StereoKeypoints>& views,
    const std::vector<geometry::SE3d>& world_from_camera,
    const DisparityPairOptions& options,
    DisparityPairStats* stats = nullptr);

struct DisparityOffsetFit {
  int num_pairs = 0;
  bool ok = false;                 // enough pairs (>= 40) for a fit
  double offset_px = 0.0;          // add to measured disparities
  double standard_error_px = 0.0;  // from four interleaved subsets (0 below 160 pairs)
  double cost = 0.0;               // robust cost at the offset
  double cost_at_zero = 0.0;
};

struct DisparityCalibration {
  DisparityOffsetFit fit;
  std::vector<DisparityPair> pairs;  // checked at the fitted offset
  DisparityPairStats stats;
  int iterations = 0;
};

// Pairs and fit, again with the pairs checked at the last fit, until the fit
// moves by less than 0.005 px (at most 5 rounds).
DisparityCalibration CalibrateDisparityOffset(const geometry::StereoCamera& camera,
                                              const ScalePyramid& pyramid,
                                              const std::vector<StereoKeypoints>& views,
                                              const std::vector<geometry::SE3d>& world_from_camera,
                                              DisparityPairOptions options = {});

// Disparity residual of one pair (frame j's measured disparity against frame
// i's depth moved by the motion), both corrected by `offset_px`, over the
// pair's level scale.
double DisparityPairResidual(const geometry::StereoCamera& camera,
                             const DisparityPair& pair,
                             double offset_px);

// The offset in [-1, 1] px minimising sum min(r^2, 1) of the residuals
// (grid search in 0.002 px steps, refined by a parabola).
DisparityOffsetFit FitDisparityOffset(const geometry::StereoCamera& camera,
                                      const std::vector<const DisparityPair*>& pairs);
DisparityOffsetFit FitDisparityOffset(const geometry::StereoCamera& camera,
                                      const std::vector<DisparityPair>& pairs);

}  // namespace twist::features
