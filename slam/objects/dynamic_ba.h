// Dynamic bundle adjustment (paper §IV-F, eq. ba):
//
//   E = Σ e_stat + Σ e_dyna + Σ e_const
//   e_stat  = ρ(‖x_ij − π(c_i T_w · w X_j)‖_Σ)
//   e_dyna  = ρ(‖x_ij − π(c_i T_w · Exp(Π ξ̃_i) · w T_o(i) · o X_j)‖_Σ)
//   e_const = ρ(‖Π ξ_{i+1} − Π ξ_i‖_W),  ξ_{i+1} = Log(P_{i+1} P_i⁻¹),  P_i = Exp(Π ξ̃_i) w T_o(i)
//   e_acc   = ρ(‖Π (ξ_{i+1} − 2 ξ_i + ξ_{i−1})‖_W')  (constant acceleration; optional)
//   e_norm  = (nᵀ v(ξ_{i+1})) / σ_n  (step along a soft normal; optional)
//
// over a window of keyframes: the temporal set (every frame of the last
// temporal_window_s seconds) where camera AND object poses are optimised, and
// the spatial set (covisible keyframes) where only camera poses are. Object
// poses are optimised through the constrained corrections ξ̃_i (the stored
// poses are constant blocks), exactly as in the paper; dynamic observations in
// keyframes where the object's pose is fixed still constrain the camera and
// the object's points. Ceres with the Schur complement (SPARSE_SCHUR or
// DENSE_SCHUR); analytic costs from slam/optimization/cost_functions, with a
// switch to their autodiff twins for checking.
//
// Plain data in and out, so that the mapper can build it from its map.
#pragma once

#include <Eigen/Core>
#include <cstdint>
#include <string>
#include <vector>

#include "absl/status/status.h"
#include "absl/status/statusor.h"
#include "slam/geometry/se3.h"
#include "slam/geometry/stereo_camera.h"

namespace twist::objects {

struct BaKeyframe {
  int64_t id = 0;
  int64_t timestamp_ns = 0;
  geometry::SE3d camera_from_world;
  bool temporal = true;  // in the temporal window (else spatial: camera pose only)
  bool fixed = false;    // gauge / outside the window
};

struct BaStaticPoint {
  int64_t id = 0;
  Eigen::Vector3d point_in_world = Eigen::Vector3d::Zero();
  bool fixed = false;
};

// An observation of a point (static: index into DynamicBaProblem::points;
// dynamic: index into BaObject::points_in_object) in a keyframe (index into
// DynamicBaProblem::keyframes).
struct BaObservation {
  int keyframe = 0;
  int point = 0;
  Eigen::Vector2d uv = Eigen::Vector2d::Zero();
  double u_right = -1.0;  // < 0: mono
  double sigma_px = 1.0;  // standard deviation of the measurement
  // Dynamic stereo observations: the disparity's own noise as a multiple k
  // of the position's (TwistObservation::disparity_noise_ratio). The
  // residual is then whitened as the twist estimator does (StereoWhitening:
  // (r_u, r_v, (r_ur − r_u)/k)), since u_right = u − d carries u's error.
  // 0: the three rows independent, each with the position's noise. Static
  // observations take 0.
  double disparity_noise_ratio = 0.0;
};

struct BaObjectFrame {
  int keyframe = 0;  // index into DynamicBaProblem::keyframes
  geometry::SE3d world_from_object;
  // Held fixed (e.g. the object's first frame in the window — the gauge of
  // its points — or a keyframe outside the temporal set).
  bool fixed = false;
  // Whether this frame comes one step after the previous one of the object
  // (false after a gap, when the object was lost): the constant-velocity
  // term only spans triplets of consecutive steps.
  bool follows_previous = true;
};

struct BaObject {
  int64_t id = 0;
  // World projector Π of the object's joint (identity for a free object).
  geometry::Matrix6d world_projector = geometry::Matrix6d::Identity();
  std::vector<BaObjectFrame> frames;  // in time order; consecutive frames get e_const
  std::vector<Eigen::Vector3d> points_in_object;
  std::vector<BaObservation> observations;
  // Per point of points_in_object, held where it is (empty: every point is
  // free). A sliding window holds the points it inherits from earlier
  // windows (ObjectBaOptions::hold_points_seen_before_window).
  std::vector<bool> fixed_points;
  // Per point (empty: none), the square root A of the information of a
  // Gaussian prior on the point at its value in points_in_object: the
  // residual A (x − x₀) (a zero matrix: no prior for that point).
  std::vector<Eigen::Matrix3d> point_prior_sqrt_information;
  // A soft freedom along a unit world direction (the normal of a planar
  // joint's plane): world_projector then includes translation along it, and
  // each step between consecutive frames gets the Gaussian prior
  // (nᵀ v(s)) / soft_normal_step_sigma_m (docs/objects.md section 30).
  // 0: none.
  Eigen::Vector3d soft_normal = Eigen::Vector3d::Zero();
  double soft_normal_step_sigma_m = 0.0;
};

struct DynamicBaProblem {
  geometry::StereoCamera camera;
  std::vector<BaKeyframe> keyframes;
  std::vector<BaStaticPoint> points;
  std::vector<BaObservation> observations;  // static
  std::vector<BaObject> objects;

  // InvalidArgument naming the first bad index / missing object frame.
  absl::Status Validate() const;
};

enum class BaLinearSolver { kSparseSchur, kDenseSchur };

struct DynamicBaOptions {
  int max_iterations = 10;
  double huber_delta = 2.447;  // on residuals in σ units (√χ²₂(0.95))
  // > 0 (the default, 7): the objects' reprojection terms take Tukey's
  // biweight at this many σ (their MAD σ, see mad_sigma_for_dynamic), which
  // gives no weight at all to a match more than c σ off (the patch matches
  // of a turning car have a one-sided tail that Huber's linear tail still
  // follows, docs/objects.md section 42). 0: Huber at huber_delta, as the
  // static terms. On the 24 rendered object runs, 7 against Huber: the
  // moving cars' RPE_R 0.2020 -> 0.1985 deg/m, ATE 0.0902 -> 0.0877 m
  // (docs/objects.md section 67).
  double dynamic_tukey_c = 7.0;
  // W^{1/2}: per-component weights of the constant-velocity term, (v, ω) in
  // 1/m and 1/rad per frame step: a change of velocity of 2.5 cm and of
  // 0.29° per frame step costs one σ. Half these weights let the objects'
  // BA fit the observation noise (docs/objects.md section 22).
  geometry::Vector6d const_velocity_sqrt_weight =
      (geometry::Vector6d() << 40, 40, 40, 200, 200, 200).finished();
  // W^{1/2} of the constant-acceleration term (Π (s_{i+1} − 2 s_i + s_{i−1})
  // over four consecutive frames, per frame step squared); zero: no term.
  geometry::Vector6d const_acceleration_sqrt_weight = geometry::Vector6d::Zero();
  // Huber threshold of both motion priors (in units of their σ).
  double const_velocity_huber = 1.0;
  // false: neither motion prior.
  bool use_const_velocity = true;
  // σ of each object's observations from the MAD of its initial residuals
  // (paper) instead of BaObservation::sigma_px; clamped below.
  bool mad_sigma_for_dynamic = true;
  double min_sigma_px = 0.5;
  bool constrained = true;  // false: Π = I for every object (free 6-DoF)
  bool use_autodiff = false;
  BaLinearSolver linear_solver = BaLinearSolver::kSparseSchur;
  // Fix the oldest keyframe when the problem has no fixed keyframe (gauge).
  bool fix_oldest_keyframe_if_none_fixed = true;
  int num_threads = 1;

  absl::Status Validate() const;
};

struct DynamicBaSummary {
  double initial_cost = 0.0;
  double final_cost = 0.0;
  int iterations = 0;
  int num_residual_blocks = 0;
  int num_static_terms = 0;
  int num_dynamic_terms = 0;
  int num_const_velocity_terms = 0;
  int num_const_acceleration_terms = 0;
  int num_normal_step_terms = 0;
  bool usable = false;
  std::string message;
};

// The temporal set: keyframes with timestamp >= newest − window (paper: 5 s).
bool InTemporalWindow(int64_t timestamp_ns, int64_t newest_timestamp_ns, double temporal_window_s);

// Solves in place: keyframe poses, static points, object poses
// (world_from_object <- Exp(Π ξ̃) world_from_object) and object points are
// updated. InvalidArgument for an inconsistent problem.
absl::StatusOr<DynamicBaSummary> SolveDynamicBa(DynamicBaProblem* problem,
                                                const DynamicBaOptions& options);

// World twists linking consecutive frames of an object, Log(P_{k+1} P_k⁻¹)
// (one per consecutive pair), after a solve.
std::vector<geometry::Vector6d> ObjectStepTwists(const BaObject& object);

}  // namespace twist::objects
