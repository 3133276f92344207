// Metrics against analytically known answers.
#include "slam/io/metrics.h"

#include <gmock/gmock.h>
#include <gtest/gtest.h>

#include <Eigen/QR>
#include <cmath>
#include <random>

#include "slam/io/json_writer.h"

namespace twist::io {
namespace {

using geometry::SE3d;
using geometry::SO3d;
using geometry::Vector6d;

constexpr double kDeg = M_PI / 180.0;

// A smooth 3D trajectory (curving, climbing, turning) with n poses.
std::vector<SE3d> CurvyTrajectory(int n) {
  std::vector<SE3d> poses;
  for (int i = 0; i < n; ++i) {
    const double s = 0.1 * i;
    const Eigen::Vector3d t(10 * std::sin(s), 0.3 * std::sin(2 * s), 12 * s);
    const SO3d r = SO3d::Exp(Eigen::Vector3d(0.05 * std::sin(s), 0.4 * s, 0.02 * std::cos(3 * s)));
    poses.emplace_back(r, t);
  }
  return poses;
}

// est_{i+1} = est_i · (gt_i⁻¹ gt_{i+1}) · delta: every relative error is `delta`.
std::vector<SE3d> WithConstantRelativeError(const std::vector<SE3d>& gt, const SE3d& delta) {
  std::vector<SE3d> est = {gt[0]};
  for (size_t i = 0; i + 1 < gt.size(); ++i) {
    est.push_back(est.back() * (gt[i].Inverse() * gt[i + 1]) * delta);
  }
  return est;
}

TEST(CameraMetrics, IdenticalGivesZeros) {
  const auto gt = CurvyTrajectory(50);
  auto m = EvaluateCamera(gt, gt);
  ASSERT_TRUE(m.ok()) << m.status();
  EXPECT_EQ(m->num_frames, 50);
  EXPECT_EQ(m->num_pairs, 49);
  EXPECT_NEAR(m->rpe_t, 0, 1e-12);
  EXPECT_NEAR(m->rpe_r_deg, 0, 1e-9);
  EXPECT_NEAR(m->ate_rmse, 0, 1e-9);
  EXPECT_GT(m->gt_path_length, 50.0);
  EXPECT_NEAR(m->est_path_length, m->gt_path_length, 1e-9);
}

// A scale error (the estimate's every position 1.004 x the truth's, as a
// rig's disparity offset gives): the path length ratio reads it exactly,
// while the rigid ATE alignment only spreads it.
TEST(CameraMetrics, PathLengthReadsAScaleError) {
  const auto gt = CurvyTrajectory(50);
  std::vector<SE3d> est = gt;
  for (SE3d& p : est) p.translation() *= 1.004;
  auto m = EvaluateCamera(gt, est);
  ASSERT_TRUE(m.ok());
  EXPECT_NEAR(m->est_path_length / m->gt_path_length, 1.004, 1e-12);
  EXPECT_GT(m->ate_rmse, 0.0);
  EXPECT_NE(FormatCameraTable(*m).find("path      1.00400 x the ground truth's"), std::string::npos)
      << FormatCameraTable(*m);
}

// The same scale error behind a rigid offset, plus a known per-frame
// wobble: the similarity alignment takes the offset and the scale out
// exactly (scale 1 / 1.004), so its ATE is the wobble's RMS alone, while
// the rigid ATE carries the scale too.
TEST(CameraMetrics, SimilarityAlignmentLeavesTheErrorBesidesTheScale) {
  const auto gt = CurvyTrajectory(50);
  const SE3d offset = SE3d::Exp((Vector6d() << 3, -2, 5, 0.3, -1.2, 0.4).finished());
  std::vector<SE3d> est;
  for (const SE3d& p : gt) {
    SE3d q = p;
    q.translation() *= 1.004;
    est.push_back(offset * q);
  }
  auto m = EvaluateCamera(gt, est);
  ASSERT_TRUE(m.ok());
  EXPECT_NEAR(m->sim3_scale, 1.0 / 1.004, 1e-12);
  EXPECT_NEAR(m->ate_sim3_rmse, 0.0, 1e-9);
  EXPECT_GT(m->ate_rmse, 0.05);

  // Alternate ±2 cm along each position's own x: zero mean, RMS 0.02 m.
  for (size_t i = 0; i < est.size(); ++i) {
    est[i].translation() += offset.so3() * Eigen::Vector3d(i % 2 ? 0.02 : -0.02, 0, 0);
  }
  m = EvaluateCamera(gt, est);
  ASSERT_TRUE(m.ok());
  EXPECT_NEAR(m->ate_sim3_rmse, 0.02, 1e-3);
  EXPECT_NEAR(m->sim3_scale, 1.0 / 1.004, 1e-4);
  EXPECT_NE(FormatCameraTable(*m).find("after Sim(3) alignment (scale 0.99"), std::string::npos)
      << FormatCameraTable(*m);

  // Without a scale error both alignments agree.
  auto same = EvaluateCamera(gt, gt);
  ASSERT_TRUE(same.ok());
  EXPECT_NEAR(same->sim3_scale, 1.0, 1e-12);
  EXPECT_NEAR(same->ate_sim3_rmse, 0.0, 1e-9);
}

TEST(CameraMetrics, ConstantExtraTranslationPerFrame) {
  const auto gt = CurvyTrajectory(60);
  const SE3d delta(SO3d(), Eigen::Vector3d(0.03, -0.04, 0.0));  // 5 cm per frame
  auto m = EvaluateCamera(gt, WithConstantRelativeError(gt, delta));
  ASSERT_TRUE(m.ok());
  EXPECT_NEAR(m->rpe_t, 0.05, 1e-9);
  EXPECT_NEAR(m->rpe_t_max, 0.05, 1e-9);
  EXPECT_NEAR(m->rpe_r_deg, 0.0, 1e-7);
  EXPECT_GT(m->ate_rmse, 0.1);  // drift accumulates
}

TEST(CameraMetrics, ConstantExtraYawPerFrame) {
  const auto gt = CurvyTrajectory(60);
  const SE3d delta(SO3d::Exp(Eigen::Vector3d(0, 0.2 * kDeg, 0)), Eigen::Vector3d::Zero());
  auto m = EvaluateCamera(gt, WithConstantRelativeError(gt, delta));
  ASSERT_TRUE(m.ok());
  EXPECT_NEAR(m->rpe_r_deg, 0.2, 1e-9);
  EXPECT_NEAR(m->rpe_t, 0.0, 1e-9);
}

TEST(CameraMetrics, RigidOffsetIsAlignedAway) {
  const auto gt = CurvyTrajectory(40);
  const SE3d offset = SE3d::Exp((Vector6d() << 3, -2, 5, 0.3, -1.2, 0.4).finished());
  std::vector<SE3d> est;
  for (const SE3d& p : gt) est.push_back(offset * p);
  auto m = EvaluateCamera(gt, est);
  ASSERT_TRUE(m.ok());
  EXPECT_NEAR(m->ate_rmse, 0, 1e-9);
  EXPECT_NEAR(m->rpe_t, 0, 1e-9);
  EXPECT_NEAR(m->rpe_r_deg, 0, 1e-7);
  // The alignment found is the inverse of the offset.
  const SE3d should_be_identity = m->alignment * offset;
  EXPECT_LT(should_be_identity.Log().norm(), 1e-9);
}

TEST(CameraMetrics, NoiseOrthogonalToTheTrajectoryGivesItsRms) {
  // Noise whose per-coordinate sequences are orthogonal to 1 and to the
  // centred ground-truth coordinates: the best alignment is the identity, so
  // the ATE is exactly the RMS of the noise.
  const auto gt = CurvyTrajectory(80);
  const int n = static_cast<int>(gt.size());
  Eigen::MatrixXd basis(n, 4);
  for (int k = 0; k < n; ++k) basis.row(k) << 1, gt[k].translation().transpose();
  Eigen::HouseholderQR<Eigen::MatrixXd> qr(basis);
  const Eigen::MatrixXd q = qr.householderQ() * Eigen::MatrixXd::Identity(n, 4);
  std::mt19937 rng(42);
  std::normal_distribution<double> noise(0.0, 0.2);
  Eigen::MatrixXd e(n, 3);
  for (int k = 0; k < n; ++k) {
    for (int c = 0; c < 3; ++c) e(k, c) = noise(rng);
  }
  e -= q * (q.transpose() * e);  // project out the affine span
  std::vector<SE3d> est;
  double sum_sq = 0;
  for (int k = 0; k < n; ++k) {
    est.emplace_back(gt[k].so3(), gt[k].translation() + e.row(k).transpose());
    sum_sq += e.row(k).squaredNorm();
  }
  auto m = EvaluateCamera(gt, est);
  ASSERT_TRUE(m.ok());
  EXPECT_NEAR(m->ate_rmse, std::sqrt(sum_sq / n), 1e-9);
  EXPECT_GT(m->ate_rmse, 0.1);
}

TEST(CameraMetrics, SizeMismatchFails) {
  const auto gt = CurvyTrajectory(10);
  auto m = EvaluateCamera(gt, std::vector<SE3d>(gt.begin(), gt.begin() + 9));
  ASSERT_FALSE(m.ok());
  EXPECT_THAT(std::string(m.status().message()), ::testing::HasSubstr("9 estimated poses for 10"));
  EXPECT_FALSE(EvaluateCamera({}, {}).ok());
}

TEST(AlignRigid, RecoversKnownTransform) {
  std::mt19937 rng(9);
  std::uniform_real_distribution<double> u(-5, 5);
  std::vector<Eigen::Vector3d> est, gt;
  const SE3d t = SE3d::Exp((Vector6d() << 1, 2, 3, 0.5, 0.1, -2.0).finished());
  for (int i = 0; i < 10; ++i) {
    est.emplace_back(u(rng), u(rng), u(rng));
    gt.push_back(t * est.back());
  }
  const SE3d a = AlignRigid(est, gt);
  EXPECT_LT((a.Inverse() * t).Log().norm(), 1e-10);
}

// --------------------------------------------------------------- objects
constexpr double kDt = 0.1;

std::vector<int64_t> Stamps(int n) {
  std::vector<int64_t> s;
  for (int i = 0; i < n; ++i) s.push_back(static_cast<int64_t>(i) * 100'000'000);
  return s;
}

// A car moving along world x at `speed` m/s (identity rotation), id/class given.
std::vector<ObjectGtRow> MovingGt(int64_t id, int n, double speed, Eigen::Vector3d start) {
  std::vector<ObjectGtRow> rows;
  for (int i = 0; i < n; ++i) {
    rows.push_back({i, id, 26, SE3d(SO3d(), start + Eigen::Vector3d(speed * kDt * i, 0, 0))});
  }
  return rows;
}

TEST(ObjectMetrics, EstimateEqualToGroundTruthUpToObjectFrameGivesZeros) {
  const auto gt = MovingGt(4, 30, 10.0, Eigen::Vector3d(2, 1, 15));
  // The estimate uses another object frame (origin 1 m off, rotated): est = gt · X.
  const SE3d x = SE3d::Exp((Vector6d() << 1, 0.2, -0.5, 0.1, 0.7, 0).finished());
  std::vector<ObjectTrackRow> est;
  for (const ObjectGtRow& g : gt) {
    ObjectTrackRow r;
    r.frame = g.frame;
    r.track_id = 77;
    r.class_id = 26;
    r.world_from_object = g.world_from_object * x;
    r.twist_in_world << 10.0, 0, 0, 0, 0, 0;
    r.instance_id = 4;
    est.push_back(r);
  }
  auto e = EvaluateObjects(gt, est, Stamps(30), ObjectEvalOptions());
  ASSERT_TRUE(e.ok()) << e.status();
  ASSERT_EQ(e->objects.size(), 1u);
  const ObjectMetrics& m = e->objects[0];
  EXPECT_EQ(m.est_track_id, 77);
  EXPECT_TRUE(m.moving);
  EXPECT_NEAR(m.gt_mean_speed_kmh, 36.0, 1e-9);
  EXPECT_DOUBLE_EQ(m.coverage, 1.0);
  EXPECT_NEAR(m.ate, 0, 1e-9);
  EXPECT_NEAR(m.rpe_t_per_m, 0, 1e-9);
  EXPECT_NEAR(m.rpe_r_deg_per_m, 0, 1e-6);
  EXPECT_NEAR(m.speed_error_kmh, 0, 1e-9);
  EXPECT_NEAR(m.speed_error_pose_kmh, 0, 1e-9);
  EXPECT_NEAR(m.distance_m, 29.0, 1e-9);
  EXPECT_EQ(e->moving.num_objects, 1);
  EXPECT_EQ(e->static_objects.num_objects, 0);
  EXPECT_NEAR(e->all.ate, 0, 1e-9);
}

TEST(ObjectMetrics, SpeedBiasGivesKnownErrors) {
  const int n = 21;
  const double v = 8.0, bias = 0.5;  // estimate moves at 8.5 m/s
  const auto gt = MovingGt(2, n, v, Eigen::Vector3d(0, 1, 20));
  const auto fake = MovingGt(2, n, v + bias, Eigen::Vector3d(5, 0, 3));  // other origin
  std::vector<ObjectTrackRow> est;
  for (const ObjectGtRow& g : fake) {
    ObjectTrackRow r;
    r.frame = g.frame;
    r.track_id = 1;
    r.class_id = 26;
    r.world_from_object = g.world_from_object;
    r.twist_in_world << v + bias, 0, 0, 0, 0, 0;
    r.instance_id = 2;
    est.push_back(r);
  }
  auto e = EvaluateObjects(gt, est, Stamps(n), ObjectEvalOptions());
  ASSERT_TRUE(e.ok()) << e.status();
  const ObjectMetrics& m = e->objects[0];
  // Error at frame k is bias·dt·k: ATE = bias·dt·sqrt(mean k²).
  double mean_k2 = 0;
  for (int k = 0; k < n; ++k) mean_k2 += k * k;
  mean_k2 /= n;
  EXPECT_NEAR(m.ate, bias * kDt * std::sqrt(mean_k2), 1e-9);
  EXPECT_NEAR(m.rpe_t_per_frame, bias * kDt, 1e-9);
  EXPECT_NEAR(m.rpe_t_per_m, bias / v, 1e-9);
  EXPECT_NEAR(m.rpe_r_deg_per_m, 0, 1e-9);
  EXPECT_NEAR(m.speed_error_kmh, bias * 3.6, 1e-9);
  EXPECT_NEAR(m.speed_error_pose_kmh, bias * 3.6, 1e-9);
  EXPECT_EQ(m.speed_samples, n - 1);
}

TEST(ObjectMetrics, ExtraYawRateGivesKnownRotationError) {
  const int n = 15;
  const double v = 5.0, alpha = 0.3 * kDeg;  // extra yaw per frame about the object y axis
  const auto gt = MovingGt(9, n, v, Eigen::Vector3d(0, 1, 10));
  std::vector<ObjectTrackRow> est;
  for (const ObjectGtRow& g : gt) {
    ObjectTrackRow r;
    r.frame = g.frame;
    r.track_id = 3;
    r.class_id = 26;
    r.world_from_object =
        g.world_from_object *
        SE3d(SO3d::Exp(Eigen::Vector3d(0, alpha * g.frame, 0)), Eigen::Vector3d::Zero());
    r.instance_id = 9;
    est.push_back(r);
  }
  auto e = EvaluateObjects(gt, est, Stamps(n), ObjectEvalOptions());
  ASSERT_TRUE(e.ok());
  const ObjectMetrics& m = e->objects[0];
  EXPECT_NEAR(m.ate, 0, 1e-9);  // rotating about its own centre does not move it
  EXPECT_NEAR(m.rpe_r_deg_per_frame, 0.3, 1e-9);
  EXPECT_NEAR(m.rpe_r_deg_per_m, 0.3 / (v * kDt), 1e-9);
}

TEST(ObjectMetrics, CoverageFragmentsStaticSplitAndVisibility) {
  const int n = 20;
  std::vector<ObjectGtRow> gt = MovingGt(1, n, 12.0, Eigen::Vector3d(0, 1, 10));
  for (const ObjectGtRow& r : MovingGt(2, n, 0.0, Eigen::Vector3d(-4, 1, 25))) gt.push_back(r);
  std::vector<ObjectTrackRow> est;
  auto add = [&](int64_t track, int64_t inst, const ObjectGtRow& g) {
    ObjectTrackRow r;
    r.frame = g.frame;
    r.track_id = track;
    r.class_id = 26;
    r.world_from_object = g.world_from_object;
    r.instance_id = inst;
    est.push_back(r);
  };
  // Object 1: frames 0..9 in track 10, frames 12..14 in track 11 (fragment).
  for (int i = 0; i < 10; ++i) add(10, 1, gt[i]);
  for (int i = 12; i < 15; ++i) add(11, 1, gt[i]);
  // Object 2 (static): frames 5..19 without instance ids (nearest-centre match).
  for (int i = 5; i < 20; ++i) add(20, -1, gt[n + i]);
  // A false positive far from everything.
  ObjectTrackRow fp;
  fp.frame = 3;
  fp.track_id = 99;
  fp.world_from_object = SE3d(SO3d(), Eigen::Vector3d(50, 0, 50));
  est.push_back(fp);

  MaskPixelCounts px;
  for (int i = 0; i < n; ++i) {
    px[{i, 26 * 1000 + 1}] = i < 10 ? 1000 : 10;  // object 1 barely visible after frame 9
    px[{i, 26 * 1000 + 2}] = 500;
  }
  ObjectEvalOptions opt;
  opt.min_mask_pixels = 100;
  auto e = EvaluateObjects(gt, est, Stamps(n), opt, &px);
  ASSERT_TRUE(e.ok()) << e.status();
  ASSERT_EQ(e->objects.size(), 2u);
  const ObjectMetrics& a = e->objects[0];
  const ObjectMetrics& b = e->objects[1];
  EXPECT_EQ(a.est_track_id, 10);
  EXPECT_EQ(a.num_est_tracks, 2);
  EXPECT_DOUBLE_EQ(a.coverage, 10.0 / 20.0);
  EXPECT_EQ(a.visible_gt_frames, 10);
  EXPECT_DOUBLE_EQ(a.visible_coverage, 1.0);
  EXPECT_TRUE(a.moving);
  EXPECT_EQ(b.est_track_id, 20);
  EXPECT_FALSE(b.moving);
  EXPECT_EQ(b.first_frame, 5);
  EXPECT_DOUBLE_EQ(b.coverage, 15.0 / 20.0);
  EXPECT_TRUE(std::isnan(b.rpe_t_per_m));  // a static object travels 0 m
  EXPECT_NEAR(b.rpe_t_per_frame, 0, 1e-12);
  EXPECT_EQ(e->num_est_tracks, 4);
  EXPECT_EQ(e->num_unmatched_est_tracks, 1);
  EXPECT_EQ(e->moving.num_objects, 1);
  EXPECT_EQ(e->static_objects.num_objects, 1);
  EXPECT_DOUBLE_EQ(e->all.coverage, 25.0 / 40.0);
  EXPECT_DOUBLE_EQ(e->all.visible_coverage, 25.0 / 30.0);

  // The tables and JSON mention every object.
  const std::string table = FormatObjectTable(*e);
  EXPECT_THAT(table, ::testing::HasSubstr("moving"));
  EXPECT_THAT(table, ::testing::HasSubstr("static"));
  JsonWriter w;
  WriteObjectsJson(*e, &w);
  EXPECT_TRUE(w.complete());
  EXPECT_THAT(w.str(), ::testing::HasSubstr("\"rpe_t_m_per_m\": null"));
}

// Each visible frame a car's evaluated track misses is put where it lies:
// before all its tracks, in another of its tracks, between them, after them.
TEST(ObjectMetrics, VisibleMissesSayWhereTheCoverageGoes) {
  const int n = 30;
  const std::vector<ObjectGtRow> gt = MovingGt(1, n, 10.0, Eigen::Vector3d(0, 1, 12));
  std::vector<ObjectTrackRow> est;
  auto add = [&](int64_t track, int first, int last) {
    for (int i = first; i <= last; ++i) {
      ObjectTrackRow r;
      r.frame = i;
      r.track_id = track;
      r.class_id = 26;
      r.world_from_object = gt[static_cast<size_t>(i)].world_from_object;
      r.instance_id = 1;
      est.push_back(r);
    }
  };
  add(7, 4, 5);    // a fragment: frames 4-5
  add(8, 8, 21);   // the evaluated track: frames 8-21 (gap 6-7)
  add(9, 24, 25);  // a fragment after a gap of 22-23
  MaskPixelCounts px;
  for (int i = 0; i < n; ++i) px[{i, 26 * 1000 + 1}] = i == 1 || i == 15 ? 50 : 3000;
  auto e = EvaluateObjects(gt, est, Stamps(n), ObjectEvalOptions(), &px);
  ASSERT_TRUE(e.ok()) << e.status();
  ASSERT_EQ(e->objects.size(), 1u);
  const ObjectMetrics& m = e->objects[0];
  EXPECT_EQ(m.est_track_id, 8);
  EXPECT_EQ(m.num_est_tracks, 3);
  // Visible: all frames but 1 and 15 (28); tracked 8-21 but 15 (13).
  EXPECT_EQ(m.visible_gt_frames, 28);
  EXPECT_EQ(m.visible_tracked_frames, 13);
  EXPECT_EQ(m.visible_misses.before_first, 3);    // 0, 2, 3
  EXPECT_EQ(m.visible_misses.other_fragment, 4);  // 4, 5, 24, 25
  EXPECT_EQ(m.visible_misses.gap, 4);             // 6, 7, 22, 23
  EXPECT_EQ(m.visible_misses.after_last, 4);      // 26-29
  EXPECT_EQ(m.visible_gt_frames - m.visible_tracked_frames,
            m.visible_misses.before_first + m.visible_misses.other_fragment + m.visible_misses.gap +
                m.visible_misses.after_last);
  EXPECT_EQ(e->moving.visible_misses.other_fragment, 4);
  EXPECT_EQ(e->by_class.at(0).aggregate.visible_misses.after_last, 4);
  JsonWriter w;
  WriteObjectsJson(*e, &w);
  ASSERT_TRUE(w.complete());
  EXPECT_THAT(w.str(), ::testing::HasSubstr("\"visible_missed\""));
  EXPECT_THAT(w.str(), ::testing::HasSubstr("\"before_first\": 3"));

  // A car never tracked misses all its visible frames before any track.
  auto none = EvaluateObjects(gt, {}, Stamps(n), ObjectEvalOptions(), &px);
  ASSERT_TRUE(none.ok()) << none.status();
  EXPECT_EQ(none->objects[0].visible_misses.before_first, 28);
}

TEST(ObjectMetrics, PerClassAggregatesSeparateCarsFromPedestrians) {
  // A moving car tracked exactly, a moving pedestrian (class 24) whose estimate
  // is 0.5 m/s too fast, and a parked car tracked exactly: "moving" pools the
  // car and the pedestrian, the class rows keep them apart.
  const int n = 11;
  std::vector<ObjectGtRow> gt = MovingGt(1, n, 10.0, Eigen::Vector3d(0, 1, 15));
  std::vector<ObjectGtRow> walker = MovingGt(2, n, 1.5, Eigen::Vector3d(3, 1, 12));
  for (ObjectGtRow& r : walker) r.class_id = 24;
  gt.insert(gt.end(), walker.begin(), walker.end());
  for (const ObjectGtRow& r : MovingGt(3, n, 0.0, Eigen::Vector3d(-4, 1, 20))) gt.push_back(r);
  const auto walker_est = MovingGt(2, n, 2.0, Eigen::Vector3d(3, 1, 12));
  std::vector<ObjectTrackRow> est;
  for (size_t k = 0; k < gt.size(); ++k) {
    ObjectTrackRow r;
    r.frame = gt[k].frame;
    r.track_id = 100 + gt[k].track_id;
    r.class_id = gt[k].class_id;
    r.instance_id = gt[k].track_id;
    r.world_from_object = gt[k].track_id == 2
                              ? walker_est[static_cast<size_t>(gt[k].frame)].world_from_object
                              : gt[k].world_from_object;
    est.push_back(r);
  }
  auto e = EvaluateObjects(gt, est, Stamps(n), ObjectEvalOptions());
  ASSERT_TRUE(e.ok()) << e.status();
  ASSERT_EQ(e->by_class.size(), 3u);
  // Sorted by class, moving first: person moving, car moving, car static.
  EXPECT_EQ(e->by_class[0].class_id, 24);
  EXPECT_TRUE(e->by_class[0].moving);
  EXPECT_EQ(e->by_class[1].class_id, 26);
  EXPECT_TRUE(e->by_class[1].moving);
  EXPECT_EQ(e->by_class[2].class_id, 26);
  EXPECT_FALSE(e->by_class[2].moving);
  const ObjectAggregate& person = e->by_class[0].aggregate;
  const ObjectAggregate& car = e->by_class[1].aggregate;
  EXPECT_EQ(person.num_objects, 1);
  EXPECT_EQ(car.num_objects, 1);
  EXPECT_EQ(e->by_class[2].aggregate.num_objects, 1);
  EXPECT_NEAR(car.ate, 0, 1e-9);
  EXPECT_NEAR(car.rpe_t_per_m, 0, 1e-9);
  // The walker's error grows by 0.5 m/s · dt per frame over 1.5 m/s · dt.
  EXPECT_NEAR(person.rpe_t_per_m, 0.5 / 1.5, 1e-9);
  EXPECT_GT(e->moving.ate, 0.0);
  EXPECT_GT(e->moving.ate, car.ate);
  EXPECT_EQ(e->moving.num_objects, 2);
  const std::string table = FormatObjectTable(*e);
  EXPECT_THAT(table, ::testing::HasSubstr("class 26 moving"));
  EXPECT_THAT(table, ::testing::HasSubstr("class 24 moving"));
  EXPECT_THAT(table, ::testing::HasSubstr("class 26 static"));
  JsonWriter w;
  WriteObjectsJson(*e, &w);
  EXPECT_TRUE(w.complete());
  EXPECT_THAT(w.str(), ::testing::HasSubstr("\"by_class\""));
}

TEST(ObjectMetrics, DuplicateRowsFail) {
  auto gt = MovingGt(1, 3, 1.0, Eigen::Vector3d::Zero());
  gt.push_back(gt[0]);
  auto e = EvaluateObjects(gt, {}, Stamps(3), ObjectEvalOptions());
  ASSERT_FALSE(e.ok());
  EXPECT_THAT(std::string(e.status().message()), ::testing::HasSubstr("appears twice in frame 0"));
  e = EvaluateObjects(
      MovingGt(1, 3, 1.0, Eigen::Vector3d::Zero()), {}, Stamps(2), ObjectEvalOptions());
  ASSERT_FALSE(e.ok());
  EXPECT_THAT(std::string(e.status().message()), ::testing::HasSubstr("no timestamp"));
}

TEST(MaskPixels, CountsPerId) {
  cv::Mat m(4, 5, CV_16UC1, cv::Scalar(7000));
  m(cv::Rect(1, 1, 2, 2)).setTo(26003);
  MaskPixelCounts c;
  CountMaskPixels(3, m, &c);
  EXPECT_EQ((c[{3, 26003}]), 4);
  EXPECT_EQ((c[{3, 7000}]), 16);
}

}  // namespace
}  // namespace twist::io
