// Label fusion for map points (paper §IV-A, after S3LAM): every observation of
// a map point votes for the panoptic label under its keypoint; the point takes
// the class with the largest vote, then the instance with the largest vote
// within that class.
#pragma once

#include <optional>
#include <vector>

#include "slam/semantic/panoptic.h"

namespace twist::semantic {

struct FusedLabel {
  PanopticLabel label;
  // Share of the total vote weight that went to label.class_id, in [0, 1].
  double class_confidence = 0.0;
  // Share of the class's vote weight that went to label.instance_id, in [0, 1].
  double instance_confidence = 0.0;
  double total_weight = 0.0;
  int num_votes = 0;
};

// Accumulates weighted votes. Small (a few distinct labels per point), cheap
// to copy, deterministic: ties go to the label voted for most recently among
// the tied ones.
class LabelVote {
 public:
  // weight > 0 (e.g. 1 per observation, or the keypoint's detection score).
  void Add(const PanopticLabel& label, double weight = 1.0);
  // Removes a previously added vote (e.g. when an observation is culled).
  // Returns false when no such vote was recorded.
  bool Remove(const PanopticLabel& label, double weight = 1.0);

  // nullopt before any vote.
  std::optional<FusedLabel> Fused() const;
  int num_votes() const { return num_votes_; }
  bool empty() const { return num_votes_ == 0; }

 private:
  struct Entry {
    PanopticLabel label;
    double weight = 0.0;
    int count = 0;
    int last_vote = 0;  // sequence number of the latest vote, for tie breaks
  };
  std::vector<Entry> entries_;
  int num_votes_ = 0;
  int sequence_ = 0;
};

// Convenience: fuses a list of labels (nullopt observations are skipped).
std::optional<FusedLabel> FuseLabels(const std::vector<std::optional<PanopticLabel>>& labels);

}  // namespace twist::semantic
