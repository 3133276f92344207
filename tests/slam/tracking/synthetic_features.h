// Synthetic "feature worlds" with exact ground truth for tracking/mapping
// tests: random 3D points, each with its own random ORB-like descriptor; a
// frame at a known pose sees the points that project into the image, with
// pixel noise, a pyramid level, a stereo coordinate for close points and a
// descriptor with a few flipped bits.
#pragma once

#include <Eigen/Core>
#include <random>
#include <vector>

#include "slam/features/orb_extractor.h"
#include "slam/map/map.h"

namespace twist::testing {

inline geometry::StereoCamera TestCamera() {
  geometry::StereoCamera c;
  c.fx = c.fy = 700.0;
  c.cx = 600.0;
  c.cy = 180.0;
  c.baseline = 0.54;
  c.width = 1200;
  c.height = 360;
  return c;
}

struct FeatureWorld {
  std::vector<Eigen::Vector3d> points;
  std::vector<map::Descriptor> descriptors;
};

// Points in a street-like volume ahead of the origin (x lateral, y down, z forward).
inline FeatureWorld MakeWorld(int n, uint32_t seed, double z_max = 60.0) {
  std::mt19937 rng(seed);
  std::uniform_real_distribution<double> ux(-12, 12), uy(-4, 1.6), uz(2, z_max);
  std::uniform_int_distribution<int> ub(0, 255);
  FeatureWorld w;
  for (int i = 0; i < n; ++i) {
    w.points.emplace_back(ux(rng), uy(rng), uz(rng));
    map::Descriptor d;
    for (auto& b : d) b = static_cast<uint8_t>(ub(rng));
    w.descriptors.push_back(d);
  }
  return w;
}

struct FrameTruth {
  std::vector<int> point_index;  // per keypoint, index into FeatureWorld
};

// Observes `world` from camera_from_world.
inline std::shared_ptr<map::FrameFeatures> Observe(const FeatureWorld& world,
                                                   const geometry::StereoCamera& cam,
                                                   const features::ScalePyramid& pyramid,
                                                   const geometry::SE3d& camera_from_world,
                                                   uint32_t seed,
                                                   double pixel_noise = 0.3,
                                                   FrameTruth* truth = nullptr) {
  std::mt19937 rng(seed);
  std::normal_distribution<double> noise(0.0, 1.0);
  std::uniform_int_distribution<int> level_dist(0, 3), bit(0, 255), flips(0, 4);
  map::FrameFeatures f;
  std::vector<uint8_t> desc_rows;
  for (size_t i = 0; i < world.points.size(); ++i) {
    const Eigen::Vector3d pc = camera_from_world * world.points[i];
    if (pc.z() < 1.0) continue;
    Eigen::Vector3d uvr;
    cam.ProjectStereoChecked(pc, &uvr);
    if (!cam.InImage(uvr.head<2>(), 20.0)) continue;
    const int level = level_dist(rng);
    const double s = pyramid.scale[level] * pixel_noise;
    cv::KeyPoint kp(static_cast<float>(uvr.x() + s * noise(rng)),
                    static_cast<float>(uvr.y() + s * noise(rng)),
                    31.f * pyramid.scale[level],
                    0.f,
                    50.f,
                    level);
    f.keypoints.push_back(kp);
    if (pc.z() < 30.0) {
      const float ur = static_cast<float>(uvr.z() + s * noise(rng));
      f.u_right.push_back(ur);
      f.depth.push_back(static_cast<float>(cam.bf() / (kp.pt.x - ur)));
    } else {
      f.u_right.push_back(-1.f);
      f.depth.push_back(-1.f);
    }
    map::Descriptor d = world.descriptors[i];
    const int nf = flips(rng);
    for (int k = 0; k < nf; ++k) d[bit(rng) % 32] ^= static_cast<uint8_t>(1u << (bit(rng) % 8));
    desc_rows.insert(desc_rows.end(), d.begin(), d.end());
    if (truth != nullptr) truth->point_index.push_back(static_cast<int>(i));
  }
  f.descriptors = cv::Mat(static_cast<int>(f.keypoints.size()), 32, CV_8UC1);
  if (!desc_rows.empty()) std::memcpy(f.descriptors.data, desc_rows.data(), desc_rows.size());
  return map::FinalizeFeatures(std::move(f), cam.width, cam.height);
}

// Forward motion with a gentle turn: pose of frame k (world_from_camera).
inline geometry::SE3d TruePose(int k) {
  Eigen::Matrix<double, 6, 1> xi;
  xi << 0.02 * k, 0.0, 0.9 * k, 0.0, 0.004 * k, 0.0;
  return geometry::SE3d::Exp(xi);
}

inline double TranslationError(const geometry::SE3d& a, const geometry::SE3d& b) {
  return (a.translation() - b.translation()).norm();
}
inline double RotationErrorDeg(const geometry::SE3d& a, const geometry::SE3d& b) {
  return (a.so3().Inverse() * b.so3()).Log().norm() * 180.0 / M_PI;
}

}  // namespace twist::testing
