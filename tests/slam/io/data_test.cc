// Tests on the real KITTI extracts in ../shared/data (skipped when absent).
#include <gmock/gmock.h>
#include <gtest/gtest.h>

#include <algorithm>
#include <cmath>
#include <filesystem>
#include <opencv2/imgcodecs.hpp>

#include "slam/io/kitti_calib.h"
#include "slam/io/kitti_labels.h"
#include "slam/io/metrics.h"
#include "slam/io/sequence.h"
#include "slam/io/trajectory_io.h"
#include "tests/slam/io/test_util.h"

namespace twist::io {
namespace {

using geometry::SE3d;
using geometry::SO3d;
using testing_util::SharedDataDir;

#define REQUIRE_DATA(sub)                                      \
  const std::string data_path = SharedDataDir() + "/" + (sub); \
  if (!std::filesystem::exists(data_path)) GTEST_SKIP() << data_path << " absent"

std::string Seq4(int s) {
  char buf[8];
  std::snprintf(buf, sizeof(buf), "%04d", s);
  return buf;
}

TEST(KittiData, AllTrackingLabelsAndCalibrationsParse) {
  REQUIRE_DATA("kitti_tracking_labels");
  int64_t total_frames = 0;
  for (int s = 0; s <= 20; ++s) {
    const std::string seq = Seq4(s);
    auto labels = ReadKittiLabels(SharedDataDir() + "/kitti_tracking_labels/" + seq + ".txt");
    ASSERT_TRUE(labels.ok()) << labels.status();
    ASSERT_FALSE(labels->empty()) << seq;
    int64_t max_frame = 0;
    int cars = 0;
    for (const KittiLabel& l : *labels) {
      max_frame = std::max(max_frame, l.frame);
      if (l.is_dont_care()) {
        EXPECT_EQ(l.track_id, -1);
      } else {
        EXPECT_GE(l.track_id, 0);
        EXPECT_GT(l.height, 0);
        EXPECT_GT(l.length, 0);
        cars += l.type == "Car";
      }
    }
    total_frames += max_frame + 1;
    EXPECT_GT(cars + 0, -1);
    auto calib = ReadKittiTrackingCalib(SharedDataDir() + "/kitti_tracking_calib/" + seq + ".txt");
    ASSERT_TRUE(calib.ok()) << calib.status();
    EXPECT_TRUE(calib->r_rect.has_value()) << seq;
    EXPECT_TRUE(calib->tr_velo_cam.has_value()) << seq;
    EXPECT_TRUE(calib->tr_imu_velo.has_value()) << seq;
    EXPECT_NEAR(calib->camera.baseline, 0.53, 0.02) << seq;
    EXPECT_GT(calib->camera.fx, 700);
    // Camera 2 sits about 6 cm to the left of camera 0 along x.
    EXPECT_NEAR(calib->left_from_ref_translation.x(), 0.06, 0.01) << seq;
  }
  // The README's total of labelled frames over 0000-0020 (frames without any
  // object at the end of a sequence are not counted by max_frame + 1).
  EXPECT_NEAR(static_cast<double>(total_frames), 8008.0, 20.0);
}

// Projects the labelled 3D boxes of the sample frames with P2 and compares the
// bounding rectangle of the projected corners (clipped to the image) with the
// labelled 2D box.
TEST(KittiData, ProjectedBoxesFallOnLabelledBoxes) {
  REQUIRE_DATA("kitti_tracking_samples");
  const std::vector<std::pair<int, std::vector<int>>> samples = {{1, {10, 15, 20}},
                                                                 {16, {2, 7, 12}}};
  int checked = 0;
  std::vector<double> errors;
  for (const auto& [s, frames] : samples) {
    const std::string seq = Seq4(s);
    auto calib = ReadKittiTrackingCalib(SharedDataDir() + "/kitti_tracking_calib/" + seq + ".txt");
    ASSERT_TRUE(calib.ok()) << calib.status();
    auto labels = ReadKittiLabels(SharedDataDir() + "/kitti_tracking_labels/" + seq + ".txt");
    ASSERT_TRUE(labels.ok()) << labels.status();
    for (int f : frames) {
      char name[32];
      std::snprintf(name, sizeof(name), "/%06d.png", f);
      const std::string image_path = data_path + "/image_02/" + seq + name;
      const cv::Mat image = cv::imread(image_path, cv::IMREAD_UNCHANGED);
      ASSERT_FALSE(image.empty()) << image_path;
      int in_frame = 0;
      for (const KittiLabel& l : *labels) {
        if (l.frame != f || l.is_dont_care()) continue;
        ++in_frame;
        // Heavily occluded or truncated boxes are annotated on the visible part only.
        if (l.occluded >= 2 || l.truncated > 0) continue;
        double u0 = 1e9, v0 = 1e9, u1 = -1e9, v1 = -1e9;
        bool behind = false;
        for (const Eigen::Vector3d& c : l.Corners()) {
          const Eigen::Vector3d uvw = calib->p2 * c.homogeneous();
          if (uvw.z() < 0.5) behind = true;
          u0 = std::min(u0, uvw.x() / uvw.z());
          u1 = std::max(u1, uvw.x() / uvw.z());
          v0 = std::min(v0, uvw.y() / uvw.z());
          v1 = std::max(v1, uvw.y() / uvw.z());
        }
        if (behind) continue;
        u0 = std::clamp(u0, 0.0, image.cols - 1.0);
        u1 = std::clamp(u1, 0.0, image.cols - 1.0);
        v0 = std::clamp(v0, 0.0, image.rows - 1.0);
        v1 = std::clamp(v1, 0.0, image.rows - 1.0);
        // Vehicles are rigid boxes: all four edges agree. For people the 2D box
        // hugs the silhouette while the 3D box is wider than the body, so only
        // the vertical extent must agree and the labelled box must lie inside
        // the projected one horizontally.
        const bool rigid =
            l.type == "Car" || l.type == "Van" || l.type == "Truck" || l.type == "Tram";
        const double vertical = std::max(std::abs(v0 - l.y1), std::abs(v1 - l.y2));
        const double horizontal = rigid ? std::max(std::abs(u0 - l.x1), std::abs(u1 - l.x2))
                                        : std::max({u0 - l.x1, l.x2 - u1, 0.0});
        const double err = std::max(vertical, horizontal);
        errors.push_back(err);
        // The labelled 2D box lies in the image.
        EXPECT_GE(l.x1, -1);
        EXPECT_LE(l.x2, image.cols + 1);
        // Vehicles agree to about a pixel (3 px at most, near cars); people and
        // cyclists to a few pixels.
        EXPECT_LE(err, rigid ? 3.0 : 5.0)
            << seq << " frame " << f << " track " << l.track_id << " " << l.type << " box (" << l.x1
            << "," << l.y1 << ")-(" << l.x2 << "," << l.y2 << ") projected (" << u0 << "," << v0
            << ")-(" << u1 << "," << v1 << ")";
        if (!rigid) {
          EXPECT_LT(u1 - u0, 3.0 * (l.x2 - l.x1)) << "projected box far too wide";
        }
        ++checked;
      }
      EXPECT_GT(in_frame, 0) << seq << " frame " << f << " has no labelled objects";
    }
  }
  ASSERT_GE(checked, 10);
  std::sort(errors.begin(), errors.end());
  EXPECT_LE(errors[errors.size() / 2], 1.0) << "median edge error";
  std::printf("checked %d boxes: median error %.2f px, max %.2f px\n",
              checked,
              errors[errors.size() / 2],
              errors.back());
  // A wrong calibration (e.g. P0 instead of P2, or the box origin at the centre
  // instead of the bottom) would move every box by many pixels.
}

TEST(KittiData, OdometryClipReads51Frames) {
  REQUIRE_DATA("kitti_odometry_06_f0-50");
  auto seq = OpenSequence(data_path, "kitti-odometry", "06");
  ASSERT_TRUE(seq.ok()) << seq.status();
  const SequenceReader& r = **seq;
  EXPECT_EQ(r.size(), 51);
  EXPECT_EQ(r.camera().width, 1226);
  EXPECT_EQ(r.camera().height, 370);
  EXPECT_DOUBLE_EQ(r.camera().fx, 707.0912);
  EXPECT_DOUBLE_EQ(r.camera().cx, 601.8873);
  EXPECT_DOUBLE_EQ(r.camera().cy, 183.1104);
  EXPECT_NEAR(r.camera().baseline, 379.8145 / 707.0912, 1e-12);
  ASSERT_TRUE(r.has_gt_poses());
  EXPECT_EQ(r.gt_world_from_camera().size(), 51u);
  EXPECT_LT(r.gt_world_from_camera()[0].translation().norm(), 1e-9);
  EXPECT_EQ(r.timestamps_ns()[1], 100'000'000);  // 1.000000e-01 s
  for (int64_t i : {0, 25, 50}) {
    auto frame = r.ReadFrame(i);
    ASSERT_TRUE(frame.ok()) << frame.status();
    EXPECT_EQ(frame->left.type(), CV_8UC1);
    EXPECT_EQ(frame->right.size(), frame->left.size());
  }
  // About 60 m of straight road.
  auto m = EvaluateCamera(r.gt_world_from_camera(), r.gt_world_from_camera());
  ASSERT_TRUE(m.ok());
  EXPECT_NEAR(m->gt_path_length, 60.0, 15.0);
}

TEST(KittiData, GroundTruthAgainstItselfIsExactlyZero) {
  REQUIRE_DATA("kitti_odometry_gt_poses");
  for (const char* s : {"00", "05", "07"}) {
    auto gt = ReadKittiPoses(data_path + "/" + s + ".txt");
    ASSERT_TRUE(gt.ok()) << gt.status();
    auto m = EvaluateCamera(*gt, *gt);
    ASSERT_TRUE(m.ok());
    // Re-orthonormalised rotations: no spurious ~0.01 °/frame from arccos(trace).
    EXPECT_LT(m->rpe_r_deg, 1e-6) << s;
    EXPECT_LT(m->rpe_t, 1e-9) << s;
    EXPECT_LT(m->ate_rmse, 1e-6) << s;
  }
}

TEST(KittiData, InjectedDriftGivesExpectedRpe) {
  REQUIRE_DATA("kitti_odometry_gt_poses");
  auto gt = ReadKittiPoses(data_path + "/00.txt");
  ASSERT_TRUE(gt.ok()) << gt.status();
  ASSERT_EQ(gt->size(), 4541u);
  // 1 cm forward and 0.02° of yaw extra every frame (relative drift).
  const SE3d delta(SO3d::Exp(Eigen::Vector3d(0, 0.02 * M_PI / 180, 0)),
                   Eigen::Vector3d(0, 0, 0.01));
  std::vector<SE3d> est = {(*gt)[0]};
  for (size_t i = 0; i + 1 < gt->size(); ++i) {
    est.push_back(est.back() * ((*gt)[i].Inverse() * (*gt)[i + 1]) * delta);
  }
  auto m = EvaluateCamera(*gt, est);
  ASSERT_TRUE(m.ok());
  EXPECT_NEAR(m->rpe_t, 0.01, 1e-7);
  EXPECT_NEAR(m->rpe_r_deg, 0.02, 1e-7);
  EXPECT_GT(m->ate_rmse, 1.0);  // drift over 3.7 km accumulates

  // Written to and read back from KITTI text, the figures stay the same.
  testing_util::ScratchDir dir;
  ASSERT_TRUE(WriteKittiPoses(dir / "est.txt", est).ok());
  auto est_read = ReadKittiPoses(dir / "est.txt");
  ASSERT_TRUE(est_read.ok());
  auto m2 = EvaluateCamera(*gt, *est_read);
  ASSERT_TRUE(m2.ok());
  EXPECT_NEAR(m2->rpe_t, 0.01, 1e-6);
  EXPECT_NEAR(m2->rpe_r_deg, 0.02, 1e-5);
}

}  // namespace
}  // namespace twist::io
