#include "slam/sim/writer.h"

#include <gtest/gtest.h>

#include <atomic>
#include <filesystem>
#include <fstream>
#include <iterator>
#include <opencv2/imgcodecs.hpp>
#include <set>
#include <sstream>
#include <string>

#include "slam/io/sequence.h"
#include "slam/joints/class_table.h"
#include "slam/sim/scenarios.h"

namespace twist::sim {
namespace {

namespace fs = std::filesystem;

fs::path FreshDir(const std::string& name) {
  const fs::path dir = fs::path(::testing::TempDir()) / ("twist_sim_" + name);
  fs::remove_all(dir);
  return dir;
}

std::string ReadAll(const fs::path& p) {
  std::ifstream in(p, std::ios::binary);
  return std::string(std::istreambuf_iterator<char>(in), std::istreambuf_iterator<char>());
}

// All regular files under `dir`, relative paths.
std::set<std::string> Files(const fs::path& dir) {
  std::set<std::string> out;
  for (const auto& e : fs::recursive_directory_iterator(dir)) {
    if (e.is_regular_file()) out.insert(fs::relative(e.path(), dir).string());
  }
  return out;
}

TEST(Writer, WritesADatasetTheKittiTrackingReaderAccepts) {
  const fs::path dir = FreshDir("parse");
  absl::StatusOr<Scenario> sc = MakeScenario("driving", 4, 3);
  ASSERT_TRUE(sc.ok());
  WriteOptions options;
  options.sequence = "0007";
  ASSERT_TRUE(WriteSequence(*sc, dir.string(), options).ok());

  absl::StatusOr<std::unique_ptr<io::SequenceReader>> seq =
      io::OpenSequence(dir.string(), "kitti-tracking", "0007");
  ASSERT_TRUE(seq.ok()) << seq.status();
  const io::SequenceReader& r = **seq;
  ASSERT_EQ(r.size(), 3);
  EXPECT_NEAR(r.camera().fx, sc->camera.fx, 1e-9);
  EXPECT_NEAR(r.camera().cx, sc->camera.cx, 1e-9);
  EXPECT_NEAR(r.camera().cy, sc->camera.cy, 1e-9);
  EXPECT_NEAR(r.camera().baseline, sc->camera.baseline, 1e-9);
  EXPECT_EQ(r.camera().width, 1242);
  EXPECT_EQ(r.camera().height, 375);
  ASSERT_TRUE(r.tracking_calib().has_value());
  EXPECT_NEAR(r.tracking_calib()->left_from_ref_translation.norm(), 0.0, 1e-12);
  EXPECT_EQ(r.timestamps_ns()[1] - r.timestamps_ns()[0], 100'000'000);
  ASSERT_TRUE(r.has_gt_poses());
  for (int i = 0; i < 3; ++i) {
    EXPECT_NEAR(
        (r.gt_world_from_camera()[i].matrix() - sc->WorldFromCamera(i).matrix()).norm(), 0.0, 1e-9);
  }
  ASSERT_TRUE(r.has_labels());
  ASSERT_TRUE(r.has_gt_objects());
  EXPECT_EQ(r.labels().size(), r.gt_objects().size());
  EXPECT_GT(r.labels().size(), 6u);
  absl::StatusOr<joints::ClassTable> classes = joints::ClassTable::FromText(r.class_table_text());
  ASSERT_TRUE(classes.ok()) << classes.status();
  EXPECT_TRUE(classes->IsDynamic(kClassCar));
  EXPECT_TRUE(classes->IsDynamic(kClassDoor));
  EXPECT_EQ(classes->Find(kClassDoor)->joint, joints::JointType::kRevolute);
  EXPECT_FALSE(classes->IsDynamic(kClassRoad));

  absl::StatusOr<StereoFrame> frame = r.ReadFrame(2);
  ASSERT_TRUE(frame.ok()) << frame.status();
  ASSERT_EQ(frame->panoptic.type(), CV_16UC1);
  EXPECT_EQ(frame->left.type(), CV_8UC3);
  // Every label of the frame is an instance of the mask with its class.
  for (const io::KittiLabel& label : r.labels()) {
    if (label.frame != 2) continue;
    const int cls = io::KittiTypeToClassId(label.type);
    const uint16_t id = PanopticId(cls, static_cast<int>(label.track_id));
    EXPECT_GT(cv::countNonZero(frame->panoptic == id), 0) << label.track_id;
  }
  // Nothing left behind but the dataset.
  for (const auto& e : fs::directory_iterator(dir.parent_path())) {
    EXPECT_EQ(e.path().filename().string().find("twist_sim_parse.tmp"), std::string::npos);
  }
}

TEST(Writer, SameSeedSameBytesOtherSeedOtherImages) {
  absl::StatusOr<Scenario> a = MakeScenario("follow_braking", 11, 2);
  absl::StatusOr<Scenario> b = MakeScenario("follow_braking", 11, 2);
  absl::StatusOr<Scenario> c = MakeScenario("follow_braking", 12, 2);
  ASSERT_TRUE(a.ok() && b.ok() && c.ok());
  const fs::path da = FreshDir("det_a"), db = FreshDir("det_b"), dc = FreshDir("det_c");
  WriteOptions options;
  options.render.gray = true;
  ASSERT_TRUE(WriteSequence(*a, da.string(), options).ok());
  ASSERT_TRUE(WriteSequence(*b, db.string(), options).ok());
  ASSERT_TRUE(WriteSequence(*c, dc.string(), options).ok());
  const std::set<std::string> files = Files(da);
  EXPECT_EQ(files, Files(db));
  EXPECT_EQ(files.size(), 2u * 3u + 6u);
  for (const std::string& f : files) EXPECT_EQ(ReadAll(da / f), ReadAll(db / f)) << f;
  EXPECT_NE(ReadAll(da / "image_02/0000/000001.png"), ReadAll(dc / "image_02/0000/000001.png"));
  const cv::Mat gray = cv::imread((da / "image_03/0000/000000.png").string(), cv::IMREAD_UNCHANGED);
  EXPECT_EQ(gray.type(), CV_8UC1);
}

TEST(Writer, AddsSequencesButNeverOverwritesOne) {
  const fs::path dir = FreshDir("merge");
  absl::StatusOr<Scenario> sc = MakeScenario("door", 1, 1);
  ASSERT_TRUE(sc.ok());
  WriteOptions options;
  options.sequence = "0001";
  ASSERT_TRUE(WriteSequence(*sc, dir.string(), options).ok());
  const std::string calib = ReadAll(dir / "calib/0001.txt");
  // Same sequence again: refused, nothing changed.
  const absl::Status again = WriteSequence(*sc, dir.string(), options);
  EXPECT_EQ(again.code(), absl::StatusCode::kAlreadyExists) << again;
  EXPECT_EQ(ReadAll(dir / "calib/0001.txt"), calib);
  // Another sequence is added next to it.
  options.sequence = "0002";
  ASSERT_TRUE(WriteSequence(*sc, dir.string(), options).ok());
  EXPECT_TRUE(fs::exists(dir / "image_02/0002/000000.png"));
  EXPECT_TRUE(fs::exists(dir / "image_02/0001/000000.png"));
  for (const auto& e : fs::directory_iterator(dir)) {
    EXPECT_EQ(e.path().filename().string().find(".tmp"), std::string::npos) << e.path();
  }
  // A trailing slash names the same directory.
  const fs::path slash = FreshDir("slash");
  ASSERT_TRUE(WriteSequence(*sc, slash.string() + "/", options).ok());
  EXPECT_TRUE(fs::exists(slash / "calib/0002.txt"));
  // A file where the dataset should go is an error.
  const fs::path file = FreshDir("file");
  std::ofstream(file) << "x";
  EXPECT_FALSE(WriteSequence(*sc, file.string(), options).ok());
}

TEST(Writer, CancelledRunLeavesNothing) {
  const fs::path dir = FreshDir("cancel");
  absl::StatusOr<Scenario> sc = MakeScenario("driving", 1, 3);
  ASSERT_TRUE(sc.ok());
  std::atomic<bool> cancel{true};
  WriteOptions options;
  options.cancel = &cancel;
  EXPECT_EQ(WriteSequence(*sc, dir.string(), options).code(), absl::StatusCode::kCancelled);
  EXPECT_FALSE(fs::exists(dir));
  for (const auto& e : fs::directory_iterator(dir.parent_path())) {
    EXPECT_EQ(e.path().filename().string().find("twist_sim_cancel"), std::string::npos) << e.path();
  }
}

TEST(Writer, CalibrationHasKittiTrackingKeys) {
  const std::string text = CalibrationText(KittiLikeCamera());
  std::istringstream in(text);
  std::string line;
  std::set<std::string> keys;
  while (std::getline(in, line)) {
    std::istringstream ls(line);
    std::string key;
    ls >> key;
    keys.insert(key);
    int n = 0;
    double v;
    while (ls >> v) ++n;
    EXPECT_EQ(n, key == "R_rect:" ? 9 : 12) << key;
  }
  EXPECT_EQ(keys,
            (std::set<std::string>{
                "P0:", "P1:", "P2:", "P3:", "R_rect:", "Tr_velo_cam:", "Tr_imu_velo:"}));
  EXPECT_NE(
      text.find("P3: 7.215377000000e+02 0.000000000000e+00 6.095593000000e+02 -3.896303580000e+02"),
      std::string::npos);
}

}  // namespace
}  // namespace twist::sim
