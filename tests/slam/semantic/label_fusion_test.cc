#include "slam/semantic/label_fusion.h"

#include <gtest/gtest.h>

namespace twist::semantic {
namespace {

TEST(LabelFusion, MajorityClassThenMajorityInstanceWithinClass) {
  LabelVote vote;
  EXPECT_FALSE(vote.Fused().has_value());
  // 4 car votes split over two instance ids (3 for instance 2), 3 road votes
  // on a single label: the class vote must win even though the single most
  // voted label (road, 3 votes) ties with (car, 2).
  vote.Add({26, 2});
  vote.Add({7, 0});
  vote.Add({26, 2});
  vote.Add({7, 0});
  vote.Add({26, 5});
  vote.Add({7, 0});
  vote.Add({26, 2});
  const auto fused = vote.Fused();
  ASSERT_TRUE(fused.has_value());
  EXPECT_EQ(fused->label, (PanopticLabel{26, 2}));
  EXPECT_NEAR(fused->class_confidence, 4.0 / 7.0, 1e-12);
  EXPECT_NEAR(fused->instance_confidence, 3.0 / 4.0, 1e-12);
  EXPECT_EQ(fused->num_votes, 7);
}

TEST(LabelFusion, WeightsAndRemoval) {
  LabelVote vote;
  vote.Add({26, 1}, 0.5);
  vote.Add({11, 0}, 2.0);
  EXPECT_EQ(vote.Fused()->label, (PanopticLabel{11, 0}));
  EXPECT_TRUE(vote.Remove({11, 0}, 2.0));
  EXPECT_FALSE(vote.Remove({11, 0}, 2.0));
  EXPECT_EQ(vote.Fused()->label, (PanopticLabel{26, 1}));
  EXPECT_DOUBLE_EQ(vote.Fused()->class_confidence, 1.0);
}

TEST(LabelFusion, TiesGoToTheMostRecentVote) {
  LabelVote vote;
  vote.Add({26, 1});
  vote.Add({24, 3});
  EXPECT_EQ(vote.Fused()->label, (PanopticLabel{24, 3}));
  vote.Add({26, 1});
  vote.Add({24, 3});
  EXPECT_EQ(vote.Fused()->label, (PanopticLabel{24, 3}));
  vote.Add({26, 1});
  EXPECT_EQ(vote.Fused()->label, (PanopticLabel{26, 1}));
}

TEST(LabelFusion, NoisyObservationsConvergeToTruth) {
  // 30 % of the observations are mislabelled at random: the vote recovers the
  // true label with a confidence close to 0.7.
  std::vector<std::optional<PanopticLabel>> labels;
  uint32_t state = 12345;
  auto next = [&state]() {
    state = state * 1664525u + 1013904223u;
    return state >> 8;
  };
  for (int k = 0; k < 200; ++k) {
    if (next() % 10 < 3) {
      labels.push_back(
          PanopticLabel{static_cast<int>(7 + next() % 20), static_cast<int>(next() % 4)});
    } else if (next() % 10 == 0) {
      labels.push_back(std::nullopt);
    } else {
      labels.push_back(PanopticLabel{26, 4});
    }
  }
  const auto fused = FuseLabels(labels);
  ASSERT_TRUE(fused.has_value());
  EXPECT_EQ(fused->label, (PanopticLabel{26, 4}));
  EXPECT_GT(fused->class_confidence, 0.6);
  EXPECT_LT(fused->class_confidence, 0.85);
}

}  // namespace
}  // namespace twist::semantic
