// Scene model of the synthetic generator: textured planar quads (static
// world geometry) and rigid objects assembled from boxes that move under a
// joint (planar on the road, or revolute about a hinge).
//
// Object frame = KITTI box frame: origin at the bottom centre of the 3D box,
// x along the length (heading), y down, z along the width. The label box is
// x ∈ [-l/2, l/2], y ∈ [-h, 0], z ∈ [-w/2, w/2]; all parts lie inside it.
#pragma once

#include <Eigen/Core>
#include <array>
#include <cstdint>
#include <string>
#include <vector>

#include "slam/geometry/se3.h"
#include "slam/sim/motion.h"

namespace twist::sim {

// Cityscapes class ids used by the generator (DESIGN.md §3) + door.
inline constexpr int kClassRoad = 7;
inline constexpr int kClassSidewalk = 8;
inline constexpr int kClassBuilding = 11;
inline constexpr int kClassWall = 12;
inline constexpr int kClassPole = 17;
inline constexpr int kClassVegetation = 21;
inline constexpr int kClassSky = 23;
inline constexpr int kClassPerson = 24;
inline constexpr int kClassCar = 26;
inline constexpr int kClassDoor = 40;

inline uint16_t PanopticId(int class_id, int instance_id) {
  return static_cast<uint16_t>(class_id * 1000 + instance_id);
}

enum class Pattern : uint8_t {
  kAsphalt,   // road with the scene's lane markings
  kPaving,    // sidewalk tiles
  kConcrete,  // curbs, plain concrete
  kFacade,    // plaster with a window grid (p0 window period, p1 floor height)
  kBrick,     // brick wall
  kRoof,      // building tops
  kDoor,      // wooden panelled door
  kInterior,  // dark room behind an opening
  kCarPaint,  // car body sides (p0: 1 = side with wheels and seams)
  kCarGlass,  // cabin with windows and pillars
  kCarFront,  // front with lights and plate
  kCarBack,   // back with lights and plate
  kTire,      // rubber
  kMetal,     // poles
  kBark,      // tree trunks
  kFoliage,   // tree canopies
  kCloth,     // clothes
  kSkin,      // heads
};

struct Material {
  Pattern pattern = Pattern::kConcrete;
  Eigen::Vector3f color = Eigen::Vector3f(0.5f, 0.5f, 0.5f);   // linear-ish RGB in [0, 1]
  Eigen::Vector3f color2 = Eigen::Vector3f(0.3f, 0.3f, 0.3f);  // secondary colour
  uint32_t seed = 0;
  float p0 = 0.0f, p1 = 0.0f, p2 = 0.0f;  // pattern parameters
};

// A planar rectangle origin + s·axis_u + t·axis_v, s ∈ [0, size_u],
// t ∈ [0, size_v], visible from the side of normal = axis_u × axis_v. Texture
// coordinates are (tex_u0 + s, tex_v0 + t) in metres.
struct Quad {
  Eigen::Vector3d origin = Eigen::Vector3d::Zero();
  Eigen::Vector3d axis_u = Eigen::Vector3d::UnitX();
  Eigen::Vector3d axis_v = Eigen::Vector3d::UnitZ();
  double size_u = 1.0;
  double size_v = 1.0;
  int material = 0;
  uint16_t panoptic = 0;
  float tex_u0 = 0.0f, tex_v0 = 0.0f;
  Eigen::Vector3d normal() const { return axis_u.cross(axis_v); }
};

// Box faces. Vertical faces have axis_v = up (-y), so t = height above the
// bottom of the face; top/bottom faces have axes along x and z.
enum BoxFace { kFacePosX = 0, kFaceNegX, kFaceBottom, kFaceTop, kFacePosZ, kFaceNegZ };

struct BoxPart {
  Eigen::Vector3d min = Eigen::Vector3d::Zero();
  Eigen::Vector3d max = Eigen::Vector3d::Ones();
  std::array<int, 6> materials{};  // per BoxFace; -1 = face not drawn
};

// Appends the drawn faces of `box`, transformed by world_from_box.
void AppendBoxQuads(const BoxPart& box,
                    const geometry::SE3d& world_from_box,
                    uint16_t panoptic,
                    std::vector<Quad>* quads);

// A painted road marking: a stripe in the ground plane (world x, z) starting
// at `start` along unit `dir`, `length` long and `width` wide, dashed with
// `period` and on-fraction `duty` (duty 1 = solid).
struct Marking {
  Eigen::Vector2d start = Eigen::Vector2d::Zero();
  Eigen::Vector2d dir = Eigen::Vector2d(0.0, 1.0);
  double length = 1.0;
  double width = 0.12;
  double period = 1.0;
  double duty = 1.0;
  Eigen::Vector3f color = Eigen::Vector3f(0.9f, 0.9f, 0.88f);
};

enum class MotionKind { kPlanar, kRevolute };

struct SceneObject {
  int track_id = 0;  // == panoptic instance id, unique in the sequence
  int class_id = kClassCar;
  std::string kitti_type = "Car";
  double h = 1.5, w = 1.8, l = 4.2;  // label box
  std::vector<BoxPart> parts;        // in the object frame
  MotionKind kind = MotionKind::kPlanar;
  PlanarMotion planar;
  RevoluteMotion revolute;

  uint16_t panoptic() const { return PanopticId(class_id, track_id); }
  geometry::SE3d WorldFromObject(double t) const {
    return kind == MotionKind::kPlanar ? planar.PoseAt(t, HeadingAxis::kX) : revolute.PoseAt(t);
  }
  // The 8 corners of the label box in the object frame.
  std::array<Eigen::Vector3d, 8> BoxCorners() const;
};

struct Scene {
  std::vector<Material> materials;
  std::vector<Quad> static_quads;  // world frame
  std::vector<Marking> markings;
  std::vector<SceneObject> objects;
  Eigen::Vector3d sun_direction =
      Eigen::Vector3d(-0.35, -0.85, 0.4).normalized();  // towards the sun
  uint32_t sky_seed = 1;

  int AddMaterial(const Material& m) {
    materials.push_back(m);
    return static_cast<int>(materials.size()) - 1;
  }
};

}  // namespace twist::sim
