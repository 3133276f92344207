// Stereo disparity error per pyramid level against the exact depth of the
// synthetic generator. Diagnostic tool, prints only.
//
//   disparity_bias [--scenario static_street] [--frames 10] [--seed 1] [--noise 1.5]
//                  [--subpixel sad|ssd] [--slam 1] [--disc 1]
// (--slam 1 runs the whole engine with its default options on the clip and
// prints ATE, RPE and the path length ratio instead. --disc 1 prints the
// errors of every stereo match against the true disparity at the keypoint's
// pixel, split by where the keypoint sits: docs/math.md sections 17, 19.)
//
// For every stereo-matched left keypoint whose neighbourhood (the SAD window
// at its level plus a margin) lies on one plane (disparity affine in the
// image to 0.02 px), the ground-truth disparity is the affine fit evaluated at
// the keypoint. Prints per level: count, mean and median signed error
// (estimated - true, px), mean absolute error, and the mean error binned by
// the fractional part of the true disparity at that level (pixel locking).
#include <algorithm>
#include <cmath>
#include <cstdio>
#include <cstdlib>
#include <cstring>
#include <string>
#include <vector>

#include "slam/features/orb_extractor.h"
#include "slam/features/stereo_matcher.h"
#include "slam/io/metrics.h"
#include "slam/sim/depth_truth.h"
#include "slam/sim/renderer.h"
#include "slam/sim/scenarios.h"
#include "slam/sim/writer.h"
#include "slam/system/slam_system.h"
#include "tests/slam/features/stereo_truth.h"

using namespace twist;

namespace {

// Brute-force sub-pixel shift (0.01 px steps) minimising the SSD of zero-mean
// 11x11 patches, right image sampled bilinearly. Level 0 only.
double BruteForceDisparity(
    const cv::Mat& left, const cv::Mat& right, double x, double y, double d0) {
  const int cx = static_cast<int>(std::lround(x)), cy = static_cast<int>(std::lround(y));
  const int w = 5;
  if (cx - w - 3 - static_cast<int>(d0) < 1 || cx + w + 2 >= left.cols || cy - w < 0 ||
      cy + w >= left.rows)
    return -1;
  double best = 1e30, best_d = d0;
  for (int k = -150; k <= 150; ++k) {
    const double d = d0 + 0.01 * k;
    double ml = 0, mr = 0;
    std::vector<double> a, b;
    for (int dy = -w; dy <= w; ++dy) {
      for (int dx = -w; dx <= w; ++dx) {
        const double xr = cx + dx - d;
        const int x0 = static_cast<int>(std::floor(xr));
        const double t = xr - x0;
        const double vr =
            (1 - t) * right.at<uint8_t>(cy + dy, x0) + t * right.at<uint8_t>(cy + dy, x0 + 1);
        a.push_back(left.at<uint8_t>(cy + dy, cx + dx));
        b.push_back(vr);
        ml += a.back();
        mr += b.back();
      }
    }
    ml /= a.size();
    mr /= b.size();
    double ssd = 0;
    for (size_t i = 0; i < a.size(); ++i) ssd += (a[i] - ml - b[i] + mr) * (a[i] - ml - b[i] + mr);
    if (ssd < best) {
      best = ssd;
      best_d = d;
    }
  }
  return best_d;
}

// Where a stereo keypoint sits against the depth buffer around it.
enum BlockKind {
  kFlat = 0,      // the true disparity over its block is affine to 0.5 px
  kNearSide = 1,  // a discontinuity, the keypoint's pixel on its nearer side
  kFarSide = 2,   // a discontinuity, the keypoint's pixel on its farther side
};

// Error of every stereo match against the true disparity at its keypoint's
// pixel, by block kind and true disparity band: count, mean of the errors
// within 1 px × level scale, share of larger ("gross") errors and their
// median. Sky counts as disparity 0.
void PrintDiscontinuityErrors(const sim::Scenario& sc,
                              const sim::Renderer& renderer,
                              const features::OrbExtractor& orb,
                              const features::StereoMatchOptions& smo,
                              int frames) {
  constexpr int kBands = 3;  // true disparity < 12, 12-24, >= 24 px
  constexpr int kKinds = 3;
  const double bf = sc.camera.bf();
  int inl[kKinds][kBands] = {};
  double sum[kKinds][kBands] = {};
  std::vector<double> gross[kKinds][kBands];
  for (int f = 0; f < frames; ++f) {
    const sim::StereoRender r = sim::RenderScenarioFrame(renderer, sc, f);
    std::vector<cv::KeyPoint> kl, kr;
    cv::Mat dl, dr;
    std::vector<cv::Mat> ll, lr;
    orb.Extract(r.left, cv::Mat(), &kl, &dl, &ll);
    orb.Extract(r.right, cv::Mat(), &kr, &dr, &lr);
    const features::StereoMatchResult st =
        features::MatchStereo(sc.camera, orb.pyramid(), kl, dl, kr, dr, ll, lr, smo);
    auto disparity_at = [&](int x, int y) {
      const float z = r.depth.at<float>(y, x);
      return std::isfinite(z) && z > 0.f ? bf / z : 0.0;
    };
    for (size_t q = 0; q < kl.size(); ++q) {
      if (st.depth[q] <= 0.f) continue;
      const int cx = static_cast<int>(std::lround(kl[q].pt.x));
      const int cy = static_cast<int>(std::lround(kl[q].pt.y));
      const double truth = disparity_at(cx, cy);
      if (truth <= 0.0) continue;
      const double s = orb.pyramid().scale[kl[q].octave];
      const int radius = static_cast<int>(std::ceil((smo.sad_half_window + 1) * s));
      BlockKind kind = kFlat;
      if (!sim::PlanarDisparity(r.depth, bf, kl[q].pt.x, kl[q].pt.y, radius, 0.5)) {
        double lo = truth, hi = truth;
        for (int y = std::max(0, cy - radius); y <= std::min(r.depth.rows - 1, cy + radius); ++y) {
          for (int x = std::max(0, cx - radius); x <= std::min(r.depth.cols - 1, cx + radius);
               ++x) {
            const double d = disparity_at(x, y);
            lo = std::min(lo, d);
            hi = std::max(hi, d);
          }
        }
        kind = truth > 0.5 * (lo + hi) ? kNearSide : kFarSide;
      }
      const int band = truth < 12.0 ? 0 : (truth < 24.0 ? 1 : 2);
      const double e = kl[q].pt.x - st.u_right[q] - truth;
      if (std::abs(e) > s) {
        gross[kind][band].push_back(e);
      } else {
        sum[kind][band] += e;
        ++inl[kind][band];
      }
    }
  }
  const char* bands[kBands] = {"< 12", "12-24", ">= 24"};
  std::printf(
      "true disparity | flat | discontinuity, near side | discontinuity, far side\n"
      "  each: n / mean error within 1 px x level scale / share beyond / median beyond (px)\n");
  for (int b = 0; b < kBands; ++b) {
    std::printf("%-6s", bands[b]);
    for (int k = 0; k < kKinds; ++k) {
      std::vector<double>& g = gross[k][b];
      const size_t n = inl[k][b] + g.size();
      double median = 0.0;
      if (!g.empty()) {
        std::nth_element(g.begin(), g.begin() + g.size() / 2, g.end());
        median = g[g.size() / 2];
      }
      std::printf(" | %6zu %+7.3f %5.1f%% %+6.1f",
                  n,
                  inl[k][b] ? sum[k][b] / inl[k][b] : 0.0,
                  n ? 100.0 * g.size() / n : 0.0,
                  median);
    }
    std::printf("\n");
  }
}

}  // namespace

int main(int argc, char** argv) {
  std::string scenario = "static_street";
  int frames = 10;
  int seed = 1;
  double noise = 1.5;
  bool slam = false;
  bool disc = false;
  features::StereoMatchOptions smo;
  for (int i = 1; i + 1 < argc; i += 2) {
    if (!std::strcmp(argv[i], "--scenario")) scenario = argv[i + 1];
    if (!std::strcmp(argv[i], "--frames")) frames = std::atoi(argv[i + 1]);
    if (!std::strcmp(argv[i], "--seed")) seed = std::atoi(argv[i + 1]);
    if (!std::strcmp(argv[i], "--noise")) noise = std::atof(argv[i + 1]);
    if (!std::strcmp(argv[i], "--slam")) slam = std::atoi(argv[i + 1]) != 0;
    if (!std::strcmp(argv[i], "--disc")) disc = std::atoi(argv[i + 1]) != 0;
    if (!std::strcmp(argv[i], "--subpixel")) {
      smo.subpixel = std::strcmp(argv[i + 1], "ssd") == 0
                         ? features::SubpixelMethod::kSsdGaussNewton
                         : features::SubpixelMethod::kSadParabola;
    }
  }
  auto sc = sim::MakeScenario(scenario, static_cast<uint32_t>(seed), frames);
  if (!sc.ok()) {
    std::fprintf(stderr, "%s\n", std::string(sc.status().message()).c_str());
    return 2;
  }
  sim::RenderOptions ro;
  ro.gray = true;
  ro.noise_sigma = noise;
  const sim::Renderer renderer(sc->camera, ro);
  if (slam) {
    // Whole engine on the rendered clip: ATE, RPE and path length ratio.
    SessionConfig config;
    config.camera = sc->camera;
    auto sys = SlamSystem::Create(config);
    std::vector<geometry::SE3d> est, gt;
    int not_ok = 0;
    for (int f = 0; f < frames; ++f) {
      const sim::StereoRender r = sim::RenderScenarioFrame(renderer, *sc, f);
      auto res = (*sys)->Process(sim::ScenarioStereoFrame(*sc, f, r));
      not_ok += res->state != TrackingState::kOk;
      est.push_back(res->world_from_camera);
      gt.push_back(sc->WorldFromCamera(f));
    }
    auto m = io::EvaluateCamera(gt, est);
    double le = 0, lg = 0;
    for (int i = 0; i + 1 < frames; ++i) {
      le += (est[i].Inverse() * est[i + 1]).translation().norm();
      lg += (gt[i].Inverse() * gt[i + 1]).translation().norm();
    }
    std::printf("%s %d frames: ATE %.4f RPE_t %.4f RPE_R %.4f not ok %d, path length est/gt %.5f\n",
                scenario.c_str(),
                frames,
                m->ate_rmse,
                m->rpe_t,
                m->rpe_r_deg,
                not_ok,
                le / lg);
    return 0;
  }
  const features::OrbExtractor orb(features::OrbOptions{});
  if (disc) {
    PrintDiscontinuityErrors(*sc, renderer, orb, smo, frames);
    return 0;
  }
  const int L = orb.options().num_levels;
  constexpr int kBins = 4;
  std::vector<std::vector<double>> err(L);
  std::vector<std::vector<double>> bin_sum(L, std::vector<double>(kBins, 0.0));
  std::vector<std::vector<int>> bin_n(L, std::vector<int>(kBins, 0));
  std::vector<int> matched(L, 0), outliers(L, 0);
  double slope_abs[3] = {0, 0, 0};
  double bf_abs = 0, bf_sum = 0;
  int bf_n = 0;
  int slope_n[3] = {0, 0, 0};
  for (int f = 0; f < frames; ++f) {
    const sim::StereoRender r = sim::RenderScenarioFrame(renderer, *sc, f);
    std::vector<cv::KeyPoint> kl;
    for (const features::testing::StereoTruth& m :
         features::testing::MatchAgainstTruth(r, sc->camera, orb, smo, &kl)) {
      const int l = m.level;
      const double s = orb.pyramid().scale[l];
      const double gt = m.truth.disparity, gx = m.truth.gx;
      const int q = m.keypoint;
      ++matched[l];
      const double e = m.estimated - gt;
      if (std::abs(e) > 1.0 * s) {
        ++outliers[l];
        continue;
      }
      err[l].push_back(e);
      if (l == 0 && std::abs(kl[q].pt.x - std::round(kl[q].pt.x)) < 1e-3) {
        const double bd = BruteForceDisparity(r.left, r.right, kl[q].pt.x, kl[q].pt.y, gt);
        if (bd > 0) {
          bf_abs += std::abs(bd - gt);
          bf_sum += bd - gt;
          ++bf_n;
        }
      }
      if (l == 0) {
        const int sb = std::abs(gx) < 0.02 ? 0 : (std::abs(gx) < 0.1 ? 1 : 2);
        slope_abs[sb] += std::abs(e);
        ++slope_n[sb];
      }
      const double frac_at_level = gt / s - std::floor(gt / s);
      const int bin = std::min(kBins - 1, static_cast<int>(frac_at_level * kBins));
      bin_sum[l][bin] += e;
      ++bin_n[l][bin];
    }
  }
  std::printf("%s, %d frames, noise %.1f: disparity error (estimated - true), px at level 0\n",
              scenario.c_str(),
              frames,
              noise);
  std::printf(
      "level   n  outl   mean  median  mean|e|   by frac(true disp at level) 0-.25 .25-.5 .5-.75 "
      ".75-1\n");
  std::vector<double> all;
  for (int l = 0; l < L; ++l) {
    auto& e = err[l];
    if (e.empty()) continue;
    all.insert(all.end(), e.begin(), e.end());
    double mean = 0.0, mabs = 0.0;
    for (double v : e) {
      mean += v;
      mabs += std::abs(v);
    }
    mean /= e.size();
    mabs /= e.size();
    std::sort(e.begin(), e.end());
    std::printf("%5d %4zu %4d %7.3f %7.3f %7.3f [p10 %6.3f p90 %6.3f] ",
                l,
                e.size(),
                outliers[l],
                mean,
                e[e.size() / 2],
                mabs,
                e[e.size() / 10],
                e[e.size() * 9 / 10]);
    for (int b = 0; b < kBins; ++b) {
      std::printf(" %6.3f", bin_n[l][b] ? bin_sum[l][b] / bin_n[l][b] : 0.0);
    }
    std::printf("\n");
  }
  for (int b = 0; b < 3; ++b) {
    std::printf("level 0, |d disp/dx| bin %d: n %d mean|e| %.3f\n",
                b,
                slope_n[b],
                slope_n[b] ? slope_abs[b] / slope_n[b] : 0.0);
  }
  std::printf("brute force SSD level 0: n %d mean %.4f mean|e| %.4f\n",
              bf_n,
              bf_n ? bf_sum / bf_n : 0.0,
              bf_n ? bf_abs / bf_n : 0.0);
  double mean = 0.0;
  for (double v : all) mean += v;
  std::sort(all.begin(), all.end());
  if (!all.empty()) {
    std::printf(
        "all   %zu mean %.4f median %.4f\n", all.size(), mean / all.size(), all[all.size() / 2]);
  }
  return 0;
}
