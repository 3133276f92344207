// EvaluateRunDirectory: a small kitti-tracking dataset with exact ground truth
// evaluated against outputs written by RunOutputWriter.
#include "slam/io/evaluation.h"

#include <gmock/gmock.h>
#include <gtest/gtest.h>

#include <cmath>
#include <opencv2/imgcodecs.hpp>

#include "slam/io/file_util.h"
#include "slam/io/run_output.h"
#include "tests/slam/io/test_util.h"

namespace twist::io {
namespace {

using geometry::SE3d;
using geometry::SO3d;
using ::testing::HasSubstr;
using testing_util::ScratchDir;
using testing_util::WriteText;

constexpr int kN = 12;
constexpr int kW = 64;
constexpr int kH = 32;

SE3d CameraPose(int i) {
  return SE3d(SO3d::Exp(Eigen::Vector3d(0, 0.01 * i, 0)), Eigen::Vector3d(0.1 * i, 0, 1.0 * i));
}
// Object 5 drives at 8 m/s along z; object 6 is parked.
SE3d ObjectPose(int id, int i) {
  if (id == 5) return SE3d(SO3d(), Eigen::Vector3d(3, 1, 10 + 0.8 * i));
  return SE3d(SO3d::Exp(Eigen::Vector3d(0, 0.5, 0)), Eigen::Vector3d(-3, 1, 20));
}

void MakeDataset(const std::string& root) {
  std::vector<SE3d> poses;
  std::vector<ObjectGtRow> objects;
  std::string times;
  for (int i = 0; i < kN; ++i) {
    char name[16];
    std::snprintf(name, sizeof(name), "%06d.png", i);
    for (const char* d : {"image_02/0000/", "image_03/0000/", "panoptic/0000/"}) {
      std::filesystem::create_directories(root + "/" + d);
    }
    cv::imwrite(root + "/image_02/0000/" + name, cv::Mat(kH, kW, CV_8UC1, cv::Scalar(i)));
    cv::imwrite(root + "/image_03/0000/" + name, cv::Mat(kH, kW, CV_8UC1, cv::Scalar(i)));
    cv::Mat pan(kH, kW, CV_16UC1, cv::Scalar(7000));
    pan(cv::Rect(0, 0, 20, 20)).setTo(26005);               // 400 px
    pan(cv::Rect(40, 0, i < 6 ? 20 : 5, 10)).setTo(26006);  // 200 px, then 50 px
    cv::imwrite(root + "/panoptic/0000/" + name, pan);
    poses.push_back(CameraPose(i));
    for (int id : {5, 6}) objects.push_back({i, id, 26, ObjectPose(id, i)});
    times += std::to_string(0.1 * i) + "\n";
  }
  WriteText(root + "/calib/0000.txt",
            "P2: 50 0 32 0 0 50 16 0 0 0 1 0\nP3: 50 0 32 -25 0 50 16 0 0 0 1 0\n");
  WriteText(root + "/poses/0000.txt", FormatKittiPoses(poses));
  WriteText(root + "/times/0000.txt", times);
  WriteText(root + "/objects_gt/0000.txt", FormatObjectsGt(objects));
}

// Writes a run whose outputs equal the ground truth (objects in their own
// frames: est = gt · X), optionally with a camera drift. With `refined`, the
// per-frame object poses drift sideways by 5 cm per frame and the refined
// trajectories (objects_refined.txt) are exact.
void WriteRun(const std::string& dir,
              double extra_forward_per_frame,
              int skip_object6_from,
              bool refined = false) {
  RunOutputWriter out;
  std::vector<TimedObjectTrajectory> trajectories(2);
  SE3d est = CameraPose(0);
  const SE3d x(SO3d::Exp(Eigen::Vector3d(0.1, 0.2, 0.3)), Eigen::Vector3d(0.5, -0.2, 1.0));
  for (int i = 0; i < kN; ++i) {
    if (i > 0) {
      est = est * (CameraPose(i - 1).Inverse() * CameraPose(i)) *
            SE3d(SO3d(), Eigen::Vector3d(0, 0, extra_forward_per_frame));
    }
    FrameResult r;
    r.index = i;
    r.timestamp_ns = i * 100'000'000LL;
    r.state = TrackingState::kOk;
    r.world_from_camera = est;
    for (int id : {5, 6}) {
      if (id == 6 && i >= skip_object6_from) continue;
      ObjectResult o;
      o.id = 100 + id;
      o.class_id = 26;
      o.instance_id = id;
      o.state = ObjectState::kTracked;
      o.world_from_object = ObjectPose(id, i) * x;
      if (id == 5) o.twist_in_world << 0, 0, 8.0, 0, 0, 0;
      TimedObjectTrajectory& t = trajectories[id == 5 ? 0 : 1];
      t.track_id = o.id;
      t.class_id = o.class_id;
      t.instance_id = o.instance_id;
      t.poses.emplace_back(r.timestamp_ns, o.world_from_object);
      if (refined) {
        o.world_from_object = SE3d(SO3d(), Eigen::Vector3d(0.05 * i, 0, 0)) * o.world_from_object;
      }
      r.objects.push_back(o);
    }
    out.Add(r);
  }
  if (refined) {
    // A pose at a time that is no frame of the run is dropped.
    trajectories[0].poses.emplace_back(kN * 100'000'000LL + 1, SE3d());
    out.SetRefinedObjects(trajectories);
  }
  ASSERT_TRUE(out.Write(dir, RunInfo()).ok());
}

// The toy masks are small: count a frame as visible from 100 px (the CLI
// default, 2000 px, is meant for full-size frames).
RunEvalOptions SmallMaskOptions() {
  RunEvalOptions options;
  options.objects.min_mask_pixels = 100;
  return options;
}

TEST(Evaluation, GroundTruthAgainstItselfGivesZeros) {
  ScratchDir dir;
  MakeDataset(dir / "data");
  WriteRun(dir / "run", 0.0, kN);
  auto seq = OpenSequence(dir / "data", "kitti-tracking", "0000");
  ASSERT_TRUE(seq.ok()) << seq.status();
  auto eval = EvaluateRunDirectory(**seq, dir / "run", SmallMaskOptions());
  ASSERT_TRUE(eval.ok()) << eval.status();
  ASSERT_TRUE(eval->camera.has_value());
  EXPECT_NEAR(eval->camera->rpe_t, 0, 1e-7);
  EXPECT_NEAR(eval->camera->rpe_r_deg, 0, 1e-5);
  EXPECT_NEAR(eval->camera->ate_rmse, 0, 1e-7);
  ASSERT_TRUE(eval->objects.has_value());
  EXPECT_EQ(eval->objects_gt_source, "objects_gt");
  ASSERT_EQ(eval->objects->objects.size(), 2u);
  const ObjectMetrics& moving = eval->objects->objects[0];
  const ObjectMetrics& parked = eval->objects->objects[1];
  EXPECT_TRUE(moving.moving);
  EXPECT_FALSE(parked.moving);
  EXPECT_NEAR(moving.gt_mean_speed_kmh, 8.0 * 3.6, 1e-6);
  EXPECT_NEAR(moving.ate, 0, 1e-6);
  EXPECT_NEAR(moving.rpe_t_per_m, 0, 1e-6);
  EXPECT_NEAR(moving.speed_error_kmh, 0, 1e-5);
  EXPECT_DOUBLE_EQ(moving.coverage, 1.0);
  EXPECT_DOUBLE_EQ(parked.coverage, 1.0);
  // Object 6 shows 200 px in frames 0-5 and 50 px after: 6 visible frames.
  EXPECT_EQ(parked.visible_gt_frames, 6);
  const std::string table = FormatRunEvaluation(*eval);
  EXPECT_THAT(table, HasSubstr("RPE_t     0.00000 m/frame"));
  const std::string json = RunEvaluationJson(*eval);
  EXPECT_THAT(json, HasSubstr("\"rpe_t_m_per_frame\": 0"));
}

TEST(Evaluation, KnownCameraDriftAndPartialCoverage) {
  ScratchDir dir;
  MakeDataset(dir / "data");
  WriteRun(dir / "run", 0.02, 9);  // 2 cm extra per frame; object 6 lost from frame 9
  auto seq = OpenSequence(dir / "data", "kitti-tracking", "0000");
  ASSERT_TRUE(seq.ok()) << seq.status();
  auto eval = EvaluateRunDirectory(**seq, dir / "run", SmallMaskOptions());
  ASSERT_TRUE(eval.ok()) << eval.status();
  EXPECT_NEAR(eval->camera->rpe_t, 0.02, 1e-6);
  EXPECT_DOUBLE_EQ(eval->objects->objects[1].coverage, 9.0 / 12.0);
  EXPECT_DOUBLE_EQ(eval->objects->objects[1].visible_coverage, 1.0);
  EXPECT_DOUBLE_EQ(eval->objects->all.coverage, 21.0 / 24.0);
}

// objects_refined.txt (RunOutputWriter::SetRefinedObjects) is scored with
// RunEvalOptions::objects_file; its twists are the central differences of the
// poses, exact for the constant-velocity car.
TEST(Evaluation, RefinedTrajectoriesAreScoredOnRequest) {
  ScratchDir dir;
  MakeDataset(dir / "data");
  WriteRun(dir / "run", 0.0, kN, /*refined=*/true);
  auto seq = OpenSequence(dir / "data", "kitti-tracking", "0000");
  ASSERT_TRUE(seq.ok()) << seq.status();
  auto online = EvaluateRunDirectory(**seq, dir / "run", SmallMaskOptions());
  ASSERT_TRUE(online.ok()) << online.status();
  EXPECT_GT(online->objects->objects[0].ate, 0.1);
  RunEvalOptions options = SmallMaskOptions();
  options.objects_file = "objects_refined.txt";
  auto refined = EvaluateRunDirectory(**seq, dir / "run", options);
  ASSERT_TRUE(refined.ok()) << refined.status();
  ASSERT_EQ(refined->objects->objects.size(), 2u);
  for (const ObjectMetrics& m : refined->objects->objects) {
    EXPECT_DOUBLE_EQ(m.coverage, 1.0);
    EXPECT_NEAR(m.ate, 0, 1e-6);
    EXPECT_NEAR(m.speed_error_kmh, 0, 1e-5);
  }
  EXPECT_NEAR(refined->objects->objects[0].rpe_t_per_m, 0, 1e-6);
  EXPECT_THAT(FormatRunEvaluation(*refined), HasSubstr("objects from objects_refined.txt"));
  EXPECT_THAT(RunEvaluationJson(*refined), HasSubstr("\"objects_file\": \"objects_refined.txt\""));
  auto rows = ReadObjectTracks(dir / "run/objects_refined.txt");
  ASSERT_TRUE(rows.ok()) << rows.status();
  EXPECT_EQ(rows->size(), 2u * kN);
  for (const ObjectTrackRow& row : *rows) {
    if (row.track_id != 105) continue;
    EXPECT_NEAR(row.twist_in_world[2], 8.0, 1e-9) << "frame " << row.frame;
  }
  // Without SetRefinedObjects there is no such file.
  WriteRun(dir / "plain", 0.0, kN);
  EXPECT_FALSE(std::filesystem::exists(dir / "plain/objects_refined.txt"));
}

// RefineCameraWithKeyFrames: with a correction that moves along one
// one-parameter subgroup, C(i) = Exp(i ξ), the interpolation between two
// keyframes is exact; outside the keyframes the nearest correction holds.
TEST(RefinedCamera, KeyFrameCorrectionsAreInterpolatedBetweenKeyFrames) {
  Eigen::Matrix<double, 6, 1> xi;
  xi << 0.02, -0.01, 0.03, 0.002, -0.001, 0.003;
  auto correction = [&](int i) { return SE3d::Exp(static_cast<double>(i) * xi); };
  std::vector<std::pair<int64_t, SE3d>> frames, keyframes;
  for (int i = 0; i < kN; ++i) {
    frames.push_back({i * 100, correction(i).Inverse() * CameraPose(i)});
  }
  for (int i : {9, 2, 5}) keyframes.push_back({i * 100, CameraPose(i)});  // any order
  keyframes.push_back({555, SE3d()});  // a keyframe of no frame is ignored
  const std::vector<SE3d> refined = RefineCameraWithKeyFrames(frames, keyframes);
  ASSERT_EQ(refined.size(), frames.size());
  for (int i = 0; i < kN; ++i) {
    const SE3d expected = i < 2   ? correction(2) * frames[i].second
                          : i > 9 ? correction(9) * frames[i].second
                                  : CameraPose(i);
    EXPECT_LT((expected.Inverse() * refined[i]).Log().norm(), 1e-9) << "frame " << i;
  }
  // Without keyframes the online poses are kept.
  const std::vector<SE3d> same = RefineCameraWithKeyFrames(frames, {});
  for (int i = 0; i < kN; ++i) {
    EXPECT_LT((frames[i].second.Inverse() * same[i]).Log().norm(), 1e-12);
  }
}

// camera_refined.txt (RunOutputWriter::SetRefinedKeyFrames) is scored with
// RunEvalOptions::camera_file: a drifting run whose every frame is a
// keyframe at its true pose evaluates to zeros.
TEST(Evaluation, RefinedCameraIsScoredOnRequest) {
  ScratchDir dir;
  MakeDataset(dir / "data");
  RunOutputWriter out;
  std::vector<std::pair<int64_t, SE3d>> keyframes;
  SE3d est = CameraPose(0);
  for (int i = 0; i < kN; ++i) {
    if (i > 0) {
      est = est * (CameraPose(i - 1).Inverse() * CameraPose(i)) *
            SE3d(SO3d(), Eigen::Vector3d(0, 0, 0.05));
    }
    FrameResult r;
    r.index = i;
    r.timestamp_ns = i * 100'000'000LL;
    r.state = TrackingState::kOk;
    r.world_from_camera = est;
    out.Add(r);
    if (i % 3 == 0 || i == kN - 1) keyframes.push_back({r.timestamp_ns, CameraPose(i)});
  }
  out.SetRefinedKeyFrames(keyframes);
  ASSERT_TRUE(out.Write(dir / "run", RunInfo()).ok());
  auto seq = OpenSequence(dir / "data", "kitti-tracking", "0000");
  ASSERT_TRUE(seq.ok()) << seq.status();
  auto online = EvaluateRunDirectory(**seq, dir / "run", SmallMaskOptions());
  ASSERT_TRUE(online.ok()) << online.status();
  EXPECT_NEAR(online->camera->rpe_t, 0.05, 1e-6);
  RunEvalOptions options = SmallMaskOptions();
  options.camera_file = "camera_refined.txt";
  auto refined = EvaluateRunDirectory(**seq, dir / "run", options);
  ASSERT_TRUE(refined.ok()) << refined.status();
  // The drift is a constant forward step: its correction grows along one
  // subgroup only approximately, so the frames between keyframes keep a
  // small error; the keyframes themselves are exact.
  EXPECT_LT(refined->camera->rpe_t, 0.2 * online->camera->rpe_t);
  EXPECT_LT(refined->camera->ate_rmse, 0.2 * online->camera->ate_rmse);
  EXPECT_THAT(FormatRunEvaluation(*refined), HasSubstr("camera from camera_refined.txt"));
  EXPECT_THAT(RunEvaluationJson(*refined), HasSubstr("\"camera_file\": \"camera_refined.txt\""));
  // Without SetRefinedKeyFrames there is no such file.
  WriteRun(dir / "plain", 0.0, kN);
  EXPECT_FALSE(std::filesystem::exists(dir / "plain/camera_refined.txt"));
}

TEST(Evaluation, Failures) {
  ScratchDir dir;
  MakeDataset(dir / "data");
  auto seq = OpenSequence(dir / "data", "kitti-tracking", "0000");
  ASSERT_TRUE(seq.ok()) << seq.status();
  auto eval = EvaluateRunDirectory(**seq, dir / "none", RunEvalOptions());
  ASSERT_FALSE(eval.ok());
  EXPECT_THAT(std::string(eval.status().message()), HasSubstr("none: no such output directory"));

  WriteRun(dir / "run", 0.0, kN);
  std::filesystem::remove(dir / "run/objects.txt");
  eval = EvaluateRunDirectory(**seq, dir / "run", RunEvalOptions());
  ASSERT_FALSE(eval.ok());
  EXPECT_THAT(std::string(eval.status().message()), HasSubstr("run/objects.txt: no such file"));

  std::vector<SE3d> short_poses(kN - 1);
  ASSERT_TRUE(WriteKittiPoses(dir / "run/camera.txt", short_poses).ok());
  eval = EvaluateRunDirectory(**seq, dir / "run", RunEvalOptions());
  ASSERT_FALSE(eval.ok());
  EXPECT_THAT(std::string(eval.status().message()),
              HasSubstr("camera.txt: 11 poses for a sequence of 12 frames"));
}

TEST(Evaluation, GroundTruthWrittenAsRunEvaluatesToZeros) {
  ScratchDir dir;
  MakeDataset(dir / "data");
  auto seq = OpenSequence(dir / "data", "kitti-tracking", "0000");
  ASSERT_TRUE(seq.ok()) << seq.status();
  ASSERT_TRUE(WriteGroundTruthAsRun(**seq, dir / "gt").ok());
  auto eval = EvaluateRunDirectory(**seq, dir / "gt", RunEvalOptions());
  ASSERT_TRUE(eval.ok()) << eval.status();
  EXPECT_NEAR(eval->camera->ate_rmse, 0, 1e-7);
  EXPECT_NEAR(eval->objects->all.ate, 0, 1e-7);
  EXPECT_NEAR(eval->objects->all.speed_error_kmh, 0, 1e-5);
  EXPECT_NEAR(eval->objects->objects[0].gt_mean_speed_kmh, 28.8, 1e-6);
  EXPECT_EQ(eval->objects->num_unmatched_est_tracks, 0);
}

TEST(Evaluation, ObjectsGroundTruthFromLabelsAndPoses) {
  KittiLabel l;
  l.frame = 1;
  l.track_id = 3;
  l.type = "Car";
  l.height = 2.0;
  l.location = Eigen::Vector3d(1, 1.5, 10);
  std::vector<SE3d> poses = {SE3d(), SE3d(SO3d(), Eigen::Vector3d(0, 0, 5))};
  auto rows = ObjectsGtFromLabels({l}, poses, Eigen::Vector3d(0.06, 0, 0));
  ASSERT_EQ(rows.size(), 1u);
  EXPECT_EQ(rows[0].class_id, 26);
  EXPECT_TRUE(rows[0].world_from_object.translation().isApprox(Eigen::Vector3d(1.06, 0.5, 15)));
}

}  // namespace
}  // namespace twist::io
