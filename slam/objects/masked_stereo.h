// Disparity of a point on an object, measured with the block restricted to
// the object's mask.
//
// The engine's stereo matcher refines each ORB match by block matching on
// the keypoint's pyramid level: an 11x11 block there covers 11·1.2^L
// level-0 pixels (39 px on level 7). On a car 20-30 m away (45-70 px wide)
// most blocks straddle the car and the background, and their disparity mixes
// the two surfaces: per point 2.6-3.4 % depth spread instead of 1.5-2.3 %,
// and errors shared by the points of one car (the same background behind
// them) of ±0.5-1.5 m at 30 m, measured against the renderer's exact depth
// (bench/objects/object_depth_bias, docs/objects.md §11). A rigid object's
// structure built on such depths is not a rigid copy of the car, and its
// motion absorbs the difference.
//
// MaskedDisparity re-measures the disparity on level 0 around the matcher's
// value: zero-mean normalised cross-correlation (robust to the two eyes'
// gain and offset) over the pixels of a window that lie inside the mask,
// integer search, parabolic sub-pixel vertex, then Gauss–Newton on the
// disparity, gain and offset with the right image interpolated linearly.
#pragma once

#include <Eigen/Core>
#include <opencv2/core.hpp>
#include <optional>
#include <vector>

namespace twist::objects {

struct MaskedStereoOptions {
  int search_px = 3;            // ± around the initial disparity (level-0 pixels)
  int min_half_window = 4;      // the window is at least 9x9
  int max_half_window = 12;     // and at most 25x25
  double min_mask_share = 0.3;  // of the window's pixels inside the mask
  int min_pixels = 30;
  double min_stddev = 2.0;  // grey levels over the masked left pixels (texture)
  double min_ncc = 0.7;
  // Gauss–Newton refinement of the sub-pixel disparity (with gain and
  // offset) after the correlation peak; 0: parabola only.
  int gauss_newton_iterations = 5;
  // The rig's disparity correction (SlamOptions::disparity_offset_px): the
  // initial disparity and the result are corrected ones, the search runs on
  // the images as they are.
  double disparity_offset_px = 0.0;
};

// Disparity (level-0 pixels, u_left − u_right) at the pixel nearest to uv,
// from the masked window of half-size `half_window` (clamped to the
// options), searched within ±search_px of `initial_disparity`; nullopt when
// the window has too few mask pixels or too little texture, the best
// correlation is weak, or the best disparity lies on the search border.
// left, right: CV_8UC1 rectified images of the same size; mask: CV_8UC1,
// non-zero on the object.
std::optional<double> MaskedDisparity(const cv::Mat& left,
                                      const cv::Mat& right,
                                      const cv::Mat& mask,
                                      const Eigen::Vector2d& uv,
                                      double initial_disparity,
                                      double half_window,
                                      const MaskedStereoOptions& options = MaskedStereoOptions());

// Static keypoints beside dynamic segments (docs/objects.md §48). The stereo
// matcher's block of a keypoint just outside a car straddles the car, whose
// disparity pulls the keypoint's towards it, and the background right beside
// a car's edge may be hidden behind the car in the right image. Each keypoint
// outside `dynamic` (CV_8UC1, non-zero on dynamic segments) but within
// `margin_px` of it that has a stereo match (u_right >= 0) gets its disparity
// measured again by MaskedDisparity on the pixels outside `dynamic`, around
// its matched disparity, with the half window
// half_window_per_level[keypoint.octave]; one that cannot be measured so
// loses its match (u_right and depth -1). depth = bf / disparity.
// Returns the number of keypoints measured again (kept or not).
int RemeasureBesideMask(const cv::Mat& left,
                        const cv::Mat& right,
                        const cv::Mat& dynamic,
                        int margin_px,
                        const std::vector<cv::KeyPoint>& keypoints,
                        const std::vector<double>& half_window_per_level,
                        double bf,
                        std::vector<float>* u_right,
                        std::vector<float>* depth,
                        const MaskedStereoOptions& options = MaskedStereoOptions());

}  // namespace twist::objects
