// Point clouds in PLY (ASCII or binary little-endian): the map points a run
// may write (points.ply / map.ply). Only the vertex element is read: x, y, z
// (float or double) and, when present, integer properties `class_id` /
// `cluster_id` and uchar `red green blue`; other properties are skipped.
#pragma once

#include <Eigen/Core>
#include <cstdint>
#include <string>
#include <vector>

#include "absl/status/status.h"
#include "absl/status/statusor.h"

namespace twist::io {

struct PlyPoint {
  Eigen::Vector3d p_in_world = Eigen::Vector3d::Zero();
  int class_id = -1;  // -1: not in the file
  int64_t cluster_id = -1;
  uint8_t r = 0, g = 0, b = 0;
  bool has_colour = false;
};

absl::StatusOr<std::vector<PlyPoint>> ReadPlyPoints(const std::string& path);

// ASCII PLY with x y z (double), class_id, cluster_id and colour.
absl::Status WritePlyPoints(const std::string& path, const std::vector<PlyPoint>& points);

}  // namespace twist::io
