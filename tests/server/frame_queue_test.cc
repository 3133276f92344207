#include "server/frame_queue.h"

#include <gtest/gtest.h>

#include <thread>

namespace twist::server {
namespace {

QueueItem Frame(int64_t index) {
  QueueItem item;
  item.index = index;
  item.timestamp_ns = index;
  return item;
}

TEST(FrameQueue, DropOldestKeepsTheNewestAndReportsDrops) {
  FrameQueue q(2, /*drop_oldest=*/true);
  for (int i = 0; i < 5; ++i) ASSERT_TRUE(q.Push(Frame(i)));
  EXPECT_EQ(q.size(), 2);
  std::vector<int64_t> dropped;
  int64_t count = 0;
  std::optional<QueueItem> item = q.Pop(&dropped, &count);
  ASSERT_TRUE(item);
  EXPECT_EQ(item->index, 3);
  EXPECT_EQ(count, 3);
  EXPECT_EQ(dropped, (std::vector<int64_t>{0, 1, 2}));
  item = q.Pop(&dropped, &count);
  EXPECT_EQ(item->index, 4);
  EXPECT_EQ(count, 0);
}

TEST(FrameQueue, ErrorsAreNeverDropped) {
  FrameQueue q(1, /*drop_oldest=*/true);
  QueueItem error = Frame(0);
  error.error = absl::InvalidArgumentError("bad");
  ASSERT_TRUE(q.Push(std::move(error)));
  ASSERT_TRUE(q.Push(Frame(1)));  // no frame to drop: the queue overfills by one
  std::vector<int64_t> dropped;
  int64_t count = 0;
  EXPECT_FALSE(q.Pop(&dropped, &count)->error.ok());
  EXPECT_EQ(q.Pop(&dropped, &count)->index, 1);
  EXPECT_EQ(count, 0);
}

TEST(FrameQueue, BlockPolicyWaitsForRoom) {
  FrameQueue q(1, /*drop_oldest=*/false);
  ASSERT_TRUE(q.Push(Frame(0)));
  std::atomic<bool> pushed{false};
  std::thread producer([&] {
    q.Push(Frame(1));
    pushed = true;
  });
  absl::SleepFor(absl::Milliseconds(50));
  EXPECT_FALSE(pushed);  // full: the producer waits (back-pressure)
  std::vector<int64_t> dropped;
  int64_t count = 0;
  EXPECT_EQ(q.Pop(&dropped, &count)->index, 0);
  producer.join();
  EXPECT_TRUE(pushed);
  EXPECT_EQ(q.Pop(&dropped, &count)->index, 1);
}

TEST(FrameQueue, CloseInputDrainsAbortDiscardsAndWakesProducers) {
  FrameQueue q(1, /*drop_oldest=*/false);
  ASSERT_TRUE(q.Push(Frame(0)));
  q.CloseInput();
  EXPECT_FALSE(q.Push(Frame(1)));
  std::vector<int64_t> dropped;
  int64_t count = 0;
  EXPECT_EQ(q.Pop(&dropped, &count)->index, 0);
  EXPECT_FALSE(q.Pop(&dropped, &count));

  FrameQueue q2(1, /*drop_oldest=*/false);
  ASSERT_TRUE(q2.Push(Frame(0)));
  std::thread blocked([&] { EXPECT_FALSE(q2.Push(Frame(1))); });
  absl::SleepFor(absl::Milliseconds(20));
  EXPECT_EQ(q2.Abort(), 1);
  blocked.join();
  EXPECT_FALSE(q2.Pop(&dropped, &count));
}

}  // namespace
}  // namespace twist::server
