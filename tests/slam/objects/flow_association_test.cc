#include "slam/objects/flow_association.h"

#include <gtest/gtest.h>

#include <algorithm>
#include <cmath>
#include <opencv2/imgproc.hpp>
#include <optional>
#include <random>

#include "slam/objects/projection_search.h"

namespace twist::objects {
namespace {

// A textured object (blurred random noise) on a flat background, and the same
// scene with the object translated by `shift` (sub-pixel, via warpAffine).
struct Rendered {
  cv::Mat prev, next;
  cv::Rect object;
};

Rendered RenderMovingPatch(const cv::Point2d& shift, uint64_t seed) {
  std::mt19937_64 rng(seed);
  std::uniform_int_distribution<int> u(0, 255);
  cv::Mat texture(120, 160, CV_8UC1);
  for (int y = 0; y < texture.rows; ++y) {
    for (int x = 0; x < texture.cols; ++x) texture.at<uint8_t>(y, x) = static_cast<uint8_t>(u(rng));
  }
  cv::GaussianBlur(texture, texture, cv::Size(0, 0), 1.5);
  cv::normalize(texture, texture, 20, 235, cv::NORM_MINMAX);
  Rendered r;
  r.object = cv::Rect(100, 80, 160, 120);
  r.prev = cv::Mat(300, 400, CV_8UC1, cv::Scalar(128));
  texture.copyTo(r.prev(r.object));
  // Object mask and its warped version so that only the object moves.
  cv::Mat moved;
  const cv::Mat m = (cv::Mat_<double>(2, 3) << 1, 0, shift.x, 0, 1, shift.y);
  cv::warpAffine(
      r.prev, moved, m, r.prev.size(), cv::INTER_CUBIC, cv::BORDER_CONSTANT, cv::Scalar(128));
  cv::Mat mask(r.prev.size(), CV_8UC1, cv::Scalar(0));
  mask(r.object).setTo(255);
  cv::Mat moved_mask;
  cv::warpAffine(mask, moved_mask, m, mask.size(), cv::INTER_NEAREST);
  r.next = cv::Mat(r.prev.size(), CV_8UC1, cv::Scalar(128));
  moved.copyTo(r.next, moved_mask);
  return r;
}

std::vector<Eigen::Vector2d> InteriorGrid(const cv::Rect& box, int margin, int step) {
  std::vector<Eigen::Vector2d> pts;
  for (int y = box.y + margin; y < box.y + box.height - margin; y += step) {
    for (int x = box.x + margin; x < box.x + box.width - margin; x += step)
      pts.emplace_back(x + 0.3, y + 0.6);
  }
  return pts;
}

TEST(FlowAssociation, SparseLucasKanadeRecoversKnownShift) {
  const cv::Point2d shift(6.4, -3.7);
  const Rendered r = RenderMovingPatch(shift, 1);
  const auto pts = InteriorGrid(r.object, 15, 10);
  const auto tracked = TrackSparseFlow(r.prev, r.next, pts, SparseFlowOptions{});
  ASSERT_TRUE(tracked.ok()) << tracked.status();
  int ok = 0;
  double max_err = 0.0;
  for (size_t k = 0; k < pts.size(); ++k) {
    if (!(*tracked)[k]) continue;
    ++ok;
    max_err =
        std::max(max_err, ((*(*tracked)[k] - pts[k]) - Eigen::Vector2d(shift.x, shift.y)).norm());
  }
  EXPECT_GE(ok, static_cast<int>(0.95 * pts.size()));
  EXPECT_LT(max_err, 0.1);
  // A prediction close to the answer gives the same result.
  std::vector<Eigen::Vector2d> predicted;
  for (const auto& p : pts) predicted.push_back(p + Eigen::Vector2d(6.0, -3.0));
  const auto seeded = TrackSparseFlow(r.prev, r.next, pts, SparseFlowOptions{}, &predicted);
  ASSERT_TRUE(seeded.ok());
  ASSERT_TRUE((*seeded)[0].has_value());
  EXPECT_LT(((*(*seeded)[0] - pts[0]) - Eigen::Vector2d(shift.x, shift.y)).norm(), 0.1);
}

TEST(FlowAssociation, SparseFlowDropsPointsOnTheUntexturedBackground) {
  const Rendered r = RenderMovingPatch({5.0, 2.0}, 2);
  const std::vector<Eigen::Vector2d> flat = {{30.0, 30.0}, {350.0, 250.0}};
  const auto tracked = TrackSparseFlow(r.prev, r.next, flat, SparseFlowOptions{});
  ASSERT_TRUE(tracked.ok());
  for (const auto& t : *tracked) EXPECT_FALSE(t.has_value());  // no texture, no track
  EXPECT_FALSE(TrackSparseFlow(r.prev, cv::Mat(), flat, SparseFlowOptions{}).ok());
}

TEST(FlowAssociation, DenseFieldFromClientIsSampledBilinearly) {
  cv::Mat flow(50, 60, CV_32FC2);
  for (int y = 0; y < flow.rows; ++y) {
    for (int x = 0; x < flow.cols; ++x) flow.at<cv::Vec2f>(y, x) = cv::Vec2f(0.1f * x, -0.05f * y);
  }
  const auto tracked = TrackDenseFlow(flow, {{10.5, 20.25}, {59.5, 3.0}, {-1.0, 2.0}});
  ASSERT_TRUE(tracked.ok());
  ASSERT_TRUE((*tracked)[0].has_value());
  EXPECT_NEAR((*tracked)[0]->x(), 10.5 + 1.05, 1e-5);
  EXPECT_NEAR((*tracked)[0]->y(), 20.25 - 1.0125, 1e-5);
  EXPECT_FALSE((*tracked)[1].has_value());  // lands outside the image
  EXPECT_FALSE((*tracked)[2].has_value());
  EXPECT_FALSE(TrackDenseFlow(cv::Mat(5, 5, CV_32FC1), {}).ok());
}

TEST(FlowAssociation, FarnebackDenseFlowOnTheRenderedPatch) {
  const cv::Point2d shift(3.0, 1.5);
  const Rendered r = RenderMovingPatch(shift, 3);
  const auto flow = ComputeDenseFlow(r.prev, r.next);
  ASSERT_TRUE(flow.ok());
  const auto pts = InteriorGrid(r.object, 25, 20);
  const auto tracked = TrackDenseFlow(*flow, pts);
  ASSERT_TRUE(tracked.ok());
  double sum = 0.0;
  int n = 0;
  for (size_t k = 0; k < pts.size(); ++k) {
    ASSERT_TRUE((*tracked)[k].has_value());
    sum += ((*(*tracked)[k] - pts[k]) - Eigen::Vector2d(shift.x, shift.y)).norm();
    ++n;
  }
  EXPECT_LT(sum / n, 0.3);
}

TEST(ProjectionSearch, PatchSearchFindsTheShiftedPatch) {
  const cv::Point2d shift(2.3, -1.6);
  const Rendered r = RenderMovingPatch(shift, 4);
  ProjectionSearchOptions options;
  const Eigen::Vector2d p(170.0, 140.0);
  const cv::Mat patch = ExtractPatch(r.prev, p, options.patch_half_size);
  ASSERT_FALSE(patch.empty());
  EXPECT_NEAR(Ncc(patch, patch), 1.0, 1e-6);
  const auto found = PatchSearch(r.next, patch, p + Eigen::Vector2d(2.0, -2.0), options);
  ASSERT_TRUE(found.has_value());
  EXPECT_LT((*found - (p + Eigen::Vector2d(shift.x, shift.y))).norm(), 0.35);
  // Nothing similar on the flat background.
  EXPECT_FALSE(PatchSearch(r.next, patch, Eigen::Vector2d(40, 40), options).has_value());
}

// A parabola's vertex from its samples; nothing along an axis whose
// neighbour is unscored or where the peak sits on the grid's edge.
TEST(ProjectionSearch, ParabolaPeakOffsetFindsTheVertex) {
  // f(x, y) = 1 - 0.1 (x - 2.3)² - 0.2 (y - 0.6)², peak sample (2, 1).
  cv::Mat scores(3, 5, CV_64F);
  for (int y = 0; y < 3; ++y) {
    for (int x = 0; x < 5; ++x)
      scores.at<double>(y, x) = 1.0 - 0.1 * (x - 2.3) * (x - 2.3) - 0.2 * (y - 0.6) * (y - 0.6);
  }
  const Eigen::Vector2d o = ParabolaPeakOffset(scores, 2, 1);
  EXPECT_NEAR(o.x(), 0.3, 1e-12);
  EXPECT_NEAR(o.y(), -0.4, 1e-12);
  EXPECT_EQ(ParabolaPeakOffset(scores, 2, 0).y(), 0.0);  // on the grid's edge
  scores.at<double>(2, 2) = -2.0;                        // an unscored neighbour
  EXPECT_EQ(ParabolaPeakOffset(scores, 2, 1).y(), 0.0);
  EXPECT_NEAR(ParabolaPeakOffset(scores, 2, 1).x(), 0.3, 1e-12);
}

// The search correlates one bilinear region instead of a patch per offset:
// its result is the brute-force search's (ExtractPatch and Ncc at every
// offset, the same sub-pixel peak), near the image border too, where some offsets'
// patches leave the image.
TEST(ProjectionSearch, PatchSearchIsTheBruteForceSearch) {
  const Rendered r = RenderMovingPatch(cv::Point2d(1.7, 2.2), 5);
  ProjectionSearchOptions options;
  const int h = options.patch_half_size;
  const int rad = static_cast<int>(std::ceil(options.patch_search_radius_px));
  auto brute_force = [&](const cv::Mat& image,
                         const cv::Mat& patch,
                         const Eigen::Vector2d& predicted) -> std::optional<Eigen::Vector2d> {
    const int w = 2 * rad + 1;
    cv::Mat scores(w, w, CV_64F, cv::Scalar(-2.0));
    double best = -2.0;
    int bx = 0, by = 0;
    for (int dy = -rad; dy <= rad; ++dy) {
      for (int dx = -rad; dx <= rad; ++dx) {
        if (dx * dx + dy * dy > options.patch_search_radius_px * options.patch_search_radius_px)
          continue;
        const cv::Mat q = ExtractPatch(image, predicted + Eigen::Vector2d(dx, dy), h);
        if (q.empty()) continue;
        const double v = Ncc(patch, q);
        scores.at<double>(dy + rad, dx + rad) = v;
        if (v > best) {
          best = v;
          bx = dx;
          by = dy;
        }
      }
    }
    if (best < options.min_ncc) return std::nullopt;
    return predicted + (Eigen::Vector2d(bx, by) + ParabolaPeakOffset(scores, bx + rad, by + rad));
  };
  std::mt19937_64 rng(11);
  std::uniform_real_distribution<double> jitter(-3.0, 3.0);
  int found = 0, compared = 0;
  for (int k = 0; k < 200; ++k) {
    const Eigen::Vector2d p(110.0 + 0.7 * k, 90.0 + 0.5 * k);
    const cv::Mat patch = ExtractPatch(r.prev, p, h);
    ASSERT_FALSE(patch.empty());
    const Eigen::Vector2d predicted = p + Eigen::Vector2d(1.7 + jitter(rng), 2.2 + jitter(rng));
    const auto fast = PatchSearch(r.next, patch, predicted, options);
    const auto slow = brute_force(r.next, patch, predicted);
    ASSERT_EQ(fast.has_value(), slow.has_value()) << k;
    ++compared;
    if (!fast) continue;
    ++found;
    EXPECT_NEAR(fast->x(), slow->x(), 1e-3) << k;
    EXPECT_NEAR(fast->y(), slow->y(), 1e-3) << k;
  }
  EXPECT_GT(found, compared / 2);
  // At the image border: offsets whose patch leaves the image are skipped.
  cv::Mat edge(60, 80, CV_8UC1);
  std::uniform_int_distribution<int> u(0, 255);
  for (int y = 0; y < edge.rows; ++y) {
    for (int x = 0; x < edge.cols; ++x) edge.at<uint8_t>(y, x) = static_cast<uint8_t>(u(rng));
  }
  cv::GaussianBlur(edge, edge, cv::Size(0, 0), 1.2);
  const Eigen::Vector2d corner(h + 1.4, h + 2.3);
  const cv::Mat patch = ExtractPatch(edge, corner, h);
  ASSERT_FALSE(patch.empty());
  const Eigen::Vector2d near_corner = corner + Eigen::Vector2d(0.6, -1.2);
  const auto at_border = PatchSearch(edge, patch, near_corner, options);
  const auto at_border_slow = brute_force(edge, patch, near_corner);
  ASSERT_TRUE(at_border.has_value() && at_border_slow.has_value());
  EXPECT_NEAR(at_border->x(), at_border_slow->x(), 1e-3);
  EXPECT_NEAR(at_border->y(), at_border_slow->y(), 1e-3);
  EXPECT_LT((*at_border - corner).norm(), 0.3);
}

// A textured object moved by `shift` over a textured background that stays
// where it is, with the object's mask in both frames.
struct RenderedOnTexture {
  cv::Mat prev, next, prev_mask, next_mask;
  cv::Rect object;
};

cv::Mat BlurredNoise(cv::Size size, uint64_t seed) {
  std::mt19937_64 rng(seed);
  std::uniform_int_distribution<int> u(0, 255);
  cv::Mat noise(size, CV_8UC1);
  for (int y = 0; y < noise.rows; ++y) {
    for (int x = 0; x < noise.cols; ++x) noise.at<uint8_t>(y, x) = static_cast<uint8_t>(u(rng));
  }
  cv::GaussianBlur(noise, noise, cv::Size(0, 0), 1.5);
  cv::normalize(noise, noise, 20, 235, cv::NORM_MINMAX);
  return noise;
}

RenderedOnTexture RenderObjectOnTexture(const cv::Point2d& shift, uint64_t seed) {
  RenderedOnTexture r;
  r.object = cv::Rect(100, 80, 160, 120);
  const cv::Mat background = BlurredNoise(cv::Size(400, 300), seed + 1000);
  cv::Mat layer(background.size(), CV_8UC1, cv::Scalar(0));
  BlurredNoise(r.object.size(), seed).copyTo(layer(r.object));
  r.prev_mask = cv::Mat(background.size(), CV_8UC1, cv::Scalar(0));
  r.prev_mask(r.object).setTo(255);
  r.prev = background.clone();
  layer.copyTo(r.prev, r.prev_mask);
  // The object's layer moved by the sub-pixel shift; its mask keeps the
  // pixels whose whole interpolation support lies on the object.
  const cv::Mat m = (cv::Mat_<double>(2, 3) << 1, 0, shift.x, 0, 1, shift.y);
  cv::Mat moved;
  cv::warpAffine(layer, moved, m, layer.size(), cv::INTER_LINEAR);
  cv::Mat support;
  cv::warpAffine(r.prev_mask, support, m, layer.size(), cv::INTER_LINEAR);
  r.next_mask = support == 255;
  r.next = background.clone();
  moved.copyTo(r.next, r.next_mask);
  return r;
}

// A reference patch that keeps only the pixels on the object (the others
// NaN), however few, as the object tracker takes it with masked patches.
cv::Mat MaskedPatch(const cv::Mat& image, const cv::Mat& mask, const Eigen::Vector2d& uv, int h) {
  return ExtractMaskedPatch(image, mask, uv, h, 0.0);
}

// A patch straddling the object's left edge keeps its pixels on the object
// and marks the others NaN (also those whose bilinear sample reads one
// background pixel); one mostly off the object stays whole.
TEST(ProjectionSearch, ExtractMaskedPatchMarksThePixelsOffTheObject) {
  const RenderedOnTexture r = RenderObjectOnTexture(cv::Point2d(0.0, 0.0), 41);
  const int h = 4;
  // Centre 2.5 px right of the edge (x = 100): the samples at x 98.5 and
  // 99.5 read background pixels (98-99, 99-100), the others do not.
  const Eigen::Vector2d uv(102.5, 140.0);
  const cv::Mat patch = ExtractMaskedPatch(r.prev, r.prev_mask, uv, h, 0.5);
  ASSERT_FALSE(patch.empty());
  const cv::Mat plain = ExtractPatch(r.prev, uv, h);
  for (int y = 0; y < patch.rows; ++y) {
    for (int x = 0; x < patch.cols; ++x) {
      const double sample_x = uv.x() + x - h;  // reads floor(sample_x) and the next pixel
      if (std::floor(sample_x) < r.object.x) {
        EXPECT_TRUE(std::isnan(patch.at<float>(y, x))) << x << "," << y;
      } else {
        EXPECT_EQ(patch.at<float>(y, x), plain.at<float>(y, x)) << x << "," << y;
      }
    }
  }
  // 7 of 9 columns on the object: masked at a share of 0.5, whole at 0.8.
  const cv::Mat whole = ExtractMaskedPatch(r.prev, r.prev_mask, uv, h, 0.8);
  for (int y = 0; y < whole.rows; ++y) {
    for (int x = 0; x < whole.cols; ++x) EXPECT_EQ(whole.at<float>(y, x), plain.at<float>(y, x));
  }
  EXPECT_TRUE(ExtractMaskedPatch(r.prev, r.prev_mask, Eigen::Vector2d(2.0, 2.0), h, 0.5).empty());
}

// Points 1-3 px inside the object's outline: their whole patches straddle
// the background, which stays where it was. The plain search is pulled
// towards the background's (zero) motion, and misses some; the masked one
// correlates only the object's pixels and finds the object's shift, to the
// parabola's sub-pixel precision, or closer with Gauss–Newton.
TEST(ProjectionSearch, MaskedPatchSearchIgnoresTheBackground) {
  const cv::Point2d shift(1.6, -1.3);
  const RenderedOnTexture r = RenderObjectOnTexture(shift, 21);
  const ProjectionSearchOptions options;
  ProjectionSearchOptions refined;
  refined.patch_gauss_newton_iterations = 5;
  const int h = options.patch_half_size;
  const Eigen::Vector2d truth(shift.x, shift.y);
  double plain_error = 0.0, masked_error = 0.0, refined_error = 0.0;
  int plain_found = 0, masked_found = 0, refined_found = 0, n = 0;
  for (int k = 0; k < 40; ++k) {
    const double inset = 1.3 + 0.05 * k;  // 1.3-3.3 px inside the outline
    const double along = r.object.y + 20.0 + 2.0 * k;
    for (const Eigen::Vector2d& p : {Eigen::Vector2d(r.object.x + inset, along),
                                     Eigen::Vector2d(r.object.br().x - 1 - inset, along)}) {
      ++n;
      const Eigen::Vector2d predicted = p + truth + Eigen::Vector2d(0.4, 0.3);
      const auto plain = PatchSearch(r.next, ExtractPatch(r.prev, p, h), predicted, options);
      if (plain) {
        ++plain_found;
        plain_error += (*plain - p - truth).norm();
      }
      const cv::Mat patch = MaskedPatch(r.prev, r.prev_mask, p, h);
      const auto masked = MaskedPatchSearch(r.next, patch, r.next_mask, predicted, options);
      if (masked) {
        ++masked_found;
        masked_error += (*masked - p - truth).norm();
      }
      const auto with_gn = MaskedPatchSearch(r.next, patch, r.next_mask, predicted, refined);
      if (with_gn) {
        ++refined_found;
        refined_error += (*with_gn - p - truth).norm();
      }
    }
  }
  ASSERT_GT(masked_found, n * 9 / 10);
  ASSERT_EQ(refined_found, masked_found);
  masked_error /= masked_found;
  refined_error /= refined_found;
  plain_error = plain_found > 0 ? plain_error / plain_found : 99.0;
  std::printf(
      "border patches: plain %d/%d found, mean error %.3f px; masked %d/%d, %.3f px "
      "(Gauss-Newton %.3f px)\n",
      plain_found,
      n,
      plain_error,
      masked_found,
      n,
      masked_error,
      refined_error);
  EXPECT_LT(plain_found, masked_found);
  EXPECT_LT(masked_error, 0.6 * plain_error);
  EXPECT_LT(refined_error, 0.1);
}

// Inside the object, the Gauss–Newton refinement takes the parabola's pull
// towards whole pixels out of the sub-pixel position.
TEST(ProjectionSearch, MaskedPatchSearchRefinesTheParabolaVertex) {
  const ProjectionSearchOptions parabola;  // the default
  ASSERT_EQ(parabola.patch_gauss_newton_iterations, 0);
  ProjectionSearchOptions refined;
  refined.patch_gauss_newton_iterations = 5;
  const int h = refined.patch_half_size;
  double error_parabola = 0.0, error_refined = 0.0;
  int n = 0;
  for (int s = 0; s < 10; ++s) {
    const cv::Point2d shift(0.1 * s - 0.45, 0.35 - 0.07 * s);
    const RenderedOnTexture r = RenderObjectOnTexture(shift, 30 + s);
    for (const Eigen::Vector2d& p : InteriorGrid(r.object, 12, 17)) {
      const cv::Mat patch = MaskedPatch(r.prev, r.prev_mask, p, h);
      const Eigen::Vector2d truth = p + Eigen::Vector2d(shift.x, shift.y);
      const auto a = MaskedPatchSearch(r.next, patch, r.next_mask, p, parabola);
      const auto b = MaskedPatchSearch(r.next, patch, r.next_mask, p, refined);
      ASSERT_TRUE(a.has_value() && b.has_value());
      error_parabola += (*a - truth).norm();
      error_refined += (*b - truth).norm();
      ++n;
    }
  }
  error_parabola /= n;
  error_refined /= n;
  std::printf("interior patches (%d): parabola %.3f px, Gauss-Newton %.3f px\n",
              n, error_parabola, error_refined);
  EXPECT_LT(error_refined, 0.03);
  EXPECT_LT(error_refined, 0.5 * error_parabola);
}

// Nothing to correlate: an empty patch, a patch with no pixel on the
// object, or a search where the object is not.
TEST(ProjectionSearch, MaskedPatchSearchRefusesPatchesOffTheObject) {
  const RenderedOnTexture r = RenderObjectOnTexture(cv::Point2d(1.0, 1.0), 40);
  const ProjectionSearchOptions options;
  const int h = options.patch_half_size;
  const Eigen::Vector2d inside(170.0, 140.0);
  EXPECT_FALSE(MaskedPatchSearch(r.next, cv::Mat(), r.next_mask, inside, options).has_value());
  cv::Mat all_nan = ExtractPatch(r.prev, inside, h);
  all_nan.setTo(std::nanf(""));
  EXPECT_FALSE(MaskedPatchSearch(r.next, all_nan, r.next_mask, inside, options).has_value());
  const cv::Mat patch = MaskedPatch(r.prev, r.prev_mask, inside, h);
  const cv::Mat no_object(r.next.size(), CV_8UC1, cv::Scalar(0));
  EXPECT_FALSE(MaskedPatchSearch(r.next, patch, no_object, inside, options).has_value());
  // With the mask it is found; with no mask at all it is the whole patch.
  EXPECT_TRUE(MaskedPatchSearch(r.next, patch, r.next_mask, inside, options).has_value());
  EXPECT_TRUE(MaskedPatchSearch(r.next, patch, cv::Mat(), inside, options).has_value());
}

// Shared pyramids give exactly the result of the images themselves.
TEST(FlowAssociation, SparseFlowOnSharedPyramidsIsTheSameAsOnImages) {
  const Rendered r = RenderMovingPatch(cv::Point2d(3.6, 1.9), 6);
  const auto pts = InteriorGrid(r.object, 12, 9);
  std::vector<Eigen::Vector2d> predicted;
  for (const auto& p : pts) predicted.push_back(p + Eigen::Vector2d(3.0, 2.0));
  const SparseFlowOptions options;
  const auto on_images = TrackSparseFlow(r.prev, r.next, pts, options, &predicted);
  const auto prev = SparseFlowPyramid(r.prev, options);
  const auto next = SparseFlowPyramid(r.next, options);
  ASSERT_TRUE(on_images.ok() && prev.ok() && next.ok());
  const auto on_pyramids = TrackSparseFlow(*prev, *next, pts, options, &predicted);
  ASSERT_TRUE(on_pyramids.ok());
  ASSERT_EQ(on_images->size(), on_pyramids->size());
  int tracked = 0;
  for (size_t k = 0; k < pts.size(); ++k) {
    ASSERT_EQ((*on_images)[k].has_value(), (*on_pyramids)[k].has_value()) << k;
    if (!(*on_images)[k]) continue;
    ++tracked;
    EXPECT_EQ((*on_images)[k]->x(), (*on_pyramids)[k]->x()) << k;
    EXPECT_EQ((*on_images)[k]->y(), (*on_pyramids)[k]->y()) << k;
  }
  EXPECT_GT(tracked, static_cast<int>(pts.size()) / 2);
  // Bad input: an empty image, pyramids of different sizes.
  EXPECT_FALSE(SparseFlowPyramid(cv::Mat(), options).ok());
  const auto small = SparseFlowPyramid(cv::Mat(50, 60, CV_8UC1, cv::Scalar(9)), options);
  ASSERT_TRUE(small.ok());
  EXPECT_FALSE(TrackSparseFlow(*prev, *small, pts, options).ok());
}

TEST(ProjectionSearch, DescriptorSearchByProjection) {
  geometry::StereoCamera cam;
  cam.fx = cam.fy = 500;
  cam.cx = 320;
  cam.cy = 240;
  cam.baseline = 0.5;
  cam.width = 640;
  cam.height = 480;
  const std::vector<Eigen::Vector3d> pts = {{0, 0, 10}, {1, 0, 10}, {0, 1, 10}};
  std::vector<cv::Mat> desc;
  for (int k = 0; k < 3; ++k) desc.push_back(cv::Mat(1, 32, CV_8UC1, cv::Scalar(k * 60)));
  FrameKeypoints kps;
  // Keypoint 0: near point 1's projection with its descriptor; keypoint 1:
  // near point 0 with a wrong descriptor; keypoint 2: near point 2, 1 bit off.
  kps.uv = {{370.0 + 2, 240.0}, {320.0, 241.0}, {320.0, 290.0 - 3}};
  kps.u_right = {-1, -1, -1};
  kps.descriptors = cv::Mat(3, 32, CV_8UC1);
  kps.descriptors.row(0).setTo(60);
  kps.descriptors.row(1).setTo(255);
  desc[2].copyTo(kps.descriptors.row(2));
  kps.descriptors.at<uint8_t>(2, 0) ^= 1;
  const auto match = SearchByProjection(
      cam, geometry::SE3d(), pts, desc, {false, false, false}, kps, ProjectionSearchOptions{});
  EXPECT_EQ(match, (std::vector<int>{-1, 0, 2}));
  const auto skipped = SearchByProjection(
      cam, geometry::SE3d(), pts, desc, {false, true, false}, kps, ProjectionSearchOptions{});
  EXPECT_EQ(skipped, (std::vector<int>{-1, -1, 2}));
}

}  // namespace
}  // namespace twist::objects
