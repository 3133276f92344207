#include "server/metrics.h"

#include <algorithm>
#include <cmath>

#include "absl/strings/str_cat.h"
#include "absl/strings/str_format.h"

namespace twist::server {
namespace {

constexpr auto kRateWindow = std::chrono::seconds(10);

void Counter(std::string* out, const char* name, const char* help, int64_t value) {
  absl::StrAppend(
      out, "# HELP ", name, " ", help, "\n# TYPE ", name, " counter\n", name, " ", value, "\n");
}

void Gauge(std::string* out, const char* name, const char* help, double value) {
  absl::StrAppend(out,
                  "# HELP ",
                  name,
                  " ",
                  help,
                  "\n# TYPE ",
                  name,
                  " gauge\n",
                  name,
                  " ",
                  absl::StrFormat("%.6g", value),
                  "\n");
}

void Summary(std::string* out,
             const char* name,
             const char* help,
             const std::deque<double>& window_ms,
             double sum_ms,
             int64_t count) {
  absl::StrAppend(out, "# HELP ", name, " ", help, "\n# TYPE ", name, " summary\n");
  const std::vector<double> values(window_ms.begin(), window_ms.end());
  for (double q : {0.5, 0.9, 0.99}) {
    absl::StrAppend(out,
                    name,
                    "{quantile=\"",
                    absl::StrFormat("%g", q),
                    "\"} ",
                    absl::StrFormat("%.6g", Quantile(values, q) / 1000.0),
                    "\n");
  }
  absl::StrAppend(out,
                  name,
                  "_sum ",
                  absl::StrFormat("%.6g", sum_ms / 1000.0),
                  "\n",
                  name,
                  "_count ",
                  count,
                  "\n");
}

void PushWindow(std::deque<double>* window, double v) {
  window->push_back(v);
  if (window->size() > Metrics::kWindow) window->pop_front();
}

}  // namespace

double Quantile(std::vector<double> values, double q) {
  if (values.empty()) return 0.0;
  std::sort(values.begin(), values.end());
  const double rank = std::ceil(q * static_cast<double>(values.size()));
  const size_t i =
      static_cast<size_t>(std::clamp(rank, 1.0, static_cast<double>(values.size()))) - 1;
  return values[i];
}

void Metrics::SessionCreated() {
  absl::MutexLock l(&mu_);
  ++sessions_created_;
}
void Metrics::SessionClosed() {
  absl::MutexLock l(&mu_);
  ++sessions_closed_;
}
void Metrics::SessionPersisted() {
  absl::MutexLock l(&mu_);
  ++sessions_persisted_;
}
void Metrics::SessionExpired() {
  absl::MutexLock l(&mu_);
  ++sessions_expired_;
}
void Metrics::StreamOpened() {
  absl::MutexLock l(&mu_);
  ++streams_opened_;
}
void Metrics::FrameRejected() {
  absl::MutexLock l(&mu_);
  ++frames_rejected_;
}
void Metrics::FramesDropped(int64_t n) {
  absl::MutexLock l(&mu_);
  frames_dropped_ += n;
}
void Metrics::BytesReceived(int64_t n) {
  absl::MutexLock l(&mu_);
  bytes_received_ += n;
}

void Metrics::FrameProcessed(double engine_ms, double server_ms) {
  absl::MutexLock l(&mu_);
  ++frames_processed_;
  engine_ms_sum_ += engine_ms;
  server_ms_sum_ += server_ms;
  PushWindow(&engine_ms_, engine_ms);
  PushWindow(&server_ms_, server_ms);
  const Clock::time_point now = Clock::now();
  recent_frames_.push_back(now);
  while (!recent_frames_.empty() && now - recent_frames_.front() > kRateWindow)
    recent_frames_.pop_front();
}

double Metrics::FramesPerSecond() const {
  absl::MutexLock l(&mu_);
  const Clock::time_point now = Clock::now();
  size_t n = 0;
  for (auto it = recent_frames_.rbegin(); it != recent_frames_.rend() && now - *it <= kRateWindow;
       ++it)
    ++n;
  return static_cast<double>(n) / std::chrono::duration<double>(kRateWindow).count();
}

std::string Metrics::PrometheusText(const MetricGauges& gauges) const {
  const double fps = FramesPerSecond();
  absl::MutexLock l(&mu_);
  std::string out;
  Gauge(&out,
        "twistslam_up",
        "1 while the server accepts work, 0 while shutting down.",
        gauges.serving ? 1 : 0);
  Gauge(&out, "twistslam_sessions", "Sessions loaded in memory.", gauges.sessions_loaded);
  Gauge(&out,
        "twistslam_sessions_streaming",
        "Sessions with a bound stream.",
        gauges.sessions_streaming);
  Gauge(&out,
        "twistslam_queue_depth_frames",
        "Frames waiting in all session input queues.",
        gauges.queue_depth_total);
  Gauge(&out,
        "twistslam_queue_depth_max_frames",
        "Frames waiting in the deepest session input queue.",
        gauges.queue_depth_max);
  Gauge(
      &out, "twistslam_frames_per_second", "Frames processed per second over the last 10 s.", fps);
  Counter(&out, "twistslam_sessions_created_total", "Sessions created.", sessions_created_);
  Counter(&out, "twistslam_sessions_closed_total", "Sessions closed.", sessions_closed_);
  Counter(&out,
          "twistslam_sessions_persisted_total",
          "Session saves to the state directory.",
          sessions_persisted_);
  Counter(&out,
          "twistslam_sessions_expired_total",
          "Sessions unloaded or closed after idling.",
          sessions_expired_);
  Counter(&out, "twistslam_streams_opened_total", "Streams bound to a session.", streams_opened_);
  Counter(&out,
          "twistslam_frames_processed_total",
          "Frames processed by the engine.",
          frames_processed_);
  Counter(&out,
          "twistslam_frames_rejected_total",
          "Frames answered with a FrameError.",
          frames_rejected_);
  Counter(&out,
          "twistslam_frames_dropped_total",
          "Frames dropped by the DROP_OLDEST policy.",
          frames_dropped_);
  Counter(&out,
          "twistslam_frame_bytes_received_total",
          "Bytes of frame messages received.",
          bytes_received_);
  Summary(&out,
          "twistslam_engine_latency_seconds",
          "Engine time per frame (SlamSystem::Process).",
          engine_ms_,
          engine_ms_sum_,
          frames_processed_);
  Summary(&out,
          "twistslam_frame_latency_seconds",
          "Server time per frame from receipt to update (decode + queue + engine).",
          server_ms_,
          server_ms_sum_,
          frames_processed_);
  return out;
}

}  // namespace twist::server
