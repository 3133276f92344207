#include <gtest/gtest.h>

#include <cstring>
#include <random>

#include "slam/mapping/local_mapper.h"
#include "slam/tracking/camera_tracker.h"
#include "slam/tracking/pose_optimizer.h"
#include "tests/slam/tracking/synthetic_features.h"

namespace twist::tracking {
namespace {

using testing::MakeWorld;
using testing::Observe;
using testing::TestCamera;
using testing::TruePose;

TEST(PoseOptimizer, RecoversAPerturbedPoseDespiteOutliers) {
  const geometry::StereoCamera cam = TestCamera();
  const auto world = MakeWorld(600, 1);
  const geometry::SE3d truth = TruePose(3).Inverse();  // camera_from_world
  std::mt19937 rng(2);
  std::normal_distribution<double> noise(0.0, 0.5);
  std::uniform_real_distribution<double> wild(-40, 40);
  std::vector<PoseObservation> obs;
  int num_outliers = 0;
  for (size_t i = 0; i < world.points.size(); ++i) {
    const Eigen::Vector3d pc = truth * world.points[i];
    Eigen::Vector3d uvr;
    if (!cam.ProjectStereoChecked(pc, &uvr, nullptr, 1.0) || !cam.InImage(uvr.head<2>())) continue;
    PoseObservation o;
    o.p_in_world = world.points[i];
    o.uv = uvr.head<2>() + Eigen::Vector2d(noise(rng), noise(rng));
    o.u_right = pc.z() < 25 ? uvr.z() + noise(rng) : -1.0;
    if (i % 10 == 0) {  // gross outliers
      o.uv += Eigen::Vector2d(wild(rng) + 20, wild(rng) + 20);
      ++num_outliers;
    }
    obs.push_back(o);
  }
  ASSERT_GT(obs.size(), 200u);
  Eigen::Matrix<double, 6, 1> delta;
  delta << 0.3, -0.1, 0.5, 0.02, -0.03, 0.01;  // 0.6 m, ~2 degrees
  geometry::SE3d estimate = truth * geometry::SE3d::Exp(delta);
  const int inliers = OptimizePose(cam, &obs, &estimate);
  EXPECT_GE(inliers, static_cast<int>(obs.size()) - num_outliers - 10);
  int flagged = 0;
  for (size_t k = 0; k < obs.size(); ++k) flagged += obs[k].outlier;
  EXPECT_GE(flagged, num_outliers - 2);
  EXPECT_LT(testing::TranslationError(estimate, truth), 0.02);
  EXPECT_LT(testing::RotationErrorDeg(estimate, truth), 0.05);
}

class TrackerTest : public ::testing::Test {
 protected:
  TrackerTest()
      : cam_(TestCamera()),
        pyramid_(features::ScalePyramid::Create(8, 1.2)),
        world_(MakeWorld(3000, 7)),
        map_(cam_, pyramid_),
        tracker_(cam_, pyramid_, TrackerOptions{}),
        mapper_(cam_, pyramid_, mapping::MapperOptions{}) {}

  map::Frame MakeFrame(int k) {
    map::Frame f;
    f.id = k;
    f.timestamp_ns = k * 100'000'000LL;
    f.features = Observe(world_, cam_, pyramid_, TruePose(k).Inverse(), 100 + k);
    f.ResetMatches();
    return f;
  }

  // Runs frames [0, n) through tracker + synchronous mapping; returns states.
  std::vector<TrackingState> Run(int n, std::vector<geometry::SE3d>* poses) {
    std::vector<TrackingState> states;
    for (int k = 0; k < n; ++k) {
      map::Frame f = MakeFrame(k);
      TrackingState s;
      if (tracker_.state() == TrackingState::kNotInitialized) {
        EXPECT_TRUE(tracker_.CanInitialize(f));
        map::KeyFrame* kf = mapper_.CreateKeyFrame(f, &map_, true);
        tracker_.Initialize(f, *kf);
        s = TrackingState::kOk;
      } else {
        s = tracker_.Track(&f, &map_);
        if (s == TrackingState::kOk && k % 3 == 0) {
          map::KeyFrame* kf = mapper_.CreateKeyFrame(f, &map_, false);
          tracker_.OnKeyFrameCreated(f, *kf);
          mapper_.ProcessKeyFrame(kf->id, &map_);
        }
      }
      states.push_back(s);
      poses->push_back(f.camera_from_world.Inverse());
    }
    return states;
  }

  // Frame 8 after a sudden 4-degree turn (truth: world_from_camera), with
  // decoys (repetitive texture) exactly at the constant-velocity predicted
  // positions of `decoys` map points, carrying their descriptors.
  map::Frame TurnWithDecoys(int decoys, geometry::SE3d* truth) {
    const geometry::SE3d turn(geometry::SO3d::Exp(Eigen::Vector3d(0, 4.0 * M_PI / 180.0, 0)),
                              Eigen::Vector3d::Zero());
    *truth = TruePose(8) * turn;
    auto features = std::make_shared<map::FrameFeatures>(
        *Observe(world_, cam_, pyramid_, truth->Inverse(), 808));
    const geometry::SE3d predicted = TruePose(8).Inverse();  // camera_from_world
    int placed = 0;
    std::vector<uint8_t> rows(features->descriptors.data,
                              features->descriptors.data + features->descriptors.total());
    for (size_t i = 0; i < world_.points.size() && placed < decoys; ++i) {
      const Eigen::Vector3d pc = predicted * world_.points[i];
      Eigen::Vector3d uvr;
      if (pc.z() < 5.0 || pc.z() > 25.0 || !cam_.ProjectStereoChecked(pc, &uvr)) continue;
      if (!cam_.InImage(uvr.head<2>(), 40.0)) continue;
      // One decoy per pyramid level the world's keypoints use, so that the
      // motion model's level window around the last observation admits one.
      for (int level = 0; level < 4; ++level) {
        features->keypoints.emplace_back(static_cast<float>(uvr.x()),
                                         static_cast<float>(uvr.y()),
                                         31.f * pyramid_.scale[level],
                                         0.f,
                                         50.f,
                                         level);
        features->u_right.push_back(static_cast<float>(uvr.z()));
        features->depth.push_back(static_cast<float>(pc.z()));
        rows.insert(rows.end(), world_.descriptors[i].begin(), world_.descriptors[i].end());
      }
      ++placed;
    }
    EXPECT_EQ(placed, decoys);
    features->descriptors = cv::Mat(static_cast<int>(features->keypoints.size()), 32, CV_8UC1);
    std::memcpy(features->descriptors.data, rows.data(), rows.size());
    features->labels.clear();
    features->is_static.clear();
    map::Frame f;
    f.id = 8;
    f.timestamp_ns = 800'000'000LL;
    f.features = map::FinalizeFeatures(std::move(*features), cam_.width, cam_.height);
    f.ResetMatches();
    return f;
  }

  geometry::StereoCamera cam_;
  features::ScalePyramid pyramid_;
  testing::FeatureWorld world_;
  map::Map map_;
  CameraTracker tracker_;
  mapping::LocalMapper mapper_;
};

TEST_F(TrackerTest, TracksASyntheticDriveAccurately) {
  std::vector<geometry::SE3d> poses;
  const auto states = Run(15, &poses);
  for (size_t k = 0; k < states.size(); ++k) {
    EXPECT_EQ(states[k], TrackingState::kOk) << "frame " << k;
    EXPECT_LT(testing::TranslationError(poses[k], TruePose(static_cast<int>(k))), 0.05) << k;
    EXPECT_LT(testing::RotationErrorDeg(poses[k], TruePose(static_cast<int>(k))), 0.1) << k;
  }
  EXPECT_GT(tracker_.stats().num_inliers, 100);
}

TEST_F(TrackerTest, RelocalizesAfterAForcedLoss) {
  std::vector<geometry::SE3d> poses;
  Run(8, &poses);
  tracker_.ForceLost();
  // A frame far from the motion-model prediction (a jump ahead): only
  // relocalisation (descriptors + PnP RANSAC) can find it.
  map::Frame f;
  f.id = 8;
  f.timestamp_ns = 800'000'000LL;
  f.features = Observe(world_, cam_, pyramid_, TruePose(10).Inverse(), 999);
  f.ResetMatches();
  const TrackingState s = tracker_.Track(&f, &map_);
  EXPECT_EQ(s, TrackingState::kRelocalized);
  EXPECT_EQ(tracker_.stats().path, TrackingPath::kRelocalization);
  EXPECT_LT(testing::TranslationError(f.camera_from_world.Inverse(), TruePose(10)), 0.05);
  EXPECT_LT(testing::RotationErrorDeg(f.camera_from_world.Inverse(), TruePose(10)), 0.1);
}

TEST_F(TrackerTest, AWeakMotionModelPoseLosesToTheReferenceKeyFrame) {
  // A sudden 4-degree turn: every true keypoint lies ~50 px from where the
  // constant-velocity prediction puts it, outside the motion model's search
  // windows. Decoys (repetitive texture) sit exactly at the predicted
  // positions of 40 map points with their descriptors, so the motion model
  // finds a consistent but wrong pose with at most 40 inliers. Descriptor tracking
  // of the reference keyframe (PnP RANSAC) must win over it.
  std::vector<geometry::SE3d> poses;
  Run(8, &poses);
  geometry::SE3d truth;
  map::Frame f = TurnWithDecoys(40, &truth);
  EXPECT_EQ(tracker_.Track(&f, &map_), TrackingState::kOk);
  EXPECT_EQ(tracker_.stats().path, TrackingPath::kReferenceKeyFrame);
  EXPECT_GT(tracker_.stats().num_inliers, 100);
  EXPECT_LT(testing::RotationErrorDeg(f.camera_from_world.Inverse(), truth), 0.1);
  EXPECT_LT(testing::TranslationError(f.camera_from_world.Inverse(), truth), 0.05);
}

TEST_F(TrackerTest, AWeakFrameAfterAConfidentMotionModelIsTrackedAgainFromTheReferenceKeyFrame) {
  // The same turn with 120 decoys: the motion model is confident (more than
  // confident_motion_inliers on the decoys), but the local map seen from its
  // pose keeps the decoys only, far under the last frame's inliers, and the
  // second search from that pose finds nothing more. The frame is tracked
  // again from the reference keyframe by descriptor, which must win.
  std::vector<geometry::SE3d> poses;
  Run(8, &poses);
  geometry::SE3d truth;
  map::Frame f = TurnWithDecoys(120, &truth);
  EXPECT_EQ(tracker_.Track(&f, &map_), TrackingState::kOk);
  EXPECT_EQ(tracker_.stats().path, TrackingPath::kReferenceKeyFrame);
  EXPECT_GT(tracker_.stats().num_inliers, 200);
  EXPECT_LT(testing::RotationErrorDeg(f.camera_from_world.Inverse(), truth), 0.1);
  EXPECT_LT(testing::TranslationError(f.camera_from_world.Inverse(), truth), 0.05);
}

// A frame that neither the motion model nor the reference keyframe tracks
// while tracking is fine (a jump ahead, as at the start of a sharp turn, with
// the reference keyframe culled) is relocalized in the same frame rather than
// reported lost.
TEST_F(TrackerTest, AFrameTheTrackingPathsMissIsRelocalizedAtOnce) {
  const int kJump = 20;  // 12 frames ahead of the motion model's prediction
  std::vector<geometry::SE3d> poses;
  Run(8, &poses);
  ASSERT_EQ(tracker_.state(), TrackingState::kOk);
  map_.EraseKeyFrame(tracker_.reference_kf_id());
  map::Frame f;
  f.id = 8;
  f.timestamp_ns = 800'000'000LL;
  f.features = Observe(world_, cam_, pyramid_, TruePose(kJump).Inverse(), 999);
  f.ResetMatches();
  const TrackingState s = tracker_.Track(&f, &map_);
  EXPECT_EQ(s, TrackingState::kRelocalized);
  EXPECT_EQ(tracker_.stats().path, TrackingPath::kRelocalization);
  // Farther from the map than RelocalizesAfterAForcedLoss's frame: fewer
  // close points.
  EXPECT_LT(testing::TranslationError(f.camera_from_world.Inverse(), TruePose(kJump)), 0.1);
  EXPECT_LT(testing::RotationErrorDeg(f.camera_from_world.Inverse(), TruePose(kJump)), 0.2);
}

TEST_F(TrackerTest, StaysLostWhenNothingMatches) {
  std::vector<geometry::SE3d> poses;
  Run(4, &poses);
  tracker_.ForceLost();
  const auto other = MakeWorld(2000, 12345);  // unrelated descriptors
  map::Frame f;
  f.id = 4;
  f.timestamp_ns = 400'000'000LL;
  f.features = Observe(other, cam_, pyramid_, TruePose(4).Inverse(), 5);
  f.ResetMatches();
  EXPECT_EQ(tracker_.Track(&f, &map_), TrackingState::kLost);
}

TEST_F(TrackerTest, DynamicKeypointsAreIgnored) {
  // Mark every keypoint dynamic after initialisation: tracking must fail
  // rather than use them.
  std::vector<geometry::SE3d> poses;
  Run(3, &poses);
  map::Frame f = MakeFrame(3);
  auto features = std::make_shared<map::FrameFeatures>(*f.features);
  std::fill(features->is_static.begin(), features->is_static.end(), 0);
  f.features = features;
  EXPECT_EQ(tracker_.Track(&f, &map_), TrackingState::kLost);
  for (uint8_t m : f.matched) EXPECT_EQ(m, 0);
}

}  // namespace
}  // namespace twist::tracking
