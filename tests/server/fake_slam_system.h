// A small deterministic SlamSystem for the server's mechanics tests: it
// checks its input like the real engine (sizes, types, timestamps), derives a
// pose from the image content, reports one object per dynamic instance in the
// mask, and saves/loads its whole state exactly. `delay_ms` slows Process()
// down to exercise queues and back-pressure.
#pragma once

#include <atomic>
#include <chrono>
#include <fstream>
#include <memory>
#include <opencv2/core.hpp>
#include <set>
#include <sstream>
#include <string>
#include <thread>

#include "absl/strings/str_cat.h"
#include "absl/synchronization/notification.h"
#include "server/session.h"
#include "slam/system/slam_system.h"

namespace twist::testing {

class FakeSlamSystem : public SlamSystem {
 public:
  FakeSlamSystem(const SessionConfig& config,
                 int delay_ms,
                 std::shared_ptr<absl::Notification> gate = nullptr)
      : config_(config), delay_ms_(delay_ms), gate_(std::move(gate)) {}

  absl::StatusOr<FrameResult> Process(const StereoFrame& frame) override {
    if (shut_down_) return absl::FailedPreconditionError("shut down");
    const auto& cam = config_.camera;
    if (frame.left.cols != cam.width || frame.left.rows != cam.height ||
        frame.right.size() != frame.left.size()) {
      return absl::InvalidArgumentError("image size does not match the calibration");
    }
    if (frame.left.type() != frame.right.type())
      return absl::InvalidArgumentError("left/right types differ");
    if (!frame.panoptic.empty() && frame.panoptic.size() != frame.left.size()) {
      return absl::InvalidArgumentError("mask size mismatch");
    }
    if (frames_ > 0 && frame.timestamp_ns <= last_ts_)
      return absl::InvalidArgumentError("timestamp not increasing");
    if (delay_ms_ > 0) std::this_thread::sleep_for(std::chrono::milliseconds(delay_ms_));
    if (gate_) gate_->WaitForNotification();  // a stalled engine until released
    // The pose integrates the image content, so a reordered, dropped or
    // duplicated frame changes every later pose.
    const double mean = cv::mean(frame.left)[0] + 0.5 * cv::mean(frame.right)[0];
    z_ += 0.01 * mean / 255.0 + cam.fx * 1e-5;
    yaw_ += 0.001 * std::fmod(mean, 7.0);
    FrameResult r;
    r.index = frame.index;
    r.timestamp_ns = frame.timestamp_ns;
    r.state = frames_ == 0 ? TrackingState::kNotInitialized : TrackingState::kOk;
    r.world_from_camera =
        geometry::SE3d(Eigen::Quaterniond(Eigen::AngleAxisd(yaw_, Eigen::Vector3d::UnitY())),
                       Eigen::Vector3d(0, 0, z_));
    r.is_keyframe = frames_ % 5 == 0;
    r.num_map_points = static_cast<int>(10 * (frames_ + 1));
    r.num_keyframes = static_cast<int>(frames_ / 5 + 1);
    if (!frame.panoptic.empty()) {
      cv::Mat ids;
      frame.panoptic.convertTo(ids, CV_32S);
      std::set<int> seen;
      for (int y = 0; y < ids.rows; y += 4)
        for (int x = 0; x < ids.cols; x += 4) seen.insert(ids.at<int>(y, x));
      for (int id : seen) {
        if (!config_.classes.IsDynamic(id / 1000) || id % 1000 == 0) continue;
        ObjectResult o;
        o.id = id;
        o.class_id = id / 1000;
        o.instance_id = id % 1000;
        o.state = ObjectState::kTracked;
        o.world_from_object =
            geometry::SE3d(Eigen::Quaterniond::Identity(), Eigen::Vector3d(1, 0, z_ + 5));
        o.twist_in_world << 1, 0, 0, 0, 0, 0.1;
        o.twist_in_joint << 1, 0, 0, 0, 0, 0.1;
        o.speed_mps = 1.0;
        o.joint = "planar";
        o.num_points = 12;
        r.objects.push_back(o);
      }
    }
    if (frames_ == 0) {
      ClusterEvent e;
      e.type = ClusterEventType::kCreated;
      e.cluster_id = 1;
      e.class_id = 7;
      e.plane = Eigen::Vector4d(0, -1, 0, 1.6);
      r.cluster_events.push_back(e);
    }
    r.timings.push_back({"fake", static_cast<double>(delay_ms_)});
    ++frames_;
    last_ts_ = frame.timestamp_ns;
    return r;
  }

  MapSnapshot Snapshot() const override {
    MapSnapshot m;
    for (int64_t i = 0; i < frames_ * 10; ++i) {
      MapSnapshot::Point p;
      p.p_in_world = Eigen::Vector3d(0.1 * i, 0, z_);
      p.class_id = 7;
      p.cluster_id = i % 3 == 0 ? 1 : -1;
      m.points.push_back(p);
    }
    MapSnapshot::KeyFrame kf;
    kf.id = 0;
    kf.world_from_camera = geometry::SE3d();
    m.keyframes.push_back(kf);
    MapSnapshot::Cluster c;
    c.id = 1;
    c.class_id = 7;
    c.plane = Eigen::Vector4d(0, -1, 0, 1.6);
    m.clusters.push_back(c);
    return m;
  }

  absl::Status Save(const std::string& path) const override {
    std::ofstream out(path + ".tmp");
    out.precision(17);
    const auto& c = config_.camera;
    out << frames_ << " " << last_ts_ << " " << z_ << " " << yaw_ << " " << c.fx << " " << c.fy
        << " " << c.cx << " " << c.cy << " " << c.baseline << " " << c.width << " " << c.height
        << " " << delay_ms_ << "\n";
    out.close();
    if (!out) return absl::InternalError("fake save failed");
    std::rename((path + ".tmp").c_str(), path.c_str());
    return absl::OkStatus();
  }

  static absl::StatusOr<std::unique_ptr<SlamSystem>> Load(const std::string& path) {
    std::ifstream in(path);
    if (!in) return absl::NotFoundError(absl::StrCat("no fake state at ", path));
    SessionConfig config;
    int64_t frames = 0, last_ts = 0;
    double z = 0, yaw = 0;
    int delay = 0;
    auto& c = config.camera;
    in >> frames >> last_ts >> z >> yaw >> c.fx >> c.fy >> c.cx >> c.cy >> c.baseline >> c.width >>
        c.height >> delay;
    if (!in) return absl::DataLossError("corrupt fake state");
    auto sys = std::make_unique<FakeSlamSystem>(config, delay);
    sys->frames_ = frames;
    sys->last_ts_ = last_ts;
    sys->z_ = z;
    sys->yaw_ = yaw;
    return std::unique_ptr<SlamSystem>(std::move(sys));
  }

  const SessionConfig& config() const override { return config_; }
  int64_t frames_processed() const override { return frames_; }
  void Shutdown() override { shut_down_ = true; }

 private:
  SessionConfig config_;
  int delay_ms_ = 0;
  std::shared_ptr<absl::Notification> gate_;
  int64_t frames_ = 0;
  int64_t last_ts_ = 0;
  double z_ = 0, yaw_ = 0;
  std::atomic<bool> shut_down_{false};
};

inline server::SlamSystemFactory FakeFactory(int delay_ms = 0,
                                             std::shared_ptr<absl::Notification> gate = nullptr) {
  server::SlamSystemFactory f;
  f.create = [delay_ms,
              gate](const SessionConfig& config) -> absl::StatusOr<std::unique_ptr<SlamSystem>> {
    if (!(config.camera.fx > 0)) return absl::InvalidArgumentError("bad camera");
    return std::unique_ptr<SlamSystem>(std::make_unique<FakeSlamSystem>(config, delay_ms, gate));
  };
  f.load = [](const std::string& path) { return FakeSlamSystem::Load(path); };
  return f;
}

}  // namespace twist::testing
