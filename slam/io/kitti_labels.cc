#include "slam/io/kitti_labels.h"

#include <cmath>

#include "slam/io/file_util.h"

namespace twist::io {

geometry::SE3d KittiLabel::RefFromObject() const {
  const double c = std::cos(rotation_y);
  const double s = std::sin(rotation_y);
  Eigen::Matrix3d r;
  r << c, 0, s, 0, 1, 0, -s, 0, c;
  // Box centre is half the height above (−y) the bottom centre.
  const Eigen::Vector3d centre = location - Eigen::Vector3d(0, height / 2, 0);
  return geometry::SE3d(r, centre);
}

std::array<Eigen::Vector3d, 8> KittiLabel::Corners() const {
  const geometry::SE3d ref_from_object = RefFromObject();
  std::array<Eigen::Vector3d, 8> corners;
  int k = 0;
  for (int sx : {-1, 1}) {
    for (int sy : {-1, 1}) {
      for (int sz : {-1, 1}) {
        const Eigen::Vector3d p(sx * length / 2, sy * height / 2, sz * width / 2);
        corners[k++] = ref_from_object * p;
      }
    }
  }
  return corners;
}

absl::StatusOr<std::vector<KittiLabel>> ReadKittiLabels(const std::string& path) {
  absl::StatusOr<std::string> text = ReadTextFile(path);
  if (!text.ok()) return text.status();
  std::vector<KittiLabel> labels;
  for (const TextLine& line : SplitLines(*text)) {
    const std::vector<std::string_view> f = SplitFields(line.text);
    if (f.size() != 17 && f.size() != 18) {
      return LineError(path,
                       line.number,
                       "expected 17 fields (frame track_id type truncated occluded alpha x1 y1 "
                       "x2 y2 h w l x y z rotation_y), found " +
                           std::to_string(f.size()));
    }
    KittiLabel l;
    int64_t occluded = 0;
    if (!ParseInt64(f[0], &l.frame) || l.frame < 0) {
      return LineError(path, line.number, "frame '" + std::string(f[0]) + "' is not an index");
    }
    if (!ParseInt64(f[1], &l.track_id)) {
      return LineError(path, line.number, "track_id '" + std::string(f[1]) + "' is not an integer");
    }
    l.type = std::string(f[2]);
    double d[13];
    for (int i = 0; i < 13; ++i) {
      const size_t idx = (i == 0) ? 3 : static_cast<size_t>(4 + i);  // skip 'occluded' (f[4])
      if (!ParseDouble(f[idx], &d[i])) {
        return LineError(
            path,
            line.number,
            "field " + std::to_string(idx + 1) + " '" + std::string(f[idx]) + "' is not a number");
      }
    }
    if (!ParseInt64(f[4], &occluded)) {
      return LineError(path, line.number, "occluded '" + std::string(f[4]) + "' is not an integer");
    }
    l.truncated = d[0];
    l.occluded = static_cast<int>(occluded);
    l.alpha = d[1];
    l.x1 = d[2];
    l.y1 = d[3];
    l.x2 = d[4];
    l.y2 = d[5];
    l.height = d[6];
    l.width = d[7];
    l.length = d[8];
    l.location = Eigen::Vector3d(d[9], d[10], d[11]);
    l.rotation_y = d[12];
    if (f.size() == 18 && !ParseDouble(f[17], &l.score)) {
      return LineError(path, line.number, "score '" + std::string(f[17]) + "' is not a number");
    }
    if (l.x2 < l.x1 || l.y2 < l.y1) {
      return LineError(path, line.number, "2D box has x2 < x1 or y2 < y1");
    }
    labels.push_back(l);
  }
  return labels;
}

int KittiTypeToClassId(const std::string& type) {
  if (type == "Car" || type == "Van") return 26;
  if (type == "Truck") return 27;
  if (type == "Pedestrian" || type == "Person_sitting" || type == "Person") return 24;
  if (type == "Cyclist") return 25;
  if (type == "Tram") return 31;
  return 0;
}

}  // namespace twist::io
