// Server metrics in Prometheus text exposition format (version 0.0.4),
// served by the --metrics-listen HTTP endpoint and the GetMetrics RPC.
// Thread-safe; one instance per server (no process-wide state).
#pragma once

#include <chrono>
#include <cstdint>
#include <deque>
#include <string>
#include <vector>

#include "absl/base/thread_annotations.h"
#include "absl/synchronization/mutex.h"

namespace twist::server {

// Values sampled at render time from the session manager.
struct MetricGauges {
  int sessions_loaded = 0;
  int sessions_streaming = 0;
  int queue_depth_total = 0;  // frames waiting in all input queues
  int queue_depth_max = 0;    // deepest single queue
  bool serving = true;
};

class Metrics {
 public:
  // Latency samples kept for the quantiles (a sliding window).
  static constexpr size_t kWindow = 2048;

  void SessionCreated();
  void SessionClosed();
  void SessionPersisted();
  void SessionExpired();
  void StreamOpened();
  void FrameProcessed(double engine_ms, double server_ms);
  void FrameRejected();
  void FramesDropped(int64_t n);
  void BytesReceived(int64_t n);

  // Frames processed per second over the last 10 s.
  double FramesPerSecond() const;
  std::string PrometheusText(const MetricGauges& gauges) const;

 private:
  using Clock = std::chrono::steady_clock;
  mutable absl::Mutex mu_;
  int64_t sessions_created_ ABSL_GUARDED_BY(mu_) = 0;
  int64_t sessions_closed_ ABSL_GUARDED_BY(mu_) = 0;
  int64_t sessions_persisted_ ABSL_GUARDED_BY(mu_) = 0;
  int64_t sessions_expired_ ABSL_GUARDED_BY(mu_) = 0;
  int64_t streams_opened_ ABSL_GUARDED_BY(mu_) = 0;
  int64_t frames_processed_ ABSL_GUARDED_BY(mu_) = 0;
  int64_t frames_rejected_ ABSL_GUARDED_BY(mu_) = 0;
  int64_t frames_dropped_ ABSL_GUARDED_BY(mu_) = 0;
  int64_t bytes_received_ ABSL_GUARDED_BY(mu_) = 0;
  double engine_ms_sum_ ABSL_GUARDED_BY(mu_) = 0;
  double server_ms_sum_ ABSL_GUARDED_BY(mu_) = 0;
  std::deque<double> engine_ms_ ABSL_GUARDED_BY(mu_);
  std::deque<double> server_ms_ ABSL_GUARDED_BY(mu_);
  std::deque<Clock::time_point> recent_frames_ ABSL_GUARDED_BY(mu_);
};

// q-quantile (0..1) of `values` by nearest rank; 0 for none.
double Quantile(std::vector<double> values, double q);

}  // namespace twist::server
