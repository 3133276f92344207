// CPU ray-caster of the synthetic generator: a z-buffer over textured planar
// quads. Geometry is exact: the pixel (u, v) with integer coordinates is the
// ray through the pixel centre (u, v) of the pinhole model of
// geometry::StereoCamera (u = fx·x/z + cx), and every pixel stores the depth and
// quad of the nearest hit, so a 3D point projects exactly where its surface
// is drawn. Shading is deferred (one texture evaluation per pixel) and
// band-limited to the pixel footprint (see procedural.h).
#pragma once

#include <cstdint>
#include <opencv2/core.hpp>
#include <vector>

#include "slam/geometry/se3.h"
#include "slam/geometry/stereo_camera.h"
#include "slam/sim/scene.h"

namespace twist::sim {

struct RenderOptions {
  bool gray = false;         // 8-bit gray instead of 8-bit BGR
  double noise_sigma = 1.5;  // sensor noise (grey levels, Gaussian-like)
  double blur_sigma = 0.5;   // optics PSF (pixels); 0 disables
  double near_clip = 0.1;    // metres
  int num_threads = 2;       // left and right are rendered in parallel
  // Objects farther than this from the camera are not drawn (a car there is
  // about 4 px long). No scenario puts objects that far from the camera
  // within its default length; long sequences stay fast.
  double object_draw_distance = 600.0;  // metres
};

// Per-eye photometric settings (exposure and noise stream).
struct Exposure {
  double gain = 1.0;
  double offset = 0.0;  // grey levels
  uint32_t noise_seed = 0;
};

// Result of rasterising one view.
struct ViewBuffers {
  cv::Mat depth;  // CV_32FC1, camera z (m), +inf where nothing was hit (sky)
  cv::Mat quad;   // CV_32SC1, index into the frame's quad list, -1 for sky
};

struct StereoRender {
  cv::Mat left, right;  // CV_8UC3 (BGR) or CV_8UC1
  cv::Mat panoptic;     // CV_16UC1, class*1000+instance of the left image
  cv::Mat depth;        // CV_32FC1, left camera z (m), +inf for sky
};

// Buffers reused from frame to frame by the scratch variant of
// Renderer::RenderStereo (saves allocating and faulting in ~20 MB per frame).
struct RenderScratch {
  ViewBuffers left, right;
  cv::Mat linear_left, linear_right;
};

class Renderer {
 public:
  Renderer(const geometry::StereoCamera& camera, const RenderOptions& options);

  // All quads of the scene at time t: the static ones and the objects' boxes
  // at their poses.
  static std::vector<Quad> QuadsAt(const Scene& scene, double t);
  // Same, leaving out the objects farther than `radius` from `centre`.
  static std::vector<Quad> QuadsAt(const Scene& scene,
                                   double t,
                                   const Eigen::Vector3d& centre,
                                   double radius);

  // Rasterises `quads` (world frame) seen from world_from_camera.
  ViewBuffers Rasterize(const std::vector<Quad>& quads,
                        const geometry::SE3d& world_from_camera) const;
  // Same into existing buffers (reallocated only when the size changes).
  void Rasterize(const std::vector<Quad>& quads,
                 const geometry::SE3d& world_from_camera,
                 ViewBuffers* out) const;

  // Number of pixels `quads` cover when drawn alone (no other occluders);
  // used for the occlusion level of the labels.
  int64_t CountCoverage(const std::vector<Quad>& quads,
                        const geometry::SE3d& world_from_camera) const;

  // Shades rasterised buffers into an 8-bit image with the given exposure
  // (t: scene time, for the objects' ground shadows).
  cv::Mat Shade(const Scene& scene,
                double t,
                const std::vector<Quad>& quads,
                const geometry::SE3d& world_from_camera,
                const ViewBuffers& buffers,
                const Exposure& exposure) const;
  // Same with a caller-owned float buffer and output image.
  void Shade(const Scene& scene,
             double t,
             const std::vector<Quad>& quads,
             const geometry::SE3d& world_from_camera,
             const ViewBuffers& buffers,
             const Exposure& exposure,
             cv::Mat* linear_buffer,
             cv::Mat* image) const;

  // Full stereo frame: left and right images, left panoptic mask and depth.
  // The right camera is at +baseline along the left camera's x axis.
  StereoRender RenderStereo(const Scene& scene,
                            double t,
                            const geometry::SE3d& world_from_left,
                            const Exposure& left,
                            const Exposure& right) const;
  // Same, reusing `scratch` and the Mats of `out` (which are overwritten in
  // place: Mats sharing their data with a previous `out` change too).
  void RenderStereo(const Scene& scene,
                    double t,
                    const geometry::SE3d& world_from_left,
                    const Exposure& left,
                    const Exposure& right,
                    RenderScratch* scratch,
                    StereoRender* out) const;

  const geometry::StereoCamera& camera() const { return camera_; }
  const RenderOptions& options() const { return options_; }

 private:
  geometry::StereoCamera camera_;
  RenderOptions options_;
};

// world_from_right = world_from_left · right_from_left⁻¹ (right camera at +b·x).
geometry::SE3d RightFromLeftPose(const geometry::SE3d& world_from_left, double baseline);

// A rendered right image moved left by `offset_px` (Keys' cubic, exact
// sub-pixel weights; the border replicated): disparities measured on it grow
// by `offset_px`, so a negative value gives the rendered rig a disparity
// offset like KITTI's (docs/math.md §21). Returns `right` itself for 0.
cv::Mat ShiftRightImage(const cv::Mat& right, double offset_px);

}  // namespace twist::sim
