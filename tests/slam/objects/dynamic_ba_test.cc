#include "slam/objects/dynamic_ba.h"

#include <gtest/gtest.h>

#include <cmath>
#include <cstdio>
#include <cstring>
#include <memory>
#include <random>

#include "tests/slam/objects/synthetic_objects.h"

namespace twist::objects {
namespace {

using namespace twist::objects::testing;  // NOLINT

struct Window {
  DynamicBaProblem problem;
  std::vector<SE3d> gt_camera_from_world;
  std::vector<SE3d> gt_world_from_object;  // per object frame
  std::vector<Eigen::Vector3d> gt_points;
};

// 10 keyframes at 10 Hz (the first 2 spatial, the last 8 temporal), a static
// street (facades and road) and one car driving on the road with a planar
// joint; stereo observations with `noise_px` Gaussian noise. With
// `car_disparity_noise_px` >= 0 the car's u_right carries its u's noise plus
// a disparity noise of that σ (u_right = u − d, as a matcher measures it),
// and its observations say so (BaObservation::disparity_noise_ratio).
Window MakeWindow(double noise_px, uint64_t seed, double car_disparity_noise_px = -1.0) {
  std::mt19937_64 rng(seed);
  std::normal_distribution<double> g(0.0, noise_px);
  std::normal_distribution<double> gd(0.0, std::max(car_disparity_noise_px, 0.0));
  Window w;
  DynamicBaProblem& p = w.problem;
  p.camera = KittiLikeCamera();
  for (int i = 0; i < 10; ++i) {
    const SE3d world_from_camera(geometry::SO3d::Exp(Eigen::Vector3d(0, 0.01 * i, 0)),
                                 Eigen::Vector3d(0, 0, 1.0 * i));
    BaKeyframe kf;
    kf.id = 100 + i;
    kf.timestamp_ns = i * 100'000'000LL;
    kf.camera_from_world = world_from_camera.Inverse();
    kf.temporal = i >= 2;
    kf.fixed = i == 0;
    p.keyframes.push_back(kf);
    w.gt_camera_from_world.push_back(kf.camera_from_world);
  }
  auto observe = [&](const SE3d& camera_from_point_frame,
                     const Eigen::Vector3d& x,
                     int kf,
                     int idx,
                     bool car,
                     std::vector<BaObservation>* out) {
    Eigen::Vector3d uvr;
    if (!p.camera.ProjectStereoChecked(camera_from_point_frame * x, &uvr, nullptr, 1.0)) return;
    if (!p.camera.InImage(uvr.head<2>(), 5) || uvr.z() < 0) return;
    BaObservation o;
    o.keyframe = kf;
    o.point = idx;
    o.uv = uvr.head<2>() + Eigen::Vector2d(g(rng), g(rng));
    o.sigma_px = std::max(noise_px, 0.3);
    if (car && car_disparity_noise_px >= 0.0) {
      o.u_right = uvr.z() + (o.uv.x() - uvr.x()) + gd(rng);
      o.disparity_noise_ratio = car_disparity_noise_px / o.sigma_px;
    } else {
      o.u_right = uvr.z() + g(rng);
    }
    out->push_back(o);
  };
  std::uniform_real_distribution<double> uz(8.0, 45.0), uy(-4.0, 1.6), ux(-7.0, 7.0);
  for (int j = 0; j < 150; ++j) {
    Eigen::Vector3d x;
    if (j % 3 == 0) {
      x = Eigen::Vector3d(ux(rng), 1.65, uz(rng));  // road
    } else {
      x = Eigen::Vector3d(j % 3 == 1 ? -8.0 : 8.0, uy(rng), uz(rng));  // facades
    }
    BaStaticPoint sp;
    sp.id = j;
    sp.point_in_world = x;
    p.points.push_back(sp);
    w.gt_points.push_back(x);
    for (int i = 0; i < 10; ++i)
      observe(w.gt_camera_from_world[static_cast<size_t>(i)], x, i, j, false, &p.observations);
  }
  // The car.
  BaObject car;
  car.id = 7;
  const SE3d world_from_joint = RoadJointFrame(Eigen::Vector3d(2.5, 0, 12.0));
  car.world_projector = PlanarProjector(world_from_joint);
  Vector6d twist_in_joint;
  twist_in_joint << 0.05, 1.3, 0, 0, 0, 0.015;
  const Vector6d step = world_from_joint.Adjoint() * twist_in_joint;
  car.points_in_object = CarPoints(40, &rng);
  SE3d pose = world_from_joint;
  for (int i = 2; i < 10; ++i) {
    BaObjectFrame f;
    f.keyframe = i;
    f.world_from_object = pose;
    f.fixed = i == 2;  // gauge of the car's points
    car.frames.push_back(f);
    w.gt_world_from_object.push_back(pose);
    for (size_t j = 0; j < car.points_in_object.size(); ++j) {
      observe(w.gt_camera_from_world[static_cast<size_t>(i)] * pose,
              car.points_in_object[j],
              i,
              static_cast<int>(j),
              true,
              &car.observations);
    }
    pose = SE3d::Exp(step) * pose;
  }
  p.objects.push_back(car);
  return w;
}

void Perturb(Window* w, uint64_t seed) {
  std::mt19937_64 rng(seed);
  std::normal_distribution<double> g(0.0, 1.0);
  DynamicBaProblem& p = w->problem;
  for (BaKeyframe& kf : p.keyframes) {
    if (kf.fixed) continue;
    Vector6d d;
    d << 0.05 * g(rng), 0.05 * g(rng), 0.05 * g(rng), 0.004 * g(rng), 0.004 * g(rng),
        0.004 * g(rng);
    kf.camera_from_world = kf.camera_from_world * SE3d::Exp(d);
  }
  for (BaStaticPoint& sp : p.points)
    sp.point_in_world += 0.1 * Eigen::Vector3d(g(rng), g(rng), g(rng));
  for (BaObject& obj : p.objects) {
    for (BaObjectFrame& f : obj.frames) {
      if (f.fixed) continue;
      Vector6d d;
      d << 0.15 * g(rng), 0.15 * g(rng), 0.15 * g(rng), 0.01 * g(rng), 0.01 * g(rng), 0.01 * g(rng);
      f.world_from_object = SE3d::Exp(obj.world_projector * d) * f.world_from_object;  // in-plane
    }
    for (Eigen::Vector3d& x : obj.points_in_object)
      x += 0.05 * Eigen::Vector3d(g(rng), g(rng), g(rng));
  }
}

struct Errors {
  double camera_m = 0.0;
  double object_m = 0.0;
  double object_deg = 0.0;
};

Errors Measure(const Window& w) {
  Errors e;
  for (size_t i = 0; i < w.problem.keyframes.size(); ++i) {
    e.camera_m += TranslationError(w.problem.keyframes[i].camera_from_world.Inverse(),
                                   w.gt_camera_from_world[i].Inverse());
  }
  e.camera_m /= w.problem.keyframes.size();
  const BaObject& car = w.problem.objects[0];
  for (size_t f = 0; f < car.frames.size(); ++f) {
    e.object_m += TranslationError(car.frames[f].world_from_object, w.gt_world_from_object[f]);
    e.object_deg += RotationErrorDeg(car.frames[f].world_from_object, w.gt_world_from_object[f]);
  }
  e.object_m /= car.frames.size();
  e.object_deg /= car.frames.size();
  return e;
}

TEST(DynamicBa, ValidatesTheProblem) {
  Window w = MakeWindow(0.3, 1);
  EXPECT_TRUE(w.problem.Validate().ok());
  DynamicBaProblem bad = w.problem;
  bad.observations[0].keyframe = 99;
  EXPECT_EQ(SolveDynamicBa(&bad, DynamicBaOptions{}).status().code(),
            absl::StatusCode::kInvalidArgument);
  bad = w.problem;
  bad.objects[0].observations[0].keyframe = 0;  // the car has no pose in keyframe 0
  EXPECT_EQ(bad.Validate().code(), absl::StatusCode::kInvalidArgument);
  bad = w.problem;
  bad.objects[0].observations[0].disparity_noise_ratio = -0.5;
  EXPECT_EQ(bad.Validate().code(), absl::StatusCode::kInvalidArgument);
  bad.objects[0].observations[0].disparity_noise_ratio = std::nan("");
  EXPECT_EQ(bad.Validate().code(), absl::StatusCode::kInvalidArgument);
  bad.objects[0].observations[0].disparity_noise_ratio = 0.4;
  EXPECT_TRUE(bad.Validate().ok());
  bad.observations[0].disparity_noise_ratio = 0.4;  // static terms have no whitening
  EXPECT_EQ(bad.Validate().code(), absl::StatusCode::kInvalidArgument);
  bad = w.problem;
  bad.objects[0].soft_normal_step_sigma_m = 0.01;  // and no direction
  EXPECT_EQ(bad.Validate().code(), absl::StatusCode::kInvalidArgument);
  bad.objects[0].soft_normal = Eigen::Vector3d(0, -1, 0);
  EXPECT_TRUE(bad.Validate().ok());
  bad.objects[0].soft_normal_step_sigma_m = -0.01;
  EXPECT_EQ(bad.Validate().code(), absl::StatusCode::kInvalidArgument);
  bad = w.problem;
  bad.objects[0].fixed_points.assign(bad.objects[0].points_in_object.size() - 1, true);
  EXPECT_EQ(bad.Validate().code(), absl::StatusCode::kInvalidArgument);
  bad.objects[0].fixed_points.push_back(false);
  EXPECT_TRUE(bad.Validate().ok());
  bad = w.problem;
  bad.objects[0].point_prior_sqrt_information.assign(bad.objects[0].points_in_object.size() + 1,
                                                     Eigen::Matrix3d::Identity());
  EXPECT_EQ(bad.Validate().code(), absl::StatusCode::kInvalidArgument);
  bad.objects[0].point_prior_sqrt_information.pop_back();
  EXPECT_TRUE(bad.Validate().ok());
  bad.objects[0].point_prior_sqrt_information[0](1, 1) = std::nan("");
  EXPECT_EQ(bad.Validate().code(), absl::StatusCode::kInvalidArgument);
  EXPECT_TRUE(InTemporalWindow(6'000'000'000, 10'000'000'000, 5.0));
  EXPECT_FALSE(InTemporalWindow(4'000'000'000, 10'000'000'000, 5.0));
}

TEST(DynamicBa, LowersErrorOnAPerturbedWindow) {
  Window w = MakeWindow(0.3, 2);
  Perturb(&w, 3);
  const Errors before = Measure(w);
  Window w_autodiff = w;
  DynamicBaOptions options;
  const auto summary = SolveDynamicBa(&w.problem, options);
  ASSERT_TRUE(summary.ok()) << summary.status();
  ASSERT_TRUE(summary->usable) << summary->message;
  const Errors after = Measure(w);
  std::printf(
      "[dynamic BA] camera %.4f -> %.4f m, object %.4f -> %.4f m, %.4f -> %.4f deg; cost %.1f -> "
      "%.1f "
      "(%d static, %d dynamic, %d const-velocity terms, %d iterations)\n",
      before.camera_m,
      after.camera_m,
      before.object_m,
      after.object_m,
      before.object_deg,
      after.object_deg,
      summary->initial_cost,
      summary->final_cost,
      summary->num_static_terms,
      summary->num_dynamic_terms,
      summary->num_const_velocity_terms,
      summary->iterations);
  EXPECT_LT(summary->final_cost, summary->initial_cost);
  EXPECT_LT(after.camera_m, 0.3 * before.camera_m);
  EXPECT_LT(after.object_m, 0.3 * before.object_m);
  EXPECT_LT(after.object_deg, 0.5 * before.object_deg);
  EXPECT_EQ(summary->num_const_velocity_terms, 6);
  // The corrected poses keep the planar constraint: every step is planar.
  for (const Vector6d& s : ObjectStepTwists(w.problem.objects[0])) {
    EXPECT_LT((w.problem.objects[0].world_projector * s - s).norm(), 1e-6);
  }

  // Autodiff twins of the same costs reach the same solution.
  DynamicBaOptions ad = options;
  ad.use_autodiff = true;
  const auto ad_summary = SolveDynamicBa(&w_autodiff.problem, ad);
  ASSERT_TRUE(ad_summary.ok() && ad_summary->usable);
  EXPECT_NEAR(ad_summary->final_cost, summary->final_cost, 1e-6 * summary->initial_cost);
  for (size_t f = 0; f < w.problem.objects[0].frames.size(); ++f) {
    EXPECT_LT(TranslationError(w.problem.objects[0].frames[f].world_from_object,
                               w_autodiff.problem.objects[0].frames[f].world_from_object),
              1e-4);
  }
}

// A fifth of the car's matches lie 10 px ahead of their point (a patch
// match that runs ahead of a turning car, docs/objects.md section 42, a
// one-sided tail). Huber's linear tail still follows them; Tukey's
// biweight (DynamicBaOptions::dynamic_tukey_c at 7, the default) gives them no
// weight: its solution is that of the window without them (but for the MAD
// σ, which they could move).
TEST(DynamicBa, TukeyLeavesAOneSidedTailOfMatchesOut) {
  // The car's poses after the BA, with the off matches kept or deleted;
  // from the true poses (the objects' σ is the MAD of the initial residuals,
  // which a tracked window's are near).
  auto solve = [](double tukey_c, bool keep_off, uint64_t seed) {
    Window w = MakeWindow(0.3, seed);
    std::mt19937_64 rng(seed + 100);
    std::bernoulli_distribution off(0.2);  // other points in every frame
    std::vector<BaObservation> kept;
    for (BaObservation o : w.problem.objects[0].observations) {
      if (off(rng)) {
        if (!keep_off) continue;
        o.uv.x() += 10.0;
        o.u_right += 10.0;
      }
      kept.push_back(o);
    }
    w.problem.objects[0].observations = kept;
    DynamicBaOptions options;
    options.dynamic_tukey_c = tukey_c;
    const auto summary = SolveDynamicBa(&w.problem, options);
    EXPECT_TRUE(summary.ok() && summary->usable);
    std::vector<SE3d> poses;
    for (const BaObjectFrame& f : w.problem.objects[0].frames) poses.push_back(f.world_from_object);
    return poses;
  };
  // How far the off matches pull the car: mean over frames and windows.
  auto pull = [&](double tukey_c) {
    double m = 0.0;
    int n = 0;
    for (uint64_t seed = 1; seed <= 4; ++seed) {
      const std::vector<SE3d> with = solve(tukey_c, true, seed);
      const std::vector<SE3d> without = solve(tukey_c, false, seed);
      for (size_t f = 0; f < with.size(); ++f, ++n) m += TranslationError(with[f], without[f]);
    }
    return m / n;
  };
  const double huber = pull(0.0);
  EXPECT_EQ(DynamicBaOptions().dynamic_tukey_c, 7.0);  // Tukey by default
  const double tukey = pull(7.0);
  std::printf(
      "[dynamic BA, 20 %% of the car's matches 10 px off] they move the car %.4f m "
      "(Huber), %.4f m (Tukey)\n",
      huber,
      tukey);
  EXPECT_GT(huber, 0.005);
  EXPECT_LT(tukey, 0.1 * huber);
  DynamicBaOptions bad;
  bad.dynamic_tukey_c = -1.0;
  EXPECT_EQ(bad.Validate().code(), absl::StatusCode::kInvalidArgument);
  bad.dynamic_tukey_c = std::nan("");
  EXPECT_EQ(bad.Validate().code(), absl::StatusCode::kInvalidArgument);
}

// Points flagged fixed (a sliding window's inherited points) keep their
// values to the bit; the others are refined.
TEST(DynamicBa, FixedPointsStayWhereTheyAre) {
  Window w = MakeWindow(0.3, 2);
  Perturb(&w, 3);
  BaObject& car = w.problem.objects[0];
  const std::vector<Eigen::Vector3d> before = car.points_in_object;
  car.fixed_points.resize(before.size());
  for (size_t k = 0; k < before.size(); ++k) car.fixed_points[k] = k % 2 == 0;
  const auto summary = SolveDynamicBa(&w.problem, DynamicBaOptions{});
  ASSERT_TRUE(summary.ok() && summary->usable);
  int moved = 0;
  for (size_t k = 0; k < before.size(); ++k) {
    if (car.fixed_points[k]) {
      EXPECT_EQ(car.points_in_object[k], before[k]) << "point " << k;
    } else {
      moved += car.points_in_object[k] != before[k] ? 1 : 0;
    }
  }
  EXPECT_EQ(moved, static_cast<int>(before.size() / 2));
}

// A point prior A (x − x₀) pulls its point towards x₀ by its weight: a
// stiff one keeps it there, a zero matrix is no prior at all.
TEST(DynamicBa, PointPriorsPullPointsToTheirValues) {
  Window w = MakeWindow(0.3, 2);
  Perturb(&w, 3);
  Window none = w, zero = w;
  BaObject& car = w.problem.objects[0];
  const std::vector<Eigen::Vector3d> before = car.points_in_object;
  car.point_prior_sqrt_information.assign(before.size(), Eigen::Matrix3d::Zero());
  for (size_t k = 0; k < before.size(); k += 2) {
    car.point_prior_sqrt_information[k] = 1e6 * Eigen::Matrix3d::Identity();
  }
  zero.problem.objects[0].point_prior_sqrt_information.assign(before.size(),
                                                              Eigen::Matrix3d::Zero());
  for (Window* x : {&w, &none, &zero}) {
    const auto summary = SolveDynamicBa(&x->problem, DynamicBaOptions{});
    ASSERT_TRUE(summary.ok() && summary->usable);
  }
  for (size_t k = 0; k < before.size(); ++k) {
    if (k % 2 == 0) {
      EXPECT_LT((car.points_in_object[k] - before[k]).norm(), 1e-5) << "point " << k;
      EXPECT_GT((none.problem.objects[0].points_in_object[k] - before[k]).norm(), 1e-3)
          << "point " << k;
    }
    EXPECT_EQ(zero.problem.objects[0].points_in_object[k],
              none.problem.objects[0].points_in_object[k])
        << "point " << k;
  }
}

// A disparity measured with its own, smaller noise (0.1 px against 1 px of
// position noise; u_right = u − d carries u's error) fixes the car's depth
// when the BA whitens it (the twist estimator's StereoWhitening). Taken as a
// third independent coordinate with the position's noise, the car's depth
// is left more to the image size of its points, 10 times noisier. The
// cameras are held at their true poses, as the engine's object BA holds
// them: with free cameras the car's world error is mostly theirs.
TEST(DynamicBa, TheDisparitysOwnNoiseWeighsTheObjectsDepth) {
  double with = 0.0, without = 0.0;
  const int kSeeds = 8;
  for (int seed = 1; seed <= kSeeds; ++seed) {
    Window w = MakeWindow(1.0, 40 + seed, 0.1);
    Perturb(&w, 60 + seed);
    for (size_t i = 0; i < w.problem.keyframes.size(); ++i) {
      w.problem.keyframes[i].camera_from_world = w.gt_camera_from_world[i];
      w.problem.keyframes[i].fixed = true;
    }
    Window plain = w;
    for (BaObservation& o : plain.problem.objects[0].observations) o.disparity_noise_ratio = 0.0;
    const auto a = SolveDynamicBa(&w.problem, DynamicBaOptions{});
    const auto b = SolveDynamicBa(&plain.problem, DynamicBaOptions{});
    ASSERT_TRUE(a.ok() && a->usable && b.ok() && b->usable);
    with += Measure(w).object_m / kSeeds;
    without += Measure(plain).object_m / kSeeds;
  }
  std::printf(
      "[dynamic BA] car position error %.4f m whitened, %.4f m independent rows\n", with, without);
  EXPECT_LT(with, 0.5 * without);
}

TEST(DynamicBa, DenseSchurAndUnconstrainedAlsoConverge) {
  for (bool constrained : {true, false}) {
    Window w = MakeWindow(0.3, 4);
    Perturb(&w, 5);
    const Errors before = Measure(w);
    DynamicBaOptions options;
    options.linear_solver = BaLinearSolver::kDenseSchur;
    options.constrained = constrained;
    const auto summary = SolveDynamicBa(&w.problem, options);
    ASSERT_TRUE(summary.ok() && summary->usable);
    const Errors after = Measure(w);
    std::printf("[dynamic BA %s] object %.4f -> %.4f m, %.4f -> %.4f deg\n",
                constrained ? "planar" : "free",
                before.object_m,
                after.object_m,
                before.object_deg,
                after.object_deg);
    EXPECT_LT(after.object_m, 0.5 * before.object_m);
    EXPECT_LT(after.camera_m, 0.5 * before.camera_m);
  }
}

TEST(DynamicBa, ConstantVelocityTermSmoothsTheTwists) {
  // Noisy observations, no perturbation: the spread of the step twists is
  // lower with the constant-velocity term than without.
  auto spread = [](const BaObject& obj) {
    const auto steps = ObjectStepTwists(obj);
    Vector6d mean = Vector6d::Zero();
    for (const auto& s : steps) mean += s;
    mean /= steps.size();
    double var = 0.0;
    for (const auto& s : steps) var += (s - mean).head<3>().squaredNorm();
    return std::sqrt(var / steps.size());
  };
  double with = 0.0, without = 0.0;
  for (uint64_t seed = 10; seed < 13; ++seed) {
    Window a = MakeWindow(1.5, seed);
    Window b = a;
    DynamicBaOptions options;
    ASSERT_TRUE(SolveDynamicBa(&a.problem, options).ok());
    options.use_const_velocity = false;
    ASSERT_TRUE(SolveDynamicBa(&b.problem, options).ok());
    with += spread(a.problem.objects[0]);
    without += spread(b.problem.objects[0]);
  }
  std::printf("[dynamic BA] step-twist spread: with constant velocity %.4f m, without %.4f m\n",
              with / 3,
              without / 3);
  EXPECT_LT(with, without);
}

// A car braking at 4 m/s² (4 cm per frame step squared) 15 m ahead of a
// camera that brakes with it, observed in stereo with noise_px noise by fixed
// cameras; its first frame fixed (the gauge), the others at the truth.
// Returns the mean over `trials` draws of the error along the road of the
// second frame after the solve: the frame that the next window, one frame
// later, keeps fixed.
double MeanSecondFrameErrorBraking(const DynamicBaOptions& options, double noise_px, int trials) {
  double sum = 0.0;
  for (int trial = 0; trial < trials; ++trial) {
    std::mt19937_64 rng(100 + trial);
    std::normal_distribution<double> g(0.0, noise_px);
    std::uniform_real_distribution<double> ux(-0.9, 0.9), uz(0.3, 1.5);
    DynamicBaProblem p;
    p.camera = KittiLikeCamera();
    BaObject car;
    car.id = 1;
    for (int k = 0; k < 30; ++k) car.points_in_object.emplace_back(ux(rng), -2.2, uz(rng));
    car.world_projector = PlanarProjector(RoadJointFrame(Eigen::Vector3d(0, 0, 15.0)));
    std::vector<double> object_z;
    double camera_z = 0.0, z = 15.0, camera_step = 1.0, step = 0.8;
    for (int i = 0; i < 10; ++i) {
      BaKeyframe kf;
      kf.id = i;
      kf.timestamp_ns = i * 100'000'000LL;
      kf.camera_from_world = SE3d(geometry::SO3d(), Eigen::Vector3d(0, 0, camera_z)).Inverse();
      kf.fixed = true;
      p.keyframes.push_back(kf);
      BaObjectFrame f;
      f.keyframe = i;
      f.world_from_object = RoadJointFrame(Eigen::Vector3d(0, 0, z));
      f.fixed = i == 0;
      car.frames.push_back(f);
      object_z.push_back(z);
      for (size_t j = 0; j < car.points_in_object.size(); ++j) {
        Eigen::Vector3d uvr;
        if (!p.camera.ProjectStereoChecked(
                kf.camera_from_world * f.world_from_object * car.points_in_object[j],
                &uvr,
                nullptr,
                1.0))
          continue;
        BaObservation o;
        o.keyframe = i;
        o.point = static_cast<int>(j);
        o.uv = uvr.head<2>() + Eigen::Vector2d(g(rng), g(rng));
        o.u_right = uvr.z() + g(rng);
        car.observations.push_back(o);
      }
      camera_z += camera_step;
      z += step;
      camera_step -= 0.04;
      step -= 0.04;
    }
    p.objects.push_back(car);
    const auto summary = SolveDynamicBa(&p, options);
    EXPECT_TRUE(summary.ok() && summary->usable);
    sum += p.objects[0].frames[1].world_from_object.translation().z() - object_z[1];
  }
  return sum / trials;
}

// The same braking car over 40 frames (16 m ahead of a camera braking with
// it, 1.0 -> 0.2 m per frame), refined as the object stage does: a window of
// the last 10 frames after every frame, the car's points and poses carried
// from window to window (a new frame starts from the constant-velocity
// extrapolation of the two before), the oldest `gauge_frames` frames of each
// window fixed. Returns the mean over `trials` draws of the error along the
// road of the newest frame at the end: what the windows have let accumulate.
double SlidingWindowDriftBraking(const DynamicBaOptions& options,
                                 int gauge_frames,
                                 double noise_px,
                                 int trials) {
  const int kFrames = 40, kWindow = 10;
  double sum = 0.0;
  for (int trial = 0; trial < trials; ++trial) {
    std::mt19937_64 rng(200 + trial);
    std::normal_distribution<double> g(0.0, noise_px);
    std::uniform_real_distribution<double> ux(-0.9, 0.9), uz(0.3, 1.5);
    const geometry::StereoCamera camera = KittiLikeCamera();
    std::vector<Eigen::Vector3d> points;
    for (int k = 0; k < 30; ++k) points.emplace_back(ux(rng), -2.2, uz(rng));
    std::vector<SE3d> camera_from_world, truth;
    std::vector<std::vector<BaObservation>> seen(kFrames);
    double camera_z = 0.0, step = 1.0;
    for (int i = 0; i < kFrames; ++i) {
      camera_from_world.push_back(
          SE3d(geometry::SO3d(), Eigen::Vector3d(0, 0, camera_z)).Inverse());
      truth.push_back(RoadJointFrame(Eigen::Vector3d(0, 0, camera_z + 16.0)));
      for (size_t j = 0; j < points.size(); ++j) {
        Eigen::Vector3d uvr;
        if (!camera.ProjectStereoChecked(
                camera_from_world[i] * truth[i] * points[j], &uvr, nullptr, 1.0))
          continue;
        BaObservation o;
        o.point = static_cast<int>(j);
        o.uv = uvr.head<2>() + Eigen::Vector2d(g(rng), g(rng));
        o.u_right = uvr.z() + g(rng);
        seen[i].push_back(o);
      }
      camera_z += step;
      step -= 0.02;
    }
    std::vector<SE3d> estimate(truth.begin(), truth.begin() + kWindow);
    std::vector<Eigen::Vector3d> points_estimate = points;
    for (int last = kWindow - 1; last < kFrames; ++last) {
      if (last >= kWindow) {
        const SE3d& a = estimate[last - 2];
        const SE3d& b = estimate[last - 1];
        estimate.push_back(b * a.Inverse() * b);
      }
      DynamicBaProblem p;
      p.camera = camera;
      BaObject car;
      car.id = 1;
      car.points_in_object = points_estimate;
      car.world_projector = PlanarProjector(truth[0]);
      for (int i = last - kWindow + 1, k = 0; i <= last; ++i, ++k) {
        BaKeyframe kf;
        kf.id = i;
        kf.timestamp_ns = i * 100'000'000LL;
        kf.camera_from_world = camera_from_world[i];
        kf.fixed = true;
        p.keyframes.push_back(kf);
        BaObjectFrame f;
        f.keyframe = k;
        f.world_from_object = estimate[i];
        f.fixed = k < gauge_frames;
        car.frames.push_back(f);
        for (BaObservation o : seen[i]) {
          o.keyframe = k;
          car.observations.push_back(o);
        }
      }
      p.objects.push_back(car);
      const auto summary = SolveDynamicBa(&p, options);
      EXPECT_TRUE(summary.ok() && summary->usable);
      for (int i = last - kWindow + 1, k = 0; i <= last; ++i, ++k) {
        estimate[i] = p.objects[0].frames[k].world_from_object;
      }
      points_estimate = p.objects[0].points_in_object;
    }
    sum += estimate.back().translation().z() - truth.back().translation().z();
  }
  return sum / trials;
}

TEST(DynamicBa, AConstantAccelerationPriorDoesNotHoldABrakingCarBack) {
  // The constant-velocity prior pulls the braking car's steps towards their
  // mean, and the frame next to the fixed one gives way: it ends ~2 cm short
  // of the truth, and a sliding window that fixes it next keeps that error
  // every frame (docs/math.md §13). The constant-acceleration prior has no
  // such pull while the deceleration is constant.
  DynamicBaOptions velocity;
  velocity.max_iterations = 3;
  velocity.const_acceleration_sqrt_weight.setZero();
  velocity.const_velocity_sqrt_weight << 40, 40, 40, 200, 200, 200;
  DynamicBaOptions acceleration = velocity;
  acceleration.const_velocity_sqrt_weight.setZero();
  acceleration.const_acceleration_sqrt_weight << 40, 40, 40, 200, 200, 200;
  const double with_velocity = MeanSecondFrameErrorBraking(velocity, 0.7, 40);
  const double with_acceleration = MeanSecondFrameErrorBraking(acceleration, 0.7, 40);
  std::printf(
      "[dynamic BA] braking car, mean error of the second frame: constant velocity "
      "%+.4f m, constant acceleration %+.4f m\n",
      with_velocity,
      with_acceleration);
  EXPECT_LT(with_velocity, -0.01);
  EXPECT_LT(std::abs(with_acceleration), 0.005);
}

// In windows that slide along the track, the constant-velocity prior's pull
// on the frame next to the fixed gauge (previous test) is kept by the next
// window and adds up; with the two oldest frames fixed, or with the
// constant-acceleration prior on translation, it does not
// (ObjectBaOptions::keep_velocity_at_gauge, docs/math.md section 13).
TEST(DynamicBa, SlidingWindowsDoNotLetABrakingCarDrift) {
  DynamicBaOptions velocity;
  velocity.max_iterations = 3;
  DynamicBaOptions acceleration = velocity;
  acceleration.const_velocity_sqrt_weight.head<3>().setZero();
  acceleration.const_acceleration_sqrt_weight << 40, 40, 40, 0, 0, 0;
  const double one_fixed = SlidingWindowDriftBraking(velocity, 1, 0.7, 12);
  const double two_fixed = SlidingWindowDriftBraking(velocity, 2, 0.7, 12);
  const double with_acceleration = SlidingWindowDriftBraking(acceleration, 1, 0.7, 12);
  std::printf(
      "[dynamic BA, sliding windows] braking car, error of the newest frame after 40 "
      "frames: constant velocity %+.4f m, with 2 fixed frames %+.4f m, constant "
      "acceleration %+.4f m\n",
      one_fixed,
      two_fixed,
      with_acceleration);
  EXPECT_LT(one_fixed, -0.2);
  EXPECT_LT(std::abs(two_fixed), 0.06);
  EXPECT_LT(std::abs(with_acceleration), 0.06);
}

// Every solved value of a problem, in a fixed order.
std::vector<double> Flatten(const DynamicBaProblem& p) {
  std::vector<double> out;
  for (const BaKeyframe& kf : p.keyframes) {
    double x[7];
    kf.camera_from_world.ToParams(x);
    out.insert(out.end(), x, x + 7);
  }
  for (const BaStaticPoint& sp : p.points)
    out.insert(out.end(), sp.point_in_world.data(), sp.point_in_world.data() + 3);
  for (const BaObject& obj : p.objects) {
    for (const BaObjectFrame& f : obj.frames) {
      double x[7];
      f.world_from_object.ToParams(x);
      out.insert(out.end(), x, x + 7);
    }
    for (const Eigen::Vector3d& x : obj.points_in_object)
      out.insert(out.end(), x.data(), x.data() + 3);
  }
  return out;
}

TEST(DynamicBa, BitIdenticalWhateverTheHeapState) {
  // Ceres orders the blocks of a Schur group by address: the solve must not
  // depend on where the allocator puts its parameter storage. Same problem,
  // solved after the heap has been fragmented in different ways (holes of
  // the sizes of the parameter arrays, freed in different orders), must give
  // bit-identical results.
  Window w = MakeWindow(0.8, 30);
  w.problem.objects.push_back(w.problem.objects[0]);  // a second car, shifted
  w.problem.objects[1].id = 8;
  for (BaObjectFrame& f : w.problem.objects[1].frames) {
    f.world_from_object =
        SE3d(geometry::SO3d(), Eigen::Vector3d(-0.2, 0, 0.3)) * f.world_from_object;
  }
  Perturb(&w, 31);
  DynamicBaOptions options;
  options.max_iterations = 8;
  Window ref = w;
  ASSERT_TRUE(SolveDynamicBa(&ref.problem, options).ok());
  const std::vector<double> expected = Flatten(ref.problem);

  std::mt19937_64 rng(32);
  std::vector<std::unique_ptr<char[]>> junk;
  for (int round = 0; round < 4; ++round) {
    // Fragment: allocate blocks of the parameter arrays' sizes, free a
    // random half of them (the survivors stay alive across rounds).
    const size_t sizes[] = {40 * 24, 40 * 48, 150 * 24, 10 * 56, 8 * 48, 8 * 56, 4096, 65536};
    for (int k = 0; k < 200; ++k) {
      const size_t n = sizes[rng() % 8] + rng() % 64;
      junk.push_back(std::make_unique<char[]>(n));
      std::memset(junk.back().get(), k & 0xff, n);
    }
    for (auto& j : junk) {
      if (rng() % 2 == 0) j.reset();
    }
    Window b = w;
    DynamicBaProblem built_late = b.problem;  // copied after the fragmentation
    ASSERT_TRUE(SolveDynamicBa(&built_late, options).ok());
    const std::vector<double> got = Flatten(built_late);
    ASSERT_EQ(got.size(), expected.size());
    EXPECT_EQ(std::memcmp(got.data(), expected.data(), got.size() * sizeof(double)), 0)
        << "round " << round;
  }
}

}  // namespace
}  // namespace twist::objects
