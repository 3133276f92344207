// Constrained twist estimation of one object between two frames (paper
// §IV-E, eq. dyna_tracking):
//
//   ξ* = argmin_ξ Σ_j ρ_Huber( ‖x_ij − π(c_i T_w · Exp(Π ξ) · w T_o(i−1) · o X_j)‖ / σ )
//
// solved by Levenberg–Marquardt (Ceres) on the analytic cost of
// slam/optimization/cost_functions/twist_tracking_cost.h. σ is the MAD
// estimate of the residual scale, σ = 1.4826 · median_k |r_k − median(r)| over
// the stacked residual components of the current inliers; it is re-estimated
// after every round, observations with ‖r_j/σ‖² above the χ² gate are
// rejected and the problem is solved again (outliers may come back).
//
// A stereo observation measures its disparity d where the point was found:
// u_right = u − d carries the position's error too. With a disparity noise of
// its own (TwistObservation::disparity_noise_ratio) the residual is whitened
// under that correlation (StereoWhitening), which weighs the depth by the
// disparity's noise instead of the position's (docs/objects.md §34).
//
// A point need not be exact: one triangulated by stereo at 26 m is uncertain
// by ~0.9 m along its ray (TwistObservation::point_sigma_in_object). Taken as
// exact, a noisy structure is best explained by the twist that keeps the view
// it was triangulated from: a car crossing the view seemed to turn with its
// bearing (docs/objects.md §27). With estimate_point_errors each such point
// gets an offset δ_j along its σ vector, prior N(0, 1), solved with the twist
// (errors in variables); the MAD scale, the gates, the significance and the
// covariance use the residuals whitened by (I + g gᵀ/σ²)^(−1/2), g the image
// of the σ vector (the same profile over δ_j to first order). Points with a
// zero σ vector are exact, as before. An optional linear prior (TwistPrior)
// enters the solve and the covariance.
//
// Π is the joint's world projector (joints::Joint::WorldProjector()); the
// solver moves ξ only inside range(Π) (a linear-subspace manifold), so the
// normal equations stay well conditioned and the result satisfies Π ξ = ξ.
// Pass Π = I for a free (unconstrained) object.
#pragma once

#include <Eigen/Core>
#include <vector>

#include "absl/status/status.h"
#include "absl/status/statusor.h"
#include "slam/geometry/se3.h"
#include "slam/geometry/stereo_camera.h"

namespace twist::objects {

// One 2D (or rectified-stereo) observation in frame i of an object point.
struct TwistObservation {
  Eigen::Vector3d point_in_object = Eigen::Vector3d::Zero();
  // The point's own uncertainty: one standard deviation along the direction
  // it is uncertain in, in the object frame (a stereo point: its depth noise
  // along the ray it was triangulated on). Zero: an exact point.
  Eigen::Vector3d point_sigma_in_object = Eigen::Vector3d::Zero();
  Eigen::Vector2d uv = Eigen::Vector2d::Zero();  // left image, pixels
  double u_right = -1.0;                         // right image u; < 0: mono
  // The disparity's own noise as a fraction k of the position's. A stereo
  // observation measures its disparity d where the point was found, so
  // u_right = u − d carries u's error too: Cov(r_u, r_v, r_ur) =
  // σ² [1 0 1; 0 1 0; 1 0 1 + k²], σ the step's scale. With k > 0 the
  // residual is whitened under that correlation (StereoWhitening), which
  // weighs the depth by the disparity's noise kσ instead of the position's.
  // A ratio rather than a σ_d in pixels: a step whose positions are poor (a
  // far seed, scattered matches: the scale above its floor) has poorer
  // disparities too. 0: u_right independent of u, with the same noise.
  double disparity_noise_ratio = 0.0;
  bool stereo() const { return u_right >= 0.0; }
};

struct TwistEstimatorOptions {
  int max_rounds = 4;          // solve / MAD / reject rounds
  int max_iterations = 20;     // LM iterations per round
  double huber_delta = 1.345;  // Huber threshold in units of σ
  // Floor on the MAD scale: keypoints are not located better than this (ORB
  // corners on pyramid levels); noise-free data would otherwise give σ = 0.
  double min_sigma_px = 0.7;
  double max_sigma_px = 50.0;  // ceiling for the first round
  // χ² gates (95 %) on ‖r/σ‖² for mono (2 dof) and stereo (3 dof) residuals.
  double chi2_mono = 5.991;
  double chi2_stereo = 7.815;
  int min_inliers = 4;        // fewer -> not successful
  bool use_autodiff = false;  // check mode: autodiff twin of the cost
  // Estimate each point's own error (see point_sigma_in_object) with the
  // twist; false: the whitening alone (the structure taken as exact in the
  // solve).
  bool estimate_point_errors = true;
  double function_tolerance = 1e-12;
  double parameter_tolerance = 1e-12;

  absl::Status Validate() const;
};

struct TwistEstimate {
  bool success = false;
  // Constrained twist of the step i−1 -> i in the world frame (Π ξ; δt = 1 frame).
  geometry::Vector6d twist = geometry::Vector6d::Zero();
  geometry::SE3d world_from_object;  // Exp(Π ξ) · world_from_object_{i−1}
  std::vector<bool> inliers;         // per observation
  int num_inliers = 0;
  double sigma_px = 0.0;       // final MAD scale
  double inlier_rms_px = 0.0;  // RMS of the inliers' residual norms
  int rounds = 0;
  int iterations = 0;  // LM iterations, all rounds
  // Gauss–Newton covariance of `twist` (world frame, one frame step):
  // B (Jᵀ W J / σ² + Bᵀ AᵀA B)⁻¹ Bᵀ over the inliers (A: the prior), with B the basis of range(Π),
  // J the residuals' Jacobian in that basis, W the Huber weights and σ the MAD scale. Supported on
  // range(Π). Valid only when `covariance_valid` (at least as many independent constraints as the
  // joint has degrees of freedom).
  geometry::Matrix6d covariance = geometry::Matrix6d::Zero();
  bool covariance_valid = false;
};

// Basis (6 x k, orthonormal columns) of range(Π); k = rank(Π).
Eigen::Matrix<double, 6, Eigen::Dynamic> ProjectorRangeBasis(const geometry::Matrix6d& projector);

// MAD scale estimate 1.4826 · median |r − median(r)| (0 for an empty input).
double MadScale(std::vector<double> residual_components);

// A zero-mean Gaussian prior on the twist, as rows of its square-root
// information: the residual A ξ (e.g. a car's rate of turn about its joint's
// axis, A = [0, axisᵀ] / σ). Empty: no prior.
struct TwistPrior {
  Eigen::Matrix<double, Eigen::Dynamic, 6> sqrt_information;
};

// Estimates the twist. `initial_twist` (e.g. the previous step's twist: the
// constant-velocity prediction) seeds the solver; it is projected with Π.
// InvalidArgument for bad options; too few inliers is reported as
// success == false (tracking an object can fail; that is data).
absl::StatusOr<TwistEstimate> EstimateObjectTwist(const geometry::StereoCamera& camera,
                                                  const geometry::SE3d& camera_from_world,
                                                  const geometry::SE3d& world_from_object_previous,
                                                  const geometry::Matrix6d& world_projector,
                                                  const std::vector<TwistObservation>& observations,
                                                  const geometry::Vector6d& initial_twist,
                                                  const TwistEstimatorOptions& options,
                                                  const TwistPrior& prior = {});

// Likelihood-ratio statistic of a twist estimate against the zero twist over
// the estimate's inlier observations, in units of its MAD scale:
//   Σ_inliers ‖r_j(0)‖²/σ² − ‖r_j(ξ*)‖²/σ².
// Under "the object did not move" it follows χ² with rank(Π) degrees of
// freedom. Observations whose point is behind the camera under either twist
// are skipped.
double TwistSignificance(const geometry::StereoCamera& camera,
                         const geometry::SE3d& camera_from_world,
                         const geometry::SE3d& world_from_object_previous,
                         const TwistEstimate& estimate,
                         const std::vector<TwistObservation>& observations);

// Upper quantile of the χ² distribution with dof ∈ [1, 6] degrees of freedom
// at confidence 0.95, 0.99 or 0.999 (the nearest tabulated confidence).
double ChiSquareQuantile(int dof, double confidence);

// Whitening of a stereo observation whose disparity has its own noise, k
// times the position's (TwistObservation::disparity_noise_ratio): with
// Cov = σ² S, S = [1 0 1; 0 1 0; 1 0 1 + k²] = L Lᵀ, L = [1 0 0; 0 1 0; 1 0 k],
// W = L⁻¹ maps the residual to (r_u, r_v, (r_ur − r_u)/k), each with noise σ.
// The identity for a mono observation or k = 0.
Eigen::Matrix3d StereoWhitening(const TwistObservation& observation);
// The same for a stereo observation with the ratio k given (k <= 0: identity).
Eigen::Matrix3d StereoWhitening(double disparity_noise_ratio);

// Whitening W of one observation's residual at a given twist and pixel scale
// σ. For an exact point, StereoWhitening. For a point with its own error g
// (the image of point_sigma_in_object), after the stereo whitening W_s:
// W = (I + h hᵀ/σ²)^(−1/2) W_s with h = W_s g, i.e.
// (I − (1 − 1/√(1 + |h|²/σ²)) ĥ ĥᵀ) W_s (3 x 3; the third row and column are
// unused for a mono observation). The point's error is dropped for a point
// not in front of the camera.
Eigen::Matrix3d ObservationWhitening(const geometry::StereoCamera& camera,
                                     const geometry::SE3d& camera_from_world,
                                     const geometry::SE3d& world_from_object_previous,
                                     const geometry::Vector6d& constrained_twist,
                                     const TwistObservation& observation,
                                     double sigma_px);

// Residual (observation − prediction) of one observation for a given twist;
// nullopt when the point is not in front of the camera.
std::optional<Eigen::Vector3d> TwistResidual(const geometry::StereoCamera& camera,
                                             const geometry::SE3d& camera_from_world,
                                             const geometry::SE3d& world_from_object_previous,
                                             const geometry::Vector6d& constrained_twist,
                                             const TwistObservation& observation);

}  // namespace twist::objects
