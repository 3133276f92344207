#pragma once

// Camera pose from 3D-2D correspondences inside RANSAC, for the tracker's
// descriptor paths (the reference keyframe and relocalization), which have
// no usable pose prior.

#include <opencv2/core.hpp>
#include <vector>

#include "slam/geometry/se3.h"
#include "slam/geometry/stereo_camera.h"

namespace twist::tracking {

struct PnpRansacOptions {
  int iterations = 300;
  double threshold_px = 3.0;
  double confidence = 0.99;
  int min_inliers = 10;
  // Percentage of the inliers that must lie in front of the returned pose.
  int min_in_front_percent = 90;
  // Share of RANSAC's inliers that must project within threshold_px of
  // their keypoints under the returned pose (see SolvePnpRansac).
  double min_consistent_share = 0.5;
  // Points farther than this many times the median distance from the
  // points' median are left out of the PnP (see SolvePnpRansac); 0: none.
  double max_distance_ratio = 100.0;
};

// Indices k of the correspondences that lie in front of camera_from_world
// and project within threshold_px of img[k] (the left camera's pinhole).
std::vector<int> PnpConsistent(const geometry::StereoCamera& camera,
                               const std::vector<cv::Point3f>& obj,
                               const std::vector<cv::Point2f>& img,
                               const geometry::SE3d& camera_from_world,
                               const std::vector<int>& candidates,
                               double threshold_px);

// Indices of the points PnP uses (see SolvePnpRansac): all but those
// farther from the points' coordinate-wise median than max_distance_ratio
// times the median distance to it; all if fewer than min_kept would remain.
std::vector<int> PnpCandidates(const std::vector<cv::Point3f>& obj,
                               double max_distance_ratio,
                               int min_kept);

// OpenCV's PnP RANSAC with AP3P on 4-point samples (deterministic). EPnP on
// minimal samples was unstable: on intersection seed 1 it returned a pose
// 16 m off with 183 "inliers" of 228, a third of them behind the camera,
// where AP3P finds the true one.
//
// Points far out of scale with the others are left out: those farther from
// the coordinate-wise median of the points than max_distance_ratio times
// the median distance to it (kept if fewer than min_inliers would remain).
// The map can hold a few points kilometres away (from rays triangulated at
// a near-zero parallax); they fit any translation, and OpenCV's closed-form
// solvers and the refinement of RANSAC's model on its inliers are pulled
// off by them. On intersection seed 6, frame 65 (the start of a turn, with
// masked object stereo on), 5 of 257 descriptor matches were 1-529 km from
// the world origin, the others within 300 m: RANSAC found 218 inliers, and
// the pose returned fitted 3 of them (263 m from the last frame's). Without
// those 5 points, 222 fit.
//
// The returned pose is also checked against RANSAC's inliers: when fewer
// than min_consistent_share of them lie within threshold_px of their
// keypoints (OpenCV's refinement moved off RANSAC's model; KITTI 06 frame
// 1: 100 of 206), the pose is solved again on those inliers with SQPnP (179
// of 206 there), the better fit is kept, *inliers becomes the ones it fits,
// and if it still fits fewer than that share the PnP fails.
//
// Returns false unless the pose is finite, has min_inliers inliers and
// min_in_front_percent of them in front of the camera. *inliers indexes
// obj / img.
bool SolvePnpRansac(const geometry::StereoCamera& camera,
                    const std::vector<cv::Point3f>& obj,
                    const std::vector<cv::Point2f>& img,
                    geometry::SE3d* camera_from_world,
                    std::vector<int>* inliers,
                    const PnpRansacOptions& options = PnpRansacOptions());

}  // namespace twist::tracking
