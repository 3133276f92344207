#include "slam/io/frame_prefetcher.h"

#include <algorithm>
#include <exception>
#include <utility>

#include "absl/strings/str_cat.h"
#include "slam/common/thread_priority.h"

namespace twist::io {

FramePrefetcher::FramePrefetcher(ReadFn read, int64_t count, int depth, int niceness)
    : read_(std::move(read)),
      count_(std::max<int64_t>(count, 0)),
      depth_(std::max(depth, 1)),
      niceness_(niceness) {
  if (count_ > 0) thread_ = std::thread([this] { Run(); });
}

FramePrefetcher::~FramePrefetcher() {
  {
    std::lock_guard<std::mutex> lock(mu_);
    stop_ = true;
  }
  cv_.notify_all();
  if (thread_.joinable()) thread_.join();
}

absl::StatusOr<StereoFrame> FramePrefetcher::ReadGuarded(int64_t i) const {
  try {
    return read_(i);
  } catch (const std::exception& e) {  // a decoder's exception must not end the process
    return absl::InternalError(absl::StrCat("frame ", i, ": ", e.what()));
  }
}

void FramePrefetcher::Run() {
  SetThisThreadNiceness(niceness_, "frame prefetcher");
  for (int64_t i = 0; i < count_; ++i) {
    {
      std::unique_lock<std::mutex> lock(mu_);
      cv_.wait(lock, [this] { return stop_ || static_cast<int>(ready_.size()) < depth_; });
      if (stop_) return;
    }
    // Read outside the lock: the consumer takes earlier frames meanwhile.
    absl::StatusOr<StereoFrame> frame = ReadGuarded(i);
    {
      std::lock_guard<std::mutex> lock(mu_);
      if (stop_) return;
      ready_.push_back(std::move(frame));
    }
    cv_.notify_all();
  }
}

absl::StatusOr<StereoFrame> FramePrefetcher::Next() {
  if (taken_ >= count_) {
    return absl::OutOfRangeError(absl::StrCat("all ", count_, " frames have been taken"));
  }
  std::unique_lock<std::mutex> lock(mu_);
  cv_.wait(lock, [this] { return !ready_.empty(); });
  absl::StatusOr<StereoFrame> frame = std::move(ready_.front());
  ready_.pop_front();
  ++taken_;
  lock.unlock();
  cv_.notify_all();
  return frame;
}

int FramePrefetcher::buffered() const {
  std::lock_guard<std::mutex> lock(mu_);
  return static_cast<int>(ready_.size());
}

}  // namespace twist::io
