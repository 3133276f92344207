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
#include <optional>
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

// The plane `plane_in_a` in frame b, where x_b = b_from_a_rotation x_a +
// b_from_a_translation: n_b = R n_a, d_b = d_a − n_b·t, normalised (so its
// sign follows NormalizePlane in frame b).
Eigen::Vector4d TransformPlane(const Eigen::Matrix3d& b_from_a_rotation,
                               const Eigen::Vector3d& b_from_a_translation,
                               const Eigen::Vector4d& plane_in_a);

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

// A plane point measured by stereo. Its error lies along the viewing ray
// (the depth error z² σ_d s / (f b) of the disparity), so its distance to a
// plane of unit normal n has the standard deviation sigma_along_m · |n · ray|:
// small for a wall seen head-on at 5 m, large for a road point 25 m ahead,
// seen at a grazing angle from a coarse pyramid level.
struct StereoPlanePoint {
  Eigen::Vector3d point = Eigen::Vector3d::Zero();
  Eigen::Vector3d ray = Eigen::Vector3d::Zero();  // unit viewing direction (camera -> point)
  double sigma_along_m = 0.0;                     // <= 0: not known
};

struct PlaneRefineOptions {
  int iterations = 4;
  // Floor on a point's distance noise (keypoint localisation, surface texture).
  double min_sigma_m = 0.003;
  // Noise of a point whose sigma_along_m is not known (points restored from
  // state files written before the noise was kept).
  double unknown_sigma_m = 0.025;
  // Tukey biweight cut-off, in units of a point's own σ: points further from
  // the plane do not count.
  double tukey_c = 4.0;

  absl::Status Validate() const;
};

// σ of the distance of `p` to a plane of unit normal n (see StereoPlanePoint).
double PlaneDistanceSigma(const StereoPlanePoint& p,
                          const Eigen::Vector3d& unit_normal,
                          const PlaneRefineOptions& options);

// Refines `initial` by iteratively reweighted total least squares: each
// iteration weights every point by Tukey's biweight of its distance in units
// of its own σ (under the current plane) times 1/σ², and takes the plane
// through the weighted centroid normal to the weighted scatter's least
// eigenvector. The RANSAC refit weighs every inlier alike, so a few far points
// or points whose stereo block straddled an occluder tilt the plane: 0.1–0.3°
// on the generated streets, i.e. 5–15 cm of height at 30 m, which the planar
// joint turns into a car's depth (docs/objects.md §26). Returns `initial`
// unchanged when fewer than 3 points keep a weight.
absl::StatusOr<Eigen::Vector4d> RefinePlaneWeighted(const std::vector<StereoPlanePoint>& points,
                                                    const Eigen::Vector4d& initial,
                                                    const PlaneRefineOptions& options);

// Keeps the plane of one planar cluster and decides when to refit as the
// cluster grows (paper: "refitted as their clusters grow").
class ClusterPlane {
 public:
  struct Options {
    PlaneRansacOptions ransac;
    PlaneRefineOptions refine;  // stereo points only (the second Update)
    // Refit (RANSAC) when the cluster has grown by this factor since the
    // last fit; <= 1: at every Update with at least min_points points.
    double refit_growth = 1.2;
    // Stereo points: between RANSAC refits, refine the current plane on the
    // current points at every Update (RefinePlaneWeighted only: cheap), so a
    // plane whose bounded buffer no longer grows follows its newest points.
    bool refine_every_update = true;
    // Such a refinement counts as a change (Update returns true: a "plane
    // updated" event, and a new reported_plane()) only once the plane has
    // turned or moved by this much since the last change reported.
    double report_angle_deg = 0.05;
    double report_offset_m = 0.005;
    // Minimum number of points before the first fit.
    int min_points = 30;
  };
  explicit ClusterPlane(const Options& options) : options_(options) {}

  // Refits if there is no plane yet or the cluster grew enough. Returns true
  // when the plane changed (caller emits a "plane updated" event).
  bool Update(const std::vector<Eigen::Vector3d>& points, std::mt19937_64* rng);
  // The same with stereo points: RANSAC on their positions, then
  // RefinePlaneWeighted with their noise; between RANSAC refits, the
  // refinement alone (refine_every_update).
  bool Update(const std::vector<StereoPlanePoint>& points, std::mt19937_64* rng);

  bool has_plane() const { return has_plane_; }
  const Eigen::Vector4d& plane() const { return plane_; }
  // The plane at the last change Update reported: it follows plane() by
  // steps of report_angle_deg / report_offset_m, not by every refinement.
  const Eigen::Vector4d& reported_plane() const { return reported_; }
  int num_points_at_fit() const { return num_points_at_fit_; }
  int num_inliers() const { return num_inliers_; }
  // Persistence (SlamSystem::Save/Load): restores what the getters returned.
  void RestoreState(bool has_plane,
                    const Eigen::Vector4d& plane,
                    const Eigen::Vector4d& reported_plane,
                    int num_points_at_fit,
                    int num_inliers) {
    has_plane_ = has_plane;
    plane_ = plane;
    reported_ = reported_plane;
    num_points_at_fit_ = num_points_at_fit;
    num_inliers_ = num_inliers;
  }

 private:
  // RANSAC fit of `positions` (nullopt: no refit due or no plane found).
  std::optional<PlaneFit> Fit(const std::vector<Eigen::Vector3d>& positions, std::mt19937_64* rng);
  bool Accept(const Eigen::Vector4d& plane, int num_inliers);

  Options options_;
  bool has_plane_ = false;
  Eigen::Vector4d plane_ = Eigen::Vector4d::Zero();
  Eigen::Vector4d reported_ = Eigen::Vector4d::Zero();  // plane at the last change reported
  int num_points_at_fit_ = 0;
  int num_inliers_ = 0;
};

}  // namespace twist::semantic
