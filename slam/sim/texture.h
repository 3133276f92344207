// Procedural surface and sky shading of the synthetic generator.
#pragma once

#include <Eigen/Core>
#include <vector>

#include "slam/sim/scene.h"

namespace twist::sim {

// Where a pixel hits a quad and how large the pixel is there.
struct SurfaceSample {
  float s = 0.0f, t = 0.0f;        // local quad coordinates (m), s ∈ [0, su], t ∈ [0, sv]
  float su = 1.0f, sv = 1.0f;      // quad size (m)
  float u0 = 0.0f, v0 = 0.0f;      // texture offsets of the quad (m)
  float fw_s = 0.0f, fw_t = 0.0f;  // pixel footprint along s and t (m)
  Eigen::Vector3d p_in_world = Eigen::Vector3d::Zero();  // for the road markings
};

// Albedo (RGB in [0, 1]) of a material at a surface sample, band-limited to
// the pixel footprint. `markings` is used by Pattern::kAsphalt only.
Eigen::Vector3f ShadeSurface(const Material& material,
                             const SurfaceSample& sample,
                             const std::vector<Marking>& markings);

// Sky colour (RGB) for a world-frame viewing direction (only the direction
// matters: the sky is at infinity, zero disparity).
Eigen::Vector3f ShadeSky(const Eigen::Vector3d& dir_in_world, uint32_t seed);

}  // namespace twist::sim
