#include "slam/map/map.h"

#include <gtest/gtest.h>

#include <atomic>
#include <memory>
#include <chrono>
#include <thread>
#include <vector>

namespace twist::map {
namespace {

geometry::StereoCamera Camera() {
  geometry::StereoCamera c;
  c.fx = c.fy = 500;
  c.cx = 320;
  c.cy = 240;
  c.baseline = 0.5;
  c.width = 640;
  c.height = 480;
  return c;
}

Frame MakeFrame(int64_t id, int n, uint8_t fill, double z) {
  FrameFeatures f;
  for (int i = 0; i < n; ++i) f.keypoints.emplace_back(10.f * i, 100.f, 31.f, 0.f, 0.f, i % 3);
  f.descriptors = cv::Mat(n, 32, CV_8UC1, cv::Scalar(fill));
  Frame frame;
  frame.id = id;
  frame.features = FinalizeFeatures(std::move(f), 640, 480);
  frame.camera_from_world = geometry::SE3d(Eigen::Matrix3d::Identity(), Eigen::Vector3d(0, 0, -z));
  frame.ResetMatches();
  return frame;
}

TEST(Map, IdsComeFromTheMapAndCovisibilityCountsSharedPoints) {
  Map map(Camera(), features::ScalePyramid::Create(8, 1.2));
  Map other(Camera(), features::ScalePyramid::Create(8, 1.2));
  KeyFrame* a = map.CreateKeyFrame(MakeFrame(0, 40, 0, 0));
  KeyFrame* b = map.CreateKeyFrame(MakeFrame(1, 40, 0, 1));
  KeyFrame* c = map.CreateKeyFrame(MakeFrame(2, 40, 0, 2));
  EXPECT_EQ(a->id, 0);
  EXPECT_EQ(c->id, 2);
  // Another map starts its own ids.
  EXPECT_EQ(other.CreateKeyFrame(MakeFrame(0, 5, 0, 0))->id, 0);
  // 30 points seen by a and b, 20 of which also by c.
  for (int i = 0; i < 30; ++i) {
    MapPoint* p = map.CreatePoint(Eigen::Vector3d(i, 0, 10), *a);
    map.AddObservation(p, a, i);
    map.AddObservation(p, b, i);
    if (i < 20) map.AddObservation(p, c, i);
  }
  map.UpdateConnections(a);
  map.UpdateConnections(b);
  map.UpdateConnections(c);
  EXPECT_EQ(a->connections.at(b->id), 30);
  EXPECT_EQ(a->connections.at(c->id), 20);
  EXPECT_EQ(a->BestCovisible(1), std::vector<int64_t>{b->id});
  EXPECT_EQ(c->ordered_connections, (std::vector<int64_t>{a->id, b->id}));
  EXPECT_EQ(map.NumGoodPoints(), 30);

  // Erasing b: points seen only by a remain with one observation -> erased.
  map.EraseKeyFrame(b->id);
  EXPECT_EQ(map.keyframe(1), nullptr);
  EXPECT_EQ(map.NumGoodPoints(), 20);
  EXPECT_EQ(a->connections.count(1), 0u);
  for (const auto& [id, p] : map.points()) EXPECT_EQ(p->observations.size(), 2u);

  // A point inserted bad (as a state file may hold one) is not counted, and
  // erasing or replacing it leaves the count right.
  auto bad = std::make_unique<MapPoint>();
  bad->id = 1000;
  bad->bad = true;
  map.InsertPoint(std::move(bad));
  EXPECT_EQ(map.NumGoodPoints(), 20);
  auto good = std::make_unique<MapPoint>();
  good->id = 1001;
  map.InsertPoint(std::move(good));
  EXPECT_EQ(map.NumGoodPoints(), 21);
  map.ReplacePoint(1000, 1001);
  EXPECT_EQ(map.NumGoodPoints(), 21);
  EXPECT_EQ(map.point(1000), nullptr);
  map.ErasePoint(1001);
  map.ErasePoint(map.points().begin()->first);
  EXPECT_EQ(map.NumGoodPoints(), 19);
  int counted = 0;
  for (const auto& [id, p] : map.points()) counted += !p->bad;
  EXPECT_EQ(counted, 19);
}

// Points are looked up by id through an index kept beside the ordered
// container: it must follow every way a point enters or leaves the map.
TEST(Map, PointLookupFollowsEveryChange) {
  Map map(Camera(), features::ScalePyramid::Create(8, 1.2));
  KeyFrame* a = map.CreateKeyFrame(MakeFrame(0, 10, 0, 0));
  KeyFrame* b = map.CreateKeyFrame(MakeFrame(1, 10, 0, 1));
  std::vector<MapPoint*> created;
  for (int i = 0; i < 10; ++i) {
    MapPoint* p = map.CreatePoint(Eigen::Vector3d(i, 0, 10), *a);
    map.AddObservation(p, a, i);
    map.AddObservation(p, b, i);
    created.push_back(p);
  }
  auto consistent = [&map] {
    for (const auto& [id, p] : map.points()) {
      if (map.point(id) != p.get()) return false;
    }
    return true;
  };
  for (MapPoint* p : created) EXPECT_EQ(map.point(p->id), p);
  EXPECT_EQ(map.point(10), nullptr);
  EXPECT_EQ(map.point(-1), nullptr);
  EXPECT_EQ(map.GoodPoint(-1), nullptr);

  map.ErasePoint(3);
  EXPECT_EQ(map.point(3), nullptr);
  EXPECT_EQ(map.GoodPoint(3), nullptr);
  map.ReplacePoint(4, 5);
  EXPECT_EQ(map.point(4), nullptr);
  EXPECT_EQ(map.point(5), created[5]);

  // A state file's point takes a free id, then replaces itself.
  auto loaded = std::make_unique<MapPoint>();
  loaded->id = 3;
  MapPoint* raw = map.InsertPoint(std::move(loaded));
  EXPECT_EQ(map.point(3), raw);
  auto again = std::make_unique<MapPoint>();
  again->id = 3;
  again->bad = true;
  MapPoint* raw2 = map.InsertPoint(std::move(again));
  EXPECT_EQ(map.point(3), raw2);
  EXPECT_EQ(map.GoodPoint(3), nullptr);  // held bad
  EXPECT_TRUE(consistent());

  // Erasing a keyframe erases the points left with one observation.
  map.EraseKeyFrame(b->id);
  EXPECT_TRUE(consistent());
  for (int64_t id = 0; id < 10; ++id) {
    if (map.points().count(id) == 0) {
      EXPECT_EQ(map.point(id), nullptr) << id;
    }
  }
}

TEST(Map, ReplaceMergesObservationsAndDescriptorIsTheMedoid) {
  Map map(Camera(), features::ScalePyramid::Create(8, 1.2));
  KeyFrame* a = map.CreateKeyFrame(MakeFrame(0, 4, 0x00, 0));
  KeyFrame* b = map.CreateKeyFrame(MakeFrame(1, 4, 0x01, 1));
  KeyFrame* c = map.CreateKeyFrame(MakeFrame(2, 4, 0xff, 2));
  MapPoint* p = map.CreatePoint(Eigen::Vector3d(0, 0, 10), *a);
  map.AddObservation(p, a, 0);
  map.AddObservation(p, b, 1);
  MapPoint* q = map.CreatePoint(Eigen::Vector3d(0, 0, 10.1), *c);
  map.AddObservation(q, c, 2);
  map.AddObservation(q, b, 3);
  const int64_t pid = p->id, qid = q->id;
  map.ReplacePoint(qid, pid);
  EXPECT_EQ(map.point(qid), nullptr);
  p = map.point(pid);
  ASSERT_NE(p, nullptr);
  EXPECT_EQ(p->observations.size(), 3u);  // b kept its first observation
  EXPECT_EQ(c->point_ids[2], pid);
  EXPECT_EQ(b->point_ids[3], -1);
  // Descriptors 0x00, 0x01, 0xff: the outlier 0xff is never the medoid.
  EXPECT_NE(p->descriptor[0], 0xff);

  map.UpdatePointNormalAndDepth(p);
  EXPECT_NEAR(p->normal.z(), 1.0, 1e-9);
  EXPECT_NEAR(p->max_distance, 10.0, 1e-5);  // level 0 in the reference kf
  EXPECT_EQ(p->PredictScale(10.0f, map.pyramid()), 0);
  EXPECT_EQ(p->PredictScale(10.0f / 1.3f, map.pyramid()), 2);
}

// The tracking thread's PriorityLock gets the map at the mapper's next
// yield: std::mutex alone lets the yielding thread take it straight back.
// Counted in the mapper's steps, not in time.
TEST(Map, APriorityWaiterGetsTheMapAtTheMappersNextYield) {
  Map map(Camera(), features::ScalePyramid::Create(8, 1.2));
  std::atomic<int> steps{0};
  std::atomic<bool> stop{false};
  std::thread mapper([&] {
    std::unique_lock<std::mutex> lock(map.mutex());
    while (!stop.load()) {
      std::this_thread::sleep_for(std::chrono::microseconds(500));  // a step's work
      ++steps;
      map.YieldToPriorityWaiter(&lock);
    }
  });
  while (steps.load() < 3) std::this_thread::yield();
  for (int round = 0; round < 300; ++round) {
    // Ask while the mapper is inside a step (holding the map).
    const int before = steps.load();
    while (steps.load() == before) std::this_thread::yield();
    const int asked = steps.load();
    const std::unique_lock<std::mutex> lock = map.PriorityLock();
    // The step under way when asked ends, then the waiter is let in (one
    // more step if the waiter was preempted past the yield's bound).
    EXPECT_LE(steps.load() - asked, 2) << "round " << round;
  }
  stop = true;
  mapper.join();
  // Without a waiter the yield only releases and retakes the lock.
  std::unique_lock<std::mutex> lock(map.mutex());
  map.YieldToPriorityWaiter(&lock);
  EXPECT_TRUE(lock.owns_lock());
}

}  // namespace
}  // namespace twist::map
