// Refinement of an object's matches by projecting its map points with the
// estimated twist (paper §IV-E, "as ORB-SLAM2 does"): every point without a
// match is projected into the current frame and matched to a keypoint within a
// radius by descriptor distance, or, for points that keep an image patch, by a
// normalised cross-correlation search around the projection.
#pragma once

#include <Eigen/Core>
#include <opencv2/core.hpp>
#include <optional>
#include <vector>

#include "slam/geometry/se3.h"
#include "slam/geometry/stereo_camera.h"

namespace twist::objects {

// Keypoints of the current left image (plain data, from the feature module).
struct FrameKeypoints {
  std::vector<Eigen::Vector2d> uv;
  std::vector<double> u_right;  // per keypoint, < 0 when no stereo match
  cv::Mat descriptors;          // one CV_8U row per keypoint (ORB: 32 bytes)
  // Optional, per keypoint: half-size (level-0 pixels) of the image window
  // its stereo depth was measured from, i.e. the matcher's block on the
  // keypoint's pyramid level (StereoMatchOptions::sad_half_window + 0.5,
  // times the level's scale); the object tracker re-measures object depths
  // with a masked window of that size (masked_stereo.h). Empty: unknown.
  std::vector<double> stereo_support_px;
};

struct ProjectionSearchOptions {
  double radius_px = 8.0;
  int max_hamming = 60;     // ORB descriptor distance of a match
  double ratio = 0.9;       // best / second-best distance (same radius)
  int patch_half_size = 4;  // (2h+1)² patch for the NCC check
  double min_ncc = 0.85;
  double patch_search_radius_px = 4.0;
  // Masked patches (MaskedPatchSearch): the least share of the patch's
  // pixels that must be on the object in both views for an offset to count.
  double min_masked_patch_share = 0.5;
  // Gauss–Newton refinement of a masked match's sub-pixel position (with
  // gain and offset) after the parabola; 0: the parabola only (default: on
  // the rendered scenes' objects the refinement turned them worse,
  // docs/objects.md §44).
  int patch_gauss_newton_iterations = 0;
};

// Hamming distance of two CV_8U descriptor rows.
int HammingDistance(const cv::Mat& a, const cv::Mat& b);

// For each point (object frame) with a descriptor row in `descriptors` (may
// be empty for points without one) and `skip[k] == false`, the index of the
// best keypoint within radius of its projection, or -1. Each keypoint is used
// at most once (the closer descriptor wins).
std::vector<int> SearchByProjection(const geometry::StereoCamera& camera,
                                    const geometry::SE3d& camera_from_object,
                                    const std::vector<Eigen::Vector3d>& points_in_object,
                                    const std::vector<cv::Mat>& descriptors,
                                    const std::vector<bool>& skip,
                                    const FrameKeypoints& keypoints,
                                    const ProjectionSearchOptions& options);

// Extracts a (2h+1)² CV_32F patch centred on uv (bilinear); empty when it
// does not fit in the image. `image` is 8-bit gray.
cv::Mat ExtractPatch(const cv::Mat& image, const Eigen::Vector2d& uv, int half_size);

// ExtractPatch restricted to an object: the pixels whose bilinear sample
// reads a pixel off `mask` (CV_8UC1, non-zero on the object) are NaN, for
// MaskedPatchSearch. When fewer than max(4, min_share × the patch's pixels)
// are on the mask, the patch stays whole (no NaN). Empty like ExtractPatch.
cv::Mat ExtractMaskedPatch(const cv::Mat& image,
                           const cv::Mat& mask,
                           const Eigen::Vector2d& uv,
                           int half_size,
                           double min_share);

// Zero-mean normalised cross-correlation of two same-size CV_32F patches.
double Ncc(const cv::Mat& a, const cv::Mat& b);

// Sub-pixel offset of the peak (cx, cy) of a CV_64F score grid: a parabola
// through its neighbours along each axis, within ±0.5; 0 along an axis where
// the peak is on the grid's edge or a neighbour is unscored (< -1.5).
Eigen::Vector2d ParabolaPeakOffset(const cv::Mat& scores, int cx, int cy);

// Searches the integer offsets within patch_search_radius_px of `predicted`
// for the best NCC with `patch`, then refines to sub-pixel with a parabola
// fit. nullopt when the best NCC is below min_ncc.
std::optional<Eigen::Vector2d> PatchSearch(const cv::Mat& image,
                                           const cv::Mat& patch,
                                           const Eigen::Vector2d& predicted,
                                           const ProjectionSearchOptions& options);

// PatchSearch restricted to the object: reference pixels that are NaN (off
// the object when the patch was taken, ExtractMaskedPatch) and current
// pixels outside `mask` (CV_8UC1, non-zero on the object; empty: no
// restriction) take no part in an offset's correlation; an offset with
// fewer than options.min_masked_patch_share of the patch's pixels left is
// not scored. With options.patch_gauss_newton_iterations > 0 the
// parabola's vertex is refined by Gauss–Newton on the shift, gain and
// offset over the peak's pixels, kept when it stays within 1 px of it.
std::optional<Eigen::Vector2d> MaskedPatchSearch(const cv::Mat& image,
                                                 const cv::Mat& patch,
                                                 const cv::Mat& mask,
                                                 const Eigen::Vector2d& predicted,
                                                 const ProjectionSearchOptions& options);

}  // namespace twist::objects
