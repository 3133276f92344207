// Rendered synthetic clips (slam/sim) for the SlamSystem tests.
#pragma once

#include <glog/logging.h>
#include <gtest/gtest.h>
#include <unistd.h>

#include <cmath>
#include <cstring>
#include <string>
#include <vector>

#include "slam/sim/depth_truth.h"
#include "slam/sim/renderer.h"
#include "slam/sim/scenarios.h"
#include "slam/system/slam_system.h"

namespace twist {

constexpr double kMaxStaticStreetAte = 0.05;  // m over 100 frames (issue target)

struct Clip {
  SessionConfig config;
  std::vector<StereoFrame> frames;
  std::vector<geometry::SE3d> gt;  // world_from_camera
};

// Renders `n` frames of a scenario; `scale` < 1 shrinks the images (faster).
inline Clip MakeClip(const std::string& scenario_name, int n, double scale, bool gray = true) {
  auto scenario = sim::MakeScenario(scenario_name, 3, n);
  CHECK(scenario.ok()) << scenario.status();
  geometry::StereoCamera cam = scenario->camera;
  cam.fx *= scale;
  cam.fy *= scale;
  cam.cx *= scale;
  cam.cy *= scale;
  cam.width = static_cast<int>(cam.width * scale);
  cam.height = static_cast<int>(cam.height * scale);
  sim::RenderOptions ro;
  ro.gray = gray;
  sim::Renderer renderer(cam, ro);
  Clip clip;
  clip.config.camera = cam;
  for (int k = 0; k < n; ++k) {
    const geometry::SE3d pose = scenario->WorldFromCamera(k);
    sim::Exposure left, right;
    left.noise_seed = 2 * k + 1;
    right.noise_seed = 2 * k + 2;
    const sim::StereoRender r =
        renderer.RenderStereo(scenario->scene, scenario->TimeOf(k), pose, left, right);
    clip.frames.push_back(sim::ScenarioStereoFrame(*scenario, k, r));
    clip.gt.push_back(pose);
  }
  return clip;
}

// Every frame of `clip` through `sys`, expecting each tracked; the poses
// (up to the first frame the engine refuses).
inline std::vector<geometry::SE3d> TrackClip(SlamSystem& sys, const Clip& clip) {
  std::vector<geometry::SE3d> est;
  for (const auto& f : clip.frames) {
    auto r = sys.Process(f);
    EXPECT_TRUE(r.ok()) << r.status();
    if (!r.ok()) break;
    EXPECT_EQ(r->state, TrackingState::kOk);
    est.push_back(r->world_from_camera);
  }
  return est;
}

inline const Clip& SmallClip() {
  static const Clip* clip = new Clip(MakeClip("static_street", 30, 0.6));
  return *clip;
}

inline bool SamePose(const geometry::SE3d& a, const geometry::SE3d& b) {
  double pa[7], pb[7];
  a.ToParams(pa);
  b.ToParams(pb);
  return std::memcmp(pa, pb, sizeof(pa)) == 0;
}

inline std::string TempPath(const std::string& name) {
  return ::testing::TempDir() + "/" + name + "_" + std::to_string(::getpid());
}

}  // namespace twist
