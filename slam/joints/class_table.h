// The semantic graph: which classes exist, which are a-priori dynamic, and to
// which static parent each dynamic class is linked by which joint.
// Session configuration, not code: many sessions with different tables share
// one process.
#pragma once

#include <map>
#include <string>
#include <vector>

#include "absl/status/status.h"
#include "absl/status/statusor.h"
#include "slam/joints/joint.h"

namespace twist::joints {

struct ClassInfo {
  int id = 0;             // panoptic class id (Cityscapes ids by default)
  std::string name;       // "car"
  bool is_dynamic = false;
  int parent_id = -1;     // static parent class for dynamic classes, -1 none
  JointType joint = JointType::kFree;
  double pitch = 0.0;     // helical joints only (m/rad)
  bool fit_plane = false; // fit a plane to this (static) class's clusters
};

class ClassTable {
 public:
  ClassTable() = default;
  // Cityscapes ids: road 7 (plane), sidewalk 8 (plane), building 11 (plane),
  // wall 12 (plane), fence 13, pole 17, vegetation 21, terrain 22, sky 23,
  // person 24, rider 25, car 26, truck 27, bus 28, train 31, motorcycle 32,
  // bicycle 33; dynamic classes planar on road; plus "door" (id 40) revolute on
  // wall used by the synthetic generator.
  static ClassTable CityscapesDefault();
  // Parses the text format documented in docs/config.md and validates it.
  static absl::StatusOr<ClassTable> FromText(const std::string& text);
  std::string ToText() const;

  // Builds and validates: unknown parent, cycles, dynamic parent, duplicate
  // ids, static class with a parent -> InvalidArgument naming the class.
  static absl::StatusOr<ClassTable> Create(std::vector<ClassInfo> classes);
  absl::Status Validate() const;

  // nullptr for unknown ids (unknown classes are treated as static).
  const ClassInfo* Find(int class_id) const;
  bool IsDynamic(int class_id) const;
  const std::vector<ClassInfo>& classes() const { return classes_; }

 private:
  std::vector<ClassInfo> classes_;
  std::map<int, size_t> index_;
};

}  // namespace twist::joints
