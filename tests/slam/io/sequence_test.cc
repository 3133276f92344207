// SequenceReader on small datasets written into a scratch directory, in both
// layouts, and every failure naming the file and the problem.
#include "slam/io/sequence.h"

#include <gmock/gmock.h>
#include <gtest/gtest.h>

#include <functional>
#include <opencv2/imgcodecs.hpp>

#include "slam/io/file_util.h"
#include "slam/io/trajectory_io.h"
#include "tests/slam/io/test_util.h"

namespace twist::io {
namespace {

using geometry::SE3d;
using ::testing::HasSubstr;
using testing_util::ScratchDir;
using testing_util::WriteText;

constexpr int kW = 40;
constexpr int kH = 24;

std::string Frame(int i) {
  char buf[16];
  std::snprintf(buf, sizeof(buf), "%06d.png", i);
  return buf;
}

cv::Mat Gray(int i, int w = kW, int h = kH) { return cv::Mat(h, w, CV_8UC1, cv::Scalar(10 + i)); }
cv::Mat Colour(int i) { return cv::Mat(kH, kW, CV_8UC3, cv::Scalar(10 + i, 20, 30)); }

std::string PosesText(int n) {
  std::vector<SE3d> poses;
  for (int i = 0; i < n; ++i)
    poses.push_back(SE3d(Eigen::Matrix3d::Identity(), Eigen::Vector3d(0, 0, i)));
  return FormatKittiPoses(poses);
}

// kitti-odometry: sequences/05 with n frames.
void MakeOdometry(const std::string& root, int n) {
  const std::string seq = root + "/sequences/05";
  for (int i = 0; i < n; ++i) {
    std::filesystem::create_directories(seq + "/image_0");
    std::filesystem::create_directories(seq + "/image_1");
    cv::imwrite(seq + "/image_0/" + Frame(i), Gray(i));
    cv::imwrite(seq + "/image_1/" + Frame(i), Gray(i + 1));
  }
  WriteText(seq + "/calib.txt",
            "P0: 30 0 20 0 0 30 12 0 0 0 1 0\nP1: 30 0 20 -15 0 30 12 0 0 0 1 0\n");
  std::string times;
  for (int i = 0; i < n; ++i) times += std::to_string(0.1 * i) + "\n";
  WriteText(seq + "/times.txt", times);
  WriteText(root + "/poses/05.txt", PosesText(n));
}

// kitti-tracking: sequence 0003 with n frames, colour images, panoptic masks.
void MakeTracking(const std::string& root, int n) {
  for (const char* d : {"image_02/0003", "image_03/0003", "panoptic/0003"}) {
    std::filesystem::create_directories(root + "/" + d);
  }
  for (int i = 0; i < n; ++i) {
    cv::imwrite(root + "/image_02/0003/" + Frame(i), Colour(i));
    cv::imwrite(root + "/image_03/0003/" + Frame(i), Colour(i + 1));
    cv::Mat pan(kH, kW, CV_16UC1, cv::Scalar(7000));
    pan(cv::Rect(5, 5, 10, 8)).setTo(26000 + 4);
    cv::imwrite(root + "/panoptic/0003/" + Frame(i), pan);
  }
  WriteText(root + "/calib/0003.txt",
            "P0: 30 0 20 0 0 30 12 0 0 0 1 0\nP1: 30 0 20 -15 0 30 12 0 0 0 1 0\n"
            "P2: 30 0 20 1.5 0 30 12 0 0 0 1 0\nP3: 30 0 20 -15 0 30 12 0 0 0 1 0\n"
            "R_rect: 1 0 0 0 1 0 0 0 1\nTr_velo_cam: 1 0 0 0 0 1 0 0 0 0 1 0\n"
            "Tr_imu_velo: 1 0 0 0 0 1 0 0 0 0 1 0\n");
  WriteText(root + "/label_02/0003.txt",
            "0 4 Car 0 0 0 5 5 14 12 1.5 1.6 4 0 1 10 0\n"
            "0 -1 DontCare -1 -1 -10 1 1 3 3 -1000 -1000 -1000 -10 -1 -1 -1\n"
            "1 4 Car 0 0 0 -3 5 50 12 1.5 1.6 4 0 1 10 0\n");
  WriteText(root + "/poses/0003.txt", PosesText(n));
  std::string times;
  for (int i = 0; i < n; ++i) times += std::to_string(0.05 * i) + "\n";
  WriteText(root + "/times/0003.txt", times);
  WriteText(root + "/objects_gt/0003.txt", "0 4 26 0 0 10 0 0 0 1\n1 4 26 0.5 0 10 0 0 0 1\n");
  WriteText(root + "/classes.txt", "# class table\n");
}

std::string Message(const absl::Status& s) { return std::string(s.message()); }

TEST(Sequence, OdometryReadsFramesAndGroundTruth) {
  ScratchDir dir;
  MakeOdometry(dir.path(), 3);
  auto seq = OpenSequence(dir.path(), "kitti-odometry", "5");  // zero-padded to 05
  ASSERT_TRUE(seq.ok()) << seq.status();
  const SequenceReader& r = **seq;
  EXPECT_EQ(r.sequence(), "05");
  EXPECT_EQ(r.size(), 3);
  EXPECT_EQ(r.camera().width, kW);
  EXPECT_EQ(r.camera().height, kH);
  EXPECT_DOUBLE_EQ(r.camera().baseline, 0.5);
  EXPECT_EQ(r.timestamps_ns(), (std::vector<int64_t>{0, 100000000, 200000000}));
  ASSERT_TRUE(r.has_gt_poses());
  EXPECT_DOUBLE_EQ(r.gt_world_from_camera()[2].translation().z(), 2.0);
  EXPECT_FALSE(r.has_masks());
  auto frame = r.ReadFrame(2);
  ASSERT_TRUE(frame.ok()) << frame.status();
  EXPECT_EQ(frame->index, 2);
  EXPECT_EQ(frame->timestamp_ns, 200000000);
  EXPECT_EQ(frame->left.type(), CV_8UC1);
  EXPECT_EQ(frame->left.at<uint8_t>(0, 0), 12);
  EXPECT_EQ(frame->right.at<uint8_t>(0, 0), 13);
  EXPECT_TRUE(frame->panoptic.empty());
  EXPECT_FALSE(r.ReadFrame(3).ok());
  EXPECT_FALSE(r.ReadFrame(-1).ok());
}

TEST(Sequence, TrackingReadsMasksBoxesAndGroundTruth) {
  ScratchDir dir;
  MakeTracking(dir.path(), 2);
  auto seq = OpenSequence(dir.path(), DatasetFormat::kKittiTracking, "3");
  ASSERT_TRUE(seq.ok()) << seq.status();
  const SequenceReader& r = **seq;
  EXPECT_EQ(r.sequence(), "0003");
  EXPECT_EQ(r.size(), 2);
  EXPECT_DOUBLE_EQ(r.camera().baseline, 16.5 / 30);
  ASSERT_TRUE(r.tracking_calib().has_value());
  EXPECT_NEAR(r.tracking_calib()->left_from_ref_translation.x(), 0.05, 1e-12);
  EXPECT_EQ(r.timestamps_ns()[1], 50000000);
  EXPECT_TRUE(r.has_masks());
  EXPECT_TRUE(r.has_labels());
  EXPECT_EQ(r.labels().size(), 3u);
  ASSERT_TRUE(r.has_gt_objects());
  EXPECT_EQ(r.gt_objects().size(), 2u);
  EXPECT_EQ(r.class_table_text(), "# class table\n");
  auto frame = r.ReadFrame(1);
  ASSERT_TRUE(frame.ok()) << frame.status();
  EXPECT_EQ(frame->left.type(), CV_8UC3);
  ASSERT_EQ(frame->panoptic.type(), CV_16UC1);
  EXPECT_EQ(frame->panoptic.at<uint16_t>(6, 6), 26004);
  EXPECT_EQ(frame->panoptic.at<uint16_t>(0, 0), 7000);
  ASSERT_EQ(frame->boxes.size(), 1u);  // DontCare (frame 0) not in frame 1 anyway
  EXPECT_EQ(frame->boxes[0].class_id, 26);
  EXPECT_EQ(frame->boxes[0].instance_id, 4);
  EXPECT_FLOAT_EQ(frame->boxes[0].x_min, 0.0f);       // clipped
  EXPECT_FLOAT_EQ(frame->boxes[0].x_max, kW - 1.0f);  // clipped
  auto frame0 = r.ReadFrame(0);
  ASSERT_TRUE(frame0.ok());
  EXPECT_EQ(frame0->boxes.size(), 1u);  // DontCare skipped
}

TEST(Sequence, TrackingUnderTrainingFolderAndDefaultTimes) {
  ScratchDir dir;
  MakeTracking(dir / "training", 2);
  std::filesystem::remove(dir / "training/times/0003.txt");
  auto seq = OpenSequence(dir.path(), "kitti-tracking", "0003");
  ASSERT_TRUE(seq.ok()) << seq.status();
  EXPECT_FALSE((*seq)->has_times_file());
  EXPECT_EQ((*seq)->timestamps_ns()[1], kDefaultFramePeriodNs);
}

TEST(Sequence, MotsInstancesMapToPanoptic) {
  ScratchDir dir;
  MakeTracking(dir.path(), 2);
  std::filesystem::remove_all(dir / "panoptic");
  std::filesystem::create_directories(dir / "instances/0003");
  for (int i = 0; i < 2; ++i) {
    cv::Mat mots(kH, kW, CV_16UC1, cv::Scalar(0));
    mots.at<uint16_t>(1, 1) = 1002;
    mots.at<uint16_t>(1, 2) = 2005;
    mots.at<uint16_t>(1, 3) = 10000;
    cv::imwrite(dir / ("instances/0003/" + Frame(i)), mots);
  }
  auto seq = OpenSequence(dir.path(), "kitti-tracking", "0003");
  ASSERT_TRUE(seq.ok()) << seq.status();
  auto mask = (*seq)->ReadMask(1);
  ASSERT_TRUE(mask.ok()) << mask.status();
  EXPECT_EQ(mask->at<uint16_t>(1, 1), 26002);
  EXPECT_EQ(mask->at<uint16_t>(1, 2), 24005);
  EXPECT_EQ(mask->at<uint16_t>(1, 3), 0);
}

TEST(Sequence, OpenFailuresNameTheFile) {
  struct Case {
    const char* what;
    std::function<void(const std::string&)> damage;
    const char* expected;
  };
  const std::vector<Case> cases = {
      {"no calib",
       [](const std::string& d) { std::filesystem::remove(d + "/sequences/05/calib.txt"); },
       "sequences/05/calib.txt: no such file"},
      {"no times",
       [](const std::string& d) { std::filesystem::remove(d + "/sequences/05/times.txt"); },
       "sequences/05/times.txt: no such file"},
      {"short times",
       [](const std::string& d) { WriteText(d + "/sequences/05/times.txt", "0\n0.1\n"); },
       "times.txt: 2 times for 3 frames (truncated?)"},
      {"short poses",
       [](const std::string& d) { WriteText(d + "/poses/05.txt", PosesText(2)); },
       "poses/05.txt: 2 poses for 3 frames"},
      {"bad pose line",
       [](const std::string& d) { WriteText(d + "/poses/05.txt", PosesText(2) + "1 2 3\n"); },
       "poses/05.txt:3: expected 12 numbers"},
      {"missing right",
       [](const std::string& d) {
         std::filesystem::remove(d + "/sequences/05/image_1/000001.png");
       },
       "image_1/000001.png: missing right image"},
      {"gap",
       [](const std::string& d) {
         std::filesystem::remove(d + "/sequences/05/image_0/000001.png");
       },
       "image_0/000001.png: missing"},
      {"no images",
       [](const std::string& d) { std::filesystem::remove_all(d + "/sequences/05/image_0"); },
       "image_0: no such directory"},
      {"16-bit left",
       [](const std::string& d) {
         cv::imwrite(d + "/sequences/05/image_0/000000.png",
                     cv::Mat(kH, kW, CV_16UC1, cv::Scalar(1)));
       },
       "image_0/000000.png: wrong bit depth: 16-bit"},
      {"truncated left",
       [](const std::string& d) {
         const std::string p = d + "/sequences/05/image_0/000000.png";
         const std::string bytes = *ReadTextFile(p);
         WriteText(p, bytes.substr(0, 20));
       },
       "image_0/000000.png: cannot decode image"},
  };
  for (const Case& c : cases) {
    ScratchDir dir;
    MakeOdometry(dir.path(), 3);
    c.damage(dir.path());
    auto seq = OpenSequence(dir.path(), "kitti-odometry", "05");
    ASSERT_FALSE(seq.ok()) << c.what;
    EXPECT_THAT(Message(seq.status()), HasSubstr(c.expected)) << c.what;
  }
}

TEST(Sequence, ReadFrameFailuresNameTheFile) {
  struct Case {
    const char* what;
    std::function<void(const std::string&)> damage;
    const char* expected;
  };
  const std::vector<Case> cases = {
      {"right wrong size",
       [](const std::string& d) {
         cv::imwrite(d + "/image_03/0003/000001.png", Gray(0, kW + 2, kH));
       },
       "image_03/0003/000001.png: wrong size 42x24, differs from the left image 40x24"},
      {"left wrong size",
       [](const std::string& d) {
         cv::imwrite(d + "/image_02/0003/000001.png", Gray(0, kW, kH - 1));
       },
       "image_02/0003/000001.png: wrong size 40x23"},
      {"gray right with colour left",
       [](const std::string& d) { cv::imwrite(d + "/image_03/0003/000001.png", Gray(0)); },
       "image_03/0003/000001.png: has 1 channels but the left image has 3"},
      {"panoptic 8-bit",
       [](const std::string& d) { cv::imwrite(d + "/panoptic/0003/000001.png", Gray(0)); },
       "panoptic/0003/000001.png: wrong bit depth: 8-bit"},
      {"panoptic wrong size",
       [](const std::string& d) {
         cv::imwrite(d + "/panoptic/0003/000001.png", cv::Mat(kH, kW - 1, CV_16UC1, cv::Scalar(0)));
       },
       "panoptic/0003/000001.png: wrong size 39x24"},
      {"right deleted after open",
       [](const std::string& d) { std::filesystem::remove(d + "/image_03/0003/000001.png"); },
       "image_03/0003/000001.png: no such file"},
  };
  for (const Case& c : cases) {
    ScratchDir dir;
    MakeTracking(dir.path(), 2);
    auto seq = OpenSequence(dir.path(), "kitti-tracking", "0003");
    ASSERT_TRUE(seq.ok()) << seq.status();
    c.damage(dir.path());
    EXPECT_TRUE((*seq)->ReadFrame(0).ok()) << c.what;
    auto frame = (*seq)->ReadFrame(1);
    ASSERT_FALSE(frame.ok()) << c.what;
    EXPECT_THAT(Message(frame.status()), HasSubstr(c.expected)) << c.what;
  }
}

TEST(Sequence, TrackingOpenFailures) {
  struct Case {
    const char* what;
    std::function<void(const std::string&)> damage;
    const char* expected;
  };
  const std::vector<Case> cases = {
      {"no calib",
       [](const std::string& d) { std::filesystem::remove(d + "/calib/0003.txt"); },
       "calib/0003.txt: no such file"},
      {"calib without P3",
       [](const std::string& d) {
         WriteText(d + "/calib/0003.txt", "P2: 30 0 20 0 0 30 12 0 0 0 1 0\n");
       },
       "calib/0003.txt: missing entry P3"},
      {"bad label line",
       [](const std::string& d) {
         WriteText(d + "/label_02/0003.txt", "0 4 Car 0 0 0 5 5 14 12 1.5\n");
       },
       "label_02/0003.txt:1: expected 17 fields"},
      {"bad objects_gt",
       [](const std::string& d) { WriteText(d + "/objects_gt/0003.txt", "0 4 26 0 0 10 0 0 0\n"); },
       "objects_gt/0003.txt:1: expected 10 fields"},
      {"objects_gt beyond sequence",
       [](const std::string& d) {
         WriteText(d + "/objects_gt/0003.txt", "5 4 26 0 0 10 0 0 0 1\n");
       },
       "objects_gt/0003.txt: frame 5 beyond"},
      {"missing panoptic frame",
       [](const std::string& d) { std::filesystem::remove(d + "/panoptic/0003/000001.png"); },
       "panoptic/0003/000001.png: missing panoptic mask"},
      {"short times",
       [](const std::string& d) { WriteText(d + "/times/0003.txt", "0\n"); },
       "times/0003.txt: 1 times for 2 frames"},
  };
  for (const Case& c : cases) {
    ScratchDir dir;
    MakeTracking(dir.path(), 2);
    c.damage(dir.path());
    auto seq = OpenSequence(dir.path(), "kitti-tracking", "0003");
    ASSERT_FALSE(seq.ok()) << c.what;
    EXPECT_THAT(Message(seq.status()), HasSubstr(c.expected)) << c.what;
  }
}

TEST(Sequence, BadArguments) {
  ScratchDir dir;
  auto seq = OpenSequence(dir / "nowhere", "kitti-odometry", "00");
  ASSERT_FALSE(seq.ok());
  EXPECT_THAT(Message(seq.status()), HasSubstr("nowhere: no such dataset directory"));
  seq = OpenSequence(dir.path(), "kitti-raw", "00");
  ASSERT_FALSE(seq.ok());
  EXPECT_THAT(Message(seq.status()), HasSubstr("unknown dataset format 'kitti-raw'"));
  seq = OpenSequence(dir.path(), "kitti-odometry", "00");
  ASSERT_FALSE(seq.ok());
  EXPECT_THAT(Message(seq.status()), HasSubstr("sequences: no such directory"));
  seq = OpenSequence(dir.path(), "kitti-tracking", "0000");
  ASSERT_FALSE(seq.ok());
  EXPECT_THAT(Message(seq.status()), HasSubstr("image_02: no such directory"));
}

}  // namespace
}  // namespace twist::io
