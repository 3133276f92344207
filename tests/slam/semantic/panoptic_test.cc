#include "slam/semantic/panoptic.h"

#include <gtest/gtest.h>

#include <map>
#include <opencv2/core.hpp>
#include <random>

namespace twist::semantic {
namespace {

TEST(Panoptic, DecodesClassAndInstance) {
  EXPECT_EQ(ClassOf(26003), 26);
  EXPECT_EQ(InstanceOf(26003), 3);
  EXPECT_EQ(MakePanopticId(7, 0), 7000);
  EXPECT_EQ(DecodePanopticId(40012), (PanopticLabel{40, 12}));
}

TEST(Panoptic, ValidatesMaskTypeAndSize) {
  EXPECT_TRUE(ValidatePanopticMask(cv::Mat(4, 5, CV_16UC1, cv::Scalar(0))).ok());
  EXPECT_TRUE(ValidatePanopticMask(cv::Mat(4, 5, CV_32SC1, cv::Scalar(0)), cv::Size(5, 4)).ok());
  EXPECT_FALSE(ValidatePanopticMask(cv::Mat(4, 5, CV_8UC1, cv::Scalar(0))).ok());
  EXPECT_FALSE(ValidatePanopticMask(cv::Mat()).ok());
  EXPECT_FALSE(ValidatePanopticMask(cv::Mat(4, 5, CV_16UC1), cv::Size(6, 4)).ok());
}

TEST(Panoptic, LabelAtSubPixelRoundsToNearestPixel) {
  for (int type : {CV_16UC1, CV_32SC1}) {
    cv::Mat mask(10, 10, type, cv::Scalar(7000));
    cv::Mat roi = mask(cv::Rect(5, 5, 3, 3));
    roi.setTo(cv::Scalar(26002));
    EXPECT_EQ(*LabelAt(mask, {5.4, 5.4}), (PanopticLabel{26, 2}));
    EXPECT_EQ(*LabelAt(mask, {4.6, 7.49}), (PanopticLabel{26, 2}));
    EXPECT_EQ(*LabelAt(mask, {4.4, 6.0}), (PanopticLabel{7, 0}));
    EXPECT_EQ(*LabelAt(mask, {7.6, 6.0}), (PanopticLabel{7, 0}));
    EXPECT_FALSE(LabelAt(mask, {-0.6, 3.0}).has_value());
    EXPECT_FALSE(LabelAt(mask, {3.0, 9.6}).has_value());
    EXPECT_TRUE(LabelAt(mask, {-0.4, 9.4}).has_value());
  }
  cv::Mat m32(3, 3, CV_32SC1, cv::Scalar(-1));
  EXPECT_FALSE(LabelAt(m32, {1.0, 1.0}).has_value());  // void
}

TEST(Panoptic, ExtractsSegmentsWithBoxes) {
  cv::Mat mask(20, 30, CV_16UC1, cv::Scalar(7000));
  mask(cv::Rect(2, 3, 4, 5)).setTo(cv::Scalar(26001));
  mask(cv::Rect(20, 10, 6, 2)).setTo(cv::Scalar(26002));
  const std::vector<Segment> all = ExtractSegments(mask);
  ASSERT_EQ(all.size(), 3u);
  EXPECT_EQ(all[0].label, (PanopticLabel{7, 0}));
  EXPECT_EQ(all[1].label, (PanopticLabel{26, 1}));
  EXPECT_EQ(all[1].num_pixels, 20);
  EXPECT_EQ(all[1].box, cv::Rect(2, 3, 4, 5));
  EXPECT_EQ(all[2].box, cv::Rect(20, 10, 6, 2));
  const std::vector<Segment> things = ExtractSegments(mask, 15, true);
  ASSERT_EQ(things.size(), 1u);
  EXPECT_EQ(things[0].label, (PanopticLabel{26, 1}));
  const cv::Mat seg = SegmentMask(mask, {26, 2});
  EXPECT_EQ(cv::countNonZero(seg), 12);
}

// Segments and their masks on a mask of blobs and scattered pixels (label
// runs of every length), in both panoptic types: counts and tight boxes as
// a per-pixel tally gives them, each segment's mask, scanned in its box
// only, is the whole-image mask of its label, and each class's mask
// (ClassMask) is the union of its segments' masks.
TEST(Panoptic, SegmentsAndTheirMasksMatchAPerPixelTally) {
  std::mt19937_64 rng(3);
  std::uniform_int_distribution<int> pick(0, 5);
  const int ids[] = {7000, 26001, 26002, 24001, 11000, 26003};
  cv::Mat mask16(40, 60, CV_16UC1, cv::Scalar(7000));
  for (int k = 0; k < 12; ++k) {
    std::uniform_int_distribution<int> x(0, 55), y(0, 35), size(1, 9);
    mask16(cv::Rect(x(rng), y(rng), size(rng), size(rng)) & cv::Rect(0, 0, 60, 40))
        .setTo(cv::Scalar(ids[pick(rng)]));
  }
  for (int k = 0; k < 80; ++k) {
    std::uniform_int_distribution<int> x(0, 59), y(0, 39);
    mask16.at<uint16_t>(y(rng), x(rng)) = static_cast<uint16_t>(ids[pick(rng)]);
  }
  cv::Mat mask32;
  mask16.convertTo(mask32, CV_32SC1);
  mask32.at<int32_t>(0, 0) = -1;  // unlabelled in the 32-bit form
  for (const cv::Mat& mask : {mask16, mask32}) {
    std::map<int, std::pair<int, cv::Rect>> tally;  // id -> (pixels, box)
    for (int y = 0; y < mask.rows; ++y) {
      for (int x = 0; x < mask.cols; ++x) {
        const int id = mask.type() == CV_16UC1 ? mask.at<uint16_t>(y, x) : mask.at<int32_t>(y, x);
        if (id < 0) continue;
        auto& [n, box] = tally[id];
        box = n == 0 ? cv::Rect(x, y, 1, 1) : (box | cv::Rect(x, y, 1, 1));
        ++n;
      }
    }
    const std::vector<Segment> segments = ExtractSegments(mask);
    ASSERT_EQ(segments.size(), tally.size());
    for (const Segment& s : segments) {
      const int id = s.label.class_id * 1000 + s.label.instance_id;
      ASSERT_EQ(tally.count(id), 1u) << id;
      EXPECT_EQ(s.num_pixels, tally[id].first) << id;
      EXPECT_EQ(s.box, tally[id].second) << id;
      const cv::Mat whole = SegmentMask(mask, s.label);
      const cv::Mat boxed = SegmentMask(mask, s.label, s.box);
      EXPECT_EQ(cv::countNonZero(whole), s.num_pixels) << id;
      EXPECT_EQ(cv::countNonZero(whole != boxed), 0) << id;
    }
    // A class's mask is the union of its instances' masks; the unlabelled
    // pixel (-1) belongs to no class.
    for (int class_id : {0, 7, 11, 24, 26}) {
      cv::Mat expected(mask.size(), CV_8UC1, cv::Scalar(0));
      for (const Segment& s : segments) {
        if (s.label.class_id == class_id) expected |= SegmentMask(mask, s.label);
      }
      const cv::Mat got = ClassMask(mask, class_id);
      ASSERT_EQ(got.type(), CV_8UC1);
      EXPECT_EQ(cv::countNonZero(got != expected), 0) << class_id;
    }
    EXPECT_EQ(cv::countNonZero(ClassMask(mask, 0)), 0);
  }
}

}  // namespace
}  // namespace twist::semantic
