// FramePrefetcher: order and single reads, errors (and exceptions) in their
// place, bounded read-ahead, early stop, no frames.
#include "slam/io/frame_prefetcher.h"

#include "slam/common/thread_priority.h"

#include <gmock/gmock.h>
#include <gtest/gtest.h>

#include <algorithm>
#include <atomic>
#include <chrono>
#include <stdexcept>
#include <thread>
#include <vector>

namespace twist::io {
namespace {

using ::testing::HasSubstr;

StereoFrame FakeFrame(int64_t i) {
  StereoFrame f;
  f.index = i;
  f.timestamp_ns = 1000 * i;
  f.left = cv::Mat(4, 6, CV_8UC1, cv::Scalar(static_cast<double>(i % 256)));
  f.right = f.left.clone();
  return f;
}

TEST(FramePrefetcher, GivesEveryFrameOnceInOrder) {
  std::vector<int64_t> read_order;  // written by the prefetcher's thread only
  FramePrefetcher frames(
      [&](int64_t i) -> absl::StatusOr<StereoFrame> {
        read_order.push_back(i);
        return FakeFrame(i);
      },
      50,
      3);
  for (int64_t i = 0; i < 50; ++i) {
    absl::StatusOr<StereoFrame> f = frames.Next();
    ASSERT_TRUE(f.ok()) << f.status();
    EXPECT_EQ(f->index, i);
    EXPECT_EQ(f->timestamp_ns, 1000 * i);
    EXPECT_EQ(f->left.at<uint8_t>(0, 0), i % 256);
  }
  absl::StatusOr<StereoFrame> past = frames.Next();
  EXPECT_EQ(past.status().code(), absl::StatusCode::kOutOfRange);
  std::vector<int64_t> expected(50);
  for (int64_t i = 0; i < 50; ++i) expected[static_cast<size_t>(i)] = i;
  EXPECT_EQ(read_order, expected);  // each read once, increasing
}

TEST(FramePrefetcher, AFrameThatFailsKeepsItsPlaceAndTheRestAreRead) {
  FramePrefetcher frames(
      [](int64_t i) -> absl::StatusOr<StereoFrame> {
        if (i == 3) return absl::DataLossError("frame 3: truncated PNG");
        if (i == 5) throw std::runtime_error("decoder exploded");
        return FakeFrame(i);
      },
      8);
  for (int64_t i = 0; i < 8; ++i) {
    absl::StatusOr<StereoFrame> f = frames.Next();
    if (i == 3) {
      ASSERT_FALSE(f.ok());
      EXPECT_EQ(f.status().code(), absl::StatusCode::kDataLoss);
      EXPECT_THAT(std::string(f.status().message()), HasSubstr("truncated PNG"));
    } else if (i == 5) {
      ASSERT_FALSE(f.ok());
      EXPECT_THAT(std::string(f.status().message()), HasSubstr("frame 5: decoder exploded"));
    } else {
      ASSERT_TRUE(f.ok()) << i << ": " << f.status();
      EXPECT_EQ(f->index, i);
    }
  }
}

TEST(FramePrefetcher, ReadsNoMoreThanItsDepthAhead) {
  constexpr int kDepth = 2;
  std::atomic<int64_t> taken{0};
  std::atomic<int64_t> max_ahead{0};
  FramePrefetcher frames(
      [&](int64_t i) -> absl::StatusOr<StereoFrame> {
        // Frames read and not taken, this one included.
        const int64_t ahead = i + 1 - taken.load();
        int64_t m = max_ahead.load();
        while (ahead > m && !max_ahead.compare_exchange_weak(m, ahead)) {
        }
        return FakeFrame(i);
      },
      30,
      kDepth);
  for (int64_t i = 0; i < 30; ++i) {
    // A slow consumer: the prefetcher has all the time it wants to run ahead.
    std::this_thread::sleep_for(std::chrono::milliseconds(2));
    EXPECT_LE(frames.buffered(), kDepth);
    ASSERT_TRUE(frames.Next().ok());
    taken.store(i + 1);
  }
  // depth frames waiting, plus the one being read when a slot frees.
  EXPECT_LE(max_ahead.load(), kDepth + 1);
  EXPECT_GE(max_ahead.load(), kDepth);  // it did read ahead
}

TEST(FramePrefetcher, StopsEarlyWithoutReadingTheRest) {
  std::atomic<int64_t> reads{0};
  {
    FramePrefetcher frames(
        [&](int64_t i) -> absl::StatusOr<StereoFrame> {
          ++reads;
          return FakeFrame(i);
        },
        1000,
        2);
    ASSERT_TRUE(frames.Next().ok());
    std::this_thread::sleep_for(std::chrono::milliseconds(20));
  }  // destroyed with the thread waiting for room
  EXPECT_LE(reads.load(), 4);
}

// The reading thread runs at the nice value asked for (its own: the
// consumer's stays as it was).
TEST(FramePrefetcher, ReadsAtItsOwnLowerPriority) {
  const int consumer = ThisThreadNiceness();
  std::vector<int> seen;  // written by the prefetcher's thread only
  {
    FramePrefetcher frames(
        [&](int64_t i) -> absl::StatusOr<StereoFrame> {
          seen.push_back(ThisThreadNiceness());
          return FakeFrame(i);
        },
        3,
        1,
        /*niceness=*/std::min(consumer + 7, 19));
    for (int i = 0; i < 3; ++i) ASSERT_TRUE(frames.Next().ok());
  }
  ASSERT_EQ(seen.size(), 3u);
  for (int n : seen) EXPECT_EQ(n, std::min(consumer + 7, 19));
  EXPECT_EQ(ThisThreadNiceness(), consumer);
}

TEST(FramePrefetcher, NoFramesNoThread) {
  int reads = 0;
  FramePrefetcher frames(
      [&](int64_t) -> absl::StatusOr<StereoFrame> {
        ++reads;
        return StereoFrame();
      },
      0);
  EXPECT_EQ(frames.Next().status().code(), absl::StatusCode::kOutOfRange);
  EXPECT_EQ(reads, 0);
}

}  // namespace
}  // namespace twist::io
