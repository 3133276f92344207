// A synthetic car sequence for the object tracker tests and benchmark: a car
// driving on the road (planar joint) seen by a camera moving forward, with
// exact ground truth. Keypoints are the projections of the car's points (plus
// optional noise) with a fixed random descriptor per point, and the client's
// dense flow carries the exact displacement of every point. A keypoint's
// noise moves its right-image u with it, and its disparity has a noise of its
// own, kDisparityNoiseRatio times the keypoint's: the ratio the tracker
// assumes (disparity_sigma_px 0.3 px on level 0 to the twist estimator's
// floor on a keypoint's position, min_sigma_px 0.7 px).
#pragma once

#include <cmath>
#include <opencv2/core.hpp>
#include <random>
#include <vector>

#include "slam/objects/joint_frames.h"
#include "slam/objects/object_tracker.h"
#include "slam/semantic/plane_fitting.h"
#include "tests/slam/objects/synthetic_objects.h"

namespace twist::objects::testing {

inline const double kDisparityNoiseRatio =
    ObjectTrackerOptions{}.disparity_sigma_px / TwistEstimatorOptions{}.min_sigma_px;

class CarSequence {
 public:
  CarSequence(double noise_px,
              uint64_t seed,
              double lateral_m = 3.0,
              int num_points = 60,
              double depth_m = 14.0)
      : noise_(noise_px), rng_(seed) {
    cam_ = KittiLikeCamera();
    road_ = semantic::NormalizePlane(Eigen::Vector4d(0, -1, 0, 1.65));
    world_from_joint_ = RoadJointFrame(Eigen::Vector3d(lateral_m, 0, depth_m));
    world_from_object_ = world_from_joint_;
    Vector6d twist_in_joint;  // per frame (10 Hz): 8 m/s forward, turning
    twist_in_joint << 0.05, 0.8, 0, 0, 0, 0.02;
    step_ = world_from_joint_.Adjoint() * twist_in_joint;
    points_ = CarPoints(num_points, &rng_);
    std::uniform_int_distribution<int> byte(0, 255);
    for (size_t k = 0; k < points_.size(); ++k) {
      cv::Mat d(1, 32, CV_8UC1);
      for (int b = 0; b < 32; ++b) d.at<uint8_t>(0, b) = static_cast<uint8_t>(byte(rng_));
      descriptors_.push_back(d);
    }
  }

  const geometry::StereoCamera& camera() const { return cam_; }
  const std::vector<Eigen::Vector3d>& points() const { return points_; }
  const SE3d& world_from_object() const { return world_from_object_; }
  const Vector6d& step() const { return step_; }
  // The car's motion per frame in the world (zero: a parked car).
  void set_step(const Vector6d& step) { step_ = step; }
  // The world step of the car, from its pose now, that moves it `forward_m`
  // along its length and turns it by `turn_rad` about its vertical axis per
  // frame (the joint's axes in the car's frame).
  Vector6d CarStep(double forward_m, double turn_rad) const {
    Vector6d in_car;
    in_car << 0.0, forward_m, 0.0, 0.0, 0.0, turn_rad;
    return world_from_object_.Adjoint() * in_car;
  }
  // Turns the car about its vertical axis by `rad` before the first frame
  // (0: its length along the road, world z).
  void set_heading(double rad) {
    world_from_object_ = world_from_joint_ * SE3d(geometry::SO3d::Exp(Eigen::Vector3d(0, 0, rad)),
                                                  Eigen::Vector3d::Zero());
  }
  // The dense flow covers this many more pixels around each point's previous
  // true projection (0: its 2 x 2 block), so that a noisy keypoint still
  // finds its point's flow.
  void set_flow_reach(int pixels) { flow_reach_ = pixels; }
  // Added to every vector of the dense flow: a tracker that chains flow from
  // frame to frame drifts by this much per frame.
  void set_flow_bias(const Eigen::Vector2d& bias_px) { flow_bias_ = bias_px; }
  // A failed measurement: until reset to the identity, the keypoints, the
  // flow and the box show the car at world_offset · (true pose), as when the
  // flow and matches lock onto an occluder; the truth is unchanged.
  void set_measurement_glitch(const SE3d& world_offset) { glitch_ = world_offset; }
  // Only the first n points are seen (keypoints and flow; 0: all), as when
  // the car is mostly occluded.
  // Gaussian noise of this σ added to the keypoints (uv and u_right) on top
  // of noise_px, as when most matches are wrong.
  void set_extra_noise_px(double sigma_px) { extra_noise_ = sigma_px; }
  // u_right's noise drawn independently of u's, with the same σ (the model
  // of the tests written before ObjectTrackerOptions::step_disparity_noise).
  void set_independent_right_noise(bool independent) { independent_right_noise_ = independent; }
  void set_shown_points(size_t n) { set_shown_range(0, n); }
  // The camera's height estimate drifts by this much per frame (world y):
  // the tracker gets the drifting pose, and the road plane as that camera
  // sees it (shifted with it), as a SLAM camera's road plane fitted on its
  // own recent points is. The images are the true ones.
  void set_camera_height_drift(double m_per_frame) { height_drift_ = m_per_frame; }
  // The road plane handed with each detection is tilted by this angle,
  // about the world x axis on even frames and about z on odd ones, as a
  // refitted plane's normal jitters (the car still drives on the true road).
  void set_road_normal_jitter(double rad) { normal_jitter_ = rad; }
  // Camera pose the tracker was given for the last frame (see above).
  const SE3d& camera_from_world_given() const { return camera_from_world_given_; }
  // True camera pose of the last frame.
  const SE3d& camera_from_world_true() const { return camera_from_world_true_; }
  // Only points [begin, end) are seen (end 0: all), as when the camera comes
  // to see other faces of the car.
  void set_shown_range(size_t begin, size_t end) {
    shown_begin_ = begin;
    shown_ = end;
  }

  // Frame i (advances the truth by one step after frame 0).
  ObjectFrameInput Next(int64_t cluster_id, bool detected) {
    if (index_ > 0) world_from_object_ = SE3d::Exp(step_) * world_from_object_;
    const SE3d world_from_camera(geometry::SO3d(), Eigen::Vector3d(0, 0, 0.6 * index_));
    ObjectFrameInput f;
    f.frame_index = index_;
    f.timestamp_ns = 1'000'000'000 + index_ * 100'000'000;
    f.camera_from_world = world_from_camera.Inverse();
    f.left = cv::Mat(cam_.height, cam_.width, CV_8UC1, cv::Scalar(100));
    f.flow = cv::Mat(cam_.height, cam_.width, CV_32FC2, cv::Scalar(0, 0));
    std::normal_distribution<double> g(0.0, noise_ > 0 ? noise_ : 1.0);
    const SE3d camera_from_object = f.camera_from_world * glitch_ * world_from_object_;
    double x0 = 1e9, y0 = 1e9, x1 = -1e9, y1 = -1e9;
    f.keypoints.descriptors = cv::Mat(0, 32, CV_8UC1);
    std::vector<Eigen::Vector2d> true_uv(points_.size());
    for (size_t k = 0; k < points_.size(); ++k) {
      const Eigen::Vector3d uvr =
          cam_.ProjectStereo(Eigen::Vector3d(camera_from_object * points_[k]));
      true_uv[k] = uvr.head<2>();
      if (!detected || !Shown(k)) continue;
      Eigen::Vector2d uv = uvr.head<2>();
      double ur = uvr.z();
      if (noise_ > 0) {
        uv += Eigen::Vector2d(g(rng_), g(rng_));
        // The disparity is measured where the keypoint was found: u_right
        // moves with u, plus the disparity's own noise.
        ur += independent_right_noise_ ? g(rng_)
                                       : (uv.x() - uvr.x()) + g(rng_) * kDisparityNoiseRatio;
      }
      if (extra_noise_ > 0) {
        std::normal_distribution<double> e(0.0, extra_noise_);
        uv += Eigen::Vector2d(e(rng_), e(rng_));
        ur += e(rng_);
      }
      f.keypoints.uv.push_back(uv);
      f.keypoints.u_right.push_back(ur);
      f.keypoints.descriptors.push_back(descriptors_[k]);
      x0 = std::min(x0, uv.x());
      y0 = std::min(y0, uv.y());
      x1 = std::max(x1, uv.x());
      y1 = std::max(y1, uv.y());
    }
    // Exact dense flow around the previous true projections (pixels claimed by
    // two points get NaN: no flow there).
    if (!prev_uv_.empty()) {
      cv::Mat owner(cam_.height, cam_.width, CV_32SC1, cv::Scalar(-1));
      for (size_t k = 0; k < points_.size(); ++k) {
        const bool hidden = !Shown(k);  // no flow (NaN) there
        const Eigen::Vector2d d = hidden ? Eigen::Vector2d(NAN, NAN)
                                         : Eigen::Vector2d(true_uv[k] - prev_uv_[k] + flow_bias_);
        const int px = static_cast<int>(std::floor(prev_uv_[k].x()));
        const int py = static_cast<int>(std::floor(prev_uv_[k].y()));
        for (int dy = -flow_reach_; dy <= 1 + flow_reach_; ++dy) {
          for (int dx = -flow_reach_; dx <= 1 + flow_reach_; ++dx) {
            if (px + dx >= 0 && py + dy >= 0 && px + dx < cam_.width && py + dy < cam_.height) {
              int& who = owner.at<int>(py + dy, px + dx);
              f.flow.at<cv::Vec2f>(py + dy, px + dx) =
                  who >= 0 ? cv::Vec2f(NAN, NAN)
                           : cv::Vec2f(static_cast<float>(d.x()), static_cast<float>(d.y()));
              who = static_cast<int>(k);
            }
          }
        }
      }
    }
    prev_uv_ = true_uv;
    if (detected) {
      ObjectDetectionInput det;
      det.cluster_id = cluster_id;
      det.class_id = 26;
      det.instance_id = static_cast<int>(cluster_id);
      det.box = cv::Rect2d(x0 - 3, y0 - 3, x1 - x0 + 6, y1 - y0 + 6);
      JointSpec spec;
      spec.type = joints::JointType::kPlanar;
      // The road in the drifting camera's world: π(X − δ).
      Eigen::Vector3d n = road_.head<3>();
      if (normal_jitter_ != 0.0) {
        const Eigen::Vector3d axis =
            index_ % 2 == 0 ? Eigen::Vector3d::UnitX() : Eigen::Vector3d::UnitZ();
        n = Eigen::AngleAxisd(normal_jitter_, axis) * n;
      }
      spec.parent_plane = semantic::NormalizePlane(
          Eigen::Vector4d(n.x(), n.y(), n.z(), road_.w() - road_.head<3>().dot(Drift())));
      spec.anchor = world_from_object_.translation();
      det.joint = ResolveJointOrFree(spec);
      f.detections.push_back(det);
    }
    camera_from_world_true_ = f.camera_from_world;
    f.camera_from_world = f.camera_from_world * SE3d(geometry::SO3d(), -Drift());
    camera_from_world_given_ = f.camera_from_world;
    ++index_;
    return f;
  }

 private:
  bool Shown(size_t k) const { return k >= shown_begin_ && (shown_ == 0 || k < shown_); }
  Eigen::Vector3d Drift() const { return Eigen::Vector3d(0.0, height_drift_ * index_, 0.0); }

  double noise_;
  double extra_noise_ = 0.0;
  bool independent_right_noise_ = false;
  double height_drift_ = 0.0;
  double normal_jitter_ = 0.0;
  SE3d camera_from_world_given_, camera_from_world_true_;
  std::mt19937_64 rng_;
  geometry::StereoCamera cam_;
  Eigen::Vector4d road_;
  SE3d world_from_joint_, world_from_object_;
  Vector6d step_;
  std::vector<Eigen::Vector3d> points_;
  std::vector<cv::Mat> descriptors_;
  std::vector<Eigen::Vector2d> prev_uv_;
  Eigen::Vector2d flow_bias_ = Eigen::Vector2d::Zero();
  SE3d glitch_;
  size_t shown_begin_ = 0;
  size_t shown_ = 0;
  int64_t index_ = 0;
  int flow_reach_ = 0;
};

}  // namespace twist::objects::testing
