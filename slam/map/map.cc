#include "slam/map/map.h"

#include <glog/logging.h>

#include <algorithm>
#include <chrono>
#include <climits>
#include <cmath>
#include <thread>

namespace twist::map {

void Frame::ResetMatches() {
  const int n = features ? features->size() : 0;
  point_ids.assign(n, -1);
  p_in_world.assign(n, Eigen::Vector3d::Zero());
  matched.assign(n, 0);
  outlier.assign(n, 0);
}

void Frame::SetMatch(int i, int64_t point_id, const Eigen::Vector3d& p) {
  point_ids[i] = point_id;
  p_in_world[i] = p;
  matched[i] = 1;
  outlier[i] = 0;
}

void Frame::ClearMatch(int i) {
  point_ids[i] = -1;
  matched[i] = 0;
  outlier[i] = 0;
}

int Frame::NumMapMatches() const {
  int n = 0;
  for (size_t i = 0; i < point_ids.size(); ++i) n += (point_ids[i] >= 0 && !outlier[i]);
  return n;
}

std::vector<int64_t> KeyFrame::BestCovisible(int n) const {
  if (n < 0 || n >= static_cast<int>(ordered_connections.size())) return ordered_connections;
  return std::vector<int64_t>(ordered_connections.begin(), ordered_connections.begin() + n);
}

int KeyFrame::TrackedPoints(int min_obs, const Map& map) const {
  int n = 0;
  for (int64_t pid : point_ids) {
    if (pid < 0) continue;
    const MapPoint* p = map.point(pid);
    if (p == nullptr || p->bad) continue;
    if (static_cast<int>(p->observations.size()) >= min_obs) ++n;
  }
  return n;
}

int MapPoint::PredictScale(float distance, const features::ScalePyramid& pyramid) const {
  if (distance <= 0.f) return 0;
  const float ratio = max_distance / distance;
  int level = static_cast<int>(std::ceil(std::log(ratio) / pyramid.log_scale_factor));
  return std::clamp(level, 0, pyramid.num_levels() - 1);
}

void Map::YieldToPriorityWaiter(std::unique_lock<std::mutex>* lock) const {
  lock->unlock();
  if (priority_waiters_.load(std::memory_order_acquire) == 0) {
    std::this_thread::yield();
  } else {
    // Until the waiter holds the map (it leaves the count once it does);
    // bounded so that a waiter that never comes cannot stall the mapper.
    for (int i = 0; i < 500 && priority_waiters_.load(std::memory_order_acquire) > 0; ++i) {
      std::this_thread::sleep_for(std::chrono::microseconds(20));
    }
  }
  lock->lock();
}

Map::Map(const geometry::StereoCamera& camera, const features::ScalePyramid& pyramid)
    : camera_(camera), pyramid_(pyramid) {}

KeyFrame* Map::CreateKeyFrame(const Frame& frame) {
  auto kf = std::make_unique<KeyFrame>();
  kf->id = next_kf_id_++;
  kf->frame_id = frame.id;
  kf->timestamp_ns = frame.timestamp_ns;
  kf->features = frame.features;
  kf->camera_from_world = frame.camera_from_world;
  kf->point_ids.assign(frame.features->size(), -1);
  KeyFrame* raw = kf.get();
  keyframes_[raw->id] = std::move(kf);
  return raw;
}

MapPoint* Map::CreatePoint(const Eigen::Vector3d& p_in_world, const KeyFrame& reference_kf) {
  auto p = std::make_unique<MapPoint>();
  p->id = next_point_id_++;
  p->p_in_world = p_in_world;
  p->reference_kf_id = reference_kf.id;
  p->first_kf_id = reference_kf.id;
  MapPoint* raw = p.get();
  points_[raw->id] = std::move(p);
  point_index_[raw->id] = raw;
  return raw;
}

KeyFrame* Map::InsertKeyFrame(std::unique_ptr<KeyFrame> kf) {
  KeyFrame* raw = kf.get();
  keyframes_[raw->id] = std::move(kf);
  return raw;
}

MapPoint* Map::InsertPoint(std::unique_ptr<MapPoint> p) {
  MapPoint* raw = p.get();
  std::unique_ptr<MapPoint>& slot = points_[raw->id];
  if (slot != nullptr && slot->bad) --num_bad_points_;
  if (raw->bad) ++num_bad_points_;
  slot = std::move(p);
  point_index_[raw->id] = raw;
  return raw;
}

KeyFrame* Map::keyframe(int64_t id) {
  auto it = keyframes_.find(id);
  return it == keyframes_.end() ? nullptr : it->second.get();
}
const KeyFrame* Map::keyframe(int64_t id) const {
  auto it = keyframes_.find(id);
  return it == keyframes_.end() ? nullptr : it->second.get();
}
MapPoint* Map::point(int64_t id) {
  auto it = point_index_.find(id);
  return it == point_index_.end() ? nullptr : it->second;
}
const MapPoint* Map::point(int64_t id) const {
  auto it = point_index_.find(id);
  return it == point_index_.end() ? nullptr : it->second;
}
MapPoint* Map::GoodPoint(int64_t id) {
  if (id < 0) return nullptr;
  MapPoint* p = point(id);
  return (p == nullptr || p->bad) ? nullptr : p;
}

int Map::NumGoodKeyFrames() const {
  int n = 0;
  for (const auto& [id, kf] : keyframes_) n += !kf->bad;
  return n;
}
int Map::NumGoodPoints() const {
  // Points leave the map as they go bad (ErasePoint); only a point inserted
  // bad (a state file's) is held bad, and counted.
  return static_cast<int>(points_.size()) - num_bad_points_;
}

void Map::AddObservation(MapPoint* point, KeyFrame* kf, int kp_index) {
  point->observations[kf->id] = kp_index;
  kf->point_ids[kp_index] = point->id;
}

void Map::EraseObservation(MapPoint* point, int64_t kf_id) {
  auto it = point->observations.find(kf_id);
  if (it == point->observations.end()) return;
  KeyFrame* kf = keyframe(kf_id);
  if (kf != nullptr && kf->point_ids[it->second] == point->id) kf->point_ids[it->second] = -1;
  point->observations.erase(it);
  if (point->reference_kf_id == kf_id && !point->observations.empty()) {
    point->reference_kf_id = point->observations.begin()->first;
  }
  // Stereo points need two keyframes to stay meaningful in the graph.
  if (point->observations.size() <= 1) ErasePoint(point->id);
}

void Map::UpdatePointDescriptor(MapPoint* point) {
  std::vector<const uint8_t*> descs;
  for (const auto& [kf_id, idx] : point->observations) {
    const KeyFrame* kf = keyframe(kf_id);
    if (kf == nullptr || kf->bad) continue;
    descs.push_back(kf->features->descriptor(idx));
  }
  if (descs.empty()) return;
  const int n = static_cast<int>(descs.size());
  int best_median = INT_MAX, best = 0;
  std::vector<int> d(n);
  for (int i = 0; i < n; ++i) {
    for (int j = 0; j < n; ++j) d[j] = features::DescriptorDistance(descs[i], descs[j]);
    std::nth_element(d.begin(), d.begin() + (n - 1) / 2, d.end());
    const int median = d[(n - 1) / 2];
    if (median < best_median) {
      best_median = median;
      best = i;
    }
  }
  std::copy(descs[best], descs[best] + point->descriptor.size(), point->descriptor.begin());
}

void Map::UpdatePointNormalAndDepth(MapPoint* point) {
  if (point->observations.empty()) return;
  Eigen::Vector3d normal = Eigen::Vector3d::Zero();
  int n = 0;
  for (const auto& [kf_id, idx] : point->observations) {
    const KeyFrame* kf = keyframe(kf_id);
    if (kf == nullptr || kf->bad) continue;
    normal += (point->p_in_world - kf->CameraCenter()).normalized();
    ++n;
  }
  const KeyFrame* ref = keyframe(point->reference_kf_id);
  if (n == 0 || ref == nullptr) return;
  auto it = point->observations.find(ref->id);
  if (it == point->observations.end()) return;
  const float dist = static_cast<float>((point->p_in_world - ref->CameraCenter()).norm());
  const int level = ref->features->keypoints[it->second].octave;
  point->max_distance = dist * pyramid_.scale[level];
  point->min_distance = point->max_distance / pyramid_.scale.back();
  point->normal = normal / n;
}

void Map::ErasePoint(int64_t point_id) {
  auto it = points_.find(point_id);
  if (it == points_.end()) return;
  MapPoint* p = it->second.get();
  if (p->bad) --num_bad_points_;
  p->bad = true;
  for (const auto& [kf_id, idx] : p->observations) {
    KeyFrame* kf = keyframe(kf_id);
    if (kf != nullptr && kf->point_ids[idx] == point_id) kf->point_ids[idx] = -1;
  }
  point_index_.erase(point_id);
  points_.erase(it);
}

void Map::ReplacePoint(int64_t old_id, int64_t new_id) {
  if (old_id == new_id) return;
  MapPoint* old_p = point(old_id);
  MapPoint* new_p = point(new_id);
  if (old_p == nullptr || new_p == nullptr) return;
  for (const auto& [kf_id, idx] : old_p->observations) {
    KeyFrame* kf = keyframe(kf_id);
    if (kf == nullptr) continue;
    if (new_p->observations.count(kf_id) == 0) {
      kf->point_ids[idx] = new_id;
      new_p->observations[kf_id] = idx;
    } else if (kf->point_ids[idx] == old_id) {
      kf->point_ids[idx] = -1;
    }
  }
  new_p->visible += old_p->visible;
  new_p->found += old_p->found;
  old_p->observations.clear();
  if (old_p->bad) --num_bad_points_;
  point_index_.erase(old_id);
  points_.erase(old_id);
  UpdatePointDescriptor(new_p);
}

void Map::UpdateConnections(KeyFrame* kf) {
  std::map<int64_t, int> counter;
  for (int64_t pid : kf->point_ids) {
    if (pid < 0) continue;
    const MapPoint* p = point(pid);
    if (p == nullptr || p->bad) continue;
    for (const auto& [other, idx] : p->observations) {
      if (other != kf->id) counter[other]++;
    }
  }
  // Drop old edges.
  for (const auto& [other, w] : kf->connections) {
    KeyFrame* o = keyframe(other);
    if (o == nullptr) continue;
    o->connections.erase(kf->id);
  }
  kf->connections.clear();
  constexpr int kMinWeight = 15;
  int64_t best_id = -1;
  int best_w = 0;
  std::vector<std::pair<int64_t, int>> edges;
  for (const auto& [other, w] : counter) {
    KeyFrame* o = keyframe(other);
    if (o == nullptr || o->bad) continue;
    if (w > best_w) {
      best_w = w;
      best_id = other;
    }
    if (w >= kMinWeight) edges.push_back({other, w});
  }
  if (edges.empty() && best_id >= 0) edges.push_back({best_id, best_w});
  auto order = [](std::map<int64_t, int>& conn, std::vector<int64_t>* ordered) {
    std::vector<std::pair<int64_t, int>> v(conn.begin(), conn.end());
    std::stable_sort(v.begin(), v.end(), [](const auto& a, const auto& b) {
      return a.second != b.second ? a.second > b.second : a.first < b.first;
    });
    ordered->clear();
    for (const auto& e : v) ordered->push_back(e.first);
  };
  for (const auto& [other, w] : edges) {
    kf->connections[other] = w;
    KeyFrame* o = keyframe(other);
    o->connections[kf->id] = w;
    order(o->connections, &o->ordered_connections);
  }
  order(kf->connections, &kf->ordered_connections);
}

void Map::EraseKeyFrame(int64_t kf_id) {
  KeyFrame* kf = keyframe(kf_id);
  if (kf == nullptr || kf->bad) return;
  kf->bad = true;
  for (const auto& [other, w] : kf->connections) {
    KeyFrame* o = keyframe(other);
    if (o == nullptr) continue;
    o->connections.erase(kf_id);
    o->ordered_connections.erase(
        std::remove(o->ordered_connections.begin(), o->ordered_connections.end(), kf_id),
        o->ordered_connections.end());
  }
  kf->connections.clear();
  kf->ordered_connections.clear();
  for (int64_t pid : std::vector<int64_t>(kf->point_ids)) {
    MapPoint* p = point(pid);
    if (p != nullptr) EraseObservation(p, kf_id);
  }
  keyframes_.erase(kf_id);
}

geometry::SE3d CanonicalPose(const geometry::SE3d& pose) {
  geometry::SE3d current = pose;
  for (int i = 0; i < 8; ++i) {
    const geometry::SE3d next(current.unit_quaternion(), current.translation());
    if (next.unit_quaternion().coeffs() == current.unit_quaternion().coeffs()) return current;
    current = next;
  }
  return current;
}

std::shared_ptr<FrameFeatures> FinalizeFeatures(FrameFeatures f, int width, int height) {
  const int n = f.size();
  if (f.u_right.size() != static_cast<size_t>(n)) f.u_right.assign(n, -1.f);
  if (f.depth.size() != static_cast<size_t>(n)) f.depth.assign(n, -1.f);
  if (f.labels.size() != static_cast<size_t>(n)) f.labels.assign(n, 0);
  if (f.is_static.size() != static_cast<size_t>(n)) f.is_static.assign(n, 1);
  f.grid = features::KeypointGrid(f.keypoints, width, height);
  return std::make_shared<FrameFeatures>(std::move(f));
}

std::shared_ptr<const FrameFeatures> WithDisparityOffset(
    const std::shared_ptr<const FrameFeatures>& features,
    const geometry::StereoCamera& camera,
    float offset) {
  if (features == nullptr || features->disparity_offset == offset) return features;
  auto out = std::make_shared<FrameFeatures>(*features);
  const float shift = offset - features->disparity_offset;
  const float bf = static_cast<float>(camera.bf());
  for (int i = 0; i < out->size(); ++i) {
    if (out->u_right[i] < 0.f) continue;
    const float u = out->keypoints[i].pt.x;
    const float disparity = u - out->u_right[i] + shift;
    if (disparity <= 0.f || u - disparity < 0.f) {
      out->u_right[i] = -1.f;
      out->depth[i] = -1.f;
      continue;
    }
    out->u_right[i] = u - disparity;
    out->depth[i] = bf / disparity;
  }
  out->disparity_offset = offset;
  return out;
}

}  // namespace twist::map
