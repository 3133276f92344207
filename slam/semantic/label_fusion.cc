#include "slam/semantic/label_fusion.h"

#include <glog/logging.h>

#include <map>

namespace twist::semantic {

void LabelVote::Add(const PanopticLabel& label, double weight) {
  CHECK_GT(weight, 0.0) << "label votes need a positive weight";
  ++sequence_;
  ++num_votes_;
  for (Entry& e : entries_) {
    if (e.label == label) {
      e.weight += weight;
      ++e.count;
      e.last_vote = sequence_;
      return;
    }
  }
  entries_.push_back(Entry{label, weight, 1, sequence_});
}

bool LabelVote::Remove(const PanopticLabel& label, double weight) {
  for (size_t k = 0; k < entries_.size(); ++k) {
    Entry& e = entries_[k];
    if (e.label != label) continue;
    --num_votes_;
    if (--e.count <= 0) {
      entries_.erase(entries_.begin() + static_cast<long>(k));
    } else {
      e.weight = std::max(0.0, e.weight - weight);
    }
    return true;
  }
  return false;
}

std::optional<FusedLabel> LabelVote::Fused() const {
  if (entries_.empty()) return std::nullopt;
  // Per class: total weight and most recent vote.
  struct ClassAcc {
    double weight = 0.0;
    int last_vote = 0;
  };
  std::map<int, ClassAcc> classes;
  double total = 0.0;
  for (const Entry& e : entries_) {
    ClassAcc& c = classes[e.label.class_id];
    c.weight += e.weight;
    c.last_vote = std::max(c.last_vote, e.last_vote);
    total += e.weight;
  }
  int best_class = 0;
  ClassAcc best{-1.0, 0};
  for (const auto& [id, c] : classes) {
    if (c.weight > best.weight || (c.weight == best.weight && c.last_vote > best.last_vote)) {
      best = c;
      best_class = id;
    }
  }
  const Entry* best_entry = nullptr;
  for (const Entry& e : entries_) {
    if (e.label.class_id != best_class) continue;
    if (best_entry == nullptr || e.weight > best_entry->weight ||
        (e.weight == best_entry->weight && e.last_vote > best_entry->last_vote)) {
      best_entry = &e;
    }
  }
  FusedLabel out;
  out.label = best_entry->label;
  out.total_weight = total;
  out.num_votes = num_votes_;
  out.class_confidence = total > 0.0 ? best.weight / total : 0.0;
  out.instance_confidence = best.weight > 0.0 ? best_entry->weight / best.weight : 0.0;
  return out;
}

std::optional<FusedLabel> FuseLabels(const std::vector<std::optional<PanopticLabel>>& labels) {
  LabelVote vote;
  for (const auto& l : labels) {
    if (l.has_value()) vote.Add(*l);
  }
  return vote.Fused();
}

}  // namespace twist::semantic
