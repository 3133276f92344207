#include "slam/objects/dynamic_ba.h"

#include <ceres/ceres.h>
#include <ceres/normal_prior.h>
#include <glog/logging.h>

#include <algorithm>
#include <array>
#include <cmath>
#include <memory>
#include <optional>
#include <unordered_map>

#include "slam/objects/subspace_manifold.h"
#include "slam/objects/twist_estimator.h"
#include "slam/optimization/cost_functions/constant_velocity_cost.h"
#include "slam/optimization/cost_functions/dynamic_reprojection_cost.h"
#include "slam/optimization/cost_functions/reprojection_cost.h"
#include "slam/optimization/manifolds/se3_manifold.h"

namespace twist::objects {

using geometry::Matrix6d;
using geometry::SE3d;
using geometry::Vector6d;

namespace {

std::string Where(const char* what, size_t i) {
  return std::string(what) + " " + std::to_string(i);
}

absl::Status CheckObservation(const BaObservation& o,
                              int num_keyframes,
                              int num_points,
                              const std::string& where) {
  if (o.keyframe < 0 || o.keyframe >= num_keyframes) {
    return absl::InvalidArgumentError(where + ": keyframe index " + std::to_string(o.keyframe) +
                                      " out of range");
  }
  if (o.point < 0 || o.point >= num_points) {
    return absl::InvalidArgumentError(where + ": point index " + std::to_string(o.point) +
                                      " out of range");
  }
  if (!(o.sigma_px > 0.0) || !o.uv.allFinite()) {
    return absl::InvalidArgumentError(where + ": needs a finite uv and sigma_px > 0");
  }
  if (!(o.disparity_noise_ratio >= 0.0) || !std::isfinite(o.disparity_noise_ratio)) {
    return absl::InvalidArgumentError(where + ": needs a finite disparity_noise_ratio >= 0");
  }
  return absl::OkStatus();
}

template <int N>
Eigen::Matrix<double, N, 1> Measurement(const BaObservation& o) {
  if constexpr (N == 2) {
    return o.uv;
  } else {
    return Eigen::Vector3d(o.uv.x(), o.uv.y(), o.u_right);
  }
}

// Residual norm of a dynamic observation at the current state (pixels).
std::optional<double> DynamicResidual(const geometry::StereoCamera& cam,
                                      const SE3d& camera_from_world,
                                      const SE3d& world_from_object,
                                      const Eigen::Vector3d& p_o,
                                      const BaObservation& o,
                                      std::vector<double>* comps) {
  Eigen::Vector3d uvr;
  if (!cam.ProjectStereoChecked(
          camera_from_world * (world_from_object * p_o), &uvr, nullptr, 1e-3)) {
    return std::nullopt;
  }
  const Eigen::Vector3d r(o.uv.x() - uvr.x(), o.uv.y() - uvr.y(), o.u_right - uvr.z());
  comps->push_back(r.x());
  comps->push_back(r.y());
  if (o.u_right >= 0.0) comps->push_back((StereoWhitening(o.disparity_noise_ratio) * r).z());
  return 0.0;
}

}  // namespace

absl::Status DynamicBaProblem::Validate() const {
  if (absl::Status s = camera.Validate(); !s.ok()) return s;
  const int nk = static_cast<int>(keyframes.size());
  for (size_t i = 0; i < observations.size(); ++i) {
    if (absl::Status s = CheckObservation(
            observations[i], nk, static_cast<int>(points.size()), Where("static observation", i));
        !s.ok()) {
      return s;
    }
    if (observations[i].disparity_noise_ratio != 0.0) {
      return absl::InvalidArgumentError(Where("static observation", i) +
                                        ": static terms take no disparity_noise_ratio");
    }
  }
  for (size_t k = 0; k < objects.size(); ++k) {
    const BaObject& obj = objects[k];
    std::vector<bool> has_frame(keyframes.size(), false);
    for (const BaObjectFrame& f : obj.frames) {
      if (f.keyframe < 0 || f.keyframe >= nk) {
        return absl::InvalidArgumentError(Where("object", k) +
                                          ": frame keyframe index out of range");
      }
      if (has_frame[static_cast<size_t>(f.keyframe)]) {
        return absl::InvalidArgumentError(Where("object", k) + ": two poses in one keyframe");
      }
      has_frame[static_cast<size_t>(f.keyframe)] = true;
    }
    if (!obj.point_prior_sqrt_information.empty() &&
        (obj.point_prior_sqrt_information.size() != obj.points_in_object.size() ||
         std::any_of(obj.point_prior_sqrt_information.begin(),
                     obj.point_prior_sqrt_information.end(),
                     [](const Eigen::Matrix3d& a) { return !a.allFinite(); }))) {
      return absl::InvalidArgumentError(Where("object", k) +
                                        ": point priors need one finite matrix per point or none");
    }
    if (!obj.fixed_points.empty() && obj.fixed_points.size() != obj.points_in_object.size()) {
      return absl::InvalidArgumentError(Where("object", k) +
                                        ": fixed_points needs one flag per point or none");
    }
    if (obj.soft_normal_step_sigma_m < 0.0 ||
        (obj.soft_normal_step_sigma_m > 0.0 && std::abs(obj.soft_normal.norm() - 1.0) > 1e-6)) {
      return absl::InvalidArgumentError(Where("object", k) +
                                        ": a soft normal needs a unit direction and sigma >= 0");
    }
    for (size_t i = 0; i < obj.observations.size(); ++i) {
      const BaObservation& o = obj.observations[i];
      const std::string where = Where("object", k) + " " + Where("observation", i);
      if (absl::Status s =
              CheckObservation(o, nk, static_cast<int>(obj.points_in_object.size()), where);
          !s.ok()) {
        return s;
      }
      if (!has_frame[static_cast<size_t>(o.keyframe)]) {
        return absl::InvalidArgumentError(where + ": the object has no pose in that keyframe");
      }
    }
  }
  return absl::OkStatus();
}

absl::Status DynamicBaOptions::Validate() const {
  if (max_iterations < 1) return absl::InvalidArgumentError("dynamic BA max_iterations < 1");
  if (!(huber_delta > 0.0) || !(const_velocity_huber > 0.0) || !(min_sigma_px > 0.0)) {
    return absl::InvalidArgumentError("dynamic BA Huber thresholds and min_sigma_px must be > 0");
  }
  if (!(dynamic_tukey_c >= 0.0) || !std::isfinite(dynamic_tukey_c)) {
    return absl::InvalidArgumentError("dynamic BA dynamic_tukey_c must be finite and >= 0");
  }
  if (!(const_velocity_sqrt_weight.array() >= 0.0).all() ||
      !(const_acceleration_sqrt_weight.array() >= 0.0).all()) {
    return absl::InvalidArgumentError("dynamic BA motion-prior weights must be >= 0");
  }
  return absl::OkStatus();
}

bool InTemporalWindow(int64_t timestamp_ns, int64_t newest_timestamp_ns, double temporal_window_s) {
  return static_cast<double>(newest_timestamp_ns - timestamp_ns) <= temporal_window_s * 1e9;
}

std::vector<Vector6d> ObjectStepTwists(const BaObject& object) {
  std::vector<Vector6d> out;
  for (size_t k = 1; k < object.frames.size(); ++k) {
    out.push_back(
        (object.frames[k].world_from_object * object.frames[k - 1].world_from_object.Inverse())
            .Log());
  }
  return out;
}

absl::StatusOr<DynamicBaSummary> SolveDynamicBa(DynamicBaProblem* problem,
                                                const DynamicBaOptions& options) {
  CHECK(problem != nullptr);
  if (absl::Status s = options.Validate(); !s.ok()) return s;
  if (absl::Status s = problem->Validate(); !s.ok()) return s;
  const geometry::StereoCamera& cam = problem->camera;
  DynamicBaSummary summary;

  ceres::Problem::Options problem_options;
  problem_options.manifold_ownership = ceres::DO_NOT_TAKE_OWNERSHIP;
  ceres::Problem ceres_problem(problem_options);
  optimization::SE3Manifold se3_manifold;
  std::vector<std::unique_ptr<ceres::Manifold>> manifolds;  // outlive the solve

  // Parameter storage: every block lives in ONE buffer, laid out in a fixed
  // logical order (static points, each object's points, each object's
  // corrections ξ̃ and poses, keyframes). Ceres' ParameterBlockOrdering keeps
  // each elimination group as a std::set<double*>, i.e. ordered by address;
  // with one buffer in logical order the address order IS the logical order,
  // independent of the heap's state, so identical problems give bit-identical
  // solutions (the synchronous engine relies on it). Nothing else below
  // depends on addresses: residual blocks are added in problem order.
  const size_t nk = problem->keyframes.size();
  size_t arena_size = 3 * problem->points.size() + 7 * nk;
  for (const BaObject& obj : problem->objects)
    arena_size += 3 * obj.points_in_object.size() + 13 * obj.frames.size();
  std::vector<double> arena(arena_size, 0.0);  // never resized below
  size_t arena_used = 0;
  auto take = [&](size_t n) {
    CHECK_LE(arena_used + n, arena.size());
    double* x = arena.data() + arena_used;
    arena_used += n;
    return x;
  };
  std::vector<double*> point_params(problem->points.size());
  for (size_t j = 0; j < problem->points.size(); ++j) {
    point_params[j] = take(3);
    Eigen::Map<Eigen::Vector3d> x(point_params[j]);
    x = problem->points[j].point_in_world;
  }
  struct ObjectParams {
    std::vector<double*> twist;
    std::vector<double*> pose;
    std::vector<double*> points;
    std::vector<int> frame_of_keyframe;
    Matrix6d projector;
  };
  std::vector<ObjectParams> obj_params(problem->objects.size());
  for (size_t k = 0; k < problem->objects.size(); ++k) {
    const BaObject& obj = problem->objects[k];
    ObjectParams& op = obj_params[k];
    op.points.resize(obj.points_in_object.size());
    for (size_t j = 0; j < obj.points_in_object.size(); ++j) {
      op.points[j] = take(3);
      Eigen::Map<Eigen::Vector3d> x(op.points[j]);
      x = obj.points_in_object[j];
    }
  }
  for (size_t k = 0; k < problem->objects.size(); ++k) {
    const BaObject& obj = problem->objects[k];
    ObjectParams& op = obj_params[k];
    op.twist.resize(obj.frames.size());
    op.pose.resize(obj.frames.size());
    for (size_t f = 0; f < obj.frames.size(); ++f) op.twist[f] = take(6);  // ξ̃ = 0
    for (size_t f = 0; f < obj.frames.size(); ++f) {
      op.pose[f] = take(7);
      obj.frames[f].world_from_object.ToParams(op.pose[f]);
    }
  }
  std::vector<double*> kf_params(nk);
  for (size_t i = 0; i < nk; ++i) {
    kf_params[i] = take(7);
    problem->keyframes[i].camera_from_world.ToParams(kf_params[i]);
  }
  CHECK_EQ(arena_used, arena.size());

  bool any_fixed = false;
  for (const BaKeyframe& kf : problem->keyframes) any_fixed |= kf.fixed;
  size_t oldest = 0;
  for (size_t i = 1; i < nk; ++i) {
    if (problem->keyframes[i].timestamp_ns < problem->keyframes[oldest].timestamp_ns) oldest = i;
  }
  auto add_keyframe = [&](int i) {
    double* x = kf_params[static_cast<size_t>(i)];
    if (ceres_problem.HasParameterBlock(x)) return x;
    ceres_problem.AddParameterBlock(x, 7, &se3_manifold);
    const bool fix = problem->keyframes[static_cast<size_t>(i)].fixed ||
                     (!any_fixed && options.fix_oldest_keyframe_if_none_fixed &&
                      static_cast<size_t>(i) == oldest);
    if (fix) ceres_problem.SetParameterBlockConstant(x);
    return x;
  };

  // Static terms.
  for (const BaObservation& o : problem->observations) {
    double* x = add_keyframe(o.keyframe);
    double* p = point_params[static_cast<size_t>(o.point)];
    const double s = 1.0 / o.sigma_px;
    ceres::CostFunction* cost;
    if (o.u_right >= 0.0) {
      cost = options.use_autodiff
                 ? optimization::ReprojectionFunctor<3>::Create(cam, Measurement<3>(o), s)
                 : static_cast<ceres::CostFunction*>(
                       new optimization::ReprojectionCost<3>(cam, Measurement<3>(o), s));
    } else {
      cost = options.use_autodiff
                 ? optimization::ReprojectionFunctor<2>::Create(cam, Measurement<2>(o), s)
                 : static_cast<ceres::CostFunction*>(
                       new optimization::ReprojectionCost<2>(cam, Measurement<2>(o), s));
    }
    ceres_problem.AddResidualBlock(cost, new ceres::HuberLoss(options.huber_delta), x, p);
    if (problem->points[static_cast<size_t>(o.point)].fixed)
      ceres_problem.SetParameterBlockConstant(p);
    ++summary.num_static_terms;
  }

  // Dynamic terms.
  for (size_t k = 0; k < problem->objects.size(); ++k) {
    const BaObject& obj = problem->objects[k];
    ObjectParams& op = obj_params[k];
    op.projector = options.constrained ? obj.world_projector : Matrix6d::Identity();
    op.frame_of_keyframe.assign(nk, -1);
    for (size_t f = 0; f < obj.frames.size(); ++f) {
      op.frame_of_keyframe[static_cast<size_t>(obj.frames[f].keyframe)] = static_cast<int>(f);
    }
    // MAD scale of the object's initial residuals (paper: Σ from the MAD).
    double mad_sigma = 0.0;
    if (options.mad_sigma_for_dynamic) {
      std::vector<double> comps;
      for (const BaObservation& o : obj.observations) {
        const int f = op.frame_of_keyframe[static_cast<size_t>(o.keyframe)];
        DynamicResidual(cam,
                        problem->keyframes[static_cast<size_t>(o.keyframe)].camera_from_world,
                        obj.frames[static_cast<size_t>(f)].world_from_object,
                        obj.points_in_object[static_cast<size_t>(o.point)],
                        o,
                        &comps);
      }
      mad_sigma = std::max(options.min_sigma_px, MadScale(comps));
    }
    for (const BaObservation& o : obj.observations) {
      const int f = op.frame_of_keyframe[static_cast<size_t>(o.keyframe)];
      double* x = add_keyframe(o.keyframe);
      double* xi = op.twist[static_cast<size_t>(f)];
      double* pose = op.pose[static_cast<size_t>(f)];
      double* p = op.points[static_cast<size_t>(o.point)];
      const double s = 1.0 / (options.mad_sigma_for_dynamic ? mad_sigma : o.sigma_px);
      ceres::CostFunction* cost;
      if (o.u_right >= 0.0) {
        const Eigen::Matrix3d w = StereoWhitening(o.disparity_noise_ratio);
        cost = options.use_autodiff
                   ? optimization::DynamicReprojectionFunctor<3>::Create(
                         cam, Measurement<3>(o), s, op.projector, w)
                   : static_cast<ceres::CostFunction*>(new optimization::DynamicReprojectionCost<3>(
                         cam, Measurement<3>(o), s, op.projector, w));
      } else {
        cost = options.use_autodiff
                   ? optimization::DynamicReprojectionFunctor<2>::Create(
                         cam, Measurement<2>(o), s, op.projector)
                   : static_cast<ceres::CostFunction*>(new optimization::DynamicReprojectionCost<2>(
                         cam, Measurement<2>(o), s, op.projector));
      }
      ceres::LossFunction* loss =
          options.dynamic_tukey_c > 0.0
              ? static_cast<ceres::LossFunction*>(new ceres::TukeyLoss(options.dynamic_tukey_c))
              : new ceres::HuberLoss(options.huber_delta);
      ceres_problem.AddResidualBlock(cost, loss, x, xi, pose, p);
      ceres_problem.SetManifold(pose, &se3_manifold);
      ceres_problem.SetParameterBlockConstant(pose);  // optimised through ξ̃ only
      if (obj.frames[static_cast<size_t>(f)].fixed) ceres_problem.SetParameterBlockConstant(xi);
      if (!obj.fixed_points.empty() && obj.fixed_points[static_cast<size_t>(o.point)]) {
        ceres_problem.SetParameterBlockConstant(p);
      }
      ++summary.num_dynamic_terms;
    }
    for (size_t j = 0; j < obj.point_prior_sqrt_information.size(); ++j) {
      const Eigen::Matrix3d& a = obj.point_prior_sqrt_information[j];
      if (a.isZero() || !ceres_problem.HasParameterBlock(op.points[j])) continue;
      ceres_problem.AddResidualBlock(
          new ceres::NormalPrior(ceres::Matrix(a), ceres::Vector(obj.points_in_object[j])),
          nullptr,
          op.points[j]);
    }
    // Priors over runs of consecutive frames: constant velocity over
    // triplets, constant acceleration over quadruplets (Huber), the step
    // along a soft normal over pairs (Gaussian).
    auto add_priors = [&](int num_frames, bool robust, const auto& make_cost) {
      int added = 0;
      for (size_t f = 0; f + static_cast<size_t>(num_frames) <= obj.frames.size(); ++f) {
        bool consecutive = true;
        for (int d = 1; d < num_frames; ++d) consecutive &= obj.frames[f + d].follows_previous;
        if (!consecutive) continue;
        std::array<double*, 8> blocks{};
        for (int d = 0; d < num_frames; ++d) {
          blocks[2 * d] = op.twist[f + d];
          blocks[2 * d + 1] = op.pose[f + d];
        }
        ceres_problem.AddResidualBlock(
            make_cost(),
            robust ? new ceres::HuberLoss(options.const_velocity_huber) : nullptr,
            std::vector<double*>(blocks.begin(), blocks.begin() + 2 * num_frames));
        for (int d = 0; d < num_frames; ++d) {
          ceres_problem.SetManifold(blocks[2 * d + 1], &se3_manifold);
          ceres_problem.SetParameterBlockConstant(blocks[2 * d + 1]);
          if (obj.frames[f + d].fixed) ceres_problem.SetParameterBlockConstant(blocks[2 * d]);
        }
        ++added;
      }
      return added;
    };
    auto motion_prior = [&](int num_frames, const Vector6d& sqrt_weight) {
      if (sqrt_weight.squaredNorm() == 0.0) return 0;
      return add_priors(num_frames, true, [&]() -> ceres::CostFunction* {
        if (num_frames == 3) {
          return options.use_autodiff
                     ? optimization::ConstantVelocityFunctor::Create(op.projector, sqrt_weight)
                     : new optimization::ConstantVelocityCost(op.projector, sqrt_weight);
        }
        return options.use_autodiff
                   ? optimization::ConstantAccelerationFunctor::Create(op.projector, sqrt_weight)
                   : new optimization::ConstantAccelerationCost(op.projector, sqrt_weight);
      });
    };
    if (options.use_const_velocity) {
      summary.num_const_velocity_terms += motion_prior(3, options.const_velocity_sqrt_weight);
      summary.num_const_acceleration_terms +=
          motion_prior(4, options.const_acceleration_sqrt_weight);
    }
    if (obj.soft_normal_step_sigma_m > 0.0 && options.constrained) {
      const Eigen::Matrix<double, 1, 6> map =
          optimization::NormalStepMap(obj.soft_normal, obj.soft_normal_step_sigma_m);
      summary.num_normal_step_terms += add_priors(2, false, [&]() -> ceres::CostFunction* {
        return options.use_autodiff
                   ? optimization::NormalStepFunctor::Create(op.projector, map, {1.0})
                   : new optimization::NormalStepCost(op.projector, map, {1.0});
      });
    }
    // Keep the corrections inside range(Π) (well-conditioned normal equations).
    const Eigen::Matrix<double, 6, Eigen::Dynamic> basis = ProjectorRangeBasis(op.projector);
    ceres::Manifold* subspace = nullptr;
    if (basis.cols() > 0 && basis.cols() < 6) {
      manifolds.push_back(std::make_unique<LinearSubspaceManifold>(basis));
      subspace = manifolds.back().get();
    }
    for (size_t f = 0; f < obj.frames.size(); ++f) {
      double* xi = op.twist[f];
      if (!ceres_problem.HasParameterBlock(xi) || ceres_problem.IsParameterBlockConstant(xi))
        continue;
      if (basis.cols() == 0) {
        ceres_problem.SetParameterBlockConstant(xi);
      } else if (subspace != nullptr) {
        ceres_problem.SetManifold(xi, subspace);
      }
    }
  }
  summary.num_residual_blocks = ceres_problem.NumResidualBlocks();
  if (summary.num_residual_blocks == 0) {
    summary.message = "nothing to optimise";
    return summary;
  }

  ceres::Solver::Options solver_options;
  solver_options.linear_solver_type = options.linear_solver == BaLinearSolver::kDenseSchur
                                          ? ceres::DENSE_SCHUR
                                          : ceres::SPARSE_SCHUR;
  solver_options.trust_region_strategy_type = ceres::LEVENBERG_MARQUARDT;
  solver_options.max_num_iterations = options.max_iterations;
  solver_options.num_threads = options.num_threads;
  solver_options.logging_type = ceres::SILENT;
  // Schur elimination order: points first (static and dynamic), then poses.
  auto* ordering = new ceres::ParameterBlockOrdering;
  auto add_to_group = [&](double* x, int group) {
    if (ceres_problem.HasParameterBlock(x)) ordering->AddElementToGroup(x, group);
  };
  for (double* p : point_params) add_to_group(p, 0);
  for (const ObjectParams& op : obj_params) {
    for (double* p : op.points) add_to_group(p, 0);
    for (double* t : op.twist) add_to_group(t, 1);
    for (double* p : op.pose) add_to_group(p, 1);
  }
  for (double* k : kf_params) add_to_group(k, 1);
  if (ordering->NumElements() > 0 && ordering->GroupSize(0) > 0) {
    solver_options.linear_solver_ordering.reset(ordering);
  } else {
    delete ordering;
    solver_options.linear_solver_type = ceres::DENSE_QR;
  }
  ceres::Solver::Summary ceres_summary;
  ceres::Solve(solver_options, &ceres_problem, &ceres_summary);
  summary.initial_cost = ceres_summary.initial_cost;
  summary.final_cost = ceres_summary.final_cost;
  summary.iterations = static_cast<int>(ceres_summary.iterations.size());
  summary.usable = ceres_summary.IsSolutionUsable();
  summary.message = ceres_summary.BriefReport();
  if (!summary.usable) return summary;

  // Write back.
  for (size_t i = 0; i < nk; ++i) {
    problem->keyframes[i].camera_from_world = SE3d::FromParams(kf_params[i]);
  }
  for (size_t j = 0; j < problem->points.size(); ++j) {
    problem->points[j].point_in_world = Eigen::Map<const Eigen::Vector3d>(point_params[j]);
  }
  for (size_t k = 0; k < problem->objects.size(); ++k) {
    BaObject& obj = problem->objects[k];
    const ObjectParams& op = obj_params[k];
    for (size_t f = 0; f < obj.frames.size(); ++f) {
      const Vector6d xi = op.projector * Eigen::Map<const Vector6d>(op.twist[f]);
      obj.frames[f].world_from_object = SE3d::Exp(xi) * obj.frames[f].world_from_object;
    }
    for (size_t j = 0; j < obj.points_in_object.size(); ++j) {
      obj.points_in_object[j] = Eigen::Map<const Eigen::Vector3d>(op.points[j]);
    }
  }
  return summary;
}

}  // namespace twist::objects
