// Ground truth derived from a rendered frame's depth buffer, for measuring
// the stereo matcher against exact disparities (bench/engine/disparity_bias,
// tests/slam/features/stereo_bias_test).
#pragma once

#include <opencv2/core.hpp>
#include <optional>

#include "slam/common/stereo_frame.h"
#include "slam/sim/renderer.h"
#include "slam/sim/scenarios.h"

namespace twist::sim {

// Disparity bf / z as an affine function of the image position around a
// point: d(x', y') = disparity + gx (x' − x) + gy (y' − y).
struct PlanarDisparityFit {
  double disparity = 0.0;  // at (x, y), level-0 pixels
  double gx = 0.0;         // ∂d/∂x
  double gy = 0.0;         // ∂d/∂y
};

// The true disparity at (x, y) (level-0 pixels) when the depth buffer seen
// through the window of half-size `half_window` around it lies on one plane,
// i.e. the disparity is affine over the window to `max_residual_px`;
// nullopt near the image border, on sky, or across a depth discontinuity or
// a curved surface (where a block matcher has no single true disparity).
std::optional<PlanarDisparityFit> PlanarDisparity(const cv::Mat& depth,
                                                  double bf,
                                                  double x,
                                                  double y,
                                                  int half_window,
                                                  double max_residual_px = 0.02);

// Frame `frame` of a scenario rendered with that frame's exposures, exactly
// as `twistslam generate` writes it.
StereoRender RenderScenarioFrame(const Renderer& renderer, const Scenario& scenario, int frame);

// The engine's input for frame `frame` of `scenario` rendered as `render`:
// index, timestamp (the frame's time in ns, + 1 µs: the convention of the
// rendered clips of the tests and benchmarks), left, right and panoptic.
StereoFrame ScenarioStereoFrame(const Scenario& scenario, int frame, const StereoRender& render);

}  // namespace twist::sim
