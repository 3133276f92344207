#include "slam/features/disparity_offset.h"

#include <algorithm>
#include <cmath>

#include "slam/features/feature_matcher.h"

namespace twist::features {

namespace {

constexpr double kGridStepPx = 0.002;
constexpr int kGridHalfSteps = 500;  // [-1, 1] px
constexpr int kMinPairs = 40;

double RobustCost(const geometry::StereoCamera& camera,
                  const std::vector<const DisparityPair*>& pairs,
                  double offset_px) {
  double c = 0.0;
  for (const DisparityPair* p : pairs) {
    const double r = DisparityPairResidual(camera, *p, offset_px);
    c += std::min(r * r, 1.0);
  }
  return c;
}

// Grid minimiser of the robust cost, refined by a parabola through the
// minimum's neighbours.
double GridMinimum(const geometry::StereoCamera& camera,
                   const std::vector<const DisparityPair*>& pairs) {
  std::vector<double> cost(2 * kGridHalfSteps + 1);
  for (int k = -kGridHalfSteps; k <= kGridHalfSteps; ++k) {
    cost[k + kGridHalfSteps] = RobustCost(camera, pairs, k * kGridStepPx);
  }
  const int b = static_cast<int>(std::min_element(cost.begin(), cost.end()) - cost.begin());
  double sub = 0.0;
  if (b > 0 && b + 1 < static_cast<int>(cost.size())) {
    const double den = cost[b - 1] - 2.0 * cost[b] + cost[b + 1];
    if (den > 0.0) sub = 0.5 * (cost[b - 1] - cost[b + 1]) / den;
  }
  return (b - kGridHalfSteps + sub) * kGridStepPx;
}

}  // namespace

StereoKeypoints ExtractStereoKeypoints(const OrbExtractor& orb,
                                       const geometry::StereoCamera& camera,
                                       const cv::Mat& left_gray,
                                       const cv::Mat& right_gray,
                                       const StereoMatchOptions& options) {
  StereoKeypoints v;
  std::vector<cv::KeyPoint> right_kps;
  cv::Mat right_desc;
  std::vector<cv::Mat> left_levels, right_levels;
  orb.Extract(left_gray, cv::Mat(), &v.keypoints, &v.descriptors, &left_levels);
  orb.Extract(right_gray, cv::Mat(), &right_kps, &right_desc, &right_levels);
  v.u_right = MatchStereo(camera,
                          orb.pyramid(),
                          v.keypoints,
                          v.descriptors,
                          right_kps,
                          right_desc,
                          left_levels,
                          right_levels,
                          options)
                  .u_right;
  return v;
}

double DisparityPairResidual(const geometry::StereoCamera& camera,
                             const DisparityPair& pair,
                             double offset_px) {
  constexpr double kInvalid = 1e3;
  const double di = pair.disparity_i + offset_px;
  const double dj = pair.disparity_j + offset_px;
  if (di <= 0.05 || dj <= 0.05) return kInvalid;
  const Eigen::Vector3d p_j = pair.j_from_i * camera.Backproject(pair.uv_i, camera.bf() / di);
  if (p_j.z() <= 0.1) return kInvalid;
  return (dj - camera.bf() / p_j.z()) / pair.level_scale;
}

std::vector<DisparityPair> CollectDisparityPairs(
    const geometry::StereoCamera& camera,
    const ScalePyramid& pyramid,
    const std::vector<StereoKeypoints>& views,
    const std::vector<geometry::SE3d>& world_from_camera,
    const DisparityPairOptions& options,
    DisparityPairStats* stats) {
  std::vector<DisparityPair> pairs;
  DisparityPairStats local;
  const int n = static_cast<int>(std::min(views.size(), world_from_camera.size()));
  const int max_level = static_cast<int>(pyramid.scale.size()) - 1;
  for (int gap : options.gaps) {
    if (gap < 1) continue;
    for (int i = 0; i + gap < n; ++i) {
      const StereoKeypoints& a = views[i];
      const StereoKeypoints& b = views[i + gap];
      if (a.descriptors.empty() || b.descriptors.empty()) continue;
      const geometry::SE3d j_from_i = world_from_camera[i + gap].Inverse() * world_from_camera[i];
      for (const auto& [qa, qb] : MatchRatio(
               a.descriptors, b.descriptors, options.ratio, options.max_descriptor_distance)) {
        if (a.u_right[qa] < 0.f || b.u_right[qb] < 0.f) continue;
        ++local.matched;
        DisparityPair p;
        p.uv_i = {a.keypoints[qa].pt.x, a.keypoints[qa].pt.y};
        p.uv_j = {b.keypoints[qb].pt.x, b.keypoints[qb].pt.y};
        p.disparity_i = a.keypoints[qa].pt.x - a.u_right[qa];
        p.disparity_j = b.keypoints[qb].pt.x - b.u_right[qb];
        p.level =
            std::clamp(std::max(a.keypoints[qa].octave, b.keypoints[qb].octave), 0, max_level);
        p.level_scale = pyramid.scale[p.level];
        p.frame_i = i;
        p.j_from_i = j_from_i;
        const double off = options.check_offset_px;
        bool keep = p.disparity_i + off > 0.05 && p.disparity_j + off > 0.05;
        if (keep) {
          const Eigen::Vector3d p_j =
              j_from_i * camera.Backproject(p.uv_i, camera.bf() / (p.disparity_i + off));
          // The residual of DisparityPairResidual(camera, p, off), from p_j.
          keep = p_j.z() > 0.5 &&
                 (camera.Project(p_j) - p.uv_j).norm() <=
                     options.max_reprojection_px * p.level_scale &&
                 std::abs(p.disparity_j + off - camera.bf() / p_j.z()) <=
                     options.max_disparity_px * p.level_scale;
        }
        if (!keep) {
          ++local.rejected;
          continue;
        }
        pairs.push_back(p);
      }
    }
  }
  if (stats != nullptr) *stats = local;
  return pairs;
}

DisparityOffsetFit FitDisparityOffset(const geometry::StereoCamera& camera,
                                      const std::vector<const DisparityPair*>& pairs) {
  DisparityOffsetFit fit;
  fit.num_pairs = static_cast<int>(pairs.size());
  if (fit.num_pairs < kMinPairs) return fit;
  fit.ok = true;
  fit.offset_px = GridMinimum(camera, pairs);
  fit.cost = RobustCost(camera, pairs, fit.offset_px);
  fit.cost_at_zero = RobustCost(camera, pairs, 0.0);
  // Four interleaved subsets: the spread of their minimisers over sqrt(4).
  constexpr int kSubsets = 4;
  if (fit.num_pairs >= kSubsets * kMinPairs) {
    double est[kSubsets], mean = 0.0;
    for (int s = 0; s < kSubsets; ++s) {
      std::vector<const DisparityPair*> sub;
      for (size_t k = s; k < pairs.size(); k += kSubsets) sub.push_back(pairs[k]);
      est[s] = GridMinimum(camera, sub);
      mean += est[s] / kSubsets;
    }
    double var = 0.0;
    for (double e : est) var += (e - mean) * (e - mean) / (kSubsets - 1);
    fit.standard_error_px = std::sqrt(var / kSubsets);
  }
  return fit;
}

DisparityOffsetFit FitDisparityOffset(const geometry::StereoCamera& camera,
                                      const std::vector<DisparityPair>& pairs) {
  std::vector<const DisparityPair*> all;
  all.reserve(pairs.size());
  for (const DisparityPair& p : pairs) all.push_back(&p);
  return FitDisparityOffset(camera, all);
}

DisparityCalibration CalibrateDisparityOffset(const geometry::StereoCamera& camera,
                                              const ScalePyramid& pyramid,
                                              const std::vector<StereoKeypoints>& views,
                                              const std::vector<geometry::SE3d>& world_from_camera,
                                              DisparityPairOptions options) {
  constexpr int kMaxRounds = 5;
  constexpr double kConvergedPx = 0.005;
  DisparityCalibration c;
  for (c.iterations = 1; c.iterations <= kMaxRounds; ++c.iterations) {
    c.pairs = CollectDisparityPairs(camera, pyramid, views, world_from_camera, options, &c.stats);
    c.fit = FitDisparityOffset(camera, c.pairs);
    if (!c.fit.ok || std::abs(c.fit.offset_px - options.check_offset_px) < kConvergedPx) break;
    options.check_offset_px = c.fit.offset_px;
  }
  c.iterations = std::min(c.iterations, kMaxRounds);
  return c;
}

}  // namespace twist::features
