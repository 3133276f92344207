#include "slam/sim/depth_truth.h"

#include <Eigen/Dense>
#include <algorithm>
#include <cmath>
#include <vector>

#include "slam/sim/writer.h"

namespace twist::sim {

std::optional<PlanarDisparityFit> PlanarDisparity(
    const cv::Mat& depth, double bf, double x, double y, int half_window, double max_residual_px) {
  const int r = half_window;
  const int cx = static_cast<int>(std::lround(x));
  const int cy = static_cast<int>(std::lround(y));
  if (cx - r < 0 || cy - r < 0 || cx + r >= depth.cols || cy + r >= depth.rows) return std::nullopt;
  // A 9×9 (or denser for small windows) sample of the window.
  const int step = std::max(1, r / 4);
  const int per_side = 2 * r / step + 1;
  Eigen::MatrixX3d a(per_side * per_side, 3);
  Eigen::VectorXd b(per_side * per_side);
  int n = 0;
  for (int dy = -r; dy <= r; dy += step) {
    for (int dx = -r; dx <= r; dx += step) {
      const float z = depth.at<float>(cy + dy, cx + dx);
      if (!std::isfinite(z) || z <= 0.f) return std::nullopt;
      a.row(n) << cx + dx - x, cy + dy - y, 1.0;
      b(n) = bf / z;
      ++n;
    }
  }
  a.conservativeResize(n, 3);
  b.conservativeResize(n);
  const Eigen::Vector3d p = a.colPivHouseholderQr().solve(b);
  if ((a * p - b).cwiseAbs().maxCoeff() > max_residual_px) return std::nullopt;
  return PlanarDisparityFit{p(2), p(0), p(1)};
}

StereoRender RenderScenarioFrame(const Renderer& renderer, const Scenario& scenario, int frame) {
  Exposure left, right;
  FrameExposures(scenario, frame, &left, &right);
  return renderer.RenderStereo(
      scenario.scene, scenario.TimeOf(frame), scenario.WorldFromCamera(frame), left, right);
}

StereoFrame ScenarioStereoFrame(const Scenario& scenario, int frame, const StereoRender& render) {
  StereoFrame f;
  f.index = frame;
  f.timestamp_ns = static_cast<int64_t>(std::llround(scenario.TimeOf(frame) * 1e9)) + 1000;
  f.left = render.left;
  f.right = render.right;
  f.panoptic = render.panoptic;
  return f;
}

}  // namespace twist::sim
