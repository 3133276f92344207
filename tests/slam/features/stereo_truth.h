// Stereo matches of a rendered frame next to their exact disparities: ORB on
// both images, MatchStereo, and for every matched left keypoint whose
// block-matching window (at its level, plus one pixel) lies on one plane the
// true disparity there (sim::PlanarDisparity). Shared by stereo_bias_test
// and bench/engine/disparity_bias.
#pragma once

#include <cmath>
#include <vector>

#include "slam/features/orb_extractor.h"
#include "slam/features/stereo_matcher.h"
#include "slam/sim/depth_truth.h"

namespace twist::features::testing {

struct StereoTruth {
  int keypoint = 0;        // index into the left keypoints
  int level = 0;           // pyramid level of the keypoint
  double estimated = 0.0;  // matched disparity (level-0 px)
  sim::PlanarDisparityFit truth;
};

inline std::vector<StereoTruth> MatchAgainstTruth(const sim::StereoRender& render,
                                                  const geometry::StereoCamera& camera,
                                                  const OrbExtractor& orb,
                                                  const StereoMatchOptions& options,
                                                  std::vector<cv::KeyPoint>* left_keypoints) {
  std::vector<cv::KeyPoint> kl, kr;
  cv::Mat dl, dr;
  std::vector<cv::Mat> ll, lr;
  orb.Extract(render.left, cv::Mat(), &kl, &dl, &ll);
  orb.Extract(render.right, cv::Mat(), &kr, &dr, &lr);
  const StereoMatchResult st = MatchStereo(camera, orb.pyramid(), kl, dl, kr, dr, ll, lr, options);
  std::vector<StereoTruth> out;
  for (size_t q = 0; q < kl.size(); ++q) {
    if (st.depth[q] <= 0.f) continue;
    const int level = kl[q].octave;
    const double s = orb.pyramid().scale[level];
    const int radius = static_cast<int>(std::ceil((options.sad_half_window + 1) * s));
    const auto truth =
        sim::PlanarDisparity(render.depth, camera.bf(), kl[q].pt.x, kl[q].pt.y, radius);
    if (!truth) continue;
    out.push_back({static_cast<int>(q), level, kl[q].pt.x - st.u_right[q], *truth});
  }
  if (left_keypoints != nullptr) *left_keypoints = std::move(kl);
  return out;
}

}  // namespace twist::features::testing
