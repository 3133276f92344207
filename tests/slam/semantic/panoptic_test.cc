#include "slam/semantic/panoptic.h"

#include <gtest/gtest.h>

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

}  // namespace
}  // namespace twist::semantic
