#include "slam/objects/twist_estimator.h"

#include <ceres/ceres.h>
#include <glog/logging.h>

#include <Eigen/Cholesky>
#include <Eigen/SVD>
#include <algorithm>
#include <cmath>
#include <memory>
#include <optional>
#include <type_traits>

#include "slam/objects/subspace_manifold.h"
#include "slam/optimization/cost_functions/twist_tracking_cost.h"

namespace twist::objects {
namespace {

using geometry::Matrix6d;
using geometry::SE3d;
using geometry::Vector6d;
using Basis = Eigen::Matrix<double, 6, Eigen::Dynamic>;

// The constants of one observation's cost.
template <int N>
optimization::TwistTrackingObservation<N> CostConstants(const geometry::StereoCamera& camera,
                                                        const SE3d& camera_from_world,
                                                        const SE3d& world_from_object_previous,
                                                        const Matrix6d& projector,
                                                        const TwistObservation& obs,
                                                        const Eigen::Matrix3d& whitening,
                                                        double sqrt_information) {
  optimization::TwistTrackingObservation<N> o;
  o.camera = camera;
  if constexpr (N == 2) {
    o.observed = obs.uv;
  } else {
    o.observed = Eigen::Vector3d(obs.uv.x(), obs.uv.y(), obs.u_right);
  }
  o.sqrt_information = sqrt_information;
  o.whitening = whitening.topLeftCorner<N, N>();
  o.camera_from_world = camera_from_world;
  o.world_from_object_previous = world_from_object_previous;
  o.world_projector = projector;
  o.point_in_object = obs.point_in_object;
  o.point_sigma_in_object = obs.point_sigma_in_object;
  return o;
}

template <int N>
ceres::CostFunction* MakeSizedCost(const optimization::TwistTrackingObservation<N>& o,
                                   bool point_error,
                                   bool autodiff) {
  if (point_error) {
    if (autodiff) return optimization::TwistDepthTrackingFunctor<N>::Create(o);
    return new optimization::TwistDepthTrackingCost<N>(o);
  }
  if (autodiff) return optimization::TwistTrackingFunctor<N>::Create(o);
  return new optimization::TwistTrackingCost<N>(o);
}

// The cost of one observation, mono (2 rows) or stereo (3), with the point's
// own error δ as a second parameter block when `point_error`.
ceres::CostFunction* MakeCost(const geometry::StereoCamera& camera,
                              const SE3d& camera_from_world,
                              const SE3d& world_from_object_previous,
                              const Matrix6d& projector,
                              const TwistObservation& obs,
                              const Eigen::Matrix3d& whitening,
                              double sqrt_information,
                              bool point_error,
                              bool autodiff) {
  auto make = [&](auto rows) {
    constexpr int N = decltype(rows)::value;
    return MakeSizedCost<N>(CostConstants<N>(camera,
                                             camera_from_world,
                                             world_from_object_previous,
                                             projector,
                                             obs,
                                             whitening,
                                             sqrt_information),
                            point_error,
                            autodiff);
  };
  return obs.stereo() ? make(std::integral_constant<int, 3>{})
                      : make(std::integral_constant<int, 2>{});
}

// r = δ: the N(0, 1) prior of a point's own error.
class UnitPrior final : public ceres::SizedCostFunction<1, 1> {
 public:
  bool Evaluate(double const* const* parameters,
                double* residuals,
                double** jacobians) const override {
    residuals[0] = parameters[0][0];
    if (jacobians != nullptr && jacobians[0] != nullptr) jacobians[0][0] = 1.0;
    return true;
  }
};

// r = a·ξ: one row of a linear twist prior.
class LinearTwistPrior final : public ceres::SizedCostFunction<1, 6> {
 public:
  explicit LinearTwistPrior(const Vector6d& row) : row_(row) {}
  bool Evaluate(double const* const* parameters,
                double* residuals,
                double** jacobians) const override {
    residuals[0] = row_.dot(Eigen::Map<const Vector6d>(parameters[0]));
    if (jacobians != nullptr && jacobians[0] != nullptr) {
      Eigen::Map<Vector6d> jacobian(jacobians[0]);
      jacobian = row_;
    }
    return true;
  }

 private:
  Vector6d row_;
};

double Median(std::vector<double>* v) {
  if (v->empty()) return 0.0;
  const size_t mid = v->size() / 2;
  std::nth_element(v->begin(), v->begin() + static_cast<long>(mid), v->end());
  const double hi = (*v)[mid];
  if (v->size() % 2 == 1) return hi;
  const double lo = *std::max_element(v->begin(), v->begin() + static_cast<long>(mid));
  return 0.5 * (lo + hi);
}

}  // namespace

absl::Status TwistEstimatorOptions::Validate() const {
  if (max_rounds < 1 || max_iterations < 1) {
    return absl::InvalidArgumentError(
        "twist estimator needs max_rounds >= 1 and max_iterations >= 1");
  }
  if (!(huber_delta > 0.0) || !(min_sigma_px > 0.0) || !(max_sigma_px >= min_sigma_px)) {
    return absl::InvalidArgumentError(
        "twist estimator needs huber_delta > 0 and 0 < min_sigma_px <= max_sigma_px");
  }
  if (!(chi2_mono > 0.0) || !(chi2_stereo > 0.0)) {
    return absl::InvalidArgumentError("twist estimator chi2 gates must be > 0");
  }
  if (min_inliers < 1) return absl::InvalidArgumentError("twist estimator min_inliers < 1");
  return absl::OkStatus();
}

Basis ProjectorRangeBasis(const Matrix6d& projector) {
  Eigen::JacobiSVD<Matrix6d> svd(projector, Eigen::ComputeFullU);
  const Vector6d s = svd.singularValues();
  int rank = 0;
  for (int k = 0; k < 6; ++k) rank += s(k) > 1e-9 * std::max(1.0, s(0)) ? 1 : 0;
  return svd.matrixU().leftCols(rank);
}

double MadScale(std::vector<double> r) {
  if (r.empty()) return 0.0;
  const double med = Median(&r);
  for (double& x : r) x = std::abs(x - med);
  return 1.4826 * Median(&r);
}

std::optional<Eigen::Vector3d> TwistResidual(const geometry::StereoCamera& camera,
                                             const SE3d& camera_from_world,
                                             const SE3d& world_from_object_previous,
                                             const Vector6d& constrained_twist,
                                             const TwistObservation& obs) {
  const Eigen::Vector3d p_c =
      camera_from_world *
      (SE3d::Exp(constrained_twist) * (world_from_object_previous * obs.point_in_object));
  Eigen::Vector3d uvr;
  if (!camera.ProjectStereoChecked(p_c, &uvr, nullptr, 1e-3)) return std::nullopt;
  return Eigen::Vector3d(
      obs.uv.x() - uvr.x(), obs.uv.y() - uvr.y(), obs.stereo() ? obs.u_right - uvr.z() : 0.0);
}

Eigen::Matrix3d StereoWhitening(const TwistObservation& obs) {
  return obs.stereo() ? StereoWhitening(obs.disparity_noise_ratio) : Eigen::Matrix3d::Identity();
}

Eigen::Matrix3d StereoWhitening(double k) {
  Eigen::Matrix3d w = Eigen::Matrix3d::Identity();
  if (!(k > 0.0)) return w;
  // The inverse of S's Cholesky factor L = [1 0 0; 0 1 0; 1 0 k].
  w(2, 0) = -1.0 / k;
  w(2, 2) = 1.0 / k;
  return w;
}

Eigen::Matrix3d ObservationWhitening(const geometry::StereoCamera& camera,
                                     const SE3d& camera_from_world,
                                     const SE3d& world_from_object_previous,
                                     const Vector6d& constrained_twist,
                                     const TwistObservation& obs,
                                     double sigma_px) {
  Eigen::Matrix3d w = StereoWhitening(obs);
  if (obs.point_sigma_in_object.isZero() || !(sigma_px > 0.0)) return w;
  const SE3d camera_from_object =
      camera_from_world * SE3d::Exp(constrained_twist) * world_from_object_previous;
  const Eigen::Vector3d p_c = camera_from_object * obs.point_in_object;
  if (!(p_c.z() > optimization::kMinProjectionDepth)) return w;
  const Eigen::Vector3d d_c = camera_from_object.rotation() * obs.point_sigma_in_object;
  Eigen::Vector3d g = Eigen::Vector3d::Zero();
  if (obs.stereo()) {
    g = optimization::ProjectionJacobian<3>(camera, p_c) * d_c;
  } else {
    g.head<2>() = optimization::ProjectionJacobian<2>(camera, p_c) * d_c;
  }
  g = w * g;  // in the stereo-whitened residual space
  const double g2 = g.squaredNorm() / (sigma_px * sigma_px);
  if (!(g2 > 0.0)) return w;
  const Eigen::Vector3d unit = g.normalized();
  return (Eigen::Matrix3d::Identity() -
          (1.0 - 1.0 / std::sqrt(1.0 + g2)) * unit * unit.transpose()) *
         w;
}

absl::StatusOr<TwistEstimate> EstimateObjectTwist(const geometry::StereoCamera& camera,
                                                  const SE3d& camera_from_world,
                                                  const SE3d& world_from_object_previous,
                                                  const Matrix6d& world_projector,
                                                  const std::vector<TwistObservation>& observations,
                                                  const Vector6d& initial_twist,
                                                  const TwistEstimatorOptions& options,
                                                  const TwistPrior& prior) {
  if (absl::Status s = options.Validate(); !s.ok()) return s;
  const size_t n = observations.size();
  TwistEstimate est;
  est.inliers.assign(n, false);
  const Basis basis = ProjectorRangeBasis(world_projector);
  // Start inside range(Π): ξ0 = B Bᵀ Π ξ_init.
  Vector6d xi = basis * (basis.transpose() * (world_projector * initial_twist));

  // Whitened residuals W_j r_j at a twist, W_j at that twist and scale σ.
  std::vector<Eigen::Matrix3d> whitening(n, Eigen::Matrix3d::Identity());
  auto update_whitening = [&](const Vector6d& twist, double sigma_px) {
    for (size_t j = 0; j < n; ++j) {
      whitening[j] = ObservationWhitening(
          camera, camera_from_world, world_from_object_previous, twist, observations[j], sigma_px);
    }
  };
  auto residuals_at = [&](const Vector6d& twist) {
    std::vector<std::optional<Eigen::Vector3d>> res(n);
    for (size_t j = 0; j < n; ++j) {
      res[j] = TwistResidual(
          camera, camera_from_world, world_from_object_previous, twist, observations[j]);
      if (res[j]) *res[j] = whitening[j] * *res[j];
    }
    return res;
  };
  // MAD over the stacked components of the given observations.
  auto mad = [&](const std::vector<std::optional<Eigen::Vector3d>>& res,
                 const std::vector<bool>* subset) {
    std::vector<double> comps;
    for (size_t j = 0; j < n; ++j) {
      if (!res[j] || (subset != nullptr && !(*subset)[j])) continue;
      comps.push_back((*res[j])(0));
      comps.push_back((*res[j])(1));
      if (observations[j].stereo()) comps.push_back((*res[j])(2));
    }
    return std::clamp(MadScale(comps), options.min_sigma_px, options.max_sigma_px);
  };

  std::vector<double> point_errors(n, 0.0);  // δ_j, in units of σ_j
  std::vector<std::optional<Eigen::Vector3d>> res = residuals_at(xi);
  std::vector<bool> active(n);
  for (size_t j = 0; j < n; ++j) active[j] = res[j].has_value();
  double sigma = mad(res, &active);
  // Whitened: points with their own error, stereo with its own disparity noise.
  const bool whitened =
      std::any_of(observations.begin(), observations.end(), [](const TwistObservation& o) {
        return !o.point_sigma_in_object.isZero() || (o.stereo() && o.disparity_noise_ratio > 0.0);
      });
  if (whitened) {  // whitened at the first scale, then the scale again
    update_whitening(xi, sigma);
    res = residuals_at(xi);
    sigma = mad(res, &active);
  }

  for (int round = 0; round < options.max_rounds; ++round) {
    const int num_active = static_cast<int>(std::count(active.begin(), active.end(), true));
    if (num_active < options.min_inliers) break;
    est.rounds = round + 1;
    if (basis.cols() > 0) {
      ceres::Problem::Options problem_options;
      problem_options.manifold_ownership = ceres::TAKE_OWNERSHIP;
      ceres::Problem problem(problem_options);
      double* x = xi.data();
      const auto ordering = std::make_shared<ceres::ParameterBlockOrdering>();
      for (size_t j = 0; j < n; ++j) {
        if (!active[j]) continue;
        const TwistObservation& ob = observations[j];
        // With its own error along its uncertain direction (prior N(0, 1)):
        // the twist and the structure's errors together (errors in
        // variables), not the twist under a structure taken as exact.
        // Otherwise an exact point (identity whitening), or the whitening
        // alone.
        const bool point_error =
            options.estimate_point_errors && !ob.point_sigma_in_object.isZero();
        ceres::CostFunction* cost = MakeCost(camera,
                                             camera_from_world,
                                             world_from_object_previous,
                                             world_projector,
                                             ob,
                                             point_error ? StereoWhitening(ob) : whitening[j],
                                             1.0 / sigma,
                                             point_error,
                                             options.use_autodiff);
        if (point_error) {
          problem.AddResidualBlock(
              cost, new ceres::HuberLoss(options.huber_delta), x, &point_errors[j]);
          problem.AddResidualBlock(new UnitPrior, nullptr, &point_errors[j]);
          ordering->AddElementToGroup(&point_errors[j], 0);
        } else {
          problem.AddResidualBlock(cost, new ceres::HuberLoss(options.huber_delta), x);
        }
      }
      for (Eigen::Index row = 0; row < prior.sqrt_information.rows(); ++row) {
        problem.AddResidualBlock(
            new LinearTwistPrior(prior.sqrt_information.row(row).transpose()), nullptr, x);
      }
      ordering->AddElementToGroup(x, 1);
      if (basis.cols() < 6) problem.SetManifold(x, new LinearSubspaceManifold(basis));
      ceres::Solver::Options solver_options;
      solver_options.minimizer_type = ceres::TRUST_REGION;
      solver_options.trust_region_strategy_type = ceres::LEVENBERG_MARQUARDT;
      if (ordering->NumElements() > 1) {
        solver_options.linear_solver_type = ceres::DENSE_SCHUR;
        solver_options.linear_solver_ordering = ordering;
      } else {
        solver_options.linear_solver_type = ceres::DENSE_QR;
      }
      solver_options.max_num_iterations = options.max_iterations;
      solver_options.function_tolerance = options.function_tolerance;
      solver_options.parameter_tolerance = options.parameter_tolerance;
      solver_options.gradient_tolerance = 1e-14;
      solver_options.num_threads = 1;
      solver_options.logging_type = ceres::SILENT;
      ceres::Solver::Summary summary;
      ceres::Solve(solver_options, &problem, &summary);
      est.iterations += static_cast<int>(summary.iterations.size());
    }
    // New scale from the current inliers (whitened at the new twist), then
    // re-gate every observation.
    if (whitened) update_whitening(xi, sigma);
    res = residuals_at(xi);
    sigma = mad(res, &active);
    std::vector<bool> next(n, false);
    for (size_t j = 0; j < n; ++j) {
      if (!res[j]) continue;
      const double chi2 = res[j]->squaredNorm() / (sigma * sigma);
      next[j] = chi2 <= (observations[j].stereo() ? options.chi2_stereo : options.chi2_mono);
    }
    const bool stable = next == active;
    active = std::move(next);
    if (stable) break;
  }

  est.twist = world_projector * xi;
  // Π is idempotent and xi lies in its range, so Π ξ == ξ up to round-off;
  // report the projected value (what the pose update uses).
  est.world_from_object = SE3d::Exp(est.twist) * world_from_object_previous;
  est.inliers = active;
  est.num_inliers = static_cast<int>(std::count(active.begin(), active.end(), true));
  est.sigma_px = sigma;
  double sum = 0.0;
  for (size_t j = 0; j < n; ++j) {
    if (active[j] && res[j]) sum += res[j]->squaredNorm();
  }
  est.inlier_rms_px = est.num_inliers > 0 ? std::sqrt(sum / est.num_inliers) : 0.0;
  est.success = est.num_inliers >= options.min_inliers;
  if (est.success && basis.cols() > 0) {
    // Information Jᵀ W J / σ² in the basis, with the cost's analytic Jacobian
    // (residuals unscaled: sqrt_information 1). The scale is the MAD over
    // every observation: it is robust to the outliers, and the inliers alone
    // are a sample truncated by the χ² gate.
    const Eigen::Index k = basis.cols();
    const double scale_all = mad(res, nullptr);
    const double huber2 = options.huber_delta * options.huber_delta;
    Eigen::MatrixXd info = Eigen::MatrixXd::Zero(k, k);
    for (size_t j = 0; j < n; ++j) {
      if (!active[j]) continue;
      const bool stereo = observations[j].stereo();
      const std::unique_ptr<ceres::CostFunction> cost(MakeCost(camera,
                                                               camera_from_world,
                                                               world_from_object_previous,
                                                               world_projector,
                                                               observations[j],
                                                               whitening[j],
                                                               1.0,
                                                               false,
                                                               false));
      const int rows = stereo ? 3 : 2;
      double r[3];
      Eigen::Matrix<double, 3, 6, Eigen::RowMajor> jac6;
      double* jacobians[1] = {jac6.data()};
      const double* parameters[1] = {xi.data()};
      if (!cost->Evaluate(parameters, r, jacobians)) continue;
      const Eigen::MatrixXd jac = jac6.topRows(rows) * basis;
      const double s2 =
          Eigen::Map<const Eigen::VectorXd>(r, rows).squaredNorm() / (scale_all * scale_all);
      const double weight = s2 <= huber2 ? 1.0 : options.huber_delta / std::sqrt(s2);
      info += weight * jac.transpose() * jac / (scale_all * scale_all);
    }
    const Eigen::MatrixXd prior_rows = prior.sqrt_information * basis;
    info += prior_rows.transpose() * prior_rows;
    Eigen::LDLT<Eigen::MatrixXd> ldlt(info);
    const double info_scale = std::max(1.0, info.diagonal().maxCoeff());
    if (ldlt.info() == Eigen::Success && ldlt.isPositive() &&
        ldlt.vectorD().minCoeff() > 1e-12 * info_scale) {
      est.covariance = basis * ldlt.solve(Eigen::MatrixXd::Identity(k, k)) * basis.transpose();
      est.covariance_valid = true;
    }
  }
  return est;
}

double TwistSignificance(const geometry::StereoCamera& camera,
                         const SE3d& camera_from_world,
                         const SE3d& world_from_object_previous,
                         const TwistEstimate& estimate,
                         const std::vector<TwistObservation>& observations) {
  CHECK_EQ(estimate.inliers.size(), observations.size());
  const double sigma2 = estimate.sigma_px * estimate.sigma_px;
  if (!(sigma2 > 0.0)) return 0.0;
  double gain = 0.0;
  for (size_t j = 0; j < observations.size(); ++j) {
    if (!estimate.inliers[j]) continue;
    const auto r0 = TwistResidual(
        camera, camera_from_world, world_from_object_previous, Vector6d::Zero(), observations[j]);
    const auto r1 = TwistResidual(
        camera, camera_from_world, world_from_object_previous, estimate.twist, observations[j]);
    if (!r0 || !r1) continue;
    const Eigen::Matrix3d w = ObservationWhitening(camera,
                                                   camera_from_world,
                                                   world_from_object_previous,
                                                   estimate.twist,
                                                   observations[j],
                                                   estimate.sigma_px);
    gain += ((w * *r0).squaredNorm() - (w * *r1).squaredNorm()) / sigma2;
  }
  return gain;
}

double ChiSquareQuantile(int dof, double confidence) {
  CHECK(dof >= 1 && dof <= 6) << "chi-square table covers 1..6 degrees of freedom, got " << dof;
  static constexpr double kTable[3][6] = {
      {3.841, 5.991, 7.815, 9.488, 11.070, 12.592},       // 0.95
      {6.635, 9.210, 11.345, 13.277, 15.086, 16.812},     // 0.99
      {10.828, 13.816, 16.266, 18.467, 20.515, 22.458}};  // 0.999
  const int row = confidence < 0.97 ? 0 : (confidence < 0.995 ? 1 : 2);
  return kTable[row][dof - 1];
}

}  // namespace twist::objects
