#include "slam/sim/scene.h"

namespace twist::sim {

void AppendBoxQuads(const BoxPart& box,
                    const geometry::SE3d& world_from_box,
                    uint16_t panoptic,
                    std::vector<Quad>* quads) {
  const Eigen::Vector3d& a = box.min;
  const Eigen::Vector3d& b = box.max;
  const Eigen::Vector3d d = b - a;
  const Eigen::Vector3d ex = Eigen::Vector3d::UnitX(), ey = Eigen::Vector3d::UnitY(),
                        ez = Eigen::Vector3d::UnitZ();
  struct Local {
    Eigen::Vector3d origin, u, v;
    double su, sv;
  };
  // Vertical faces: axis_v = -y (up) from the bottom (max y) edge; normals outward.
  const std::array<Local, 6> faces = {{
      {Eigen::Vector3d(b.x(), b.y(), a.z()), ez, -ey, d.z(), d.y()},   // +X
      {Eigen::Vector3d(a.x(), b.y(), b.z()), -ez, -ey, d.z(), d.y()},  // -X
      {Eigen::Vector3d(a.x(), b.y(), b.z()), ex, -ez, d.x(), d.z()},   // bottom (+Y)
      {Eigen::Vector3d(a.x(), a.y(), a.z()), ex, ez, d.x(), d.z()},    // top (-Y)
      {Eigen::Vector3d(b.x(), b.y(), b.z()), -ex, -ey, d.x(), d.y()},  // +Z
      {Eigen::Vector3d(a.x(), b.y(), a.z()), ex, -ey, d.x(), d.y()},   // -Z
  }};
  const Eigen::Matrix3d r = world_from_box.rotation();
  for (int f = 0; f < 6; ++f) {
    if (box.materials[f] < 0) continue;
    Quad q;
    q.origin = world_from_box * faces[f].origin;
    q.axis_u = r * faces[f].u;
    q.axis_v = r * faces[f].v;
    q.size_u = faces[f].su;
    q.size_v = faces[f].sv;
    q.material = box.materials[f];
    q.panoptic = panoptic;
    // Texture coordinates: vertical faces start at the box-frame position of
    // the face so that adjacent faces/parts continue their patterns; heights
    // are measured from the box bottom.
    if (f == kFaceTop || f == kFaceBottom) {
      q.tex_u0 = static_cast<float>(a.x());
      q.tex_v0 = static_cast<float>(f == kFaceTop ? a.z() : -b.z());
    } else {
      q.tex_u0 = static_cast<float>(f == kFacePosX   ? a.z()
                                    : f == kFaceNegX ? -b.z()
                                    : f == kFacePosZ ? -b.x()
                                                     : a.x());
      q.tex_v0 = static_cast<float>(-b.y());
    }
    quads->push_back(q);
  }
}

std::array<Eigen::Vector3d, 8> SceneObject::BoxCorners() const {
  std::array<Eigen::Vector3d, 8> c;
  int i = 0;
  for (double x : {-0.5 * l, 0.5 * l})
    for (double y : {-h, 0.0})
      for (double z : {-0.5 * w, 0.5 * w}) c[i++] = Eigen::Vector3d(x, y, z);
  return c;
}

}  // namespace twist::sim
