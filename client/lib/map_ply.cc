#include "client/lib/map_ply.h"

#include <cstdio>

namespace twist::client {
namespace {

// Cityscapes-like colours for the default classes; a hash colour otherwise.
void ClassColour(int class_id, int* r, int* g, int* b) {
  switch (class_id) {
    case 7:
      *r = 128;
      *g = 64;
      *b = 128;
      return;  // road
    case 8:
      *r = 244;
      *g = 35;
      *b = 232;
      return;  // sidewalk
    case 11:
      *r = 70;
      *g = 70;
      *b = 70;
      return;  // building
    case 12:
      *r = 102;
      *g = 102;
      *b = 156;
      return;  // wall
    case 21:
      *r = 107;
      *g = 142;
      *b = 35;
      return;  // vegetation
    case 24:
      *r = 220;
      *g = 20;
      *b = 60;
      return;  // person
    case 26:
      *r = 0;
      *g = 0;
      *b = 142;
      return;  // car
    default:
      break;
  }
  const unsigned h = static_cast<unsigned>(class_id) * 2654435761u;
  *r = 64 + static_cast<int>(h & 127);
  *g = 64 + static_cast<int>((h >> 8) & 127);
  *b = 64 + static_cast<int>((h >> 16) & 127);
}

}  // namespace

std::string MapToPly(const MapSnapshot& map) {
  std::string out;
  const size_t n = map.points.size() + map.keyframes.size();
  out +=
      "ply\nformat ascii 1.0\ncomment TwistSLAM map: points by class, then keyframe centres "
      "(class_id -1)\n";
  out += "element vertex " + std::to_string(n) + "\n";
  out += "property float x\nproperty float y\nproperty float z\n";
  out += "property uchar red\nproperty uchar green\nproperty uchar blue\n";
  out += "property int class_id\nproperty int cluster_id\nend_header\n";
  char line[160];
  for (const MapSnapshot::Point& p : map.points) {
    int r, g, b;
    ClassColour(p.class_id, &r, &g, &b);
    std::snprintf(line,
                  sizeof(line),
                  "%.6f %.6f %.6f %d %d %d %d %lld\n",
                  p.p_in_world.x(),
                  p.p_in_world.y(),
                  p.p_in_world.z(),
                  r,
                  g,
                  b,
                  p.class_id,
                  static_cast<long long>(p.cluster_id));
    out += line;
  }
  for (const MapSnapshot::KeyFrame& kf : map.keyframes) {
    const Eigen::Vector3d c = kf.world_from_camera.translation();
    std::snprintf(line, sizeof(line), "%.6f %.6f %.6f 255 255 255 -1 -1\n", c.x(), c.y(), c.z());
    out += line;
  }
  return out;
}

}  // namespace twist::client
