// `twistslam plot --est OUTDIR [--dataset DIR --format F --seq SEQ] [--out DIR]`
// PNG pictures of a run (DESIGN.md §7), drawn with OpenCV:
//   topview.png  top view (x right, z forward/up) of the camera trajectory
//                (and ground truth), object trajectories with their ids, and
//                the map points of OUTDIR/points.ply or map.ply when present
//   speeds.png   speed over time of the moving objects (estimate from the
//                world twists of objects.txt; ground truth dashed)
#include <algorithm>
#include <cmath>
#include <iostream>
#include <map>
#include <opencv2/core.hpp>
#include <opencv2/imgcodecs.hpp>
#include <opencv2/imgproc.hpp>
#include <set>
#include <string>
#include <vector>

#include "client/cli_util.h"
#include "client/commands.h"
#include "slam/io/evaluation.h"
#include "slam/io/file_util.h"
#include "slam/io/ply.h"
#include "slam/io/sequence.h"
#include "slam/io/trajectory_io.h"

namespace twist::cli {
namespace {

using Polyline = std::vector<cv::Point2d>;

const cv::Scalar kWhite(255, 255, 255);
const cv::Scalar kBlack(0, 0, 0);
const cv::Scalar kGrid(228, 228, 228);
const cv::Scalar kAxis(90, 90, 90);
const cv::Scalar kEstCamera(200, 90, 20);  // blue (BGR)
const cv::Scalar kGtCamera(40, 160, 40);   // green
const cv::Scalar kPoints(150, 150, 150);
constexpr int kFont = cv::FONT_HERSHEY_SIMPLEX;

// A distinct, readable colour per id (golden-angle hue walk).
cv::Scalar ColourForId(int64_t id) {
  const double hue = std::fmod(static_cast<double>(id % 997) * 137.508, 360.0);
  cv::Mat hsv(1, 1, CV_8UC3, cv::Scalar(hue / 2.0, 220, 200));
  cv::Mat bgr;
  cv::cvtColor(hsv, bgr, cv::COLOR_HSV2BGR);
  const cv::Vec3b c = bgr.at<cv::Vec3b>(0, 0);
  return cv::Scalar(c[0], c[1], c[2]);
}

// 1, 2, 5 x 10^k step giving about `target` intervals over `range`.
double NiceStep(double range, int target) {
  if (!(range > 0)) return 1.0;
  const double raw = range / target;
  const double mag = std::pow(10.0, std::floor(std::log10(raw)));
  for (double m : {1.0, 2.0, 5.0, 10.0}) {
    if (m * mag >= raw) return m * mag;
  }
  return 10.0 * mag;
}

std::string TickText(double v, double step) {
  char buf[32];
  const int decimals = step >= 1.0 ? 0 : static_cast<int>(std::ceil(-std::log10(step)));
  std::snprintf(buf, sizeof(buf), "%.*f", decimals, std::abs(v) < step * 1e-6 ? 0.0 : v);
  return buf;
}

// Data -> pixel mapping of one plot area with axes, ticks and grid.
class Axes {
 public:
  // `right_margin` leaves room for a legend; `negate_y_ticks` labels the
  // vertical axis with −y (used when the vertical axis shows x growing down).
  Axes(cv::Size size,
       double x0,
       double x1,
       double y0,
       double y1,
       bool equal_aspect,
       int right_margin = 30,
       bool negate_y_ticks = false)
      : size_(size), negate_y_ticks_(negate_y_ticks) {
    area_ = cv::Rect(80, 50, size.width - 80 - right_margin, size.height - 50 - 60);
    if (!(x1 > x0)) {
      x0 -= 1;
      x1 += 1;
    }
    if (!(y1 > y0)) {
      y0 -= 1;
      y1 += 1;
    }
    if (equal_aspect) {
      // Same metres per pixel on both axes: grow the tighter range.
      const double sx = (x1 - x0) / area_.width;
      const double sy = (y1 - y0) / area_.height;
      const double s = std::max(sx, sy);
      const double cx = 0.5 * (x0 + x1), cy = 0.5 * (y0 + y1);
      x0 = cx - 0.5 * s * area_.width;
      x1 = cx + 0.5 * s * area_.width;
      y0 = cy - 0.5 * s * area_.height;
      y1 = cy + 0.5 * s * area_.height;
    }
    x0_ = x0;
    x1_ = x1;
    y0_ = y0;
    y1_ = y1;
  }

  cv::Point ToPixel(double x, double y) const {
    const double u = area_.x + (x - x0_) / (x1_ - x0_) * area_.width;
    const double v = area_.y + area_.height - (y - y0_) / (y1_ - y0_) * area_.height;
    return cv::Point(static_cast<int>(std::lround(u * 16)), static_cast<int>(std::lround(v * 16)));
  }
  bool Inside(double x, double y) const { return x >= x0_ && x <= x1_ && y >= y0_ && y <= y1_; }

  void DrawFrame(cv::Mat* img,
                 const std::string& title,
                 const std::string& xlabel,
                 const std::string& ylabel) const {
    const double xs = NiceStep(x1_ - x0_, 8);
    const double ys = NiceStep(y1_ - y0_, 6);
    for (double x = std::ceil(x0_ / xs) * xs; x <= x1_ + 1e-9; x += xs) {
      const int u = Pix(ToPixel(x, y0_).x);
      cv::line(*img, {u, area_.y}, {u, area_.y + area_.height}, kGrid, 1);
      const std::string t = TickText(x, xs);
      int base = 0;
      const cv::Size ts = cv::getTextSize(t, kFont, 0.45, 1, &base);
      cv::putText(*img,
                  t,
                  {u - ts.width / 2, area_.y + area_.height + 18},
                  kFont,
                  0.45,
                  kAxis,
                  1,
                  cv::LINE_AA);
    }
    for (double y = std::ceil(y0_ / ys) * ys; y <= y1_ + 1e-9; y += ys) {
      const int v = Pix(ToPixel(x0_, y).y);
      cv::line(*img, {area_.x, v}, {area_.x + area_.width, v}, kGrid, 1);
      const std::string t = TickText(negate_y_ticks_ ? -y : y, ys);
      int base = 0;
      const cv::Size ts = cv::getTextSize(t, kFont, 0.45, 1, &base);
      cv::putText(
          *img, t, {area_.x - ts.width - 6, v + ts.height / 2}, kFont, 0.45, kAxis, 1, cv::LINE_AA);
    }
    cv::rectangle(*img, area_, kAxis, 1);
    int base = 0;
    const cv::Size tt = cv::getTextSize(title, kFont, 0.65, 2, &base);
    cv::putText(
        *img, title, {(size_.width - tt.width) / 2, 30}, kFont, 0.65, kBlack, 2, cv::LINE_AA);
    const cv::Size xl = cv::getTextSize(xlabel, kFont, 0.5, 1, &base);
    cv::putText(*img,
                xlabel,
                {area_.x + (area_.width - xl.width) / 2, size_.height - 15},
                kFont,
                0.5,
                kBlack,
                1,
                cv::LINE_AA);
    // Vertical y label: draw horizontally on a strip and rotate it.
    const cv::Size yl = cv::getTextSize(ylabel, kFont, 0.5, 1, &base);
    cv::Mat strip(yl.height + base + 6, yl.width + 6, CV_8UC3, kWhite);
    cv::putText(strip, ylabel, {3, yl.height + 2}, kFont, 0.5, kBlack, 1, cv::LINE_AA);
    cv::Mat rotated;
    cv::rotate(strip, rotated, cv::ROTATE_90_COUNTERCLOCKWISE);
    const int top = std::max(0, area_.y + (area_.height - rotated.rows) / 2);
    if (top + rotated.rows <= img->rows && rotated.cols + 8 <= area_.x) {
      rotated.copyTo((*img)(cv::Rect(8, top, rotated.cols, rotated.rows)));
    }
  }

  // Polyline in data coordinates (sub-pixel, anti-aliased), optionally dashed.
  void DrawPolyline(cv::Mat* img,
                    const Polyline& pts,
                    const cv::Scalar& colour,
                    int thickness,
                    bool dashed = false) const {
    cv::Mat roi = (*img)(area_);
    const cv::Point offset(area_.x * 16, area_.y * 16);
    double run = 0;
    for (size_t i = 1; i < pts.size(); ++i) {
      const cv::Point a = ToPixel(pts[i - 1].x, pts[i - 1].y) - offset;
      const cv::Point b = ToPixel(pts[i].x, pts[i].y) - offset;
      if (dashed) {
        const double len = std::hypot(b.x - a.x, b.y - a.y) / 16.0;
        run += len;
        if (std::fmod(run, 14.0) > 8.0) continue;
      }
      cv::line(roi, a, b, colour, thickness, cv::LINE_AA, 4);
    }
  }
  void DrawDot(cv::Mat* img, double x, double y, const cv::Scalar& colour, int radius) const {
    if (!Inside(x, y)) return;
    cv::circle(*img, ToPixel(x, y), radius * 16, colour, cv::FILLED, cv::LINE_AA, 4);
  }
  void DrawLabel(
      cv::Mat* img, double x, double y, const std::string& text, const cv::Scalar& colour) const {
    if (!Inside(x, y)) return;
    const cv::Point p = ToPixel(x, y);
    const cv::Point at(Pix(p.x) + 5, Pix(p.y) - 5);
    cv::putText(*img, text, at, kFont, 0.45, kWhite, 3, cv::LINE_AA);
    cv::putText(*img, text, at, kFont, 0.45, colour, 1, cv::LINE_AA);
  }
  const cv::Rect& area() const { return area_; }

 private:
  static int Pix(int fixed) { return (fixed + 8) / 16; }
  cv::Size size_;
  bool negate_y_ticks_ = false;
  cv::Rect area_;
  double x0_ = 0, x1_ = 1, y0_ = 0, y1_ = 1;
};

struct LegendEntry {
  std::string text;
  cv::Scalar colour;
  bool dashed = false;
  bool dot = false;
};

void DrawLegend(cv::Mat* img, const cv::Rect& area, const std::vector<LegendEntry>& entries) {
  if (entries.empty()) return;
  int width = 0, base = 0;
  for (const LegendEntry& e : entries) {
    width = std::max(width, cv::getTextSize(e.text, kFont, 0.45, 1, &base).width);
  }
  const int row = 18;
  const cv::Rect box(
      area.x + area.width + 12, area.y, width + 50, static_cast<int>(entries.size()) * row + 8);
  cv::Mat roi = (*img)(box & cv::Rect(0, 0, img->cols, img->rows));
  cv::Mat white(roi.size(), roi.type(), kWhite);
  cv::addWeighted(roi, 0.15, white, 0.85, 0.0, roi);
  cv::rectangle(*img, box, kAxis, 1);
  for (size_t i = 0; i < entries.size(); ++i) {
    const int y = box.y + 12 + static_cast<int>(i) * row;
    const LegendEntry& e = entries[i];
    if (e.dot) {
      cv::circle(*img, {box.x + 20, y}, 3, e.colour, cv::FILLED, cv::LINE_AA);
    } else if (e.dashed) {
      cv::line(*img, {box.x + 6, y}, {box.x + 14, y}, e.colour, 2, cv::LINE_AA);
      cv::line(*img, {box.x + 22, y}, {box.x + 30, y}, e.colour, 2, cv::LINE_AA);
    } else {
      cv::line(*img, {box.x + 6, y}, {box.x + 34, y}, e.colour, 2, cv::LINE_AA);
    }
    cv::putText(*img, e.text, {box.x + 42, y + 5}, kFont, 0.45, kBlack, 1, cv::LINE_AA);
  }
}

bool WritePng(const std::string& path, const cv::Mat& img, std::string* error) {
  std::vector<uchar> buf;
  if (!cv::imencode(".png", img, buf)) {
    *error = "cannot encode " + path;
    return false;
  }
  return WriteFileAtomic(path, std::string(buf.begin(), buf.end()), error);
}

struct Inputs {
  std::vector<geometry::SE3d> est_camera;
  std::vector<int64_t> est_stamps_ns;  // from camera_tum.txt when present
  std::vector<io::ObjectTrackRow> est_objects;
  std::vector<io::PlyPoint> points;
  std::string points_file;
  std::vector<geometry::SE3d> gt_camera;
  std::vector<io::ObjectGtRow> gt_objects;
  std::vector<int64_t> stamps_ns;  // dataset times
};

// Key that gives matched estimate/ground truth the same colour.
int64_t ColourKey(const io::ObjectTrackRow& r) {
  return r.instance_id >= 0 ? r.instance_id : r.track_id;
}

cv::Mat DrawTopView(const Inputs& in, const std::string& title) {
  // Bounds from trajectories (points may extend far; they do not widen the view
  // beyond 15 m around the trajectories).
  double x0 = 1e18, x1 = -1e18, z0 = 1e18, z1 = -1e18;
  auto grow = [&](const Eigen::Vector3d& p) {
    x0 = std::min(x0, p.x());
    x1 = std::max(x1, p.x());
    z0 = std::min(z0, p.z());
    z1 = std::max(z1, p.z());
  };
  for (const auto& p : in.est_camera) grow(p.translation());
  for (const auto& p : in.gt_camera) grow(p.translation());
  for (const auto& r : in.est_objects) grow(r.world_from_object.translation());
  for (const auto& r : in.gt_objects) grow(r.world_from_object.translation());
  if (x0 > x1) x0 = -10, x1 = 10, z0 = -10, z1 = 10;
  const double pad = std::max(3.0, 0.05 * std::max(x1 - x0, z1 - z0));
  x0 -= pad, x1 += pad, z0 -= pad, z1 += pad;
  // Long forward runs are drawn with z to the right and x downwards (still
  // seen from above, not mirrored); otherwise x right and z up.
  const bool forward_right = (z1 - z0) > 1.5 * (x1 - x0);
  const double h0 = forward_right ? z0 : x0, h1 = forward_right ? z1 : x1;
  const double v0 = forward_right ? -x1 : z0, v1 = forward_right ? -x0 : z1;
  // Fit the canvas to the data's aspect ratio (equal scale on both axes).
  const int legend_width = 330;
  const int plot_w = 1500 - 80 - legend_width;
  const int plot_h = std::clamp(static_cast<int>(plot_w * (v1 - v0) / (h1 - h0)), 360, 1000);
  const cv::Size size(1500, plot_h + 110);
  cv::Mat img(size, CV_8UC3, kWhite);
  Axes axes(size, h0, h1, v0, v1, /*equal_aspect=*/true, legend_width, forward_right);
  // Data point (x, z) -> plot coordinates.
  auto H = [&](double x, double z) { return forward_right ? z : x; };
  auto V = [&](double x, double z) { return forward_right ? -x : z; };
  if (forward_right) {
    axes.DrawFrame(&img, title, "z (m, forward)", "x (m, right; grows downwards)");
  } else {
    axes.DrawFrame(&img, title, "x (m, right)", "z (m, forward)");
  }

  std::vector<LegendEntry> legend;
  if (!in.points.empty()) {
    int drawn = 0;
    for (const io::PlyPoint& p : in.points) {
      const double h = H(p.p_in_world.x(), p.p_in_world.z());
      const double v = V(p.p_in_world.x(), p.p_in_world.z());
      if (!axes.Inside(h, v)) continue;
      const cv::Point q = axes.ToPixel(h, v);
      const cv::Point c((q.x + 8) / 16, (q.y + 8) / 16);
      if (c.inside(axes.area())) {
        cv::rectangle(img, cv::Rect(c.x, c.y, 2, 2) & axes.area(), kPoints, cv::FILLED);
        ++drawn;
      }
    }
    legend.push_back({"map points (" + std::to_string(drawn) + ", " + in.points_file + ")",
                      kPoints,
                      false,
                      true});
  }
  // Ground-truth objects: thin dashed in their id colour.
  std::map<int64_t, Polyline> gt_tracks;
  for (const auto& r : in.gt_objects) {
    const Eigen::Vector3d& t = r.world_from_object.translation();
    gt_tracks[r.track_id].push_back({H(t.x(), t.z()), V(t.x(), t.z())});
  }
  for (const auto& [id, line] : gt_tracks) {
    axes.DrawPolyline(&img, line, ColourForId(id), 1, /*dashed=*/true);
    if (line.size() == 1) axes.DrawDot(&img, line[0].x, line[0].y, ColourForId(id), 2);
  }
  // Estimated objects: solid, labelled with the track id at the end.
  std::map<int64_t, Polyline> est_tracks;
  std::map<int64_t, int64_t> est_key;
  for (const auto& r : in.est_objects) {
    const Eigen::Vector3d& t = r.world_from_object.translation();
    est_tracks[r.track_id].push_back({H(t.x(), t.z()), V(t.x(), t.z())});
    est_key[r.track_id] = ColourKey(r);
  }
  for (const auto& [id, line] : est_tracks) {
    const cv::Scalar c = ColourForId(est_key[id]);
    axes.DrawPolyline(&img, line, c, 2);
    axes.DrawDot(&img, line.back().x, line.back().y, c, 3);
    axes.DrawLabel(&img, line.back().x, line.back().y, "#" + std::to_string(id), c);
  }
  if (!in.est_camera.empty()) {
    Polyline line;
    for (const auto& p : in.est_camera) {
      line.push_back({H(p.translation().x(), p.translation().z()),
                      V(p.translation().x(), p.translation().z())});
    }
    axes.DrawPolyline(&img, line, kEstCamera, 2);
    axes.DrawDot(&img, line.front().x, line.front().y, kEstCamera, 4);
    axes.DrawLabel(&img, line.front().x, line.front().y, "start", kEstCamera);
    legend.push_back({"camera, estimate", kEstCamera});
  }
  if (!in.gt_camera.empty()) {
    Polyline line;
    for (const auto& p : in.gt_camera) {
      line.push_back({H(p.translation().x(), p.translation().z()),
                      V(p.translation().x(), p.translation().z())});
    }
    axes.DrawPolyline(&img, line, kGtCamera, 2, /*dashed=*/true);  // on top, dashed
    legend.push_back({"camera, ground truth", kGtCamera, true});
  }

  if (!est_tracks.empty()) {
    legend.push_back({"objects, estimate (#track id)", cv::Scalar(60, 60, 60)});
  }
  if (!gt_tracks.empty()) {
    legend.push_back({"objects, ground truth", cv::Scalar(60, 60, 60), true});
  }
  DrawLegend(&img, axes.area(), legend);
  return img;
}

double TimeOf(const Inputs& in, int64_t frame) {
  if (frame >= 0 && frame < static_cast<int64_t>(in.stamps_ns.size())) {
    return io::NsToSeconds(in.stamps_ns[frame] - in.stamps_ns[0]);
  }
  if (frame >= 0 && frame < static_cast<int64_t>(in.est_stamps_ns.size())) {
    return io::NsToSeconds(in.est_stamps_ns[frame] - in.est_stamps_ns[0]);
  }
  return 0.1 * static_cast<double>(frame);
}

cv::Mat DrawSpeeds(const Inputs& in, const std::string& title, int max_objects) {
  const cv::Size size(1500, 700);
  cv::Mat img(size, CV_8UC3, kWhite);
  // Estimated speeds: |v + ω × t| of the object origin from the world twist.
  std::map<int64_t, Polyline> est;
  std::map<int64_t, int64_t> key;
  for (const auto& r : in.est_objects) {
    const Eigen::Vector3d v = r.twist_in_world.head<3>() +
                              r.twist_in_world.tail<3>().cross(r.world_from_object.translation());
    est[r.track_id].push_back({TimeOf(in, r.frame), v.norm() * 3.6});
    key[r.track_id] = ColourKey(r);
  }
  // Ground-truth speeds by finite differences over consecutive frames.
  std::map<int64_t, std::map<int64_t, Eigen::Vector3d>> gt_pos;
  for (const auto& r : in.gt_objects)
    gt_pos[r.track_id][r.frame] = r.world_from_object.translation();
  std::map<int64_t, Polyline> gt;
  for (const auto& [id, frames] : gt_pos) {
    for (const auto& [f, p] : frames) {
      auto prev = frames.find(f - 1);
      if (prev == frames.end()) continue;
      const double dt = TimeOf(in, f) - TimeOf(in, f - 1);
      if (!(dt > 0)) continue;
      gt[id].push_back({TimeOf(in, f), (p - prev->second).norm() / dt * 3.6});
    }
  }
  // Choose the objects to show: moving ones (peak > 2 km/h), longest first.
  auto peak = [](const Polyline& l) {
    double m = 0;
    for (const auto& p : l) m = std::max(m, p.y);
    return m;
  };
  std::vector<std::pair<size_t, int64_t>> est_order, gt_order;
  for (const auto& [id, l] : est) {
    if (l.size() >= 2 && peak(l) > 2.0) est_order.push_back({l.size(), id});
  }
  for (const auto& [id, l] : gt) {
    if (l.size() >= 2 && peak(l) > 2.0) gt_order.push_back({l.size(), id});
  }
  std::sort(est_order.rbegin(), est_order.rend());
  std::sort(gt_order.rbegin(), gt_order.rend());
  std::set<int64_t> shown_keys;
  std::vector<int64_t> est_shown, gt_shown;
  for (const auto& [n, id] : est_order) {
    if (static_cast<int>(est_shown.size()) >= max_objects) break;
    est_shown.push_back(id);
    shown_keys.insert(key[id]);
  }
  for (const auto& [n, id] : gt_order) {
    const bool matched = shown_keys.count(id) > 0;
    if (matched || static_cast<int>(est_shown.size() + gt_shown.size()) < max_objects) {
      gt_shown.push_back(id);
    }
  }
  // Time axis spans the whole run.
  double t1 = std::max(1.0, TimeOf(in, static_cast<int64_t>(in.est_camera.size()) - 1));
  double v1 = 10.0;
  for (int64_t id : est_shown) {
    for (const auto& p : est[id]) t1 = std::max(t1, p.x), v1 = std::max(v1, p.y);
  }
  for (int64_t id : gt_shown) {
    for (const auto& p : gt[id]) t1 = std::max(t1, p.x), v1 = std::max(v1, p.y);
  }
  Axes axes(size, 0.0, t1 * 1.04, 0.0, v1 * 1.1, /*equal_aspect=*/false, /*right_margin=*/330);
  axes.DrawFrame(&img, title, "time (s)", "speed (km/h)");
  std::vector<LegendEntry> legend;
  for (int64_t id : gt_shown) {
    axes.DrawPolyline(&img, gt[id], ColourForId(id), 1, /*dashed=*/true);
  }
  for (int64_t id : est_shown) {
    const cv::Scalar c = ColourForId(key[id]);
    axes.DrawPolyline(&img, est[id], c, 2);
    const cv::Point2d end = est[id].back();
    axes.DrawLabel(&img, end.x, end.y, "#" + std::to_string(id), c);
    legend.push_back(
        {"track #" + std::to_string(id) + " (instance " + std::to_string(key[id]) + ")", c});
  }
  for (int64_t id : gt_shown) {
    if (shown_keys.count(id)) continue;
    legend.push_back(
        {"instance " + std::to_string(id) + " (ground truth only)", ColourForId(id), true});
  }
  if (!est_shown.empty()) legend.push_back({"solid: estimate", cv::Scalar(60, 60, 60)});
  if (!gt_shown.empty()) legend.push_back({"dashed: ground truth", cv::Scalar(60, 60, 60), true});
  if (est_shown.empty() && gt_shown.empty()) {
    cv::putText(img,
                "no moving object",
                {axes.area().x + 20, axes.area().y + 40},
                kFont,
                0.7,
                kAxis,
                1,
                cv::LINE_AA);
  }
  DrawLegend(&img, axes.area(), legend);
  return img;
}

}  // namespace

int PlotCommand(int argc, char** argv) {
  ArgParser parser("plot");
  parser.AddValue("est", "OUTDIR", "output directory of `twistslam run`")
      .AddValue("dataset", "DIR", "dataset root, to draw the ground truth", /*required=*/false)
      .AddValue("format", "FORMAT", "kitti-odometry or kitti-tracking (with --dataset)", false)
      .AddValue("seq", "SEQ", "sequence name (with --dataset)", false)
      .AddValue("out", "DIR", "where to write the PNGs", false, "OUTDIR")
      .AddValue("max-objects", "N", "objects in the speed plot", false, "10");
  std::optional<Args> args = parser.Parse(argc, argv);
  if (!args) return parser.exit_code();
  const bool with_gt = args->Has("dataset") || args->Has("format") || args->Has("seq");
  if (with_gt && !(args->Has("dataset") && args->Has("format") && args->Has("seq"))) {
    return Fail("plot", "--dataset, --format and --seq go together", 2);
  }
  const std::optional<int64_t> max_objects = args->GetInt("max-objects", 10);
  if (!max_objects || *max_objects < 1 || *max_objects > 50) {
    return Fail("plot", "--max-objects must be an integer in [1, 50]", 2);
  }
  const std::string est_dir = args->Get("est");
  const std::string out_dir = args->Get("out", est_dir);
  if (!io::DirExists(est_dir)) return Fail("plot", est_dir + ": no such output directory");

  Inputs in;
  const std::string camera_path = io::JoinPath(est_dir, "camera.txt");
  const std::string tum_path = io::JoinPath(est_dir, "camera_tum.txt");
  if (io::FileExists(tum_path)) {
    auto tum = io::ReadTumTrajectory(tum_path);
    if (!tum.ok()) return Fail("plot", std::string(tum.status().message()));
    for (const auto& p : *tum) in.est_stamps_ns.push_back(p.timestamp_ns);
    if (!io::FileExists(camera_path)) {
      for (const auto& p : *tum) in.est_camera.push_back(p.world_from_camera);
    }
  }
  if (io::FileExists(camera_path)) {
    auto cam = io::ReadKittiPoses(camera_path);
    if (!cam.ok()) return Fail("plot", std::string(cam.status().message()));
    in.est_camera = std::move(*cam);
  }
  if (in.est_camera.empty()) {
    return Fail("plot", camera_path + ": no such file (nor camera_tum.txt)");
  }
  const std::string objects_path = io::JoinPath(est_dir, "objects.txt");
  if (io::FileExists(objects_path)) {
    auto objects = io::ReadObjectTracks(objects_path);
    if (!objects.ok()) return Fail("plot", std::string(objects.status().message()));
    in.est_objects = std::move(*objects);
  }
  for (const char* name : {"points.ply", "map.ply"}) {
    const std::string path = io::JoinPath(est_dir, name);
    if (!io::FileExists(path)) continue;
    auto points = io::ReadPlyPoints(path);
    if (!points.ok()) return Fail("plot", std::string(points.status().message()));
    in.points = std::move(*points);
    in.points_file = name;
    break;
  }
  std::string title = "run " + est_dir;
  if (with_gt) {
    auto seq = io::OpenSequence(args->Get("dataset"), args->Get("format"), args->Get("seq"));
    if (!seq.ok()) return Fail("plot", std::string(seq.status().message()));
    in.gt_camera = (*seq)->gt_world_from_camera();
    in.gt_objects = (*seq)->gt_objects();
    if (!(*seq)->has_gt_objects() && (*seq)->has_labels() && (*seq)->has_gt_poses() &&
        (*seq)->tracking_calib()) {
      in.gt_objects = io::ObjectsGtFromLabels((*seq)->labels(),
                                              (*seq)->gt_world_from_camera(),
                                              (*seq)->tracking_calib()->left_from_ref_translation);
    }
    in.stamps_ns = (*seq)->timestamps_ns();
    title += "  vs  " + args->Get("format") + " " + (*seq)->sequence();
  }

  std::string error;
  if (!MakeDirs(out_dir, &error)) return Fail("plot", error);
  const std::string top_path = io::JoinPath(out_dir, "topview.png");
  const std::string speed_path = io::JoinPath(out_dir, "speeds.png");
  if (!WritePng(top_path, DrawTopView(in, "Top view: " + title), &error))
    return Fail("plot", error);
  if (!WritePng(speed_path,
                DrawSpeeds(in, "Object speeds: " + title, static_cast<int>(*max_objects)),
                &error)) {
    return Fail("plot", error);
  }
  std::cout << "wrote " << top_path << " and " << speed_path << "\n";
  return 0;
}

}  // namespace twist::cli
