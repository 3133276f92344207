// Robust pose-only optimisation of one stereo camera (motion-only BA).
//
// Hand-rolled Gauss-Newton on the 6 pose parameters rather than Ceres: the
// problem has a single 6x6 block, and building a ceres::Problem (2000 residual
// blocks, autodiff, a solver per outlier round) costs several milliseconds per
// frame against ~1 ms for this loop; the tracker runs it 2-3 times per frame.
//
// Residuals: stereo observations (u, v, u_right) or monocular (u, v),
// weighted by 1 / sigma² of the keypoint's pyramid level, under a Huber loss
// with threshold sqrt(chi2(0.95)); four rounds of iterations, after each the
// observations are re-classified as inliers/outliers by their chi² (the last
// round without the robust loss), as in ORB-SLAM2's PoseOptimization.
// Internally the increment is applied on the left of camera_from_world
// (T <- Exp(δ) T), which gives the simplest Jacobian [I, -[p_c]x].
#pragma once

#include <Eigen/Core>
#include <vector>

#include "slam/geometry/se3.h"
#include "slam/geometry/stereo_camera.h"

namespace twist::tracking {

struct PoseObservation {
  Eigen::Vector3d p_in_world;
  Eigen::Vector2d uv;
  double u_right = -1.0;  // < 0: monocular observation
  double inv_sigma2 = 1.0;
  bool outlier = false;  // output (input: initial classification)
};

struct PoseOptimizerOptions {
  int rounds = 4;
  int iterations_per_round = 10;
  double chi2_mono = 5.991;    // 95% of chi²(2)
  double chi2_stereo = 7.815;  // 95% of chi²(3)
};

// Refines `camera_from_world` in place; returns the number of inliers.
int OptimizePose(const geometry::StereoCamera& camera,
                 std::vector<PoseObservation>* observations,
                 geometry::SE3d* camera_from_world,
                 const PoseOptimizerOptions& options = {});

}  // namespace twist::tracking
