// Reads the frames of a sequence ahead of their use, on a thread of its own.
//
//   io::FramePrefetcher frames(
//       [&](int64_t i) { return reader.ReadFrame(i); }, /*count=*/reader.size());
//   for (int64_t i = 0; i < reader.size(); ++i) {
//     absl::StatusOr<StereoFrame> frame = frames.Next();   // frame i, or its error
//     ...
//   }
//
// Decoding a KITTI-size frame (two PNG images and a 16-bit panoptic PNG)
// takes tens of milliseconds; with the prefetcher it overlaps the processing
// of the frame before. Frames come out in order, each exactly once, with the
// error of a frame that failed to read in its place (the frames after it are
// still read). At most `depth` frames are read and not yet taken, so memory
// stays bounded however slow the consumer is. The destructor stops the
// thread (it finishes the frame it is reading, at most), so a consumer may
// stop early. One consumer thread; `read` is called from the prefetcher's
// thread only, in increasing order of the index.
#pragma once

#include <condition_variable>
#include <cstdint>
#include <deque>
#include <functional>
#include <mutex>
#include <thread>

#include "absl/status/statusor.h"
#include "slam/common/stereo_frame.h"

namespace twist::io {

class FramePrefetcher {
 public:
  using ReadFn = std::function<absl::StatusOr<StereoFrame>(int64_t)>;

  // Reads frames 0 .. count-1 through `read`, up to `depth` (≥ 1) ahead, on
  // a thread at nice value `niceness` (> 0: below the consumer's, so that
  // decoding ahead does not take the CPU from the frames' processing on a
  // small machine; it is ahead and off the critical path).
  FramePrefetcher(ReadFn read, int64_t count, int depth = 2, int niceness = 0);
  ~FramePrefetcher();
  FramePrefetcher(const FramePrefetcher&) = delete;
  FramePrefetcher& operator=(const FramePrefetcher&) = delete;

  // The next frame in order (blocks until it is read), or the error of
  // reading it; OutOfRange once all `count` frames have been taken.
  absl::StatusOr<StereoFrame> Next();

  // Frames read and not yet taken (≤ depth); for tests and progress.
  int buffered() const;

 private:
  void Run();
  // read_(i), with an exception turned into that frame's error.
  absl::StatusOr<StereoFrame> ReadGuarded(int64_t i) const;

  const ReadFn read_;
  const int64_t count_;
  const int depth_;
  const int niceness_;
  int64_t taken_ = 0;  // consumer's count

  mutable std::mutex mu_;
  std::condition_variable cv_;
  std::deque<absl::StatusOr<StereoFrame>> ready_;  // guarded by mu_
  bool stop_ = false;                              // guarded by mu_
  std::thread thread_;
};

}  // namespace twist::io
