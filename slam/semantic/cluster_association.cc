#include "slam/semantic/cluster_association.h"

#include <glog/logging.h>

#include <algorithm>
#include <cmath>
#include <opencv2/core.hpp>

#include "slam/semantic/hungarian.h"

namespace twist::semantic {

double BoxIoU(const cv::Rect2d& a, const cv::Rect2d& b) {
  const double inter = (a & b).area();
  const double uni = a.area() + b.area() - inter;
  return uni > 0.0 ? inter / uni : 0.0;
}

double MaskIoU(const cv::Mat& a, const cv::Mat& b, cv::Rect roi) {
  CHECK_EQ(a.type(), CV_8UC1);
  CHECK_EQ(b.type(), CV_8UC1);
  CHECK(a.size() == b.size()) << "mask IoU needs masks of the same size";
  const cv::Rect full(0, 0, a.cols, a.rows);
  roi = roi.empty() ? full : (roi & full);
  if (roi.empty()) return 0.0;
  cv::Mat inter, uni;
  cv::bitwise_and(a(roi), b(roi), inter);
  cv::bitwise_or(a(roi), b(roi), uni);
  const int n_uni = cv::countNonZero(uni);
  return n_uni > 0 ? static_cast<double>(cv::countNonZero(inter)) / n_uni : 0.0;
}

absl::Status ClusterAssociationOptions::Validate() const {
  if (point_weight < 0 || overlap_weight < 0 || point_weight + overlap_weight <= 0) {
    return absl::InvalidArgumentError(
        "cluster association weights must be >= 0 with a positive sum");
  }
  if (lost_after_frames < 1 || remove_after_frames < lost_after_frames) {
    return absl::InvalidArgumentError(
        "cluster association needs 1 <= lost_after_frames <= remove_after_frames");
  }
  return absl::OkStatus();
}

ClusterAssociator::ClusterAssociator(const ClusterAssociationOptions& options) : options_(options) {
  CHECK(options_.Validate().ok()) << options_.Validate().message();
}

ClusterTrack* ClusterAssociator::Find(int64_t id) {
  auto it = clusters_.find(id);
  return it == clusters_.end() ? nullptr : &it->second;
}

void ClusterAssociator::SetPrediction(int64_t id, const cv::Rect2d& box, const cv::Mat& mask) {
  ClusterTrack* c = Find(id);
  if (c == nullptr) return;
  c->predicted_box = box;
  c->predicted_mask = mask;
}

void ClusterAssociator::AddPoints(int64_t id, const std::vector<int64_t>& point_ids) {
  ClusterTrack* c = Find(id);
  if (c == nullptr) return;
  c->point_ids.insert(point_ids.begin(), point_ids.end());
}

double ClusterAssociator::Score(const Detection& d, const ClusterTrack& c) const {
  if (d.label.class_id != c.class_id) return 0.0;
  // Overlap with where the cluster should be (prediction) or was (last seen).
  double overlap = 0.0;
  const cv::Mat& ref_mask = !c.predicted_mask.empty() ? c.predicted_mask : c.last_mask;
  if (!d.mask.empty() && !ref_mask.empty() && d.mask.size() == ref_mask.size()) {
    // Scan only the union of the boxes when both boxes are known (a box
    // must cover its mask); otherwise the whole image.
    const std::optional<cv::Rect2d> ref_box =
        !c.predicted_mask.empty() ? c.predicted_box : std::optional<cv::Rect2d>(c.last_box);
    cv::Rect roi;
    bool disjoint = false;
    if (ref_box && !d.box.empty() && !ref_box->empty()) {
      const cv::Rect2d u = d.box | *ref_box;
      roi = cv::Rect(static_cast<int>(std::floor(u.x)),
                     static_cast<int>(std::floor(u.y)),
                     static_cast<int>(std::ceil(u.width)) + 2,
                     static_cast<int>(std::ceil(u.height)) + 2);
      // Masks inside boxes that do not meet (a pixel of slack) share no pixel.
      const cv::Rect2d slack_d(d.box.x - 1, d.box.y - 1, d.box.width + 2, d.box.height + 2);
      disjoint = (slack_d & *ref_box).empty();
    }
    overlap = disjoint ? 0.0 : MaskIoU(d.mask, ref_mask, roi);
  } else {
    overlap = BoxIoU(d.box, c.predicted_box.value_or(c.last_box));
  }
  double score;
  if (!d.point_ids.empty() && options_.point_weight > 0.0) {
    int shared = 0;
    for (int64_t id : d.point_ids) shared += c.point_ids.count(id) > 0 ? 1 : 0;
    const double point_share = static_cast<double>(shared) / d.point_ids.size();
    score = (options_.point_weight * point_share + options_.overlap_weight * overlap) /
            (options_.point_weight + options_.overlap_weight);
  } else {
    score = overlap;  // nothing else to go by
  }
  if (d.label.instance_id == c.instance_id && score > 0.0) score += options_.instance_bonus;
  return score;
}

AssociationResult ClusterAssociator::Associate(const std::vector<Detection>& detections) {
  AssociationResult result;
  const size_t n = detections.size();
  result.cluster_of_detection.assign(n, -1);
  result.score_of_detection.assign(n, 0.0);

  auto make_event = [&](ClusterEventType type, const ClusterTrack& c) {
    ClusterEvent e;
    e.type = type;
    e.cluster_id = c.id;
    e.class_id = c.class_id;
    e.instance_id = c.instance_id;
    e.is_dynamic = dynamic_classes_.count(c.class_id) > 0;
    return e;
  };

  // Stuff: one cluster per class.
  std::vector<size_t> things;
  for (size_t k = 0; k < n; ++k) {
    const Detection& d = detections[k];
    if (options_.stuff_by_class && d.label.instance_id == 0) {
      for (auto& [id, c] : clusters_) {
        if (c.class_id == d.label.class_id && c.instance_id == 0) {
          result.cluster_of_detection[k] = id;
          result.score_of_detection[k] = 1.0;
          break;
        }
      }
    } else {
      things.push_back(k);
    }
  }

  // Things: Hungarian on the score matrix (stuff clusters never absorb things).
  std::vector<int64_t> ids;
  for (const auto& [id, c] : clusters_) {
    if (!(options_.stuff_by_class && c.is_stuff)) ids.push_back(id);
  }
  Eigen::MatrixXd score =
      Eigen::MatrixXd::Zero(static_cast<int>(things.size()), static_cast<int>(ids.size()));
  for (size_t r = 0; r < things.size(); ++r) {
    for (size_t col = 0; col < ids.size(); ++col) {
      score(static_cast<int>(r), static_cast<int>(col)) =
          Score(detections[things[r]], clusters_.at(ids[col]));
    }
  }
  const std::vector<int> assignment = MaxScoreAssignment(score, options_.min_score);
  for (size_t r = 0; r < things.size(); ++r) {
    if (assignment[r] < 0) continue;
    result.cluster_of_detection[things[r]] = ids[static_cast<size_t>(assignment[r])];
    result.score_of_detection[things[r]] = score(static_cast<int>(r), assignment[r]);
  }

  // Update matched clusters, create new ones.
  std::unordered_set<int64_t> seen;
  for (size_t k = 0; k < n; ++k) {
    const Detection& d = detections[k];
    int64_t id = result.cluster_of_detection[k];
    if (id < 0 || seen.count(id) > 0) {
      ClusterTrack c;
      c.id = next_id_++;
      c.class_id = d.label.class_id;
      c.instance_id = d.label.instance_id;
      c.state = ClusterState::kNew;
      c.is_stuff = d.label.instance_id == 0;
      id = c.id;
      clusters_.emplace(id, std::move(c));
      result.created.push_back(id);
      result.cluster_of_detection[k] = id;
      result.score_of_detection[k] = 0.0;
      result.events.push_back(make_event(ClusterEventType::kCreated, clusters_.at(id)));
    } else {
      clusters_.at(id).state = ClusterState::kTracked;  // also when re-found after a loss
    }
    seen.insert(id);
    ClusterTrack& c = clusters_.at(id);
    c.instance_id = d.label.instance_id;
    c.last_box = d.box;
    c.last_mask = d.mask;
    c.point_ids.insert(d.point_ids.begin(), d.point_ids.end());
    c.frames_since_seen = 0;
    ++c.num_frames_seen;
  }

  // Age unseen clusters.
  for (auto it = clusters_.begin(); it != clusters_.end();) {
    ClusterTrack& c = it->second;
    c.predicted_box.reset();
    c.predicted_mask = cv::Mat();
    if (seen.count(c.id) > 0) {
      ++it;
      continue;
    }
    ++c.frames_since_seen;
    if (c.frames_since_seen >= options_.remove_after_frames) {
      result.removed.push_back(c.id);
      result.events.push_back(make_event(ClusterEventType::kRemoved, c));
      it = clusters_.erase(it);
      continue;
    }
    if (c.frames_since_seen >= options_.lost_after_frames && c.state != ClusterState::kLost) {
      c.state = ClusterState::kLost;
      result.lost.push_back(c.id);
      result.events.push_back(make_event(ClusterEventType::kLost, c));
    }
    ++it;
  }
  return result;
}

}  // namespace twist::semantic
