#include "slam/semantic/plane_fitting.h"

#include <glog/logging.h>

#include <Eigen/Eigenvalues>
#include <Eigen/Geometry>
#include <Eigen/SVD>
#include <algorithm>
#include <cmath>
#include <limits>
#include <string>

namespace twist::semantic {

Eigen::Vector4d NormalizePlane(const Eigen::Vector4d& plane) {
  CHECK_GT(plane.head<3>().norm(), 0.0) << "plane normal must be non-zero";
  Eigen::Vector4d p = plane / plane.norm();
  bool flip = p(3) < 0.0;
  if (p(3) == 0.0) {
    for (int k = 0; k < 3; ++k) {
      if (p(k) != 0.0) {
        flip = p(k) < 0.0;
        break;
      }
    }
  }
  return flip ? Eigen::Vector4d(-p) : p;
}

double PointPlaneDistance(const Eigen::Vector4d& plane, const Eigen::Vector3d& p) {
  return (plane.head<3>().dot(p) + plane(3)) / plane.head<3>().norm();
}

Eigen::Vector3d PlaneNormal(const Eigen::Vector4d& plane) { return plane.head<3>().normalized(); }

Eigen::Vector4d TransformPlane(const Eigen::Matrix3d& b_from_a_rotation,
                               const Eigen::Vector3d& b_from_a_translation,
                               const Eigen::Vector4d& plane_in_a) {
  const Eigen::Vector3d n = b_from_a_rotation * plane_in_a.head<3>();
  return NormalizePlane(
      Eigen::Vector4d(n.x(), n.y(), n.z(), plane_in_a.w() - n.dot(b_from_a_translation)));
}

absl::StatusOr<Eigen::Vector4d> FitPlaneLeastSquares(const std::vector<Eigen::Vector3d>& points) {
  if (points.size() < 3) {
    return absl::InvalidArgumentError("plane fit needs at least 3 points, got " +
                                      std::to_string(points.size()));
  }
  Eigen::Vector3d centroid = Eigen::Vector3d::Zero();
  for (const auto& p : points) centroid += p;
  centroid /= static_cast<double>(points.size());
  Eigen::Matrix3d scatter = Eigen::Matrix3d::Zero();
  for (const auto& p : points) {
    const Eigen::Vector3d d = p - centroid;
    scatter += d * d.transpose();
  }
  Eigen::JacobiSVD<Eigen::Matrix3d> svd(scatter, Eigen::ComputeFullU);
  const Eigen::Vector3d s = svd.singularValues();
  // Collinear (or coincident) points: the two smallest singular values vanish.
  if (!(s(1) > 1e-12 * std::max(1.0, s(0)))) {
    return absl::InvalidArgumentError("plane fit: points are collinear or coincident");
  }
  const Eigen::Vector3d n = svd.matrixU().col(2);
  return NormalizePlane(Eigen::Vector4d(n.x(), n.y(), n.z(), -n.dot(centroid)));
}

absl::Status PlaneRansacOptions::Validate() const {
  if (!(inlier_threshold_m > 0.0)) {
    return absl::InvalidArgumentError("plane RANSAC inlier_threshold_m must be > 0");
  }
  if (max_iterations < 1) return absl::InvalidArgumentError("plane RANSAC max_iterations < 1");
  if (!(confidence > 0.0 && confidence < 1.0)) {
    return absl::InvalidArgumentError("plane RANSAC confidence must be in (0, 1)");
  }
  if (min_inliers < 3) return absl::InvalidArgumentError("plane RANSAC min_inliers < 3");
  if (!(min_inlier_ratio >= 0.0 && min_inlier_ratio <= 1.0)) {
    return absl::InvalidArgumentError("plane RANSAC min_inlier_ratio must be in [0, 1]");
  }
  return absl::OkStatus();
}

namespace {

// Calls fn(k) for each point k within `threshold` of `plane`.
template <typename Fn>
void ForEachInlier(const std::vector<Eigen::Vector3d>& points,
                   const Eigen::Vector4d& plane,
                   double threshold,
                   Fn&& fn) {
  const Eigen::Vector3d n = plane.head<3>();
  const double inv_norm = 1.0 / n.norm();
  for (size_t k = 0; k < points.size(); ++k) {
    if (std::abs((n.dot(points[k]) + plane(3)) * inv_norm) <= threshold) fn(k);
  }
}

std::vector<int> Inliers(const std::vector<Eigen::Vector3d>& points,
                         const Eigen::Vector4d& plane,
                         double threshold) {
  std::vector<int> inliers;
  ForEachInlier(
      points, plane, threshold, [&](size_t k) { inliers.push_back(static_cast<int>(k)); });
  return inliers;
}

// Inliers(...).size() without collecting them: most RANSAC hypotheses lose,
// and only a winner's inliers are kept.
int CountInliers(const std::vector<Eigen::Vector3d>& points,
                 const Eigen::Vector4d& plane,
                 double threshold) {
  int count = 0;
  ForEachInlier(points, plane, threshold, [&](size_t) { ++count; });
  return count;
}

double RmsDistance(const std::vector<Eigen::Vector3d>& points,
                   const std::vector<int>& inliers,
                   const Eigen::Vector4d& plane) {
  if (inliers.empty()) return 0.0;
  double sum = 0.0;
  for (int k : inliers) {
    const double d = PointPlaneDistance(plane, points[static_cast<size_t>(k)]);
    sum += d * d;
  }
  return std::sqrt(sum / static_cast<double>(inliers.size()));
}

}  // namespace

absl::StatusOr<PlaneFit> FitPlaneRansac(const std::vector<Eigen::Vector3d>& points,
                                        const PlaneRansacOptions& options,
                                        std::mt19937_64* rng,
                                        const Eigen::Vector4d* hypothesis) {
  CHECK(rng != nullptr);
  if (absl::Status s = options.Validate(); !s.ok()) return s;
  const int n = static_cast<int>(points.size());
  if (n < 3) {
    return absl::InvalidArgumentError("plane RANSAC needs at least 3 points, got " +
                                      std::to_string(n));
  }
  std::vector<int> best_inliers;
  Eigen::Vector4d best_plane = Eigen::Vector4d::Zero();
  if (hypothesis != nullptr && hypothesis->head<3>().norm() > 0.0) {
    best_plane = NormalizePlane(*hypothesis);
    best_inliers = Inliers(points, best_plane, options.inlier_threshold_m);
  }
  std::uniform_int_distribution<int> pick(0, n - 1);
  int required = options.max_iterations;
  int it = 0;
  for (; it < std::min(required, options.max_iterations); ++it) {
    const int i0 = pick(*rng);
    int i1 = pick(*rng);
    int i2 = pick(*rng);
    if (i0 == i1 || i0 == i2 || i1 == i2) continue;
    const Eigen::Vector3d& a = points[static_cast<size_t>(i0)];
    const Eigen::Vector3d normal =
        (points[static_cast<size_t>(i1)] - a).cross(points[static_cast<size_t>(i2)] - a);
    if (normal.norm() < 1e-12) continue;
    const Eigen::Vector4d plane(normal.x(), normal.y(), normal.z(), -normal.dot(a));
    if (CountInliers(points, plane, options.inlier_threshold_m) >
        static_cast<int>(best_inliers.size())) {
      best_inliers = Inliers(points, plane, options.inlier_threshold_m);
      best_plane = NormalizePlane(plane);
      // Adaptive number of iterations for the requested confidence.
      const double w = static_cast<double>(best_inliers.size()) / n;
      const double p_fail = 1.0 - w * w * w;
      if (p_fail <= 0.0) {
        required = it + 1;
      } else {
        const double k = std::log(1.0 - options.confidence) / std::log(p_fail);
        required = static_cast<int>(std::min<double>(options.max_iterations, std::ceil(k)));
      }
    }
  }
  const int needed =
      std::max(options.min_inliers, static_cast<int>(std::ceil(options.min_inlier_ratio * n)));
  if (static_cast<int>(best_inliers.size()) < needed) {
    return absl::NotFoundError("no plane with enough inliers: best has " +
                               std::to_string(best_inliers.size()) + " of " + std::to_string(n) +
                               " points, need " + std::to_string(needed));
  }
  // SVD refit on the inliers, then re-collect the inliers of the refined plane
  // (twice: the refit usually gathers a few more).
  for (int refine = 0; refine < 2; ++refine) {
    std::vector<Eigen::Vector3d> in;
    in.reserve(best_inliers.size());
    for (int k : best_inliers) in.push_back(points[static_cast<size_t>(k)]);
    absl::StatusOr<Eigen::Vector4d> refit = FitPlaneLeastSquares(in);
    if (!refit.ok()) break;
    std::vector<int> inliers = Inliers(points, *refit, options.inlier_threshold_m);
    if (inliers.size() < best_inliers.size()) break;
    best_plane = *refit;
    best_inliers = std::move(inliers);
  }
  PlaneFit fit;
  fit.plane = best_plane;
  fit.rms_distance_m = RmsDistance(points, best_inliers, best_plane);
  fit.inliers = std::move(best_inliers);
  fit.iterations = it;
  return fit;
}

absl::Status PlaneRefineOptions::Validate() const {
  if (iterations < 1) return absl::InvalidArgumentError("plane refinement iterations < 1");
  if (!(min_sigma_m > 0.0) || !(unknown_sigma_m > 0.0)) {
    return absl::InvalidArgumentError("plane refinement sigmas must be > 0");
  }
  if (!(tukey_c > 0.0)) return absl::InvalidArgumentError("plane refinement tukey_c must be > 0");
  return absl::OkStatus();
}

double PlaneDistanceSigma(const StereoPlanePoint& p,
                          const Eigen::Vector3d& unit_normal,
                          const PlaneRefineOptions& options) {
  if (!(p.sigma_along_m > 0.0)) return options.unknown_sigma_m;
  return std::max(options.min_sigma_m, p.sigma_along_m * std::abs(unit_normal.dot(p.ray)));
}

absl::StatusOr<Eigen::Vector4d> RefinePlaneWeighted(const std::vector<StereoPlanePoint>& points,
                                                    const Eigen::Vector4d& initial,
                                                    const PlaneRefineOptions& options) {
  if (absl::Status s = options.Validate(); !s.ok()) return s;
  if (!(initial.head<3>().norm() > 0.0)) {
    return absl::InvalidArgumentError("plane refinement needs an initial plane");
  }
  Eigen::Vector4d plane = NormalizePlane(initial);
  std::vector<double> w(points.size());
  for (int it = 0; it < options.iterations; ++it) {
    const Eigen::Vector3d n = PlaneNormal(plane);
    const double d = plane(3) / plane.head<3>().norm();
    double sum_w = 0.0;
    int used = 0;
    Eigen::Vector3d centroid = Eigen::Vector3d::Zero();
    for (size_t k = 0; k < points.size(); ++k) {
      const double sigma = PlaneDistanceSigma(points[k], n, options);
      const double u = (n.dot(points[k].point) + d) / (sigma * options.tukey_c);
      w[k] = std::abs(u) < 1.0 ? (1.0 - u * u) * (1.0 - u * u) / (sigma * sigma) : 0.0;
      if (w[k] > 0.0) ++used;
      sum_w += w[k];
      centroid += w[k] * points[k].point;
    }
    if (used < 3) break;
    centroid /= sum_w;
    Eigen::Matrix3d scatter = Eigen::Matrix3d::Zero();
    for (size_t k = 0; k < points.size(); ++k) {
      if (w[k] == 0.0) continue;
      const Eigen::Vector3d r = points[k].point - centroid;
      scatter += w[k] * r * r.transpose();
    }
    const Eigen::SelfAdjointEigenSolver<Eigen::Matrix3d> eig(scatter);
    const Eigen::Vector3d ev = eig.eigenvalues();
    if (!(ev(1) > 1e-12 * std::max(1.0, ev(2)))) break;  // collinear support
    Eigen::Vector3d m = eig.eigenvectors().col(0);
    if (m.dot(n) < 0.0) m = -m;
    plane = NormalizePlane(Eigen::Vector4d(m.x(), m.y(), m.z(), -m.dot(centroid)));
  }
  return plane;
}

std::optional<PlaneFit> ClusterPlane::Fit(const std::vector<Eigen::Vector3d>& positions,
                                          std::mt19937_64* rng) {
  const int n = static_cast<int>(positions.size());
  if (n < options_.min_points) return std::nullopt;
  if (has_plane_ && options_.refit_growth > 1.0 && n < options_.refit_growth * num_points_at_fit_) {
    return std::nullopt;
  }
  absl::StatusOr<PlaneFit> fit =
      FitPlaneRansac(positions, options_.ransac, rng, has_plane_ ? &plane_ : nullptr);
  num_points_at_fit_ = n;  // do not retry on every point when the fit fails
  if (!fit.ok()) return std::nullopt;
  return *std::move(fit);
}

bool ClusterPlane::Accept(const Eigen::Vector4d& plane, int num_inliers) {
  const bool changed = !has_plane_ || !plane.isApprox(plane_, 1e-12);
  plane_ = plane;
  num_inliers_ = num_inliers;
  has_plane_ = true;
  if (changed) reported_ = plane;
  return changed;
}

bool ClusterPlane::Update(const std::vector<Eigen::Vector3d>& points, std::mt19937_64* rng) {
  const std::optional<PlaneFit> fit = Fit(points, rng);
  if (!fit) return false;
  return Accept(fit->plane, static_cast<int>(fit->inliers.size()));
}

bool ClusterPlane::Update(const std::vector<StereoPlanePoint>& points, std::mt19937_64* rng) {
  std::vector<Eigen::Vector3d> positions;
  positions.reserve(points.size());
  for (const StereoPlanePoint& p : points) positions.push_back(p.point);
  const std::optional<PlaneFit> fit = Fit(positions, rng);
  if (!fit) {
    if (!has_plane_ || !options_.refine_every_update ||
        static_cast<int>(points.size()) < options_.min_points) {
      return false;
    }
    absl::StatusOr<Eigen::Vector4d> refined = RefinePlaneWeighted(points, plane_, options_.refine);
    if (!refined.ok()) return false;
    plane_ = *refined;
    const Eigen::Vector3d n = PlaneNormal(plane_), m = PlaneNormal(reported_);
    const double turned = std::acos(std::clamp(n.dot(m), -1.0, 1.0)) * 180.0 / M_PI;
    const double moved =
        std::abs(plane_(3) / plane_.head<3>().norm() - reported_(3) / reported_.head<3>().norm());
    if (turned <= options_.report_angle_deg && moved <= options_.report_offset_m) return false;
    reported_ = plane_;
    return true;
  }
  absl::StatusOr<Eigen::Vector4d> refined =
      RefinePlaneWeighted(points, fit->plane, options_.refine);
  return Accept(refined.ok() ? *refined : fit->plane, static_cast<int>(fit->inliers.size()));
}

}  // namespace twist::semantic
