#include "slam/semantic/cluster_association.h"

#include <gtest/gtest.h>

#include "slam/semantic/hungarian.h"

namespace twist::semantic {
namespace {

TEST(Hungarian, FindsTheOptimalAssignment) {
  Eigen::MatrixXd cost(3, 3);
  cost << 4, 1, 3,  //
      2, 0, 5,      //
      3, 2, 2;
  // Optimum: (0,1) + (1,0) + (2,2) = 1 + 2 + 2 = 5; greedy would take (1,1) first.
  EXPECT_EQ(SolveAssignment(cost), (std::vector<int>{1, 0, 2}));
  Eigen::MatrixXd wide(2, 4);
  wide << 5, 1, 9, 9,  //
      1, 2, 9, 9;
  EXPECT_EQ(SolveAssignment(wide), (std::vector<int>{1, 0}));
  EXPECT_EQ(SolveAssignment(Eigen::MatrixXd(wide.transpose())), (std::vector<int>{1, 0, -1, -1}));
  Eigen::MatrixXd score(2, 2);
  score << 0.9, 0.1,  //
      0.05, 0.1;
  EXPECT_EQ(MaxScoreAssignment(score, 0.2), (std::vector<int>{0, -1}));
}

TEST(ClusterAssociation, IoUs) {
  EXPECT_NEAR(BoxIoU({0, 0, 10, 10}, {5, 0, 10, 10}), 50.0 / 150.0, 1e-12);
  EXPECT_EQ(BoxIoU({0, 0, 1, 1}, {2, 2, 1, 1}), 0.0);
  cv::Mat a(10, 10, CV_8UC1, cv::Scalar(0)), b = a.clone();
  a(cv::Rect(0, 0, 4, 4)).setTo(255);
  b(cv::Rect(2, 0, 4, 4)).setTo(255);
  EXPECT_NEAR(MaskIoU(a, b), 8.0 / 24.0, 1e-12);
  EXPECT_NEAR(MaskIoU(a, b, cv::Rect(0, 0, 6, 4)), 8.0 / 24.0, 1e-12);      // union of the boxes
  EXPECT_NEAR(MaskIoU(a, b, cv::Rect(-3, -3, 50, 50)), 8.0 / 24.0, 1e-12);  // clipped
  EXPECT_EQ(MaskIoU(a, b, cv::Rect(20, 20, 5, 5)), 0.0);
}

// Score's overlap is the masks' IoU whether the boxes overlap, touch along
// an edge or lie apart (it skips the scan when they cannot share a pixel).
TEST(ClusterAssociation, ScoreOverlapIsTheMaskIoU) {
  ClusterAssociationOptions options;
  options.point_weight = 0.0;
  options.instance_bonus = 0.0;
  ClusterAssociator associator(options);
  const cv::Rect cluster_box(10, 10, 8, 6);
  ClusterTrack c;
  c.class_id = 26;
  c.instance_id = 1;
  c.last_box = cluster_box;
  c.last_mask = cv::Mat(40, 60, CV_8UC1, cv::Scalar(0));
  c.last_mask(cluster_box).setTo(255);
  for (const cv::Rect& box : {cv::Rect(12, 11, 8, 6),    // overlapping
                              cv::Rect(17, 15, 5, 5),    // one shared pixel
                              cv::Rect(18, 10, 5, 6),    // touching the right edge
                              cv::Rect(10, 16, 8, 3),    // touching the bottom edge
                              cv::Rect(30, 30, 5, 5)}) {  // apart
    Detection d;
    d.label = {26, 2};
    d.box = box;
    d.mask = cv::Mat(40, 60, CV_8UC1, cv::Scalar(0));
    d.mask(box).setTo(255);
    EXPECT_DOUBLE_EQ(associator.Score(d, c), MaskIoU(d.mask, c.last_mask)) << box;
  }
  Detection one_pixel;
  one_pixel.label = {26, 2};
  one_pixel.box = cv::Rect(17, 15, 5, 5);
  one_pixel.mask = cv::Mat(40, 60, CV_8UC1, cv::Scalar(0));
  one_pixel.mask(one_pixel.box).setTo(255);
  EXPECT_NEAR(associator.Score(one_pixel, c), 1.0 / (48 + 25 - 1), 1e-12);
}

// Two cars driving side by side to the right, seen for 10 frames; the
// segmenter swaps their instance ids at frame 4 and again at frame 7, and
// gives a brand-new id at frame 8.
struct Car {
  cv::Rect2d box;
  std::vector<int64_t> points;
};

Detection MakeDetection(const Car& car, int instance, int frame, bool with_points, bool with_mask) {
  Detection d;
  d.label = {26, instance};
  d.box = car.box;
  if (with_mask) {
    d.mask = cv::Mat(200, 400, CV_8UC1, cv::Scalar(0));
    d.mask(cv::Rect(car.box) & cv::Rect(0, 0, 400, 200)).setTo(255);
  }
  if (with_points) {
    // A different subset of the car's points every frame (60 %).
    for (size_t k = 0; k < car.points.size(); ++k) {
      if ((k + static_cast<size_t>(frame)) % 5 < 3) d.point_ids.push_back(car.points[k]);
    }
  }
  return d;
}

void RunSwapScenario(bool with_points, bool with_mask, bool far_apart) {
  ClusterAssociator assoc(ClusterAssociationOptions{});
  Car a{{20, 50, 60, 40}, {}}, b{{far_apart ? 200.0 : 75.0, 55, 60, 40}, {}};
  for (int64_t k = 0; k < 20; ++k) {
    a.points.push_back(100 + k);
    b.points.push_back(200 + k);
  }
  int64_t id_a = -1, id_b = -1;
  for (int frame = 0; frame < 10; ++frame) {
    int inst_a = 1, inst_b = 2;
    if (frame >= 4 && frame < 7) std::swap(inst_a, inst_b);
    if (frame >= 8) inst_a = 9;
    std::vector<Detection> dets = {MakeDetection(b, inst_b, frame, with_points, with_mask),
                                   MakeDetection(a, inst_a, frame, with_points, with_mask)};
    const AssociationResult r = assoc.Associate(dets);
    ASSERT_EQ(r.cluster_of_detection.size(), 2u);
    if (frame == 0) {
      EXPECT_EQ(r.created.size(), 2u);
      id_b = r.cluster_of_detection[0];
      id_a = r.cluster_of_detection[1];
      EXPECT_NE(id_a, id_b);
    } else {
      EXPECT_TRUE(r.created.empty()) << "frame " << frame;
      EXPECT_EQ(r.cluster_of_detection[0], id_b) << "frame " << frame;
      EXPECT_EQ(r.cluster_of_detection[1], id_a) << "frame " << frame;
    }
    // Cars move 6 px per frame.
    a.box.x += 6;
    b.box.x += 6;
  }
  EXPECT_EQ(assoc.clusters().at(id_a).instance_id, 9);
  EXPECT_EQ(assoc.clusters().at(id_a).state, ClusterState::kTracked);
}

TEST(ClusterAssociation, RobustToInstanceIdSwapsWithPointsAndMasks) {
  RunSwapScenario(true, true, false);
}
TEST(ClusterAssociation, RobustToInstanceIdSwapsWithPointsOnly) {
  RunSwapScenario(true, false, false);
}
TEST(ClusterAssociation, RobustToInstanceIdSwapsWithBoxesOnly) {
  RunSwapScenario(false, false, true);
}

TEST(ClusterAssociation, PointsWinOverOverlapAndIds) {
  // The detection overlaps cluster 1's box a little and carries cluster 1's
  // instance id, but its matched points all belong to cluster 2.
  ClusterAssociator assoc(ClusterAssociationOptions{});
  Detection d1{{26, 1}, {0, 0, 50, 50}, cv::Mat(), {1, 2, 3, 4}};
  Detection d2{{26, 2}, {100, 0, 50, 50}, cv::Mat(), {5, 6, 7, 8}};
  const AssociationResult r0 = assoc.Associate({d1, d2});
  Detection d{{26, 1}, {60, 0, 50, 50}, cv::Mat(), {5, 6, 7}};
  const AssociationResult r1 = assoc.Associate({d});
  EXPECT_EQ(r1.cluster_of_detection[0], r0.cluster_of_detection[1]);
}

TEST(ClusterAssociation, ClassMismatchNeverAssociates) {
  ClusterAssociator assoc(ClusterAssociationOptions{});
  const AssociationResult r0 = assoc.Associate({Detection{{26, 1}, {0, 0, 50, 50}, cv::Mat(), {}}});
  const AssociationResult r1 = assoc.Associate({Detection{{24, 1}, {0, 0, 50, 50}, cv::Mat(), {}}});
  EXPECT_NE(r1.cluster_of_detection[0], r0.cluster_of_detection[0]);
  EXPECT_EQ(r1.created.size(), 1u);
}

TEST(ClusterAssociation, LostAfterNFramesThenRefoundThenRemoved) {
  ClusterAssociationOptions options;
  options.lost_after_frames = 2;
  options.remove_after_frames = 5;
  ClusterAssociator assoc(options);
  const Detection car{{26, 1}, {0, 0, 50, 50}, cv::Mat(), {1, 2, 3}};
  const int64_t id = assoc.Associate({car}).cluster_of_detection[0];
  EXPECT_EQ(assoc.clusters().at(id).state, ClusterState::kNew);
  EXPECT_TRUE(assoc.Associate({}).lost.empty());
  const AssociationResult lost = assoc.Associate({});
  ASSERT_EQ(lost.lost, (std::vector<int64_t>{id}));
  ASSERT_EQ(lost.events.size(), 1u);
  EXPECT_EQ(lost.events[0].type, ClusterEventType::kLost);
  EXPECT_EQ(assoc.clusters().at(id).state, ClusterState::kLost);
  // Re-found by its points although the segmenter gave it a new id.
  const AssociationResult back =
      assoc.Associate({Detection{{26, 4}, {5, 0, 50, 50}, cv::Mat(), {2, 3}}});
  EXPECT_EQ(back.cluster_of_detection[0], id);
  EXPECT_EQ(assoc.clusters().at(id).state, ClusterState::kTracked);
  for (int k = 0; k < 4; ++k) EXPECT_TRUE(assoc.Associate({}).removed.empty());
  EXPECT_EQ(assoc.Associate({}).removed, (std::vector<int64_t>{id}));
  EXPECT_TRUE(assoc.clusters().empty());
}

TEST(ClusterAssociation, StuffIsOneClusterPerClass) {
  ClusterAssociator assoc(ClusterAssociationOptions{});
  assoc.set_dynamic_classes({26});
  const AssociationResult r0 =
      assoc.Associate({Detection{{7, 0}, {0, 100, 400, 100}, cv::Mat(), {}},
                       Detection{{26, 1}, {0, 0, 50, 50}, cv::Mat(), {}}});
  ASSERT_EQ(r0.events.size(), 2u);
  EXPECT_FALSE(r0.events[0].is_dynamic);
  EXPECT_TRUE(r0.events[1].is_dynamic);
  // The road seen elsewhere in the image is still the same road cluster.
  const AssociationResult r1 = assoc.Associate({Detection{{7, 0}, {0, 0, 10, 10}, cv::Mat(), {}}});
  EXPECT_EQ(r1.cluster_of_detection[0], r0.cluster_of_detection[0]);
}

}  // namespace
}  // namespace twist::semantic
