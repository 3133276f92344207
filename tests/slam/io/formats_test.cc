// Text formats, calibration, labels, images, JSON: round trips and every
// failure mode naming the file and the problem.
#include <gmock/gmock.h>
#include <gtest/gtest.h>

#include <cmath>
#include <opencv2/imgcodecs.hpp>
#include <random>

#include "slam/io/file_util.h"
#include "slam/io/image_io.h"
#include "slam/io/json_writer.h"
#include "slam/io/kitti_calib.h"
#include "slam/io/kitti_labels.h"
#include "slam/io/ply.h"
#include "slam/io/run_output.h"
#include "slam/io/trajectory_io.h"
#include "tests/slam/io/test_util.h"

namespace twist::io {
namespace {

using geometry::SE3d;
using ::testing::HasSubstr;
using testing_util::ScratchDir;
using testing_util::WriteText;

SE3d RandomPose(std::mt19937* rng) {
  std::normal_distribution<double> n(0.0, 1.0);
  geometry::Vector6d xi;
  for (int i = 0; i < 6; ++i) xi(i) = n(*rng);
  xi.head<3>() *= 10.0;
  return SE3d::Exp(xi);
}

void ExpectPoseNear(const SE3d& a, const SE3d& b, double tol) {
  EXPECT_LT((a.translation() - b.translation()).norm(), tol);
  EXPECT_LT((a.Inverse() * b).so3().Log().norm(), tol);
}

// ---------------------------------------------------------------- file_util
TEST(FileUtil, SplitLinesKeepsNumbersAndSkipsBlank) {
  const auto lines = SplitLines("a\r\n\n  \n# c\nb", /*skip_comments=*/true);
  ASSERT_EQ(lines.size(), 2u);
  EXPECT_EQ(lines[0].number, 1);
  EXPECT_EQ(lines[0].text, "a");
  EXPECT_EQ(lines[1].number, 5);
  EXPECT_EQ(lines[1].text, "b");
}

TEST(FileUtil, StrictNumbers) {
  double d = 0;
  int64_t i = 0;
  EXPECT_TRUE(ParseDouble("1.5e-3", &d));
  EXPECT_DOUBLE_EQ(d, 1.5e-3);
  EXPECT_FALSE(ParseDouble("1.5x", &d));
  EXPECT_FALSE(ParseDouble("nan", &d));
  EXPECT_FALSE(ParseDouble("inf", &d));
  EXPECT_FALSE(ParseDouble("", &d));
  EXPECT_TRUE(ParseInt64("-12", &i));
  EXPECT_EQ(i, -12);
  EXPECT_FALSE(ParseInt64("1.0", &i));
}

TEST(FileUtil, MissingFileNamed) {
  ScratchDir dir;
  auto text = ReadTextFile(dir / "nope.txt");
  ASSERT_FALSE(text.ok());
  EXPECT_EQ(text.status().code(), absl::StatusCode::kNotFound);
  EXPECT_THAT(std::string(text.status().message()), HasSubstr("nope.txt: no such file"));
}

TEST(FileUtil, AtomicWriteReplacesAndLeavesNoTemp) {
  ScratchDir dir;
  ASSERT_TRUE(WriteFileAtomic(dir / "f.txt", "one").ok());
  ASSERT_TRUE(WriteFileAtomic(dir / "f.txt", "two").ok());
  EXPECT_EQ(*ReadTextFile(dir / "f.txt"), "two");
  int files = 0;
  for (const auto& e : std::filesystem::directory_iterator(dir.path())) {
    (void)e;
    ++files;
  }
  EXPECT_EQ(files, 1);
  EXPECT_FALSE(WriteFileAtomic(dir / "no/such/dir/f.txt", "x").ok());
}

TEST(FileUtil, FormatDoubleRoundTrips) {
  for (double v : {0.1, 1.0 / 3.0, 12345.678, -2.5e-12, 0.0}) {
    EXPECT_EQ(std::strtod(FormatDouble(v).c_str(), nullptr), v);
  }
}

// ---------------------------------------------------------------- poses
TEST(KittiPoses, RoundTrip) {
  ScratchDir dir;
  std::mt19937 rng(7);
  std::vector<SE3d> poses;
  for (int i = 0; i < 20; ++i) poses.push_back(RandomPose(&rng));
  ASSERT_TRUE(WriteKittiPoses(dir / "p.txt", poses).ok());
  auto read = ReadKittiPoses(dir / "p.txt");
  ASSERT_TRUE(read.ok()) << read.status();
  ASSERT_EQ(read->size(), poses.size());
  for (size_t i = 0; i < poses.size(); ++i) ExpectPoseNear((*read)[i], poses[i], 1e-8);
}

TEST(KittiPoses, ReorthonormalisesRotation) {
  ScratchDir dir;
  // A rotation about y by 0.3 rad, perturbed off SO(3) by 1e-4.
  const double c = std::cos(0.3), s = std::sin(0.3);
  char line[512];
  std::snprintf(line, sizeof(line), "%.9f 0 %.9f 1 0 1.0001 0 2 %.9f 0 %.9f 3\n", c, s, -s, c);
  WriteText(dir / "p.txt", line);
  auto read = ReadKittiPoses(dir / "p.txt");
  ASSERT_TRUE(read.ok()) << read.status();
  const Eigen::Matrix3d r = (*read)[0].rotation();
  EXPECT_LT((r.transpose() * r - Eigen::Matrix3d::Identity()).norm(), 1e-12);
  EXPECT_NEAR((*read)[0].so3().Log().y(), 0.3, 1e-4);
  EXPECT_EQ((*read)[0].translation(), Eigen::Vector3d(1, 2, 3));
}

TEST(KittiPoses, Failures) {
  ScratchDir dir;
  WriteText(dir / "short.txt", "1 0 0 0 0 1 0 0 0 0 1 0\n1 0 0 0 0 1 0 0 0 0 1\n");
  auto r = ReadKittiPoses(dir / "short.txt");
  ASSERT_FALSE(r.ok());
  EXPECT_THAT(std::string(r.status().message()), HasSubstr("short.txt:2: expected 12 numbers"));

  WriteText(dir / "garbage.txt", "1 0 0 0 0 1 0 0 0 0 1 x\n");
  r = ReadKittiPoses(dir / "garbage.txt");
  ASSERT_FALSE(r.ok());
  EXPECT_THAT(std::string(r.status().message()), HasSubstr("garbage.txt:1: field 12 'x'"));

  WriteText(dir / "notrot.txt", "2 0 0 0 0 1 0 0 0 0 1 0\n");
  r = ReadKittiPoses(dir / "notrot.txt");
  ASSERT_FALSE(r.ok());
  EXPECT_THAT(std::string(r.status().message()),
              HasSubstr("notrot.txt:1: the 3x3 part is not a rotation"));

  WriteText(dir / "empty.txt", "\n");
  r = ReadKittiPoses(dir / "empty.txt");
  ASSERT_FALSE(r.ok());
  EXPECT_THAT(std::string(r.status().message()), HasSubstr("empty.txt: no poses"));

  r = ReadKittiPoses(dir / "missing.txt");
  ASSERT_FALSE(r.ok());
  EXPECT_THAT(std::string(r.status().message()), HasSubstr("missing.txt: no such file"));
}

// ---------------------------------------------------------------- times
TEST(Times, ParsesToNanoseconds) {
  ScratchDir dir;
  WriteText(dir / "times.txt", "0.000000e+00\n1.036000e-01\n2.072000e-01\n");
  auto t = ReadTimes(dir / "times.txt");
  ASSERT_TRUE(t.ok()) << t.status();
  EXPECT_EQ(*t, (std::vector<int64_t>{0, 103600000, 207200000}));
  EXPECT_EQ(FormatTimes({0, 103600000, 1500000000001}),
            "0.000000000\n0.103600000\n1500.000000001\n");
}

TEST(Times, Failures) {
  ScratchDir dir;
  WriteText(dir / "t.txt", "0.1\n0.1\n");
  auto t = ReadTimes(dir / "t.txt");
  ASSERT_FALSE(t.ok());
  EXPECT_THAT(std::string(t.status().message()), HasSubstr("t.txt:2: times must increase"));
  WriteText(dir / "u.txt", "0.1 0.2\n");
  t = ReadTimes(dir / "u.txt");
  ASSERT_FALSE(t.ok());
  EXPECT_THAT(std::string(t.status().message()), HasSubstr("u.txt:1: expected 1 numbers"));
  WriteText(dir / "v.txt", "-1\n");
  EXPECT_FALSE(ReadTimes(dir / "v.txt").ok());
}

// ---------------------------------------------------------------- TUM
TEST(Tum, RoundTrip) {
  ScratchDir dir;
  std::mt19937 rng(3);
  std::vector<StampedPose> poses;
  for (int i = 0; i < 10; ++i) poses.push_back({i * 100'000'000LL + 7, RandomPose(&rng)});
  ASSERT_TRUE(WriteTumTrajectory(dir / "t.txt", poses).ok());
  auto read = ReadTumTrajectory(dir / "t.txt");
  ASSERT_TRUE(read.ok()) << read.status();
  ASSERT_EQ(read->size(), poses.size());
  for (size_t i = 0; i < poses.size(); ++i) {
    EXPECT_EQ((*read)[i].timestamp_ns, poses[i].timestamp_ns);
    ExpectPoseNear((*read)[i].world_from_camera, poses[i].world_from_camera, 1e-6);
  }
}

TEST(Tum, Failures) {
  ScratchDir dir;
  WriteText(dir / "t.txt", "# comment\n0.0 1 2 3 0 0 0 1\n0.1 1 2 3 0 0 0 2\n");
  auto r = ReadTumTrajectory(dir / "t.txt");
  ASSERT_FALSE(r.ok());
  EXPECT_THAT(std::string(r.status().message()), HasSubstr("t.txt:3: quaternion"));
  WriteText(dir / "u.txt", "0.0 1 2 3 0 0 1\n");
  r = ReadTumTrajectory(dir / "u.txt");
  ASSERT_FALSE(r.ok());
  EXPECT_THAT(std::string(r.status().message()), HasSubstr("u.txt:1: expected 8 numbers"));
}

// ---------------------------------------------------------------- objects
TEST(ObjectTracks, RoundTripWithAndWithoutInstance) {
  ScratchDir dir;
  std::mt19937 rng(11);
  std::vector<ObjectTrackRow> rows;
  for (int i = 0; i < 6; ++i) {
    ObjectTrackRow r;
    r.frame = i;
    r.track_id = 100 + i % 2;
    r.class_id = 26;
    r.world_from_object = RandomPose(&rng);
    r.twist_in_world << 1, 2, 3, 0.1, 0.2, 0.3 * i;
    r.instance_id = (i % 2) ? -1 : 5;
    rows.push_back(r);
  }
  ASSERT_TRUE(WriteObjectTracks(dir / "objects.txt", rows).ok());
  auto read = ReadObjectTracks(dir / "objects.txt");
  ASSERT_TRUE(read.ok()) << read.status();
  ASSERT_EQ(read->size(), rows.size());
  for (size_t i = 0; i < rows.size(); ++i) {
    EXPECT_EQ((*read)[i].frame, rows[i].frame);
    EXPECT_EQ((*read)[i].track_id, rows[i].track_id);
    EXPECT_EQ((*read)[i].class_id, 26);
    EXPECT_EQ((*read)[i].instance_id, rows[i].instance_id);
    ExpectPoseNear((*read)[i].world_from_object, rows[i].world_from_object, 1e-6);
    EXPECT_LT(((*read)[i].twist_in_world - rows[i].twist_in_world).norm(), 1e-8);
  }
}

TEST(ObjectTracks, Failures) {
  ScratchDir dir;
  WriteText(dir / "o.txt", "0 1 26 0 0 0 0 0 0 1 0 0 0 0 0\n");
  auto r = ReadObjectTracks(dir / "o.txt");
  ASSERT_FALSE(r.ok());
  EXPECT_THAT(std::string(r.status().message()), HasSubstr("o.txt:1: expected 16 fields"));
  WriteText(dir / "p.txt", "0 1.5 26 0 0 0 0 0 0 1 0 0 0 0 0 0\n");
  r = ReadObjectTracks(dir / "p.txt");
  ASSERT_FALSE(r.ok());
  EXPECT_THAT(std::string(r.status().message()), HasSubstr("p.txt:1: track_id '1.5'"));
  WriteText(dir / "q.txt", "");
  r = ReadObjectTracks(dir / "q.txt");
  ASSERT_TRUE(r.ok());
  EXPECT_TRUE(r->empty());
}

TEST(ObjectsGt, RoundTripAndFailures) {
  ScratchDir dir;
  std::mt19937 rng(5);
  std::vector<ObjectGtRow> rows;
  for (int i = 0; i < 4; ++i) rows.push_back({i, 3, 26, RandomPose(&rng)});
  ASSERT_TRUE(WriteObjectsGt(dir / "g.txt", rows).ok());
  auto read = ReadObjectsGt(dir / "g.txt");
  ASSERT_TRUE(read.ok()) << read.status();
  ASSERT_EQ(read->size(), 4u);
  for (size_t i = 0; i < rows.size(); ++i) {
    EXPECT_EQ((*read)[i].frame, rows[i].frame);
    ExpectPoseNear((*read)[i].world_from_object, rows[i].world_from_object, 1e-6);
  }
  WriteText(dir / "h.txt", "0 3 26 0 0 0 0 0 0 1\n-1 3 26 0 0 0 0 0 0 1\n");
  read = ReadObjectsGt(dir / "h.txt");
  ASSERT_FALSE(read.ok());
  EXPECT_THAT(std::string(read.status().message()), HasSubstr("h.txt:2: negative frame"));
}

// ---------------------------------------------------------------- calibration
constexpr char kOdometryCalib[] =
    "P0: 7.07e+02 0 6.01e+02 0 0 7.07e+02 1.83e+02 0 0 0 1 0\n"
    "P1: 7.07e+02 0 6.01e+02 -3.535e+02 0 7.07e+02 1.83e+02 0 0 0 1 0\n"
    "P2: 7.07e+02 0 6.01e+02 46 0 7.07e+02 1.83e+02 0 0 0 1 0\n"
    "Tr: 1 0 0 0 0 1 0 0 0 0 1 0\n";

TEST(Calib, Odometry) {
  ScratchDir dir;
  WriteText(dir / "calib.txt", kOdometryCalib);
  auto calib = ReadKittiOdometryCalib(dir / "calib.txt");
  ASSERT_TRUE(calib.ok()) << calib.status();
  EXPECT_DOUBLE_EQ(calib->camera.fx, 707);
  EXPECT_DOUBLE_EQ(calib->camera.fy, 707);
  EXPECT_DOUBLE_EQ(calib->camera.cx, 601);
  EXPECT_DOUBLE_EQ(calib->camera.cy, 183);
  EXPECT_DOUBLE_EQ(calib->camera.baseline, 0.5);
}

TEST(Calib, TrackingBothSpellings) {
  ScratchDir dir;
  const std::string p =
      "P0: 700 0 600 0 0 700 180 0 0 0 1 0\n"
      "P1: 700 0 600 -350 0 700 180 0 0 0 1 0\n"
      "P2: 700 0 600 42 0 700 180 0.7 0 0 1 0.001\n"
      "P3: 700 0 600 -336 0 700 180 0.7 0 0 1 0.001\n";
  WriteText(dir / "a.txt",
            p + "R_rect: 1 0 0 0 1 0 0 0 1\n"
                "Tr_velo_cam: 0 -1 0 0 0 0 -1 0 1 0 0 0\n"
                "Tr_imu_velo: 1 0 0 1 0 1 0 0 0 0 1 0\n");
  WriteText(dir / "b.txt",
            p + "R0_rect: 1 0 0 0 1 0 0 0 1\n"
                "Tr_velo_to_cam: 0 -1 0 0 0 0 -1 0 1 0 0 0\n"
                "Tr_imu_to_velo: 1 0 0 1 0 1 0 0 0 0 1 0\n");
  for (const char* name : {"a.txt", "b.txt"}) {
    auto c = ReadKittiTrackingCalib(dir / name);
    ASSERT_TRUE(c.ok()) << c.status();
    EXPECT_TRUE(c->r_rect.has_value());
    EXPECT_TRUE(c->tr_velo_cam.has_value());
    EXPECT_TRUE(c->tr_imu_velo.has_value());
    EXPECT_DOUBLE_EQ((*c->tr_imu_velo)(0, 3), 1.0);
    EXPECT_DOUBLE_EQ(c->camera.baseline, 0.54);
    EXPECT_NEAR(c->left_from_ref_translation.z(), 0.001, 1e-12);
    EXPECT_NEAR(c->left_from_ref_translation.x(), (42 - 600 * 0.001) / 700, 1e-12);
  }
}

TEST(Calib, Failures) {
  ScratchDir dir;
  WriteText(dir / "c1.txt", "P0: 1 0 0 0 0 1 0 0 0 0 1 0\n");
  auto c = ReadKittiOdometryCalib(dir / "c1.txt");
  ASSERT_FALSE(c.ok());
  EXPECT_THAT(std::string(c.status().message()), HasSubstr("c1.txt: missing entry P1"));

  WriteText(dir / "c2.txt", "P0: 1 0 0 0 0 1 0 0 0 0 1\nP1: 1 0 0 0 0 1 0 0 0 0 1 0\n");
  c = ReadKittiOdometryCalib(dir / "c2.txt");
  ASSERT_FALSE(c.ok());
  EXPECT_THAT(std::string(c.status().message()), HasSubstr("c2.txt: entry P0 has 11 numbers"));

  WriteText(dir / "c3.txt", "P0 1 0 0 0 0 1 0 0 0 0 1 0\n");
  c = ReadKittiOdometryCalib(dir / "c3.txt");
  ASSERT_FALSE(c.ok());
  EXPECT_THAT(std::string(c.status().message()), HasSubstr("c3.txt:1: expected 'KEY: numbers'"));

  WriteText(dir / "c4.txt",
            "P0: 700 0 600 0 0 700 180 0 0 0 1 0\nP1: 700 0 600 350 0 700 180 0 0 0 1 0\n");
  c = ReadKittiOdometryCalib(dir / "c4.txt");
  ASSERT_FALSE(c.ok());
  EXPECT_THAT(std::string(c.status().message()), HasSubstr("baseline must be positive"));

  WriteText(dir / "c5.txt",
            "P0: 700 0 600 0 0 700 180 0 0 0 1 0\nP1: 710 0 600 -350 0 700 180 0 0 0 1 0\n");
  c = ReadKittiOdometryCalib(dir / "c5.txt");
  ASSERT_FALSE(c.ok());
  EXPECT_THAT(std::string(c.status().message()), HasSubstr("not rectified"));

  WriteText(dir / "c6.txt",
            "P2: 700 0 600 0 0 700 180 0 0 0 1 0\nP3: 700 0 600 -350 0 700 180 0 0 0 1 0\nR_rect: "
            "1 0 0\n");
  auto t = ReadKittiTrackingCalib(dir / "c6.txt");
  ASSERT_FALSE(t.ok());
  EXPECT_THAT(std::string(t.status().message()), HasSubstr("c6.txt: entry R_rect has 3 numbers"));

  WriteText(dir / "c7.txt",
            "P2: 700 0 600 0 0 700 180 0 0 0 1 0\nP2: 700 0 600 0 0 700 180 0 0 0 1 0\n");
  t = ReadKittiTrackingCalib(dir / "c7.txt");
  ASSERT_FALSE(t.ok());
  EXPECT_THAT(std::string(t.status().message()), HasSubstr("c7.txt:2: duplicate entry P2"));
}

// ---------------------------------------------------------------- labels
TEST(Labels, ParsesAndBuildsBox) {
  ScratchDir dir;
  WriteText(
      dir / "l.txt",
      "0 -1 DontCare -1 -1 -10.000000 356.4 195.8 374.1 216.6 -1000 -1000 -1000 -10 -1 -1 -1\n"
      "3 7 Car 0 1 -1.5 100 120 300 250 1.5 1.6 4.0 2.0 1.7 10.0 0.0\n");
  auto labels = ReadKittiLabels(dir / "l.txt");
  ASSERT_TRUE(labels.ok()) << labels.status();
  ASSERT_EQ(labels->size(), 2u);
  EXPECT_TRUE((*labels)[0].is_dont_care());
  const KittiLabel& car = (*labels)[1];
  EXPECT_EQ(car.frame, 3);
  EXPECT_EQ(car.track_id, 7);
  EXPECT_EQ(car.type, "Car");
  EXPECT_EQ(car.occluded, 1);
  EXPECT_DOUBLE_EQ(car.height, 1.5);
  EXPECT_DOUBLE_EQ(car.width, 1.6);
  EXPECT_DOUBLE_EQ(car.length, 4.0);
  EXPECT_EQ(car.location, Eigen::Vector3d(2.0, 1.7, 10.0));
  EXPECT_EQ(KittiTypeToClassId("Car"), 26);
  EXPECT_EQ(KittiTypeToClassId("Pedestrian"), 24);
  EXPECT_EQ(KittiTypeToClassId("DontCare"), 0);
  // rotation_y = 0: length along camera x, height along y (centre 0.75 m above), width along z.
  const auto corners = car.Corners();
  Eigen::Vector3d lo = corners[0], hi = corners[0];
  for (const auto& c : corners) {
    lo = lo.cwiseMin(c);
    hi = hi.cwiseMax(c);
  }
  EXPECT_TRUE(lo.isApprox(Eigen::Vector3d(0.0, 0.2, 9.2)));
  EXPECT_TRUE(hi.isApprox(Eigen::Vector3d(4.0, 1.7, 10.8)));
}

TEST(Labels, Failures) {
  ScratchDir dir;
  WriteText(dir / "a.txt", "0 1 Car 0 0 0 1 2 3 4 1 1 1 0 0 10\n");
  auto l = ReadKittiLabels(dir / "a.txt");
  ASSERT_FALSE(l.ok());
  EXPECT_THAT(std::string(l.status().message()), HasSubstr("a.txt:1: expected 17 fields"));
  WriteText(dir / "b.txt",
            "0 1 Car 0 0 0 1 2 3 4 1 1 1 0 0 10 0\n0 1 Car 0 0 0 1 2 3 4 1 1 1 0 0 z 0\n");
  l = ReadKittiLabels(dir / "b.txt");
  ASSERT_FALSE(l.ok());
  EXPECT_THAT(std::string(l.status().message()), HasSubstr("b.txt:2: field 16 'z'"));
  WriteText(dir / "c.txt", "0 1 Car 0 0.5 0 1 2 3 4 1 1 1 0 0 10 0\n");
  l = ReadKittiLabels(dir / "c.txt");
  ASSERT_FALSE(l.ok());
  EXPECT_THAT(std::string(l.status().message()), HasSubstr("c.txt:1: occluded '0.5'"));
  WriteText(dir / "d.txt", "0 1 Car 0 0 0 10 2 3 4 1 1 1 0 0 10 0\n");
  l = ReadKittiLabels(dir / "d.txt");
  ASSERT_FALSE(l.ok());
  EXPECT_THAT(std::string(l.status().message()), HasSubstr("d.txt:1: 2D box"));
}

// ---------------------------------------------------------------- images
TEST(Images, ReadsGrayColourAndLabels) {
  ScratchDir dir;
  cv::Mat gray(4, 6, CV_8UC1, cv::Scalar(9));
  cv::Mat colour(4, 6, CV_8UC3, cv::Scalar(1, 2, 3));
  cv::Mat bgra(4, 6, CV_8UC4, cv::Scalar(1, 2, 3, 255));
  cv::Mat label(4, 6, CV_16UC1, cv::Scalar(26003));
  ASSERT_TRUE(cv::imwrite(dir / "g.png", gray));
  ASSERT_TRUE(cv::imwrite(dir / "c.png", colour));
  ASSERT_TRUE(cv::imwrite(dir / "a.png", bgra));
  ASSERT_TRUE(cv::imwrite(dir / "l.png", label));
  auto g = ReadImage8(dir / "g.png");
  ASSERT_TRUE(g.ok());
  EXPECT_EQ(g->type(), CV_8UC1);
  auto c = ReadImage8(dir / "c.png");
  ASSERT_TRUE(c.ok());
  EXPECT_EQ(c->type(), CV_8UC3);
  auto a = ReadImage8(dir / "a.png");
  ASSERT_TRUE(a.ok());
  EXPECT_EQ(a->type(), CV_8UC3);
  auto l = ReadLabelImage16(dir / "l.png");
  ASSERT_TRUE(l.ok());
  EXPECT_EQ(l->type(), CV_16UC1);
  EXPECT_EQ(l->at<uint16_t>(2, 3), 26003);
}

TEST(Images, Failures) {
  ScratchDir dir;
  cv::Mat gray(4, 6, CV_8UC1, cv::Scalar(9));
  cv::Mat label(4, 6, CV_16UC1, cv::Scalar(26003));
  ASSERT_TRUE(cv::imwrite(dir / "g.png", gray));
  ASSERT_TRUE(cv::imwrite(dir / "l.png", label));
  // Missing.
  auto r = ReadImage8(dir / "none.png");
  ASSERT_FALSE(r.ok());
  EXPECT_THAT(std::string(r.status().message()), HasSubstr("none.png: no such file"));
  // Wrong bit depth both ways.
  r = ReadImage8(dir / "l.png");
  ASSERT_FALSE(r.ok());
  EXPECT_THAT(std::string(r.status().message()), HasSubstr("l.png: wrong bit depth: 16-bit"));
  r = ReadLabelImage16(dir / "g.png");
  ASSERT_FALSE(r.ok());
  EXPECT_THAT(std::string(r.status().message()), HasSubstr("g.png: wrong bit depth: 8-bit"));
  // Truncated PNG.
  std::string bytes = *ReadTextFile(dir / "g.png");
  WriteText(dir / "t.png", bytes.substr(0, bytes.size() / 2));
  r = ReadImage8(dir / "t.png");
  ASSERT_FALSE(r.ok());
  EXPECT_THAT(std::string(r.status().message()), HasSubstr("t.png: cannot decode image"));
  // Not an image at all.
  WriteText(dir / "x.png", "hello");
  r = ReadImage8(dir / "x.png");
  ASSERT_FALSE(r.ok());
  EXPECT_THAT(std::string(r.status().message()), HasSubstr("x.png: cannot decode"));
  // Wrong size.
  absl::Status s = CheckSameSize(gray, dir / "g.png", cv::Size(7, 4), "the left image");
  ASSERT_FALSE(s.ok());
  EXPECT_THAT(std::string(s.message()),
              HasSubstr("g.png: wrong size 6x4, differs from the left image 7x4"));
}

// ---------------------------------------------------------------- JSON
TEST(Json, EscapesAndNests) {
  EXPECT_EQ(JsonEscape("a\"b\\c\n\x01"), "\"a\\\"b\\\\c\\n\\u0001\"");
  JsonWriter w(/*pretty=*/false);
  w.BeginObject();
  w.Key("x").Number(1.5).Key("n").Number(NAN).Key("arr").BeginArray().Int(1).Int(-2).EndArray();
  w.Key("o").BeginObject().EndObject().Key("s").String("q\"").Key("b").Bool(true).Key("z").Null();
  w.EndObject();
  EXPECT_TRUE(w.complete());
  EXPECT_EQ(w.str(),
            "{\"x\":1.5,\"n\":null,\"arr\":[1,-2],\"o\":{},\"s\":\"q\\\"\",\"b\":true,\"z\":null}");
}

// ---------------------------------------------------------------- run outputs
TEST(RunOutput, WritesAllFilesReadableBack) {
  ScratchDir dir;
  RunOutputWriter out;
  std::mt19937 rng(1);
  for (int i = 0; i < 5; ++i) {
    FrameResult r;
    r.index = i;
    r.timestamp_ns = i * 100'000'000LL;
    r.state = i == 0 ? TrackingState::kNotInitialized : TrackingState::kOk;
    r.world_from_camera = RandomPose(&rng);
    r.timings.push_back({"track", 10.0 + i});
    ObjectResult o;
    o.id = 4;
    o.class_id = 26;
    o.instance_id = 2;
    o.state = i == 3 ? ObjectState::kLost : ObjectState::kTracked;
    o.world_from_object = RandomPose(&rng);
    o.twist_in_world << 1, 0, 0, 0, 0, 0.1;
    r.objects.push_back(o);
    out.Add(r);
  }
  RunInfo info;
  info.dataset = "/data/\"x\"";
  info.format = "kitti-tracking";
  info.sequence = "0001";
  info.numbers.push_back({"extra", 2.5});
  ASSERT_TRUE(out.Write(dir / "run", info).ok());
  auto cam = ReadKittiPoses(dir / "run/camera.txt");
  ASSERT_TRUE(cam.ok()) << cam.status();
  EXPECT_EQ(cam->size(), 5u);
  auto tum = ReadTumTrajectory(dir / "run/camera_tum.txt");
  ASSERT_TRUE(tum.ok()) << tum.status();
  EXPECT_EQ(tum->back().timestamp_ns, 400'000'000);
  auto objects = ReadObjectTracks(dir / "run/objects.txt");
  ASSERT_TRUE(objects.ok()) << objects.status();
  EXPECT_EQ(objects->size(), 4u);  // the lost one is not written
  EXPECT_EQ((*objects)[0].instance_id, 2);
  auto summary = ReadTextFile(dir / "run/summary.json");
  ASSERT_TRUE(summary.ok());
  EXPECT_THAT(*summary, HasSubstr("\"frames\": 5"));
  EXPECT_THAT(*summary, HasSubstr("\"ok\": 4"));
  EXPECT_THAT(*summary, HasSubstr("\"extra\": 2.5"));
  EXPECT_THAT(*summary, HasSubstr("\"median\": 12"));
  EXPECT_THAT(*summary, HasSubstr("\\\"x\\\""));
}

// objects_refined.txt: rows at the added frames only, ordered by frame, the
// twist the central difference two rows either side (cut at the ends).
TEST(RunOutput, RefinedRowsAndTheirTwists) {
  ScratchDir dir;
  RunOutputWriter out;
  for (int i = 0; i < 6; ++i) {
    FrameResult r;
    r.index = i;
    r.timestamp_ns = i * 100'000'000LL;
    out.Add(r);
  }
  EXPECT_TRUE(out.RefinedObjectRows().empty());
  TimedObjectTrajectory t;
  t.track_id = 7;
  t.class_id = 26;
  t.instance_id = 3;
  for (int i = 0; i < 6; ++i) {  // z = i^2: accelerating, no rotation
    t.poses.emplace_back(
        i * 100'000'000LL,
        geometry::SE3d(Eigen::Quaterniond::Identity(), Eigen::Vector3d(0, 0, i * i)));
  }
  t.poses.emplace_back(550'000'000LL, geometry::SE3d());  // not a frame: dropped
  out.SetRefinedObjects({t});
  const std::vector<ObjectTrackRow> rows = out.RefinedObjectRows();
  ASSERT_EQ(rows.size(), 6u);
  const double expected_vz[6] = {
      4 / 0.2, 9 / 0.3, 16 / 0.4, (25 - 1) / 0.4, (25 - 4) / 0.3, (25 - 9) / 0.2};
  for (int i = 0; i < 6; ++i) {
    EXPECT_EQ(rows[i].frame, i);
    EXPECT_EQ(rows[i].track_id, 7);
    EXPECT_EQ(rows[i].instance_id, 3);
    EXPECT_NEAR(rows[i].twist_in_world[2], expected_vz[i], 1e-9) << "row " << i;
    EXPECT_NEAR(rows[i].twist_in_world.tail<3>().norm(), 0.0, 1e-12);
  }
  ASSERT_TRUE(out.Write(dir / "run", RunInfo()).ok());
  auto back = ReadObjectTracks(dir / "run/objects_refined.txt");
  ASSERT_TRUE(back.ok()) << back.status();
  EXPECT_EQ(back->size(), 6u);
}

// ---------------------------------------------------------------- PLY
TEST(Ply, AsciiRoundTrip) {
  ScratchDir dir;
  std::vector<PlyPoint> pts(3);
  for (int i = 0; i < 3; ++i) {
    pts[i].p_in_world = Eigen::Vector3d(i, -0.5 * i, 10.25 + i);
    pts[i].class_id = 7 + i;
    pts[i].cluster_id = 100 + i;
    pts[i].r = 200;
  }
  ASSERT_TRUE(WritePlyPoints(dir / "m.ply", pts).ok());
  auto read = ReadPlyPoints(dir / "m.ply");
  ASSERT_TRUE(read.ok()) << read.status();
  ASSERT_EQ(read->size(), 3u);
  EXPECT_EQ((*read)[2].p_in_world, Eigen::Vector3d(2, -1, 12.25));
  EXPECT_EQ((*read)[1].class_id, 8);
  EXPECT_EQ((*read)[1].cluster_id, 101);
  EXPECT_EQ((*read)[0].r, 200);
}

TEST(Ply, BinaryLittleEndianAndTruncation) {
  ScratchDir dir;
  std::string bytes =
      "ply\nformat binary_little_endian 1.0\ncomment x\nelement vertex 2\nproperty float x\n"
      "property float y\nproperty float z\nproperty uchar label\nelement face 0\n"
      "property list uchar int vertex_indices\nend_header\n";
  for (int i = 0; i < 2; ++i) {
    const float xyz[3] = {1.5f * i, 2.0f, -3.0f};
    bytes.append(reinterpret_cast<const char*>(xyz), sizeof(xyz));
    bytes.push_back(static_cast<char>(9));
  }
  WriteText(dir / "b.ply", bytes);
  auto read = ReadPlyPoints(dir / "b.ply");
  ASSERT_TRUE(read.ok()) << read.status();
  ASSERT_EQ(read->size(), 2u);
  EXPECT_EQ((*read)[1].p_in_world, Eigen::Vector3d(1.5, 2.0, -3.0));
  WriteText(dir / "t.ply", bytes.substr(0, bytes.size() - 5));
  read = ReadPlyPoints(dir / "t.ply");
  ASSERT_FALSE(read.ok());
  EXPECT_THAT(std::string(read.status().message()), HasSubstr("t.ply: truncated binary PLY body"));
  WriteText(dir / "n.ply", "hello");
  read = ReadPlyPoints(dir / "n.ply");
  ASSERT_FALSE(read.ok());
  EXPECT_THAT(std::string(read.status().message()), HasSubstr("n.ply: not a PLY file"));
}

}  // namespace
}  // namespace twist::io
