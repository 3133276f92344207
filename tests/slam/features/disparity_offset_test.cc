// The rig's disparity offset (slam/features/disparity_offset.h): the right
// image shift that simulates it (sim::ShiftRightImage), the matcher's correction, and
// the calibration from known motion on rendered frames whose rig is given a
// known offset (exact ground truth: the renderer's rig has none).
#include "slam/features/disparity_offset.h"

#include <gtest/gtest.h>

#include <cmath>
#include <cstdio>
#include <vector>

#include "slam/features/orb_extractor.h"
#include "slam/features/stereo_matcher.h"
#include "slam/sim/depth_truth.h"
#include "slam/sim/renderer.h"
#include "slam/sim/scenarios.h"

namespace twist::features {
namespace {

// Band-limited texture sampled at continuous x.
double Wave(double x, double y) {
  return 128.0 + 50.0 * std::sin(0.31 * x + 0.2 * y) + 30.0 * std::sin(0.13 * x - 0.4 * y + 1.0);
}

cv::Mat WaveImage(double shift) {
  cv::Mat m(40, 120, CV_8UC1);
  for (int y = 0; y < m.rows; ++y)
    for (int x = 0; x < m.cols; ++x)
      m.at<uint8_t>(y, x) = cv::saturate_cast<uint8_t>(Wave(x + shift, y));
  return m;
}

TEST(ShiftRightImage, MovesTheContentLeftByTheOffset) {
  const cv::Mat image = WaveImage(0.0);
  // Zero: the image itself.
  EXPECT_EQ(sim::ShiftRightImage(image, 0.0).data, image.data);
  for (double offset : {1.0, -2.0, 0.3, -0.45, 1.6}) {
    const cv::Mat shifted = sim::ShiftRightImage(image, offset);
    ASSERT_EQ(shifted.size(), image.size());
    ASSERT_EQ(shifted.type(), image.type());
    const cv::Mat expected = WaveImage(offset);
    double max_error = 0.0;
    for (int y = 0; y < image.rows; ++y)
      for (int x = 4; x < image.cols - 4; ++x)
        max_error = std::max(
            max_error, std::abs(double(shifted.at<uint8_t>(y, x)) - expected.at<uint8_t>(y, x)));
    // Cubic interpolation of a smooth texture: within 2 grey levels (exact
    // for whole pixels up to the 8-bit rounding).
    EXPECT_LE(max_error, std::round(offset) == offset ? 0.0 : 2.0) << offset;
  }
}

TEST(MatchStereo, AddsTheRigsDisparityOffset) {
  auto sc = sim::MakeScenario("static_street", 1, 1);
  ASSERT_TRUE(sc.ok());
  sim::RenderOptions ro;
  ro.gray = true;
  const sim::StereoRender r = sim::RenderScenarioFrame(sim::Renderer(sc->camera, ro), *sc, 0);
  const OrbExtractor orb(OrbOptions{});
  const StereoKeypoints plain = ExtractStereoKeypoints(orb, sc->camera, r.left, r.right);
  StereoMatchOptions o;
  o.disparity_offset_px = 0.37;
  const StereoKeypoints corrected = ExtractStereoKeypoints(orb, sc->camera, r.left, r.right, o);
  ASSERT_EQ(plain.u_right.size(), corrected.u_right.size());
  int both = 0;
  for (size_t i = 0; i < plain.u_right.size(); ++i) {
    if (plain.u_right[i] < 0.f || corrected.u_right[i] < 0.f) continue;
    ++both;
    EXPECT_NEAR(plain.u_right[i] - corrected.u_right[i], 0.37, 1e-4);
  }
  EXPECT_GT(both, 300);
}

// Rendered frames of a street (exact poses) and their stereo keypoints, the
// right images shifted by each of `rig_offsets` to give the rig a known
// offset: measured disparities that much too large (negative: too small, as
// KITTI's).
struct Views {
  geometry::StereoCamera camera;
  ScalePyramid pyramid;
  std::vector<geometry::SE3d> poses;
  std::vector<std::vector<StereoKeypoints>> views;  // per rig offset, per frame
};

Views RenderViews(const std::vector<double>& rig_offsets, int frames) {
  auto sc = sim::MakeScenario("static_street", 2, frames);
  EXPECT_TRUE(sc.ok());
  sim::RenderOptions ro;
  ro.gray = true;
  const sim::Renderer renderer(sc->camera, ro);
  const OrbExtractor orb(OrbOptions{});
  Views v;
  v.camera = sc->camera;
  v.pyramid = orb.pyramid();
  v.views.resize(rig_offsets.size());
  for (int f = 0; f < frames; ++f) {
    const sim::StereoRender r = sim::RenderScenarioFrame(renderer, *sc, f);
    for (size_t k = 0; k < rig_offsets.size(); ++k) {
      v.views[k].push_back(ExtractStereoKeypoints(
          orb, sc->camera, r.left, sim::ShiftRightImage(r.right, rig_offsets[k])));
    }
    v.poses.push_back(sc->WorldFromCamera(f));
  }
  return v;
}

// The offset a shifted right image gives the matcher's disparities: the
// mean change of every keypoint matched in both (the SAD parabola follows a
// sub-pixel shift to ~90 %: pixel locking).
double MatcherResponse(const std::vector<StereoKeypoints>& plain,
                       const std::vector<StereoKeypoints>& shifted) {
  double sum = 0.0;
  int n = 0;
  for (size_t f = 0; f < plain.size(); ++f) {
    for (size_t i = 0; i < plain[f].u_right.size(); ++i) {
      if (plain[f].u_right[i] < 0.f || shifted[f].u_right[i] < 0.f) continue;
      const double change = plain[f].u_right[i] - shifted[f].u_right[i];
      if (std::abs(change) > 1.5) continue;  // another match
      sum += change;
      ++n;
    }
  }
  return n > 0 ? sum / n : 0.0;
}

TEST(DisparityOffset, CalibratedFromKnownMotion) {
  const std::vector<double> rigs = {0.0, -0.25, 0.25};
  const Views v = RenderViews(rigs, 24);
  for (size_t k = 0; k < rigs.size(); ++k) {
    const DisparityCalibration c =
        CalibrateDisparityOffset(v.camera, v.pyramid, v.views[k], v.poses);
    const DisparityPairStats& stats = c.stats;
    const DisparityOffsetFit& fit = c.fit;
    const double response = k == 0 ? 0.0 : MatcherResponse(v.views[0], v.views[k]);
    std::printf(
        "  rig offset %+.2f px (matcher %+.3f): %d pairs of %d, estimate %+.3f px (+- %.3f), %d "
        "rounds\n",
        rigs[k],
        response,
        fit.num_pairs,
        stats.matched,
        fit.offset_px,
        fit.standard_error_px,
        c.iterations);
    ASSERT_TRUE(fit.ok);
    EXPECT_GT(fit.num_pairs, 10000);
    // The correction undoes what the matcher sees of the rig's offset; the
    // renderer's own rig reads -0.003 px over 100 frames (docs/math.md §21).
    EXPECT_NEAR(fit.offset_px, -response, 0.03) << rigs[k];
    EXPECT_LT(fit.standard_error_px, 0.05) << rigs[k];
    if (k > 0) {
      EXPECT_GT(std::abs(response), 0.8 * std::abs(rigs[k])) << rigs[k];
      EXPECT_LT(fit.cost, fit.cost_at_zero) << rigs[k];
    }
  }
}

TEST(DisparityOffset, WrongMotionIsRejectedAndTooFewPairsDoNotFit) {
  const Views v = RenderViews({0.0}, 4);
  const std::vector<StereoKeypoints>& views = v.views[0];
  // Poses of a camera that did not move: most pairs fail the motion check
  // (the distant ones barely move in the image).
  std::vector<geometry::SE3d> still(v.poses.size(), geometry::SE3d());
  DisparityPairStats stats;
  const std::vector<DisparityPair> pairs =
      CollectDisparityPairs(v.camera, v.pyramid, views, still, DisparityPairOptions(), &stats);
  EXPECT_GT(stats.matched, 500);
  EXPECT_LT(pairs.size(), stats.matched / 2u);
  // Fewer poses than views: only the views with a pose take part; none, none.
  EXPECT_TRUE(
      CollectDisparityPairs(v.camera, v.pyramid, views, {}, DisparityPairOptions()).empty());
  // No pairs, or fewer than 40: no fit.
  EXPECT_FALSE(FitDisparityOffset(v.camera, std::vector<DisparityPair>()).ok);
  const std::vector<DisparityPair> good =
      CollectDisparityPairs(v.camera, v.pyramid, views, v.poses, DisparityPairOptions());
  ASSERT_GT(good.size(), 40u);
  const DisparityOffsetFit few =
      FitDisparityOffset(v.camera, std::vector<DisparityPair>(good.begin(), good.begin() + 39));
  EXPECT_FALSE(few.ok);
  EXPECT_EQ(few.num_pairs, 39);
}

}  // namespace
}  // namespace twist::features
