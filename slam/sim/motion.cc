#include "slam/sim/motion.h"

#include <glog/logging.h>

#include <algorithm>
#include <cmath>

namespace twist::sim {

Eigen::Matrix3d RotY(double angle) {
  const double c = std::cos(angle), s = std::sin(angle);
  Eigen::Matrix3d r;
  r << c, 0.0, s, 0.0, 1.0, 0.0, -s, 0.0, c;
  return r;
}

PlanarMotion::PlanarMotion(const PlanarState& start,
                           std::vector<PlanarSegment> segments,
                           double body_y)
    : start_(start), segments_(std::move(segments)), body_y_(body_y) {
  CHECK_GE(start.speed, 0.0);
  double t = 0.0, s = 0.0;
  PlanarState state = start;
  for (const PlanarSegment& seg : segments_) {
    CHECK_GE(seg.duration, 0.0);
    starts_.push_back({t, s, state});
    double ds = 0.0;
    state = Advance(state, seg, seg.duration, &ds);
    t += seg.duration;
    s += ds;
  }
  starts_.push_back({t, s, state});  // the open-ended straight tail
}

PlanarState PlanarMotion::Advance(const PlanarState& s,
                                  const PlanarSegment& seg,
                                  double dt,
                                  double* distance) {
  double ds, v_end;
  if (seg.accel < 0.0 && s.speed + seg.accel * dt < 0.0) {
    const double tau = s.speed / -seg.accel;
    ds = s.speed * tau + 0.5 * seg.accel * tau * tau;
    v_end = 0.0;
  } else {
    ds = s.speed * dt + 0.5 * seg.accel * dt * dt;
    v_end = s.speed + seg.accel * dt;
  }
  PlanarState out = s;
  out.speed = v_end;
  if (std::abs(seg.curvature) < 1e-12) {
    out.x += ds * std::sin(s.yaw);
    out.z += ds * std::cos(s.yaw);
  } else {
    const double yaw1 = s.yaw + seg.curvature * ds;
    out.x += (std::cos(s.yaw) - std::cos(yaw1)) / seg.curvature;
    out.z += (std::sin(yaw1) - std::sin(s.yaw)) / seg.curvature;
    out.yaw = yaw1;
  }
  if (distance != nullptr) *distance = ds;
  return out;
}

PlanarState PlanarMotion::StateAt(double t) const {
  if (t < 0.0) {
    const PlanarSegment straight{-t, 0.0, 0.0};
    PlanarState back = start_;
    back.yaw += M_PI;
    PlanarState s = Advance(back, straight, -t, nullptr);
    s.yaw = start_.yaw;
    return s;
  }
  // Last segment start with t0 <= t.
  size_t i = 0;
  while (i + 1 < starts_.size() && starts_[i + 1].t0 <= t) ++i;
  const PlanarSegment seg = i < segments_.size() ? segments_[i] : PlanarSegment{0.0, 0.0, 0.0};
  return Advance(starts_[i].state, seg, t - starts_[i].t0, nullptr);
}

double PlanarMotion::DistanceAt(double t) const {
  if (t <= 0.0) return 0.0;
  size_t i = 0;
  while (i + 1 < starts_.size() && starts_[i + 1].t0 <= t) ++i;
  const PlanarSegment seg = i < segments_.size() ? segments_[i] : PlanarSegment{0.0, 0.0, 0.0};
  double ds = 0.0;
  Advance(starts_[i].state, seg, t - starts_[i].t0, &ds);
  return starts_[i].s0 + ds;
}

geometry::SE3d PlanarMotion::PoseAt(double t, HeadingAxis axis) const {
  const PlanarState s = StateAt(t);
  const double angle = axis == HeadingAxis::kZ ? s.yaw : s.yaw - M_PI / 2.0;
  return geometry::SE3d(RotY(angle), Eigen::Vector3d(s.x, body_y_, s.z));
}

RevoluteMotion::RevoluteMotion(const geometry::SE3d& world_from_body_closed,
                               const Eigen::Vector3d& hinge_point,
                               const Eigen::Vector3d& hinge_axis,
                               double angle0,
                               double angle1,
                               double t0,
                               double t1)
    : world_from_body_closed_(world_from_body_closed),
      hinge_point_(hinge_point),
      hinge_axis_(hinge_axis.normalized()),
      angle0_(angle0),
      angle1_(angle1),
      t0_(t0),
      t1_(t1) {
  CHECK_GT(t1, t0);
}

double RevoluteMotion::AngleAt(double t) const {
  const double u = std::clamp((t - t0_) / (t1_ - t0_), 0.0, 1.0);
  const double smooth = u * u * (3.0 - 2.0 * u);
  return angle0_ + (angle1_ - angle0_) * smooth;
}

geometry::SE3d RevoluteMotion::PoseAt(double t) const {
  const Eigen::Matrix3d r = Eigen::AngleAxisd(AngleAt(t), hinge_axis_).toRotationMatrix();
  const geometry::SE3d about_hinge(r, hinge_point_ - r * hinge_point_);
  return about_hinge * world_from_body_closed_;
}

}  // namespace twist::sim
