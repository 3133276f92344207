#include <gtest/gtest.h>

#include <cmath>
#include <opencv2/imgproc.hpp>
#include <random>

#include "slam/features/feature_matcher.h"
#include "slam/features/orb_extractor.h"
#include "slam/features/stereo_matcher.h"

namespace twist::features {
namespace {

// Blurred random blobs: a corner-rich texture with exact control of the seed.
cv::Mat TexturedImage(int width, int height, uint32_t seed) {
  cv::Mat img(height, width, CV_8UC1, cv::Scalar(128));
  std::mt19937 rng(seed);
  std::uniform_int_distribution<int> ux(0, width - 1), uy(0, height - 1), ur(2, 9), uc(0, 255);
  for (int i = 0; i < width * height / 60; ++i) {
    const cv::Point c(ux(rng), uy(rng));
    const int r = ur(rng);
    if (i % 2 == 0) {
      cv::circle(img, c, r, cv::Scalar(uc(rng)), cv::FILLED, cv::LINE_AA);
    } else {
      cv::rectangle(img, c, c + cv::Point(r, r + 2), cv::Scalar(uc(rng)), cv::FILLED);
    }
  }
  cv::GaussianBlur(img, img, cv::Size(3, 3), 0.8);
  return img;
}

geometry::StereoCamera TestCamera(int w, int h) {
  geometry::StereoCamera cam;
  cam.fx = cam.fy = 700.0;
  cam.cx = w / 2.0;
  cam.cy = h / 2.0;
  cam.baseline = 0.5;
  cam.width = w;
  cam.height = h;
  return cam;
}

TEST(OrbExtractor, RespectsBudgetAndSpreadsOverTheImage) {
  const cv::Mat img = TexturedImage(640, 360, 1);
  OrbOptions opt;
  opt.num_features = 1000;
  OrbExtractor orb(opt);
  std::vector<cv::KeyPoint> kps;
  cv::Mat desc;
  orb.Extract(img, cv::Mat(), &kps, &desc);
  ASSERT_EQ(desc.rows, static_cast<int>(kps.size()));
  EXPECT_LE(static_cast<int>(kps.size()), 1000);
  EXPECT_GE(static_cast<int>(kps.size()), 800);
  // Every 4x3 block of the image gets a share.
  int counts[12] = {0};
  int max_level = 0;
  for (const auto& kp : kps) {
    counts[std::min(3, static_cast<int>(kp.pt.x / 160)) +
           4 * std::min(2, static_cast<int>(kp.pt.y / 120))]++;
    max_level = std::max(max_level, kp.octave);
  }
  for (int c : counts) EXPECT_GT(c, 25);
  EXPECT_GE(max_level, 5);
}

TEST(OrbExtractor, DeterministicAndMaskExcludes) {
  const cv::Mat img = TexturedImage(640, 360, 2);
  OrbExtractor orb(OrbOptions{});
  std::vector<cv::KeyPoint> a, b;
  cv::Mat da, db;
  orb.Extract(img, cv::Mat(), &a, &da);
  OrbExtractor orb2(OrbOptions{});
  orb2.Extract(img, cv::Mat(), &b, &db);
  ASSERT_EQ(a.size(), b.size());
  EXPECT_EQ(cv::norm(da, db, cv::NORM_HAMMING), 0.0);

  cv::Mat mask(img.size(), CV_8UC1, cv::Scalar(255));
  mask(cv::Rect(0, 0, 320, 360)).setTo(0);
  std::vector<cv::KeyPoint> m;
  cv::Mat dm;
  orb.Extract(img, mask, &m, &dm);
  ASSERT_GT(m.size(), 200u);
  for (const auto& kp : m) EXPECT_GE(kp.pt.x, 319.0f);
}

// A favoured region's corners come on top of the budget: the rest of the
// image gets exactly the keypoints it gets with the region excluded.
TEST(OrbExtractor, FavouredRegionIsExtraToTheBudget) {
  const cv::Mat img = TexturedImage(640, 360, 4);
  OrbOptions opt;
  opt.num_features = 1000;
  opt.favoured_on_top = true;
  OrbExtractor orb(opt);
  const cv::Rect region(200, 100, 240, 160);
  cv::Mat excluded(img.size(), CV_8UC1, cv::Scalar(1)),
      favoured(img.size(), CV_8UC1, cv::Scalar(1));
  excluded(region).setTo(0);
  favoured(region).setTo(200);
  std::vector<cv::KeyPoint> plain, without, with;
  cv::Mat dp, dw, df;
  orb.Extract(img, cv::Mat(), &plain, &dp);
  orb.Extract(img, excluded, &without, &dw);
  orb.Extract(img, favoured, &with, &df);
  ASSERT_EQ(df.rows, static_cast<int>(with.size()));
  EXPECT_LE(static_cast<int>(plain.size()), 1000);
  EXPECT_GE(static_cast<int>(without.size()), 900);  // the budget, outside the region
  // Every keypoint found with the region excluded is found with it favoured,
  // at the same place and level, with the same descriptor.
  int outside = 0;
  for (size_t i = 0; i < without.size(); ++i) {
    bool found = false;
    for (size_t j = 0; j < with.size() && !found; ++j) {
      if (with[j].octave == without[i].octave && with[j].pt == without[i].pt) {
        found =
            cv::norm(dw.row(static_cast<int>(i)), df.row(static_cast<int>(j)), cv::NORM_HAMMING) ==
            0;
      }
    }
    EXPECT_TRUE(found) << i;
    ++outside;
  }
  // The others are the region's (within a level's rounding of its border).
  const cv::Rect grown(region.x - 4, region.y - 4, region.width + 8, region.height + 8);
  const int inside = static_cast<int>(with.size()) - outside;
  EXPECT_GE(inside, 100);
  int in_region = 0;
  for (const cv::KeyPoint& kp : with) in_region += grown.contains(kp.pt) ? 1 : 0;
  EXPECT_GE(in_region, inside);
  EXPECT_GT(static_cast<int>(with.size()), 1000);  // over the budget
  // The keypoints the spread over all corners would not have kept are marked
  // (the camera's extra ones, all outside the region); the others are within
  // the budget.
  const cv::Rect shrunk(region.x + 4, region.y + 4, region.width - 8, region.height - 8);
  int extra = 0;
  for (const cv::KeyPoint& kp : with) {
    if (kp.class_id != OrbExtractor::kExtraKeypoint) continue;
    ++extra;
    EXPECT_FALSE(shrunk.contains(kp.pt)) << kp.pt;  // (a level's rounding at the border)
  }
  EXPECT_GT(extra, 50);
  EXPECT_LE(static_cast<int>(with.size()) - extra, 1000 + opt.num_levels);
  for (const cv::KeyPoint& kp : without) EXPECT_TRUE(kp.class_id == -1 || kp.class_id == 1);
  for (const cv::KeyPoint& kp : plain) EXPECT_EQ(kp.class_id, -1);
  // Without the option the region's corners take part of the budget.
  opt.favoured_on_top = false;
  std::vector<cv::KeyPoint> shared;
  cv::Mat ds;
  OrbExtractor(opt).Extract(img, favoured, &shared, &ds);
  EXPECT_LE(static_cast<int>(shared.size()), 1000);
  for (const cv::KeyPoint& kp : shared) EXPECT_EQ(kp.class_id, -1);
}

TEST(OrbExtractor, BudgetScaleMultipliesTheFeatures) {
  const cv::Mat img = TexturedImage(640, 360, 5);
  OrbOptions opt;
  opt.num_features = 800;
  OrbExtractor orb(opt);
  std::vector<cv::KeyPoint> one, more;
  cv::Mat d1, d2;
  orb.Extract(img, cv::Mat(), &one, &d1);
  orb.Extract(img, cv::Mat(), &more, &d2, nullptr, 1.5);
  EXPECT_LE(static_cast<int>(one.size()), 800);
  EXPECT_GE(static_cast<int>(one.size()), 700);
  EXPECT_LE(static_cast<int>(more.size()), 1200 + opt.num_levels);
  EXPECT_GE(static_cast<int>(more.size()), 1050);
}

TEST(OrbExtractor, DescriptorsAreRotationInvariant) {
  const cv::Mat img = TexturedImage(480, 480, 3);
  cv::Mat rotated;
  cv::rotate(img, rotated, cv::ROTATE_90_CLOCKWISE);
  OrbOptions opt;
  opt.num_features = 800;
  OrbExtractor orb(opt);
  std::vector<cv::KeyPoint> ka, kb;
  cv::Mat da, db;
  orb.Extract(img, cv::Mat(), &ka, &da);
  orb.Extract(rotated, cv::Mat(), &kb, &db);
  auto matches = MatchRatio(da, db, 0.8f, kThresholdLow);
  ASSERT_GT(matches.size(), 100u);
  OrientationFilter filter;
  for (size_t i = 0; i < matches.size(); ++i) {
    filter.Add(ka[matches[i].first].angle, kb[matches[i].second].angle, static_cast<int>(i));
  }
  const auto rejected = filter.Rejected();
  std::vector<char> bad(matches.size(), 0);
  for (int r : rejected) bad[r] = 1;
  int good = 0, kept = 0;
  for (size_t i = 0; i < matches.size(); ++i) {
    if (bad[i]) continue;
    ++kept;
    // (x, y) -> (H - 1 - y, x) for a clockwise rotation.
    const cv::Point2f p = ka[matches[i].first].pt;
    const cv::Point2f expected(img.rows - 1 - p.y, p.x);
    if (cv::norm(expected - kb[matches[i].second].pt) < 3.0 * (1 << ka[matches[i].first].octave))
      ++good;
  }
  EXPECT_GT(kept, 100);
  EXPECT_GT(good, 0.9 * kept);
}

TEST(StereoMatcher, RecoversDepthOfAPlaneWithSubpixelAccuracy) {
  const int w = 800, h = 300;
  const cv::Mat left = TexturedImage(w, h, 4);
  const geometry::StereoCamera cam = TestCamera(w, h);
  const double disparity = 23.37;  // fronto-parallel plane
  const double depth = cam.bf() / disparity;
  cv::Mat right;
  const cv::Mat shift = (cv::Mat_<double>(2, 3) << 1, 0, -disparity, 0, 1, 0);
  cv::warpAffine(left, right, shift, left.size(), cv::INTER_CUBIC, cv::BORDER_REFLECT);

  OrbExtractor orb(OrbOptions{});
  std::vector<cv::KeyPoint> kl, kr;
  cv::Mat dl, dr;
  std::vector<cv::Mat> ll, lr;
  orb.Extract(left, cv::Mat(), &kl, &dl, &ll);
  orb.Extract(right, cv::Mat(), &kr, &dr, &lr);
  const StereoMatchResult res = MatchStereo(cam, orb.pyramid(), kl, dl, kr, dr, ll, lr);
  ASSERT_GT(res.num_matches, 0.5 * kl.size());
  std::vector<double> errs;
  for (size_t i = 0; i < kl.size(); ++i) {
    if (res.depth[i] <= 0) continue;
    if (kl[i].pt.x < disparity + 20) continue;  // no valid right pixel there
    // Disparity error in level pixels (the refinement works on the level).
    const double disparity_error = (kl[i].pt.x - res.u_right[i]) - disparity;
    errs.push_back(std::abs(disparity_error) / orb.pyramid().scale[kl[i].octave]);
    EXPECT_NEAR(res.depth[i], cam.bf() / (kl[i].pt.x - res.u_right[i]), 1e-3 * depth);
  }
  ASSERT_GT(errs.size(), 100u);
  std::sort(errs.begin(), errs.end());
  const double median = errs[errs.size() / 2];
  const double p90 = errs[errs.size() * 9 / 10];
  // Sub-pixel: SAD + parabola on this sharp-edged texture has some pixel
  // locking (about 0.15 px mean error at level 0); integer matching would give
  // errors up to 0.5 px.
  EXPECT_LT(median, 0.25);
  EXPECT_LT(p90, 0.45);
}

// The SAD median that rejects poor block matches is that of the keypoints
// within the budget: extra keypoints (OrbExtractor::kExtraKeypoint) on a
// noisier part of the image leave the others' matches exactly as they are;
// counted in the median, they would change them.
TEST(StereoMatcher, ExtraKeypointsDoNotMoveTheRejectionThreshold) {
  const int w = 800, h = 300;
  const cv::Mat left = TexturedImage(w, h, 6);
  const geometry::StereoCamera cam = TestCamera(w, h);
  const double disparity = 17.6;
  cv::Mat right;
  const cv::Mat shift = (cv::Mat_<double>(2, 3) << 1, 0, -disparity, 0, 1, 0);
  cv::warpAffine(left, right, shift, left.size(), cv::INTER_CUBIC, cv::BORDER_REFLECT);
  // The right half of the right image is noisy: high SADs there.
  cv::Mat noise(h, w / 2, CV_8SC1);
  cv::randn(noise, 0, 12);
  cv::Mat half = right(cv::Rect(w / 2, 0, w / 2, h));
  cv::Mat noisy;
  half.convertTo(noisy, CV_16S);
  cv::Mat noise16;
  noise.convertTo(noise16, CV_16S);
  noisy += noise16;
  noisy.convertTo(half, CV_8U);

  OrbExtractor orb(OrbOptions{});
  std::vector<cv::KeyPoint> kl, kr;
  cv::Mat dl, dr;
  std::vector<cv::Mat> ll, lr;
  orb.Extract(left, cv::Mat(), &kl, &dl, &ll);
  orb.Extract(right, cv::Mat(), &kr, &dr, &lr);
  // Budget: the left half; extra: the right half.
  std::vector<cv::KeyPoint> budget, all = kl;
  cv::Mat budget_desc;
  for (size_t i = 0; i < kl.size(); ++i) {
    if (kl[i].pt.x >= w / 2 - 30) {
      all[i].class_id = OrbExtractor::kExtraKeypoint;
    } else {
      budget.push_back(kl[i]);
      budget_desc.push_back(dl.row(static_cast<int>(i)));
    }
  }
  ASSERT_GT(budget.size(), 200u);
  ASSERT_GT(all.size(), budget.size() + 200u);
  const StereoMatchResult alone =
      MatchStereo(cam, orb.pyramid(), budget, budget_desc, kr, dr, ll, lr);
  const StereoMatchResult marked = MatchStereo(cam, orb.pyramid(), all, dl, kr, dr, ll, lr);
  const StereoMatchResult unmarked = MatchStereo(cam, orb.pyramid(), kl, dl, kr, dr, ll, lr);
  int differ_unmarked = 0;
  for (size_t i = 0, j = 0; i < kl.size(); ++i) {
    if (all[i].class_id == OrbExtractor::kExtraKeypoint) continue;
    EXPECT_EQ(marked.u_right[i], alone.u_right[j]) << i;
    EXPECT_EQ(marked.depth[i], alone.depth[j]) << i;
    differ_unmarked += unmarked.u_right[i] != alone.u_right[j] ? 1 : 0;
    ++j;
  }
  EXPECT_GT(differ_unmarked, 0);  // the noisy half moves the median when counted
}

TEST(KeypointGrid, FindsOnlyPointsInTheWindow) {
  std::vector<cv::KeyPoint> kps;
  std::mt19937 rng(5);
  std::uniform_real_distribution<float> ux(0, 640), uy(0, 480);
  for (int i = 0; i < 2000; ++i) kps.emplace_back(ux(rng), uy(rng), 31.f, -1, 0, i % 4);
  KeypointGrid grid(kps, 640, 480);
  const auto found = grid.FeaturesInArea(kps, 300, 200, 25, 1, 2);
  int expected = 0;
  for (const auto& kp : kps) {
    if (std::fabs(kp.pt.x - 300) < 25 && std::fabs(kp.pt.y - 200) < 25 && kp.octave >= 1 &&
        kp.octave <= 2) {
      ++expected;
    }
  }
  EXPECT_EQ(static_cast<int>(found.size()), expected);
  EXPECT_GT(expected, 0);
}

}  // namespace
}  // namespace twist::features
