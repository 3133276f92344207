// Plane fitting for planar static clusters (paper §IV-B): π = (a, b, c, d),
// πᵀ (x, 1) = 0, by RANSAC on 3-point samples and an SVD refit on the inliers.
//
// Normalisation: |(a, b, c, d)| = 1 as in the paper (DESIGN.md §1), with the
// sign chosen so that d >= 0 (the world origin, i.e. the first camera, lies on
// the positive side). The Euclidean distance of x to the plane is
// (n·x + d) / |n| with n = (a, b, c): use PointPlaneDistance.
#pragma once

#include <Eigen/Core>
#include <cstdint>
#include <random>
#include <vector>

#include "absl/status/status.h"
#include "absl/status/statusor.h"

namespace twist::semantic {

// Scales to |π| = 1 and flips so that d >= 0 (when d == 0: the first non-zero
// normal component is positive). CHECKs a non-zero normal.
Eigen::Vector4d NormalizePlane(const Eigen::Vector4d& plane);

// Signed Euclidean distance of p to the plane (positive on the side of the
// normal).
double PointPlaneDistance(const Eigen::Vector4d& plane, const Eigen::Vector3d& p);

// Unit normal (a, b, c)/|(a, b, c)|.
Eigen::Vector3d PlaneNormal(const Eigen::Vector4d& plane);

// Least-squares plane through >= 3 non-collinear points (SVD of the centred
// points; the normal is the singular vector of the smallest singular value).
absl::StatusOr<Eigen::Vector4d> FitPlaneLeastSquares(const std::vector<Eigen::Vector3d>& points);

struct PlaneRansacOptions {
  double inlier_threshold_m = 0.05;  // point-plane distance of an inlier
  int max_iterations = 1000;
  double confidence = 0.999;  // adaptive stop once reached
  int min_inliers = 10;       // fewer -> NotFound
  double min_inlier_ratio = 0.2;

  absl::Status Validate() const;
};

struct PlaneFit {
  Eigen::Vector4d plane = Eigen::Vector4d::Zero();  // normalised, see NormalizePlane
  std::vector<int> inliers;                         // indices into the input points
  double rms_distance_m = 0.0;                      // over the inliers
  int iterations = 0;
};

// RANSAC + SVD refit. The random generator is the caller's (seed it for
// reproducible results). `hypothesis`, when given (e.g. the previous plane of
// a growing cluster), is scored first so that a refit never gets worse than it.
// NotFound when no plane gathers enough inliers; InvalidArgument for < 3 points.
absl::StatusOr<PlaneFit> FitPlaneRansac(const std::vector<Eigen::Vector3d>& points,
                                        const PlaneRansacOptions& options,
                                        std::mt19937_64* rng,
                                        const Eigen::Vector4d* hypothesis = nullptr);

// Keeps the plane of one planar cluster and decides when to refit as the
// cluster grows (paper: "refitted as their clusters grow").
class ClusterPlane {
 public:
  struct Options {
    PlaneRansacOptions ransac;
    // Refit when the cluster has grown by this factor since the last fit.
    double refit_growth = 1.2;
    // Minimum number of points before the first fit.
    int min_points = 30;
  };
  explicit ClusterPlane(const Options& options) : options_(options) {}

  // Refits if there is no plane yet or the cluster grew enough. Returns true
  // when the plane changed (caller emits a "plane updated" event).
  bool Update(const std::vector<Eigen::Vector3d>& points, std::mt19937_64* rng);

  bool has_plane() const { return has_plane_; }
  const Eigen::Vector4d& plane() const { return plane_; }
  int num_points_at_fit() const { return num_points_at_fit_; }
  int num_inliers() const { return num_inliers_; }
  // Persistence (SlamSystem::Save/Load): restores what the getters returned.
  void RestoreState(bool has_plane,
                    const Eigen::Vector4d& plane,
                    int num_points_at_fit,
                    int num_inliers) {
    has_plane_ = has_plane;
    plane_ = plane;
    num_points_at_fit_ = num_points_at_fit;
    num_inliers_ = num_inliers;
  }

 private:
  Options options_;
  bool has_plane_ = false;
  Eigen::Vector4d plane_ = Eigen::Vector4d::Zero();
  int num_points_at_fit_ = 0;
  int num_inliers_ = 0;
};

}  // namespace twist::semantic
