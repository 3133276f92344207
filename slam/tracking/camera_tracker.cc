#include "slam/tracking/camera_tracker.h"

#include <glog/logging.h>

#include <algorithm>
#include <climits>
#include <cmath>
#include <cstring>
#include <set>
#include <unordered_set>

#include "slam/features/feature_matcher.h"
#include "slam/tracking/pnp.h"

namespace twist::tracking {

using features::DescriptorDistance;
using features::kThresholdHigh;
using features::kThresholdLow;

CameraTracker::CameraTracker(const geometry::StereoCamera& camera,
                             const features::ScalePyramid& pyramid,
                             const TrackerOptions& options)
    : camera_(camera), pyramid_(pyramid), options_(options) {}

bool CameraTracker::CanInitialize(const map::Frame& frame) const {
  int n = 0;
  const auto& f = *frame.features;
  for (int i = 0; i < f.size(); ++i) n += (f.depth[i] > 0.f && f.is_static[i]);
  return n >= options_.min_init_stereo_points;
}

void CameraTracker::Initialize(const map::Frame& frame, const map::KeyFrame& kf) {
  state_ = TrackingState::kOk;
  reference_kf_id_ = kf.id;
  last_frame_ = frame;
  last_frame_.reference_kf_id = kf.id;
  last_from_reference_ = geometry::SE3d();
  velocity_.reset();
  OnKeyFrameCreated(frame, kf);
}

void CameraTracker::OnKeyFrameCreated(const map::Frame& frame, const map::KeyFrame& kf) {
  CHECK_EQ(frame.id, last_frame_.id);
  last_kf_frame_id_ = frame.id;
  last_frame_is_keyframe_ = true;
  reference_kf_id_ = kf.id;
  last_frame_.reference_kf_id = kf.id;
  last_from_reference_ =
      map::CanonicalPose(last_frame_.camera_from_world * kf.camera_from_world.Inverse());
  for (int i = 0; i < static_cast<int>(kf.point_ids.size()); ++i) {
    if (kf.point_ids[i] >= 0) {
      last_frame_.point_ids[i] = kf.point_ids[i];
      last_frame_.matched[i] = 1;
      last_frame_.outlier[i] = 0;
    }
  }
}

CameraTracker::State CameraTracker::GetState() const {
  State s;
  s.state = state_;
  s.last_frame = last_frame_;
  s.last_frame_is_keyframe = last_frame_is_keyframe_;
  s.velocity = velocity_;
  s.last_from_reference = last_from_reference_;
  s.reference_kf_id = reference_kf_id_;
  s.last_kf_frame_id = last_kf_frame_id_;
  s.last_reloc_frame_id = last_reloc_frame_id_;
  s.last_inliers = last_inliers_;
  return s;
}

void CameraTracker::SetState(State s) {
  state_ = s.state;
  last_frame_ = std::move(s.last_frame);
  last_frame_is_keyframe_ = s.last_frame_is_keyframe;
  velocity_ = s.velocity;
  last_from_reference_ = s.last_from_reference;
  reference_kf_id_ = s.reference_kf_id;
  last_kf_frame_id_ = s.last_kf_frame_id;
  last_reloc_frame_id_ = s.last_reloc_frame_id;
  last_inliers_ = s.last_inliers;
}

TrackingState CameraTracker::Track(map::Frame* frame, map::Map* map) {
  if (state_ == TrackingState::kNotInitialized) return state_;
  const std::unique_lock<std::mutex> lock = map->PriorityLock();
  // Stereo measurements with the map's current disparity offset estimate.
  const float offset = static_cast<float>(map->disparity_offset());
  frame->features = map::WithDisparityOffset(frame->features, camera_, offset);
  if (last_frame_.features != nullptr) {
    last_frame_.features = map::WithDisparityOffset(last_frame_.features, camera_, offset);
  }
  frame->ResetMatches();
  bool ok = false;
  bool relocalized = false;
  TrackingPath path = TrackingPath::kNone;
  if (state_ == TrackingState::kOk || state_ == TrackingState::kRelocalized) {
    UpdateLastFrame(map);
    int inliers = 0;
    if (velocity_.has_value()) {
      inliers = TrackWithMotionModel(frame, map);
      path = TrackingPath::kMotionModel;
    }
    if (inliers == 0) {
      inliers = TrackReferenceKeyFrame(frame, map);
      path = TrackingPath::kReferenceKeyFrame;
    } else if (inliers < options_.confident_motion_inliers) {
      // A weak motion-model pose: descriptor tracking of the reference
      // keyframe, which needs no prior, gets a say.
      map::Frame alternative = *frame;
      const int alt_inliers = TrackReferenceKeyFrame(&alternative, map);
      VLOG(1) << "frame " << frame->id << ": weak motion model (" << inliers
              << " inliers), reference keyframe " << alt_inliers;
      if (alt_inliers > inliers) {
        *frame = std::move(alternative);
        inliers = alt_inliers;
        path = TrackingPath::kReferenceKeyFrame;
      }
    }
    ok = inliers > 0;
  }
  const bool was_tracking = path != TrackingPath::kNone;
  auto relocalize = [&]() {
    frame->ResetMatches();
    frame->camera_from_world = last_frame_.camera_from_world;
    ok = Relocalize(frame, map);
    relocalized = ok;
    path = TrackingPath::kRelocalization;
  };
  if (!was_tracking) relocalize();
  const bool recent_reloc =
      frame->id - last_reloc_frame_id_ < options_.recent_relocalization_frames;
  if (ok) ok = TrackLocalMap(frame, map, relocalized || recent_reloc);
  if (ok && path == TrackingPath::kMotionModel && options_.retry_weak_frames_from_reference &&
      options_.research_inlier_ratio > 0.0) {
    const int first = CountMapInliers(*frame);
    if (first < options_.research_inlier_ratio * last_inliers_) {
      map::Frame alternative = *frame;
      const bool alt_ok = TrackReferenceKeyFrame(&alternative, map) > 0 &&
                          TrackLocalMap(&alternative, map, recent_reloc);
      const int second = alt_ok ? CountMapInliers(alternative) : 0;
      VLOG(1) << "frame " << frame->id << ": weak frame (" << first
              << " local-map inliers), from the reference keyframe " << second;
      if (second > first) {
        *frame = std::move(alternative);
        path = TrackingPath::kReferenceKeyFrame;
      }
      // TrackLocalMap sets the tracker's reference keyframe from its pass:
      // it must be the kept pass's. (Both passes counted their points as
      // visible/found, which only feeds the points' culling ratio.)
      reference_kf_id_ = frame->reference_kf_id;
    }
  }
  if (!ok && was_tracking && options_.relocalize_on_failure) {
    // Neither the motion model nor the reference keyframe held (the start of
    // a sharp turn): the frame is relocalized at once rather than lost.
    VLOG(1) << "frame " << frame->id << ": tracking failed, relocalizing in the same frame";
    relocalize();
    if (ok) ok = TrackLocalMap(frame, map, true);
  }

  if (ok) {
    state_ = relocalized ? TrackingState::kRelocalized : TrackingState::kOk;
    if (!relocalized) {
      velocity_ = frame->camera_from_world * last_frame_.camera_from_world.Inverse();
    } else {
      velocity_.reset();
    }
  } else {
    state_ = TrackingState::kLost;
    velocity_.reset();
  }
  frame->camera_from_world = map::CanonicalPose(frame->camera_from_world);
  if (velocity_.has_value()) velocity_ = map::CanonicalPose(*velocity_);
  ComputeStats(*frame);
  stats_.path = path;
  last_inliers_ = ok ? stats_.num_inliers : 0;
  VLOG(1) << "frame " << frame->id << " path " << static_cast<int>(path) << " ok " << ok
          << " inliers " << stats_.num_inliers << " close tracked " << stats_.num_tracked_close
          << " untracked " << stats_.num_untracked_close;
  // The next frame only keeps inlier map points; temporary points are rebuilt.
  for (int i = 0; i < static_cast<int>(frame->matched.size()); ++i) {
    if (frame->matched[i] && (frame->outlier[i] || frame->point_ids[i] < 0)) frame->ClearMatch(i);
  }
  if (ok || last_frame_.features == nullptr) {
    frame->reference_kf_id = reference_kf_id_;
    last_frame_ = *frame;
    last_frame_is_keyframe_ = false;
    const map::KeyFrame* ref = map->keyframe(reference_kf_id_);
    if (ref != nullptr) {
      last_from_reference_ =
          map::CanonicalPose(frame->camera_from_world * ref->camera_from_world.Inverse());
    }
  }
  return state_;
}

void CameraTracker::UpdateLastFrame(map::Map* map) {
  map::Frame& last = last_frame_;
  const map::KeyFrame* ref = map->keyframe(last.reference_kf_id);
  if (ref != nullptr) {
    last.camera_from_world = map::CanonicalPose(last_from_reference_ * ref->camera_from_world);
  }
  for (int i = 0; i < static_cast<int>(last.point_ids.size()); ++i) {
    if (last.point_ids[i] < 0) {
      last.matched[i] = 0;
      continue;
    }
    const map::MapPoint* p = map->GoodPoint(last.point_ids[i]);
    if (p == nullptr) {
      last.ClearMatch(i);
    } else {
      last.p_in_world[i] = p->p_in_world;
      last.matched[i] = 1;
    }
  }
  if (last_frame_is_keyframe_) return;
  // Temporary visual-odometry points from the last frame's stereo depth: all
  // close ones, at least the `max_temporary_points` closest.
  const auto& f = *last.features;
  std::vector<std::pair<float, int>> by_depth;
  for (int i = 0; i < f.size(); ++i) {
    if (f.depth[i] > 0.f && f.is_static[i]) by_depth.push_back({f.depth[i], i});
  }
  std::sort(by_depth.begin(), by_depth.end());
  const geometry::SE3d world_from_last = last.camera_from_world.Inverse();
  const double close = options_.close_depth_baselines * camera_.baseline;
  int count = 0;
  for (const auto& [depth, i] : by_depth) {
    if (!last.matched[i]) {
      const Eigen::Vector3d pc =
          camera_.Backproject(Eigen::Vector2d(f.keypoints[i].pt.x, f.keypoints[i].pt.y), depth);
      last.p_in_world[i] = world_from_last * pc;
      last.matched[i] = 1;
      last.point_ids[i] = -1;
    }
    ++count;
    if (depth > close && count > options_.max_temporary_points) break;
  }
}

int CameraTracker::SearchLastFrame(map::Frame* frame, const map::Frame& last, float radius) const {
  const auto& f = *frame->features;
  const auto& lf = *last.features;
  const geometry::SE3d& T = frame->camera_from_world;
  // Motion along the optical axis decides which levels can match.
  const Eigen::Vector3d t_last_cur = (last.camera_from_world * T.Inverse()).translation();
  const bool forward = t_last_cur.z() > camera_.baseline;
  const bool backward = -t_last_cur.z() > camera_.baseline;
  features::OrientationFilter rot;
  int n = 0;
  for (int i = 0; i < lf.size(); ++i) {
    if (!last.matched[i] || last.outlier[i]) continue;
    const Eigen::Vector3d pc = T * last.p_in_world[i];
    Eigen::Vector3d uvr;
    if (!camera_.ProjectStereoChecked(pc, &uvr)) continue;
    if (!camera_.InImage(uvr.head<2>())) continue;
    const int level = lf.keypoints[i].octave;
    const float r = radius * pyramid_.scale[level];
    std::vector<int> idx;
    if (forward) {
      idx = f.grid.FeaturesInArea(f.keypoints, uvr.x(), uvr.y(), r, level, -1);
    } else if (backward) {
      idx = f.grid.FeaturesInArea(f.keypoints, uvr.x(), uvr.y(), r, 0, level);
    } else {
      idx = f.grid.FeaturesInArea(
          f.keypoints, uvr.x(), uvr.y(), r, std::max(0, level - 1), level + 1);
    }
    int best = INT_MAX, best_j = -1;
    const uint8_t* d = lf.descriptor(i);
    for (int j : idx) {
      if (frame->matched[j] || !f.is_static[j]) continue;
      if (f.u_right[j] >= 0.f && std::fabs(uvr.z() - f.u_right[j]) > r) continue;
      const int dist = DescriptorDistance(d, f.descriptor(j));
      if (dist < best) {
        best = dist;
        best_j = j;
      }
    }
    if (best_j < 0 || best > kThresholdHigh) continue;
    frame->SetMatch(best_j, last.point_ids[i], last.p_in_world[i]);
    rot.Add(lf.keypoints[i].angle, f.keypoints[best_j].angle, best_j);
    ++n;
  }
  for (int j : rot.Rejected()) {
    frame->ClearMatch(j);
    --n;
  }
  return n;
}

int CameraTracker::SearchKeyFramePoints(map::Frame* frame,
                                        const map::KeyFrame& kf,
                                        const map::Map& map,
                                        float radius,
                                        int max_distance) const {
  const auto& f = *frame->features;
  const auto& kff = *kf.features;
  const geometry::SE3d& T = frame->camera_from_world;
  features::OrientationFilter rot;
  int n = 0;
  for (int i = 0; i < kff.size(); ++i) {
    if (kf.point_ids[i] < 0) continue;
    const map::MapPoint* p = map.point(kf.point_ids[i]);
    if (p == nullptr || p->bad) continue;
    const Eigen::Vector3d pc = T * p->p_in_world;
    Eigen::Vector3d uvr;
    if (!camera_.ProjectStereoChecked(pc, &uvr)) continue;
    if (!camera_.InImage(uvr.head<2>())) continue;
    const int level = kff.keypoints[i].octave;
    const float r = radius * pyramid_.scale[level];
    const auto idx =
        f.grid.FeaturesInArea(f.keypoints, uvr.x(), uvr.y(), r, std::max(0, level - 2), level + 2);
    int best = INT_MAX, second = INT_MAX, best_j = -1;
    for (int j : idx) {
      if (frame->matched[j] || !f.is_static[j]) continue;
      const int dist = DescriptorDistance(p->descriptor.data(), f.descriptor(j));
      if (dist < best) {
        second = best;
        best = dist;
        best_j = j;
      } else if (dist < second) {
        second = dist;
      }
    }
    if (best_j < 0 || best > max_distance) continue;
    if (static_cast<float>(best) > 0.8f * static_cast<float>(second)) continue;
    frame->SetMatch(best_j, p->id, p->p_in_world);
    rot.Add(kff.keypoints[i].angle, f.keypoints[best_j].angle, best_j);
    ++n;
  }
  for (int j : rot.Rejected()) {
    frame->ClearMatch(j);
    --n;
  }
  return n;
}

int CameraTracker::CountMapInliers(const map::Frame& frame) {
  int n = 0;
  for (int i = 0; i < static_cast<int>(frame.point_ids.size()); ++i) {
    n += frame.matched[i] && !frame.outlier[i] && frame.point_ids[i] >= 0;
  }
  return n;
}

int CameraTracker::Optimize(map::Frame* frame) {
  const auto& f = *frame->features;
  std::vector<PoseObservation> obs;
  std::vector<int> index;
  obs.reserve(f.size());
  for (int i = 0; i < f.size(); ++i) {
    if (!frame->matched[i]) continue;
    PoseObservation o;
    o.p_in_world = frame->p_in_world[i];
    o.uv = Eigen::Vector2d(f.keypoints[i].pt.x, f.keypoints[i].pt.y);
    o.u_right = f.u_right[i];
    o.inv_sigma2 = pyramid_.inv_sigma2[f.keypoints[i].octave];
    obs.push_back(o);
    index.push_back(i);
  }
  if (obs.size() < 3) return 0;
  const int inliers = OptimizePose(camera_, &obs, &frame->camera_from_world, options_.pose);
  for (size_t k = 0; k < obs.size(); ++k) frame->outlier[index[k]] = obs[k].outlier;
  return inliers;
}

int CameraTracker::TrackWithMotionModel(map::Frame* frame, map::Map* map) {
  frame->camera_from_world = *velocity_ * last_frame_.camera_from_world;
  int n = SearchLastFrame(frame, last_frame_, static_cast<float>(options_.motion_search_radius));
  if (n < 20) {
    frame->ResetMatches();
    n = SearchLastFrame(frame, last_frame_, 2.f * options_.motion_search_radius);
  }
  VLOG(2) << "motion model matches " << n;
  if (n < 20) return 0;
  Optimize(frame);
  int map_inliers = 0;
  for (int i = 0; i < static_cast<int>(frame->matched.size()); ++i) {
    if (!frame->matched[i]) continue;
    if (frame->outlier[i]) {
      frame->ClearMatch(i);
    } else if (frame->point_ids[i] >= 0) {
      ++map_inliers;
    }
  }
  return map_inliers >= options_.min_motion_inliers ? map_inliers : 0;
}

namespace {

// PnP RANSAC (SolvePnpRansac) on the frame's current matches;
// on success sets the pose and clears the outlier matches.
bool PoseFromMatchesRansac(const geometry::StereoCamera& camera, map::Frame* frame) {
  const auto& f = *frame->features;
  std::vector<cv::Point3f> obj;
  std::vector<cv::Point2f> img;
  std::vector<int> index;
  for (int i = 0; i < f.size(); ++i) {
    if (!frame->matched[i]) continue;
    const Eigen::Vector3d& p = frame->p_in_world[i];
    obj.emplace_back(
        static_cast<float>(p.x()), static_cast<float>(p.y()), static_cast<float>(p.z()));
    img.push_back(f.keypoints[i].pt);
    index.push_back(i);
  }
  if (obj.size() < 10) return false;
  std::vector<int> inliers;
  if (!SolvePnpRansac(camera, obj, img, &frame->camera_from_world, &inliers)) return false;
  std::vector<char> keep(index.size(), 0);
  for (int k : inliers) keep[k] = 1;
  for (size_t k = 0; k < index.size(); ++k) {
    if (!keep[k]) frame->ClearMatch(index[k]);
  }
  return true;
}

}  // namespace

int CameraTracker::TrackReferenceKeyFrame(map::Frame* frame, map::Map* map) {
  const map::KeyFrame* ref = map->keyframe(reference_kf_id_);
  if (ref == nullptr) return 0;
  frame->ResetMatches();
  frame->camera_from_world = last_frame_.camera_from_world;
  // No usable motion prior: match the reference keyframe's points by
  // descriptor only (ratio + orientation tests), as ORB-SLAM2 does with its
  // vocabulary, then optimise from the last pose.
  const auto& f = *frame->features;
  std::vector<int> query_index;
  for (int i = 0; i < f.size(); ++i) {
    if (f.is_static[i]) query_index.push_back(i);
  }
  std::vector<int64_t> pids;
  std::vector<int> kps;
  for (int i = 0; i < ref->features->size(); ++i) {
    const map::MapPoint* p = map->GoodPoint(ref->point_ids[i]);
    if (p == nullptr) continue;
    pids.push_back(p->id);
    kps.push_back(i);
  }
  if (pids.size() < 15 || query_index.size() < 15) return 0;
  cv::Mat query(static_cast<int>(query_index.size()), 32, CV_8UC1);
  for (size_t k = 0; k < query_index.size(); ++k) {
    std::memcpy(query.ptr<uint8_t>(static_cast<int>(k)), f.descriptor(query_index[k]), 32);
  }
  cv::Mat train(static_cast<int>(pids.size()), 32, CV_8UC1);
  for (size_t k = 0; k < pids.size(); ++k) {
    std::memcpy(
        train.ptr<uint8_t>(static_cast<int>(k)), map->point(pids[k])->descriptor.data(), 32);
  }
  const auto m = features::MatchRatio(query, train, 0.75f, kThresholdHigh);
  features::OrientationFilter rot;
  for (size_t k = 0; k < m.size(); ++k) {
    const int i = query_index[m[k].first];
    frame->SetMatch(i, pids[m[k].second], map->point(pids[m[k].second])->p_in_world);
    rot.Add(ref->features->keypoints[kps[m[k].second]].angle, f.keypoints[i].angle, i);
  }
  for (int j : rot.Rejected()) frame->ClearMatch(j);
  int n = 0;
  for (uint8_t x : frame->matched) n += x;
  if (n < 15) return 0;
  // The last pose may be far off (no velocity): an initial pose from PnP
  // RANSAC avoids optimising from a poor start with wrong matches.
  PoseFromMatchesRansac(camera_, frame);
  Optimize(frame);
  int inliers = 0;
  for (int i = 0; i < static_cast<int>(frame->matched.size()); ++i) {
    if (!frame->matched[i]) continue;
    if (frame->outlier[i]) {
      frame->ClearMatch(i);
    } else {
      ++inliers;
    }
  }
  return inliers >= options_.min_motion_inliers ? inliers : 0;
}

int CameraTracker::SearchLocalPoints(map::Frame* frame,
                                     map::Map* map,
                                     const std::vector<int64_t>& local_points,
                                     bool count_visible) {
  const auto& f = *frame->features;
  const geometry::SE3d& T = frame->camera_from_world;
  const Eigen::Vector3d center = frame->CameraCenter();
  int n = 0;
  for (int64_t pid : local_points) {
    map::MapPoint* p = map->point(pid);
    if (p == nullptr || p->bad) continue;
    if (p->last_local_map_frame == frame->id) continue;  // already matched
    const Eigen::Vector3d pc = T * p->p_in_world;
    Eigen::Vector3d uvr;
    if (!camera_.ProjectStereoChecked(pc, &uvr)) continue;
    if (!camera_.InImage(uvr.head<2>())) continue;
    const Eigen::Vector3d po = p->p_in_world - center;
    const float dist = static_cast<float>(po.norm());
    if (dist < 0.8f * p->min_distance || dist > 1.2f * p->max_distance) continue;
    const double view_cos = po.dot(p->normal) / dist;
    if (view_cos < 0.5) continue;
    if (count_visible) p->visible++;
    const int level = p->PredictScale(dist, pyramid_);
    const float r = (view_cos > 0.998 ? 2.5f : 4.0f) * pyramid_.scale[level];
    const auto idx = f.grid.FeaturesInArea(f.keypoints, uvr.x(), uvr.y(), r, level - 1, level);
    int best = INT_MAX, second = INT_MAX, best_j = -1, best_level = -1, second_level = -1;
    for (int j : idx) {
      // Map points may replace temporary (visual-odometry) matches.
      if ((frame->matched[j] && frame->point_ids[j] >= 0) || !f.is_static[j]) continue;
      if (f.u_right[j] >= 0.f && std::fabs(uvr.z() - f.u_right[j]) > r) continue;
      const int d = DescriptorDistance(p->descriptor.data(), f.descriptor(j));
      if (d < best) {
        second = best;
        second_level = best_level;
        best = d;
        best_j = j;
        best_level = f.keypoints[j].octave;
      } else if (d < second) {
        second = d;
        second_level = f.keypoints[j].octave;
      }
    }
    if (best_j < 0 || best > kThresholdHigh) continue;
    if (best_level == second_level &&
        static_cast<float>(best) > 0.8f * static_cast<float>(second)) {
      continue;
    }
    frame->SetMatch(best_j, p->id, p->p_in_world);
    ++n;
  }
  return n;
}

bool CameraTracker::TrackLocalMap(map::Frame* frame, map::Map* map, bool just_relocalized) {
  // Local keyframes: those observing the frame's map points, weighted.
  std::map<int64_t, int> counter;
  for (int i = 0; i < static_cast<int>(frame->point_ids.size()); ++i) {
    if (!frame->matched[i] || frame->point_ids[i] < 0) continue;
    map::MapPoint* p = map->GoodPoint(frame->point_ids[i]);
    if (p == nullptr) {
      frame->ClearMatch(i);
      continue;
    }
    for (const auto& [kf_id, idx] : p->observations) counter[kf_id]++;
  }
  std::vector<int64_t> local_kfs;
  std::set<int64_t> in_local;
  int best = 0;
  for (const auto& [kf_id, c] : counter) {
    if (map->keyframe(kf_id) == nullptr) continue;
    local_kfs.push_back(kf_id);
    in_local.insert(kf_id);
    if (c > best) {
      best = c;
      reference_kf_id_ = kf_id;
    }
  }
  const size_t direct = local_kfs.size();
  for (size_t k = 0;
       k < direct && static_cast<int>(local_kfs.size()) < options_.max_local_keyframes;
       ++k) {
    const map::KeyFrame* kf = map->keyframe(local_kfs[k]);
    for (int64_t nb : kf->BestCovisible(10)) {
      if (in_local.insert(nb).second) {
        local_kfs.push_back(nb);
        break;  // one new neighbour per keyframe, as ORB-SLAM2
      }
    }
  }
  // Local points.
  for (int i = 0; i < static_cast<int>(frame->point_ids.size()); ++i) {
    if (!frame->matched[i] || frame->point_ids[i] < 0) continue;
    map::MapPoint* p = map->point(frame->point_ids[i]);
    p->last_local_map_frame = frame->id;
    p->visible++;
  }
  std::vector<int64_t> local_points;
  std::unordered_set<int64_t> seen;  // a hash set: tens of thousands of inserts a frame
  seen.reserve(4096);
  for (int64_t kf_id : local_kfs) {
    const map::KeyFrame* kf = map->keyframe(kf_id);
    for (int64_t pid : kf->point_ids) {
      if (pid >= 0 && seen.insert(pid).second) local_points.push_back(pid);
    }
  }
  SearchLocalPoints(frame, map, local_points, /*count_visible=*/true);
  Optimize(frame);
  int inliers = CountMapInliers(*frame);
  if (options_.research_inlier_ratio > 0.0 &&
      inliers < options_.research_inlier_ratio * last_inliers_) {
    // Second search from the optimised pose: the outliers are released and
    // the inliers kept (marked, so that they are not searched again). It is
    // kept only if it brings the frame back to the trigger's level: on
    // intersection seed 4, frame 91 (91 inliers against 453 in the frame
    // before), the second search reached 103 inliers with a pose 0.26 m off.
    const map::Frame first_pass = *frame;
    for (int i = 0; i < static_cast<int>(frame->point_ids.size()); ++i) {
      if (!frame->matched[i] || frame->point_ids[i] < 0) continue;
      map::MapPoint* p = map->point(frame->point_ids[i]);
      if (p == nullptr) continue;
      if (frame->outlier[i]) {
        p->last_local_map_frame = -1;
        frame->ClearMatch(i);
        continue;
      }
      p->last_local_map_frame = frame->id;
    }
    const int found = SearchLocalPoints(frame, map, local_points, /*count_visible=*/false);
    Optimize(frame);
    const int second = CountMapInliers(*frame);
    const bool kept = second >= options_.research_inlier_ratio * last_inliers_;
    VLOG(1) << "frame " << frame->id << ": " << inliers << " local-map inliers against "
            << last_inliers_ << " in the last frame; second search found " << found << ", "
            << second << " inliers" << (kept ? "" : ", not kept");
    if (kept) {
      inliers = second;
    } else {
      *frame = first_pass;
    }
  }
  for (int i = 0; i < static_cast<int>(frame->point_ids.size()); ++i) {
    if (!frame->matched[i] || frame->outlier[i] || frame->point_ids[i] < 0) continue;
    map::MapPoint* p = map->point(frame->point_ids[i]);
    if (p != nullptr) p->found++;
  }
  frame->reference_kf_id = reference_kf_id_;
  const int needed =
      just_relocalized ? options_.min_relocalized_inliers : options_.min_local_map_inliers;
  return inliers >= needed;
}

bool CameraTracker::Relocalize(map::Frame* frame, map::Map* map) {
  const auto& f = *frame->features;
  // Query: static keypoints of the frame.
  std::vector<int> query_index;
  for (int i = 0; i < f.size(); ++i) {
    if (f.is_static[i]) query_index.push_back(i);
  }
  cv::Mat query(static_cast<int>(query_index.size()), 32, CV_8UC1);
  for (size_t k = 0; k < query_index.size(); ++k) {
    std::memcpy(query.ptr<uint8_t>(static_cast<int>(k)), f.descriptor(query_index[k]), 32);
  }
  // Candidates: the most recent keyframes, ranked by ratio-test matches.
  struct Candidate {
    int64_t kf_id;
    std::vector<std::pair<int, int64_t>> matches;  // (frame kp, point id)
  };
  std::vector<Candidate> candidates;
  int tried = 0;
  for (auto it = map->keyframes().rbegin();
       it != map->keyframes().rend() && tried < options_.relocalization_keyframes;
       ++it, ++tried) {
    const map::KeyFrame& kf = *it->second;
    std::vector<int64_t> pids;
    std::vector<int> kps;
    for (int i = 0; i < kf.features->size(); ++i) {
      if (kf.point_ids[i] >= 0 && map->GoodPoint(kf.point_ids[i]) != nullptr) {
        pids.push_back(kf.point_ids[i]);
        kps.push_back(i);
      }
    }
    if (pids.size() < 15) continue;
    cv::Mat train(static_cast<int>(pids.size()), 32, CV_8UC1);
    for (size_t k = 0; k < pids.size(); ++k) {
      std::memcpy(
          train.ptr<uint8_t>(static_cast<int>(k)), map->point(pids[k])->descriptor.data(), 32);
    }
    const auto m = features::MatchRatio(query, train, 0.75f, kThresholdLow);
    features::OrientationFilter rot;
    for (size_t k = 0; k < m.size(); ++k) {
      rot.Add(kf.features->keypoints[kps[m[k].second]].angle,
              f.keypoints[query_index[m[k].first]].angle,
              static_cast<int>(k));
    }
    std::vector<char> bad(m.size(), 0);
    for (int r : rot.Rejected()) bad[r] = 1;
    Candidate c{kf.id, {}};
    for (size_t k = 0; k < m.size(); ++k) {
      if (!bad[k]) c.matches.push_back({query_index[m[k].first], pids[m[k].second]});
    }
    if (c.matches.size() >= 15) candidates.push_back(std::move(c));
  }
  std::stable_sort(
      candidates.begin(), candidates.end(), [](const Candidate& a, const Candidate& b) {
        return a.matches.size() > b.matches.size();
      });
  if (candidates.size() > 5) candidates.resize(5);

  for (const Candidate& c : candidates) {
    std::vector<cv::Point3f> obj;
    std::vector<cv::Point2f> img;
    for (const auto& [kp, pid] : c.matches) {
      const Eigen::Vector3d& p = map->point(pid)->p_in_world;
      obj.emplace_back(
          static_cast<float>(p.x()), static_cast<float>(p.y()), static_cast<float>(p.z()));
      img.push_back(f.keypoints[kp].pt);
    }
    std::vector<int> inliers;
    geometry::SE3d camera_from_world;
    if (!SolvePnpRansac(camera_, obj, img, &camera_from_world, &inliers)) continue;
    frame->ResetMatches();
    frame->camera_from_world = camera_from_world;
    for (int k : inliers) {
      const auto& [kp, pid] = c.matches[k];
      frame->SetMatch(kp, pid, map->point(pid)->p_in_world);
    }
    int good = Optimize(frame);
    if (good < 10) continue;
    for (int i = 0; i < f.size(); ++i) {
      if (frame->matched[i] && frame->outlier[i]) frame->ClearMatch(i);
    }
    if (good < options_.min_relocalized_inliers) {
      SearchKeyFramePoints(frame, *map->keyframe(c.kf_id), *map, 10.f, kThresholdHigh);
      good = Optimize(frame);
    }
    if (good >= options_.min_relocalized_inliers) {
      for (int i = 0; i < f.size(); ++i) {
        if (frame->matched[i] && frame->outlier[i]) frame->ClearMatch(i);
      }
      last_reloc_frame_id_ = frame->id;
      reference_kf_id_ = c.kf_id;
      return true;
    }
  }
  return false;
}

void CameraTracker::ComputeStats(const map::Frame& frame) {
  stats_ = TrackingStats();
  const auto& f = *frame.features;
  const double close = options_.close_depth_baselines * camera_.baseline;
  for (int i = 0; i < f.size(); ++i) {
    const bool inlier = frame.matched[i] && !frame.outlier[i] && frame.point_ids[i] >= 0;
    if (inlier) ++stats_.num_inliers;
    if (!f.is_static[i] || !(f.depth[i] > 0.f) || f.depth[i] >= close) continue;
    if (inlier) {
      ++stats_.num_tracked_close;
    } else {
      ++stats_.num_untracked_close;
    }
  }
}

}  // namespace twist::tracking
