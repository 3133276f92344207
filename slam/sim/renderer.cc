#include "slam/sim/renderer.h"

#include <glog/logging.h>

#include <algorithm>
#include <array>
#include <cmath>
#include <limits>
#include <opencv2/imgproc.hpp>
#include <thread>

#include "slam/sim/procedural.h"
#include "slam/sim/texture.h"

namespace twist::sim {
namespace {

// A quad in the camera frame with the constants of its ray intersection:
// for the ray d = (xn, yn, 1), depth z = c / (n·d), s = z (eu·d) - a_u,
// t = z (ev·d) - a_v.
struct CamQuad {
  Eigen::Vector3d p0, eu, ev, n;
  double su, sv;
  double c, a_u, a_v;
};

bool ToCamera(const Quad& q, const geometry::SE3d& camera_from_world, CamQuad* out) {
  const Eigen::Matrix3d r = camera_from_world.rotation();
  out->p0 = camera_from_world * q.origin;
  out->eu = r * q.axis_u;
  out->ev = r * q.axis_v;
  out->n = out->eu.cross(out->ev);
  out->su = q.size_u;
  out->sv = q.size_v;
  out->c = out->n.dot(out->p0);
  out->a_u = out->p0.dot(out->eu);
  out->a_v = out->p0.dot(out->ev);
  return out->c < -1e-12;  // the camera sees the front side
}

// Pixel bounding box [x0, x1] x [y0, y1] of a camera-frame quad clipped at z >= near.
bool PixelBounds(const CamQuad& q,
                 const geometry::StereoCamera& cam,
                 double near,
                 int* x0,
                 int* x1,
                 int* y0,
                 int* y1) {
  const std::array<Eigen::Vector3d, 4> corners = {
      q.p0, q.p0 + q.su * q.eu, q.p0 + q.su * q.eu + q.sv * q.ev, q.p0 + q.sv * q.ev};
  double umin = std::numeric_limits<double>::infinity(), umax = -umin, vmin = umin, vmax = -umin;
  int count = 0;
  auto add = [&](const Eigen::Vector3d& p) {
    const double u = cam.fx * p.x() / p.z() + cam.cx;
    const double v = cam.fy * p.y() / p.z() + cam.cy;
    umin = std::min(umin, u);
    umax = std::max(umax, u);
    vmin = std::min(vmin, v);
    vmax = std::max(vmax, v);
    ++count;
  };
  // Sutherland-Hodgman against the plane z = near (only vertices are needed).
  for (int i = 0; i < 4; ++i) {
    const Eigen::Vector3d& a = corners[i];
    const Eigen::Vector3d& b = corners[(i + 1) % 4];
    const bool ina = a.z() >= near, inb = b.z() >= near;
    if (ina) add(a);
    if (ina != inb) add(a + (b - a) * ((near - a.z()) / (b.z() - a.z())));
  }
  if (count == 0) return false;
  const double big = 1e7;
  *x0 = static_cast<int>(std::max(0.0, std::floor(std::max(-big, umin)) - 1.0));
  *x1 = static_cast<int>(std::min(cam.width - 1.0, std::ceil(std::min(big, umax)) + 1.0));
  *y0 = static_cast<int>(std::max(0.0, std::floor(std::max(-big, vmin)) - 1.0));
  *y1 = static_cast<int>(std::min(cam.height - 1.0, std::ceil(std::min(big, vmax)) + 1.0));
  return *x0 <= *x1 && *y0 <= *y1;
}

// Gaussian-like noise from one hash: the sum of its four bytes (Irwin-Hall),
// scaled to unit variance.
inline float HashNoise(uint32_t seed, uint32_t index) {
  const uint32_t h = procedural::Hash(seed ^ (index * 0x9e3779b9U));
  const int sum = static_cast<int>(h & 0xffU) + static_cast<int>((h >> 8) & 0xffU) +
                  static_cast<int>((h >> 16) & 0xffU) + static_cast<int>(h >> 24);
  // Mean 4·127.5, variance 4·(256² − 1)/12.
  return (static_cast<float>(sum) - 510.0f) * (1.0f / 147.8f);
}

// Shadow cast by a car onto the ground right below it (ambient occlusion).
struct GroundShadow {
  geometry::SE3d object_from_world;
  double half_l, half_w, radius_sq;
  Eigen::Vector3d center;
};

// Rasterises into buffers covering the pixel rectangle `roi` (stride = roi.width).
void RasterizeRegion(const std::vector<Quad>& quads,
                     const geometry::SE3d& world_from_camera,
                     const geometry::StereoCamera& cam,
                     double near,
                     const cv::Rect& roi,
                     float* depth_buf,
                     int32_t* id_buf) {
  const geometry::SE3d camera_from_world = world_from_camera.Inverse();
  std::vector<double> xn(roi.width);
  for (int x = 0; x < roi.width; ++x) xn[x] = (roi.x + x - cam.cx) / cam.fx;
  for (size_t i = 0; i < quads.size(); ++i) {
    CamQuad q;
    if (!ToCamera(quads[i], camera_from_world, &q)) continue;
    int x0, x1, y0, y1;
    if (!PixelBounds(q, cam, near, &x0, &x1, &y0, &y1)) continue;
    x0 = std::max(x0, roi.x) - roi.x;
    x1 = std::min(x1, roi.x + roi.width - 1) - roi.x;
    y0 = std::max(y0, roi.y);
    y1 = std::min(y1, roi.y + roi.height - 1);
    const int32_t id = static_cast<int32_t>(i);
    for (int y = y0; y <= y1; ++y) {
      const double yn = (y - cam.cy) / cam.fy;
      const double nd0 = q.n.y() * yn + q.n.z();
      const double du0 = q.eu.y() * yn + q.eu.z();
      const double dv0 = q.ev.y() * yn + q.ev.z();
      float* depth = depth_buf + static_cast<size_t>(y - roi.y) * roi.width;
      int32_t* ids = id_buf + static_cast<size_t>(y - roi.y) * roi.width;
      for (int x = x0; x <= x1; ++x) {
        const double nd = q.n.x() * xn[x] + nd0;
        if (nd >= 0.0) continue;
        const double z = q.c / nd;
        if (z < near || z >= depth[x]) continue;
        const double s = z * (q.eu.x() * xn[x] + du0) - q.a_u;
        if (s < 0.0 || s >= q.su) continue;
        const double t = z * (q.ev.x() * xn[x] + dv0) - q.a_v;
        if (t < 0.0 || t >= q.sv) continue;
        depth[x] = static_cast<float>(z);
        ids[x] = id;
      }
    }
  }
}

}  // namespace

geometry::SE3d RightFromLeftPose(const geometry::SE3d& world_from_left, double baseline) {
  return world_from_left *
         geometry::SE3d(Eigen::Matrix3d::Identity(), Eigen::Vector3d(baseline, 0, 0));
}

Renderer::Renderer(const geometry::StereoCamera& camera, const RenderOptions& options)
    : camera_(camera), options_(options) {
  CHECK(camera.Validate().ok()) << camera.Validate();
}

std::vector<Quad> Renderer::QuadsAt(const Scene& scene, double t) {
  return QuadsAt(scene, t, Eigen::Vector3d::Zero(), std::numeric_limits<double>::infinity());
}

std::vector<Quad> Renderer::QuadsAt(const Scene& scene,
                                    double t,
                                    const Eigen::Vector3d& centre,
                                    double radius) {
  std::vector<Quad> quads = scene.static_quads;
  for (const SceneObject& object : scene.objects) {
    const geometry::SE3d world_from_object = object.WorldFromObject(t);
    if ((world_from_object.translation() - centre).norm() > radius) continue;
    for (const BoxPart& part : object.parts) {
      AppendBoxQuads(part, world_from_object, object.panoptic(), &quads);
    }
  }
  return quads;
}

ViewBuffers Renderer::Rasterize(const std::vector<Quad>& quads,
                                const geometry::SE3d& world_from_camera) const {
  ViewBuffers out;
  Rasterize(quads, world_from_camera, &out);
  return out;
}

void Renderer::Rasterize(const std::vector<Quad>& quads,
                         const geometry::SE3d& world_from_camera,
                         ViewBuffers* out) const {
  const int w = camera_.width, h = camera_.height;
  out->depth.create(h, w, CV_32FC1);
  out->depth.setTo(cv::Scalar(std::numeric_limits<float>::infinity()));
  out->quad.create(h, w, CV_32SC1);
  out->quad.setTo(cv::Scalar(-1));
  RasterizeRegion(quads,
                  world_from_camera,
                  camera_,
                  options_.near_clip,
                  cv::Rect(0, 0, w, h),
                  out->depth.ptr<float>(),
                  out->quad.ptr<int32_t>());
}

int64_t Renderer::CountCoverage(const std::vector<Quad>& quads,
                                const geometry::SE3d& world_from_camera) const {
  // Union of the quads' pixel bounds, then a local z-buffer over it.
  const geometry::SE3d camera_from_world = world_from_camera.Inverse();
  int rx0 = camera_.width, ry0 = camera_.height, rx1 = -1, ry1 = -1;
  for (const Quad& quad : quads) {
    CamQuad q;
    if (!ToCamera(quad, camera_from_world, &q)) continue;
    int x0, x1, y0, y1;
    if (!PixelBounds(q, camera_, options_.near_clip, &x0, &x1, &y0, &y1)) continue;
    rx0 = std::min(rx0, x0);
    ry0 = std::min(ry0, y0);
    rx1 = std::max(rx1, x1);
    ry1 = std::max(ry1, y1);
  }
  if (rx1 < rx0 || ry1 < ry0) return 0;
  const cv::Rect roi(rx0, ry0, rx1 - rx0 + 1, ry1 - ry0 + 1);
  std::vector<float> depth(static_cast<size_t>(roi.area()), std::numeric_limits<float>::infinity());
  std::vector<int32_t> ids(static_cast<size_t>(roi.area()), -1);
  RasterizeRegion(
      quads, world_from_camera, camera_, options_.near_clip, roi, depth.data(), ids.data());
  return std::count_if(ids.begin(), ids.end(), [](int32_t v) { return v >= 0; });
}

cv::Mat Renderer::Shade(const Scene& scene,
                        double t,
                        const std::vector<Quad>& quads,
                        const geometry::SE3d& world_from_camera,
                        const ViewBuffers& buffers,
                        const Exposure& exposure) const {
  cv::Mat linear, out;
  Shade(scene, t, quads, world_from_camera, buffers, exposure, &linear, &out);
  return out;
}

void Renderer::Shade(const Scene& scene,
                     double t,
                     const std::vector<Quad>& quads,
                     const geometry::SE3d& world_from_camera,
                     const ViewBuffers& buffers,
                     const Exposure& exposure,
                     cv::Mat* linear_buffer,
                     cv::Mat* image) const {
  const int w = camera_.width, h = camera_.height;
  const geometry::SE3d camera_from_world = world_from_camera.Inverse();
  const Eigen::Matrix3d world_from_camera_r = world_from_camera.rotation();
  // Per-quad constants, computed lazily for the quads that were hit.
  std::vector<CamQuad> cam_quads(quads.size());
  std::vector<float> light(quads.size(), -1.0f);
  // Ground shadows of the cars.
  std::vector<GroundShadow> shadows;
  for (const SceneObject& object : scene.objects) {
    if (object.class_id != kClassCar) continue;
    const geometry::SE3d world_from_object = object.WorldFromObject(t);
    // Beyond ~150 m the shadow is less than a pixel tall.
    if ((world_from_object.translation() - world_from_camera.translation()).norm() > 150.0)
      continue;
    GroundShadow g;
    g.object_from_world = world_from_object.Inverse();
    g.half_l = 0.5 * object.l + 0.12;
    g.half_w = 0.5 * object.w + 0.12;
    g.radius_sq = g.half_l * g.half_l + g.half_w * g.half_w + 1.0;
    g.center = world_from_object.translation();
    shadows.push_back(g);
  }
  linear_buffer->create(h, w, CV_32FC3);
  cv::Mat& linear = *linear_buffer;
  for (int y = 0; y < h; ++y) {
    const double yn = (y - camera_.cy) / camera_.fy;
    const int32_t* ids = buffers.quad.ptr<int32_t>(y);
    cv::Vec3f* row = linear.ptr<cv::Vec3f>(y);
    for (int x = 0; x < w; ++x) {
      const double xn = (x - camera_.cx) / camera_.fx;
      const Eigen::Vector3d d(xn, yn, 1.0);
      Eigen::Vector3f c;
      const int32_t id = ids[x];
      if (id < 0) {
        c = ShadeSky(world_from_camera_r * d, scene.sky_seed);
      } else {
        const Quad& quad = quads[id];
        CamQuad& q = cam_quads[id];
        if (light[id] < 0.0f) {
          ToCamera(quad, camera_from_world, &q);
          const double lambert = std::max(0.0, quad.normal().dot(scene.sun_direction));
          light[id] = static_cast<float>(0.62 + 0.48 * lambert);
        }
        const double nd = q.n.dot(d);
        const double z = q.c / nd;
        const Eigen::Vector3d p = z * d;
        // dP/dx and dP/dy of the hit point for one pixel step.
        const Eigen::Vector3d ddx(1.0 / camera_.fx, 0.0, 0.0), ddy(0.0, 1.0 / camera_.fy, 0.0);
        const Eigen::Vector3d dpdx = z * (ddx - d * (q.n.dot(ddx) / nd));
        const Eigen::Vector3d dpdy = z * (ddy - d * (q.n.dot(ddy) / nd));
        SurfaceSample sample;
        sample.s = static_cast<float>(p.dot(q.eu) - q.a_u);
        sample.t = static_cast<float>(p.dot(q.ev) - q.a_v);
        sample.su = static_cast<float>(q.su);
        sample.sv = static_cast<float>(q.sv);
        sample.u0 = quad.tex_u0;
        sample.v0 = quad.tex_v0;
        sample.fw_s = static_cast<float>(std::abs(dpdx.dot(q.eu)) + std::abs(dpdy.dot(q.eu)));
        sample.fw_t = static_cast<float>(std::abs(dpdx.dot(q.ev)) + std::abs(dpdy.dot(q.ev)));
        sample.p_in_world = world_from_camera * p;
        const Material& material = scene.materials[quad.material];
        c = ShadeSurface(material, sample, scene.markings) * light[id];
        if (material.pattern == Pattern::kAsphalt || material.pattern == Pattern::kPaving) {
          const float fw = std::max(sample.fw_s, sample.fw_t);
          for (const GroundShadow& g : shadows) {
            if ((sample.p_in_world - g.center).squaredNorm() > g.radius_sq) continue;
            const Eigen::Vector3d o = g.object_from_world * sample.p_in_world;
            const float cover = procedural::FilteredBox(static_cast<float>(o.x()),
                                                        static_cast<float>(-g.half_l),
                                                        static_cast<float>(g.half_l),
                                                        2.0f * fw + 0.25f) *
                                procedural::FilteredBox(static_cast<float>(o.z()),
                                                        static_cast<float>(-g.half_w),
                                                        static_cast<float>(g.half_w),
                                                        2.0f * fw + 0.25f);
            c *= 1.0f - 0.6f * cover;
          }
        }
      }
      row[x] = cv::Vec3f(c.z(), c.y(), c.x());  // BGR
    }
  }
  if (options_.blur_sigma > 0.0) {
    cv::GaussianBlur(linear,
                     linear,
                     cv::Size(3, 3),
                     options_.blur_sigma,
                     options_.blur_sigma,
                     cv::BORDER_REPLICATE);
  }
  const float gain = static_cast<float>(255.0 * exposure.gain);
  const float offset = static_cast<float>(exposure.offset);
  const float sigma = static_cast<float>(options_.noise_sigma);
  image->create(h, w, options_.gray ? CV_8UC1 : CV_8UC3);
  cv::Mat& out = *image;
  for (int y = 0; y < h; ++y) {
    const cv::Vec3f* row = linear.ptr<cv::Vec3f>(y);
    uint8_t* dst = out.ptr<uint8_t>(y);
    for (int x = 0; x < w; ++x) {
      const uint32_t pixel = static_cast<uint32_t>(y * w + x);
      if (options_.gray) {
        const float v = 0.114f * row[x][0] + 0.587f * row[x][1] + 0.299f * row[x][2];
        const float n = sigma * HashNoise(exposure.noise_seed, pixel);
        dst[x] = cv::saturate_cast<uint8_t>(gain * v + offset + n);
      } else {
        for (int k = 0; k < 3; ++k) {
          const float n =
              sigma * HashNoise(exposure.noise_seed, pixel * 3u + static_cast<uint32_t>(k));
          dst[3 * x + k] = cv::saturate_cast<uint8_t>(gain * row[x][k] + offset + n);
        }
      }
    }
  }
}

StereoRender Renderer::RenderStereo(const Scene& scene,
                                    double t,
                                    const geometry::SE3d& world_from_left,
                                    const Exposure& left,
                                    const Exposure& right) const {
  RenderScratch scratch;
  StereoRender out;
  RenderStereo(scene, t, world_from_left, left, right, &scratch, &out);
  return out;
}

void Renderer::RenderStereo(const Scene& scene,
                            double t,
                            const geometry::SE3d& world_from_left,
                            const Exposure& left,
                            const Exposure& right,
                            RenderScratch* scratch,
                            StereoRender* out) const {
  const std::vector<Quad> quads =
      QuadsAt(scene, t, world_from_left.translation(), options_.object_draw_distance);
  const geometry::SE3d world_from_right = RightFromLeftPose(world_from_left, camera_.baseline);
  auto render_right = [&]() {
    Rasterize(quads, world_from_right, &scratch->right);
    Shade(scene,
          t,
          quads,
          world_from_right,
          scratch->right,
          right,
          &scratch->linear_right,
          &out->right);
  };
  std::thread worker;
  if (options_.num_threads >= 2) worker = std::thread(render_right);
  // The left depth is rasterised straight into the output.
  scratch->left.depth = out->depth;
  Rasterize(quads, world_from_left, &scratch->left);
  out->depth = scratch->left.depth;
  Shade(scene, t, quads, world_from_left, scratch->left, left, &scratch->linear_left, &out->left);
  const ViewBuffers& buffers = scratch->left;
  out->panoptic.create(camera_.height, camera_.width, CV_16UC1);
  for (int y = 0; y < camera_.height; ++y) {
    const int32_t* ids = buffers.quad.ptr<int32_t>(y);
    uint16_t* dst = out->panoptic.ptr<uint16_t>(y);
    for (int x = 0; x < camera_.width; ++x) {
      dst[x] = ids[x] < 0 ? PanopticId(kClassSky, 0) : quads[ids[x]].panoptic;
    }
  }
  if (worker.joinable()) {
    worker.join();
  } else {
    render_right();
  }
}

cv::Mat ShiftRightImage(const cv::Mat& right, double offset_px) {
  if (offset_px == 0.0 || right.empty()) return right;
  // dst(x, y) = src(x + offset, y): content moves left, u_right shrinks by
  // offset, the disparity u_left - u_right grows by it. Keys' cubic (a =
  // -0.5) with exact weights: cv::warpAffine would round the shift to 1/32 px.
  const int whole = static_cast<int>(std::floor(offset_px));
  const double f = offset_px - whole;
  auto keys = [](double t) {
    constexpr double a = -0.5;
    t = std::abs(t);
    if (t <= 1.0) return (a + 2.0) * t * t * t - (a + 3.0) * t * t + 1.0;
    if (t < 2.0) return a * t * t * t - 5.0 * a * t * t + 8.0 * a * t - 4.0 * a;
    return 0.0;
  };
  // filter2D correlates: dst(x) = sum_j kernel(j) src(x + j - anchor).
  const int anchor = std::abs(whole) + 1;
  cv::Mat kernel = cv::Mat::zeros(1, 2 * anchor + 3, CV_32F);
  for (int k = -1; k <= 2; ++k)
    kernel.at<float>(0, anchor + whole + k) = static_cast<float>(keys(f - k));
  cv::Mat out;
  cv::filter2D(right, out, -1, kernel, cv::Point(anchor, 0), 0.0, cv::BORDER_REPLICATE);
  return out;
}

}  // namespace twist::sim
