// The bounded input queue between a stream's reader (decodes frames) and its
// worker (runs the engine and writes updates). Bounded by construction, so a
// slow engine or a stalled client cannot grow memory:
//  - BLOCK: Push waits for room -> the reader stops reading -> HTTP/2 flow
//    control pushes back on the client;
//  - DROP_OLDEST: Push evicts the oldest queued frame and records its index,
//    which the worker reports to the client (FramesDropped).
// Errors for rejected frames travel through the same queue so the client sees
// answers in the order it sent frames.
#pragma once

#include <chrono>
#include <cstdint>
#include <deque>
#include <optional>
#include <vector>

#include "absl/base/thread_annotations.h"
#include "absl/status/status.h"
#include "absl/synchronization/mutex.h"
#include "slam/common/stereo_frame.h"

namespace twist::server {

struct QueueItem {
  // A decoded frame, or (when !error.ok()) a frame rejected by the reader.
  StereoFrame frame;
  absl::Status error;
  int64_t index = 0;
  int64_t timestamp_ns = 0;
  double decode_ms = 0.0;
  std::chrono::steady_clock::time_point enqueued;
};

class FrameQueue {
 public:
  // Indices of dropped frames kept for the next report; beyond this only the
  // count grows (a client that never reads cannot grow memory either).
  static constexpr size_t kMaxPendingDropReports = 1024;

  FrameQueue(int capacity, bool drop_oldest)
      : capacity_(capacity > 0 ? capacity : 1), drop_oldest_(drop_oldest) {}

  // False when the queue is closed (the item is discarded). May block under
  // BLOCK until room is free or the queue closes.
  bool Push(QueueItem item) {
    absl::MutexLock lock(&mu_);
    if (!drop_oldest_) {
      auto room = [this]() ABSL_SHARED_LOCKS_REQUIRED(mu_) {
        return closed_ || static_cast<int>(items_.size()) < capacity_;
      };
      mu_.Await(absl::Condition(&room));
    }
    if (closed_) return false;
    while (static_cast<int>(items_.size()) >= capacity_) {
      // Drop the oldest frame (errors are never dropped: they are tiny and
      // answer a frame the client already sent).
      auto it = items_.begin();
      while (it != items_.end() && !it->error.ok()) ++it;
      if (it == items_.end()) break;
      if (pending_dropped_.size() < kMaxPendingDropReports) pending_dropped_.push_back(it->index);
      ++pending_dropped_count_;
      items_.erase(it);
    }
    items_.push_back(std::move(item));
    return true;
  }

  // Blocks until an item is available (returned) or the queue is closed and
  // empty (nullopt). Dropped-frame reports accumulated so far move to
  // *dropped / *dropped_count.
  std::optional<QueueItem> Pop(std::vector<int64_t>* dropped, int64_t* dropped_count) {
    absl::MutexLock lock(&mu_);
    auto ready = [this]() ABSL_SHARED_LOCKS_REQUIRED(mu_) { return closed_ || !items_.empty(); };
    mu_.Await(absl::Condition(&ready));
    dropped->swap(pending_dropped_);
    pending_dropped_.clear();
    *dropped_count = pending_dropped_count_;
    pending_dropped_count_ = 0;
    if (items_.empty()) return std::nullopt;
    QueueItem item = std::move(items_.front());
    items_.pop_front();
    return item;
  }

  // No more pushes; queued items are still popped (drain).
  void CloseInput() {
    absl::MutexLock lock(&mu_);
    closed_ = true;
  }
  // No more pushes and queued items are discarded; returns how many frames.
  int Abort() {
    absl::MutexLock lock(&mu_);
    closed_ = true;
    int n = 0;
    for (const QueueItem& item : items_) n += item.error.ok() ? 1 : 0;
    items_.clear();
    return n;
  }
  // Waits until the queue is empty or `deadline` passes; true if empty.
  bool WaitEmpty(absl::Time deadline) {
    absl::MutexLock lock(&mu_);
    auto empty = [this]() ABSL_SHARED_LOCKS_REQUIRED(mu_) { return items_.empty(); };
    return mu_.AwaitWithDeadline(absl::Condition(&empty), deadline);
  }
  int size() const {
    absl::MutexLock lock(&mu_);
    return static_cast<int>(items_.size());
  }
  int capacity() const { return capacity_; }

 private:
  const int capacity_;
  const bool drop_oldest_;
  mutable absl::Mutex mu_;
  std::deque<QueueItem> items_ ABSL_GUARDED_BY(mu_);
  std::vector<int64_t> pending_dropped_ ABSL_GUARDED_BY(mu_);
  int64_t pending_dropped_count_ ABSL_GUARDED_BY(mu_) = 0;
  bool closed_ ABSL_GUARDED_BY(mu_) = false;
};

}  // namespace twist::server
