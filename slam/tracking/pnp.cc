#include "slam/tracking/pnp.h"

#include <glog/logging.h>

#include <algorithm>
#include <cstddef>
#include <opencv2/calib3d.hpp>
#include <opencv2/core/eigen.hpp>

namespace twist::tracking {
namespace {

bool PoseFromRodrigues(const cv::Mat& rvec, const cv::Mat& tvec, geometry::SE3d* pose) {
  if (rvec.empty() || tvec.empty()) return false;
  cv::Mat rotation;
  cv::Rodrigues(rvec, rotation);
  Eigen::Matrix3d r;
  Eigen::Vector3d t;
  cv::cv2eigen(rotation, r);
  cv::cv2eigen(tvec, t);
  if (!r.allFinite() || !t.allFinite()) return false;
  *pose = geometry::SE3d(Eigen::Quaterniond(r).normalized(), t);
  return true;
}

// The correspondences `indices` of obj / img.
void Gather(const std::vector<cv::Point3f>& obj,
            const std::vector<cv::Point2f>& img,
            const std::vector<int>& indices,
            std::vector<cv::Point3f>* obj_out,
            std::vector<cv::Point2f>* img_out) {
  obj_out->clear();
  img_out->clear();
  for (int k : indices) {
    obj_out->push_back(obj[k]);
    img_out->push_back(img[k]);
  }
}

}  // namespace

std::vector<int> PnpConsistent(const geometry::StereoCamera& camera,
                               const std::vector<cv::Point3f>& obj,
                               const std::vector<cv::Point2f>& img,
                               const geometry::SE3d& camera_from_world,
                               const std::vector<int>& candidates,
                               double threshold_px) {
  std::vector<int> out;
  const double threshold2 = threshold_px * threshold_px;
  for (int k : candidates) {
    const Eigen::Vector3d p = camera_from_world * Eigen::Vector3d(obj[k].x, obj[k].y, obj[k].z);
    if (!(p.z() > 0.0)) continue;
    const Eigen::Vector2d uv = camera.Project(p);
    if ((uv - Eigen::Vector2d(img[k].x, img[k].y)).squaredNorm() <= threshold2) out.push_back(k);
  }
  return out;
}

std::vector<int> PnpCandidates(const std::vector<cv::Point3f>& obj,
                               double max_distance_ratio,
                               int min_kept) {
  std::vector<int> all(obj.size());
  for (size_t k = 0; k < obj.size(); ++k) all[k] = static_cast<int>(k);
  if (!(max_distance_ratio > 0.0) || obj.empty()) return all;
  auto median = [](std::vector<double> v) {
    const auto mid = v.begin() + static_cast<std::ptrdiff_t>(v.size() / 2);
    std::nth_element(v.begin(), mid, v.end());
    return *mid;
  };
  std::vector<double> xs, ys, zs;
  for (const cv::Point3f& p : obj) {
    xs.push_back(p.x);
    ys.push_back(p.y);
    zs.push_back(p.z);
  }
  const Eigen::Vector3d centre(median(xs), median(ys), median(zs));
  std::vector<double> dist;
  for (const cv::Point3f& p : obj) dist.push_back((Eigen::Vector3d(p.x, p.y, p.z) - centre).norm());
  const double limit = max_distance_ratio * median(dist);
  std::vector<int> kept;
  for (size_t k = 0; k < obj.size(); ++k) {
    if (dist[k] <= limit) kept.push_back(static_cast<int>(k));
  }
  return static_cast<int>(kept.size()) >= min_kept ? kept : all;
}

bool SolvePnpRansac(const geometry::StereoCamera& camera,
                    const std::vector<cv::Point3f>& obj,
                    const std::vector<cv::Point2f>& img,
                    geometry::SE3d* camera_from_world,
                    std::vector<int>* inliers,
                    const PnpRansacOptions& options) {
  const std::vector<int> candidates =
      PnpCandidates(obj, options.max_distance_ratio, options.min_inliers);
  if (candidates.size() < obj.size()) {
    VLOG(2) << "PnP: " << obj.size() - candidates.size() << " of " << obj.size()
            << " points left out, far out of scale with the others";
  }
  std::vector<cv::Point3f> obj_used;
  std::vector<cv::Point2f> img_used;
  Gather(obj, img, candidates, &obj_used, &img_used);
  const cv::Mat k =
      (cv::Mat_<double>(3, 3) << camera.fx, 0, camera.cx, 0, camera.fy, camera.cy, 0, 0, 1);
  cv::Mat rvec, tvec;
  std::vector<int> used_inliers;
  if (!cv::solvePnPRansac(obj_used,
                          img_used,
                          k,
                          cv::noArray(),
                          rvec,
                          tvec,
                          false,
                          options.iterations,
                          static_cast<float>(options.threshold_px),
                          options.confidence,
                          used_inliers,
                          cv::SOLVEPNP_AP3P) ||
      static_cast<int>(used_inliers.size()) < options.min_inliers) {
    return false;
  }
  geometry::SE3d pose;
  if (!PoseFromRodrigues(rvec, tvec, &pose)) return false;
  inliers->clear();
  for (int i : used_inliers) inliers->push_back(candidates[i]);
  std::vector<int> consistent =
      PnpConsistent(camera, obj, img, pose, *inliers, options.threshold_px);
  const double needed = options.min_consistent_share * static_cast<double>(inliers->size());
  if (static_cast<double>(consistent.size()) < needed) {
    // OpenCV's refinement of RANSAC's model on its inliers moved away from
    // it: solve again on those inliers with SQPnP and keep the better fit.
    Gather(obj, img, *inliers, &obj_used, &img_used);
    cv::Mat rvec2, tvec2;
    geometry::SE3d pose2;
    std::vector<int> consistent2;
    if (cv::solvePnP(
            obj_used, img_used, k, cv::noArray(), rvec2, tvec2, false, cv::SOLVEPNP_SQPNP) &&
        PoseFromRodrigues(rvec2, tvec2, &pose2)) {
      consistent2 = PnpConsistent(camera, obj, img, pose2, *inliers, options.threshold_px);
    }
    VLOG(1) << "PnP RANSAC: the pose returned fits " << consistent.size() << " of its "
            << inliers->size() << " inliers, SQPnP on them " << consistent2.size();
    if (consistent2.size() > consistent.size()) {
      pose = pose2;
      consistent = std::move(consistent2);
    }
    if (static_cast<double>(consistent.size()) < needed ||
        static_cast<int>(consistent.size()) < options.min_inliers) {
      return false;
    }
    *inliers = std::move(consistent);
  }
  size_t in_front = 0;
  for (int i : *inliers) {
    in_front += (pose * Eigen::Vector3d(obj[i].x, obj[i].y, obj[i].z)).z() > 0.0;
  }
  if (100 * in_front < static_cast<size_t>(options.min_in_front_percent) * inliers->size()) {
    return false;
  }
  *camera_from_world = pose;
  return true;
}

}  // namespace twist::tracking
