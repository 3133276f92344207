#include "slam/sim/scenarios.h"

#include <algorithm>
#include <array>
#include <cmath>
#include <utility>

#include "absl/strings/str_cat.h"
#include "slam/sim/procedural.h"

namespace twist::sim {
namespace {

using geometry::SE3d;
using Color = Eigen::Vector3f;

// Deterministic generator (splitmix64): identical sequences on every platform.
class Rng {
 public:
  explicit Rng(uint64_t seed) : state_(seed * 0x9e3779b97f4a7c15ULL + 0x1234567ULL) {}
  uint64_t Next() {
    uint64_t z = (state_ += 0x9e3779b97f4a7c15ULL);
    z = (z ^ (z >> 30)) * 0xbf58476d1ce4e5b9ULL;
    z = (z ^ (z >> 27)) * 0x94d049bb133111ebULL;
    return z ^ (z >> 31);
  }
  double Uniform(double a, double b) {
    return a + (b - a) * (static_cast<double>(Next() >> 11) * (1.0 / 9007199254740992.0));
  }
  bool Chance(double p) { return Uniform(0.0, 1.0) < p; }
  uint32_t Seed() { return static_cast<uint32_t>(Next() >> 32); }
  template <typename T>
  const T& Pick(const std::vector<T>& v) {
    return v[static_cast<size_t>(Uniform(0.0, static_cast<double>(v.size()) - 1e-9))];
  }

 private:
  uint64_t state_;
};

constexpr double G = kCameraHeight;  // road plane y
constexpr double kSidewalkWidth = 3.0;

// Street cross-section of the main street (along z):
//   left sidewalk [-10.5, -7.5], left parking [-7.5, -5.25], oncoming lane
//   [-5.25, -1.75], camera lane [-1.75, 1.75], right parking [1.75, 4],
//   right sidewalk [4, 7]; facades at x = 7 and x = -10.5.
constexpr double kRoadRight = 4.0;
constexpr double kRoadLeft = -7.5;
constexpr double kParkRight = 2.9;
constexpr double kParkLeft = -6.4;
constexpr double kOncomingLane = -3.5;
// Cross street (along x) half width.
constexpr double kCrossHalf = 5.75;

enum Edge : unsigned { kWest = 1, kEast = 2, kSouth = 4, kNorth = 8 };

struct Interval {
  double lo, hi;
};
bool Overlaps(const std::vector<Interval>& excl, double lo, double hi) {
  for (const Interval& e : excl) {
    if (hi > e.lo && lo < e.hi) return true;
  }
  return false;
}

class Builder {
 public:
  Builder(Scenario* scenario, uint32_t seed) : scene_(&scenario->scene), rng_(seed) {
    scene_->sky_seed = rng_.Seed();
    Material road;
    road.pattern = Pattern::kAsphalt;
    road.color = Color(0.33f, 0.33f, 0.34f);
    road.seed = rng_.Seed();
    road_material_ = scene_->AddMaterial(road);
    Material curb;
    curb.pattern = Pattern::kConcrete;
    curb.color = Color(0.62f, 0.61f, 0.58f);
    curb.seed = rng_.Seed();
    curb_material_ = scene_->AddMaterial(curb);
    Material roof;
    roof.pattern = Pattern::kRoof;
    roof.color = Color(0.25f, 0.24f, 0.24f);
    roof.seed = rng_.Seed();
    roof_material_ = scene_->AddMaterial(roof);
  }

  Rng& rng() { return rng_; }

  // The whole ground as one asphalt quad (normal up).
  void Road(double x0, double x1, double z0, double z1) {
    Quad q;
    q.origin = Eigen::Vector3d(x0, G, z0);
    q.axis_u = Eigen::Vector3d::UnitX();
    q.axis_v = Eigen::Vector3d::UnitZ();
    q.size_u = x1 - x0;
    q.size_v = z1 - z0;
    q.material = road_material_;
    q.panoptic = PanopticId(kClassRoad, 0);
    q.tex_u0 = static_cast<float>(x0);
    q.tex_v0 = static_cast<float>(z0);
    scene_->static_quads.push_back(q);
  }

  void AddMarking(Eigen::Vector2d start,
                  Eigen::Vector2d dir,
                  double length,
                  double width,
                  double period = 1.0,
                  double duty = 1.0) {
    Marking m;
    m.start = start;
    m.dir = dir.normalized();
    m.length = length;
    m.width = width;
    m.period = period;
    m.duty = duty;
    scene_->markings.push_back(m);
  }

  // A static box in world coordinates (x, z ranges; heights above the road
  // from y_bottom to y_top, metres up).
  void StaticBox(double x0,
                 double x1,
                 double h0,
                 double h1,
                 double z0,
                 double z1,
                 std::array<int, 6> materials,
                 uint16_t panoptic) {
    BoxPart box;
    box.min = Eigen::Vector3d(x0, -h1, z0);
    box.max = Eigen::Vector3d(x1, -h0, z1);
    box.materials = materials;
    AppendBoxQuads(box,
                   SE3d(Eigen::Matrix3d::Identity(), Eigen::Vector3d(0, G, 0)),
                   panoptic,
                   &scene_->static_quads);
  }

  // A city block: raised sidewalk slab, buildings along the street edges set
  // back by the sidewalk width, trees and poles near the curb.
  void Block(double x0,
             double x1,
             double z0,
             double z1,
             unsigned edges,
             const std::vector<Interval>& no_building_z = {}) {
    Material paving;
    paving.pattern = Pattern::kPaving;
    const float tone = static_cast<float>(rng_.Uniform(0.5, 0.66));
    paving.color = Color(tone, tone * 0.98f, tone * 0.95f);
    paving.color2 = paving.color * 0.55f;
    paving.p0 = static_cast<float>(rng_.Pick(std::vector<double>{0.3, 0.4, 0.5}));
    paving.seed = rng_.Seed();
    const int pav = scene_->AddMaterial(paving);
    StaticBox(x0,
              x1,
              0.0,
              kCurbHeight,
              z0,
              z1,
              {curb_material_, curb_material_, -1, pav, curb_material_, curb_material_},
              PanopticId(kClassSidewalk, 0));
    const double sw = kSidewalkWidth;
    if (edges & kWest) {
      BuildingRow(/*along_z=*/true, x0 + sw, +1.0, z0, z1, no_building_z);
      Furniture(true, x0 + 0.7, z0 + 2.0, z1 - 2.0, -1.0, no_building_z);
    }
    if (edges & kEast) {
      BuildingRow(true, x1 - sw, -1.0, z0, z1, no_building_z);
      Furniture(true, x1 - 0.7, z0 + 2.0, z1 - 2.0, +1.0, no_building_z);
    }
    if (edges & kSouth) {
      BuildingRow(false, z0 + sw, +1.0, x0, x1, {});
      Furniture(false, z0 + 0.7, x0 + 2.0, x1 - 2.0, -1.0, {});
    }
    if (edges & kNorth) {
      BuildingRow(false, z1 - sw, -1.0, x0, x1, {});
      Furniture(false, z1 - 0.7, x0 + 2.0, x1 - 2.0, +1.0, {});
    }
  }

  int NewTrackId() { return next_track_id_++; }

  // A car (or van) following `motion` (body_y = road level).
  int AddCar(PlanarMotion motion, bool van = false) {
    SceneObject obj;
    obj.track_id = NewTrackId();
    obj.class_id = kClassCar;
    obj.kitti_type = van ? "Van" : "Car";
    obj.l = van ? rng_.Uniform(4.8, 5.4) : rng_.Uniform(3.9, 4.6);
    obj.w = van ? rng_.Uniform(1.9, 2.0) : rng_.Uniform(1.70, 1.85);
    obj.h = van ? rng_.Uniform(1.95, 2.2) : rng_.Uniform(1.40, 1.55);
    static const std::vector<Color> kPaints = {Color(0.86f, 0.86f, 0.85f),
                                               Color(0.60f, 0.62f, 0.65f),
                                               Color(0.08f, 0.08f, 0.09f),
                                               Color(0.62f, 0.08f, 0.07f),
                                               Color(0.10f, 0.22f, 0.52f),
                                               Color(0.26f, 0.27f, 0.29f),
                                               Color(0.16f, 0.32f, 0.20f),
                                               Color(0.80f, 0.66f, 0.22f),
                                               Color(0.45f, 0.30f, 0.20f)};
    const Color paint = rng_.Pick(kPaints);
    const int side = AddMat(Pattern::kCarPaint, paint, paint, 1.0f);
    const int top = AddMat(Pattern::kCarPaint, paint, paint, 0.0f);
    const int front = AddMat(Pattern::kCarFront, paint, paint);
    const int back = AddMat(Pattern::kCarBack, paint, paint);
    const int glass = AddMat(Pattern::kCarGlass, paint, paint * 0.9f);
    const int tire = AddMat(Pattern::kTire, Color::Constant(0.06f), Color::Constant(0.5f));
    const double l = obj.l, w = obj.w, h = obj.h;
    const double belt = van ? 1.1 : 0.95;  // body/cabin split height
    BoxPart body;
    body.min = Eigen::Vector3d(-0.5 * l, -belt, -0.5 * w + 0.03);
    body.max = Eigen::Vector3d(0.5 * l, -0.3, 0.5 * w - 0.03);
    body.materials = {front, back, -1, top, side, side};
    obj.parts.push_back(body);
    BoxPart cabin;
    const double cab_front = van ? 0.5 * l - 0.9 : 0.5 * l - 1.3;
    const double cab_back = van ? -0.5 * l + 0.1 : -0.5 * l + 0.9;
    cabin.min = Eigen::Vector3d(cab_back, -h, -0.5 * w + 0.12);
    cabin.max = Eigen::Vector3d(cab_front, -belt, 0.5 * w - 0.12);
    cabin.materials = {glass, glass, -1, top, glass, glass};
    obj.parts.push_back(cabin);
    const double r = 0.33;
    for (double xc : {0.5 * l - 0.85, -0.5 * l + 0.85}) {
      for (int s : {-1, 1}) {
        BoxPart wheel;
        const double z_in = s * (0.5 * w - 0.25), z_out = s * 0.5 * w;
        wheel.min = Eigen::Vector3d(xc - r, -2.0 * r, std::min(z_in, z_out));
        wheel.max = Eigen::Vector3d(xc + r, 0.0, std::max(z_in, z_out));
        wheel.materials = {tire, tire, -1, tire, tire, tire};
        obj.parts.push_back(wheel);
      }
    }
    obj.kind = MotionKind::kPlanar;
    obj.planar = std::move(motion);
    scene_->objects.push_back(std::move(obj));
    return scene_->objects.back().track_id;
  }

  int AddPedestrian(PlanarMotion motion) {
    SceneObject obj;
    obj.track_id = NewTrackId();
    obj.class_id = kClassPerson;
    obj.kitti_type = "Pedestrian";
    obj.l = 0.6;
    obj.w = 0.66;
    obj.h = 1.75;
    static const std::vector<Color> kClothes = {Color(0.15f, 0.2f, 0.45f),
                                                Color(0.7f, 0.15f, 0.12f),
                                                Color(0.2f, 0.2f, 0.22f),
                                                Color(0.85f, 0.85f, 0.8f),
                                                Color(0.2f, 0.45f, 0.25f),
                                                Color(0.75f, 0.6f, 0.2f)};
    const Color shirt = rng_.Pick(kClothes), shirt2 = rng_.Pick(kClothes);
    const int top = AddMat(Pattern::kCloth, shirt, shirt2, rng_.Chance(0.5) ? 0.12f : 0.0f);
    const int legs = AddMat(Pattern::kCloth, rng_.Pick(kClothes) * 0.7f, shirt2, 0.0f);
    const Color skin = rng_.Pick(std::vector<Color>{
        Color(0.85f, 0.68f, 0.55f), Color(0.55f, 0.38f, 0.28f), Color(0.35f, 0.24f, 0.18f)});
    const int head = AddMat(Pattern::kSkin, skin, Color(0.12f, 0.09f, 0.06f));
    const int bag = AddMat(Pattern::kCloth, rng_.Pick(kClothes) * 0.6f, shirt, 0.0f);
    auto part = [&](double x0, double x1, double y0, double y1, double z0, double z1, int m) {
      BoxPart p;
      p.min = Eigen::Vector3d(x0, -y1, z0);
      p.max = Eigen::Vector3d(x1, -y0, z1);
      p.materials = {m, m, -1, m, m, m};
      obj.parts.push_back(p);
    };
    part(-0.1, 0.1, 0.0, 0.86, -0.19, -0.03, legs);
    part(-0.1, 0.1, 0.0, 0.86, 0.03, 0.19, legs);
    part(-0.13, 0.13, 0.86, 1.46, -0.22, 0.22, top);
    part(-0.08, 0.08, 0.84, 1.44, -0.31, -0.22, top);
    part(-0.08, 0.08, 0.84, 1.44, 0.22, 0.31, top);
    part(-0.11, 0.11, 1.48, 1.74, -0.09, 0.09, head);
    part(-0.29, -0.13, 1.0, 1.4, -0.16, 0.16, bag);
    obj.kind = MotionKind::kPlanar;
    obj.planar = std::move(motion);
    scene_->objects.push_back(std::move(obj));
    return scene_->objects.back().track_id;
  }

  // Parked cars in a row along z at lateral x, heading yaw (0 = +z, π = -z).
  void ParkedRow(double x,
                 double z0,
                 double z1,
                 double yaw,
                 double gap_prob,
                 const std::vector<Interval>& exclusions) {
    double z = z0 + rng_.Uniform(0.0, 3.0);
    while (z < z1) {
      if (rng_.Chance(gap_prob)) {
        z += rng_.Uniform(3.0, 9.0);
        continue;
      }
      const double len = 4.7;  // slot for the car, checked before sizing
      if (Overlaps(exclusions, z, z + len) || z + len > z1) {
        z += 1.0;
        continue;
      }
      const double zc = z + 0.5 * len;
      PlanarState s{x + rng_.Uniform(-0.15, 0.15), zc, yaw + rng_.Uniform(-0.04, 0.04), 0.0};
      AddCar(PlanarMotion(s, {}, G), rng_.Chance(0.08));
      z += len + 0.6 + rng_.Uniform(0.6, 2.5);
    }
  }

  // A brick wall (class wall) along z with facade at x = x_face (street at
  // smaller x), from z0 to z1, with a door opening at [door_z0, door_z0 + door_w].
  // The door turns about its vertical hinge (at door_z0) from closed to
  // `angle1` between t0 and t1 (negative angles open towards the street).
  void DoorWall(
      double x_face, double z0, double z1, double door_z0, double angle1, double t0, double t1) {
    Material brick;
    brick.pattern = Pattern::kBrick;
    brick.color = Color(0.55f, 0.25f, 0.17f);
    brick.color2 = Color(0.7f, 0.68f, 0.62f);
    brick.seed = rng_.Seed();
    const int b = scene_->AddMaterial(brick);
    const int interior =
        AddMat(Pattern::kInterior, Color(0.07f, 0.065f, 0.06f), Color(0.1f, 0.1f, 0.1f));
    const uint16_t wall_id = PanopticId(kClassWall, 0);
    const double depth = 12.0, height = 9.0;
    const double door_w = 1.1, door_h = 2.25;
    const double floor = kCurbHeight;
    const double x1 = x_face + depth;
    const double dz1 = door_z0 + door_w;
    // Left and right pieces; their faces towards the opening are the vestibule.
    StaticBox(
        x_face, x1, floor, height, z0, door_z0, {b, b, -1, roof_material_, interior, b}, wall_id);
    StaticBox(x_face, x1, floor, height, dz1, z1, {b, b, -1, roof_material_, b, interior}, wall_id);
    StaticBox(x_face,
              x1,
              floor + door_h,
              height,
              door_z0,
              dz1,
              {b, b, interior, roof_material_, b, b},
              wall_id);
    // Back of the vestibule, 1.5 m deep.
    Quad back;
    back.origin = Eigen::Vector3d(x_face + 1.5, G - floor, door_z0);
    back.axis_u = Eigen::Vector3d::UnitZ();
    back.axis_v = -Eigen::Vector3d::UnitY();
    back.size_u = door_w;
    back.size_v = door_h;
    // Visible from the street side: normal (-y) × z = -x.
    std::swap(back.axis_u, back.axis_v);
    std::swap(back.size_u, back.size_v);
    back.material = interior;
    back.panoptic = wall_id;
    scene_->static_quads.push_back(back);

    // The door: KITTI box frame, x along the width, z = thickness.
    SceneObject door;
    door.track_id = NewTrackId();
    door.class_id = kClassDoor;
    door.kitti_type = "Door";
    door.l = door_w - 0.04;
    door.w = 0.05;
    door.h = door_h - 0.02;
    const int wood = AddMat(Pattern::kDoor, Color(0.42f, 0.24f, 0.12f), Color(0.5f, 0.3f, 0.16f));
    BoxPart slab;
    slab.min = Eigen::Vector3d(-0.5 * door.l, -door.h, -0.5 * door.w);
    slab.max = Eigen::Vector3d(0.5 * door.l, 0.0, 0.5 * door.w);
    slab.materials = {wood, wood, -1, wood, wood, wood};
    door.parts.push_back(slab);
    // Closed: object x -> world +z, object z -> world -x (towards the street).
    const double x_mid = x_face + 0.1;
    const double hinge_z = door_z0 + 0.02;
    const SE3d closed(RotY(-M_PI / 2.0),
                      Eigen::Vector3d(x_mid, G - floor - 0.005, hinge_z + 0.5 * door.l));
    door.kind = MotionKind::kRevolute;
    door.revolute = RevoluteMotion(
        closed, Eigen::Vector3d(x_mid, G, hinge_z), Eigen::Vector3d::UnitY(), 0.0, angle1, t0, t1);
    scene_->objects.push_back(std::move(door));
  }

 private:
  int AddMat(Pattern p, const Color& c, const Color& c2, float p0 = 0.0f) {
    Material m;
    m.pattern = p;
    m.color = c;
    m.color2 = c2;
    m.p0 = p0;
    m.seed = rng_.Seed();
    return scene_->AddMaterial(m);
  }

  // Buildings whose facade lies on the plane (along_z ? x : z) = face, the
  // body extending towards `dir` (±1), spanning [a0, a1] along the street.
  void BuildingRow(bool along_z,
                   double face,
                   double dir,
                   double a0,
                   double a1,
                   const std::vector<Interval>& skip) {
    static const std::vector<Color> kWalls = {Color(0.78f, 0.72f, 0.6f),
                                              Color(0.62f, 0.6f, 0.58f),
                                              Color(0.62f, 0.36f, 0.28f),
                                              Color(0.85f, 0.82f, 0.74f),
                                              Color(0.55f, 0.62f, 0.68f),
                                              Color(0.9f, 0.88f, 0.85f),
                                              Color(0.7f, 0.55f, 0.42f)};
    double a = a0;
    while (a < a1 - 3.0) {
      const double width = std::min(rng_.Uniform(8.0, 22.0), a1 - a);
      if (rng_.Chance(0.12)) {
        a += rng_.Uniform(2.0, 5.0);
        continue;
      }
      if (Overlaps(skip, a, a + width)) {
        a += width;
        continue;
      }
      Material facade;
      facade.pattern = Pattern::kFacade;
      facade.color = rng_.Pick(kWalls);
      facade.color2 = facade.color * static_cast<float>(rng_.Chance(0.5) ? 0.75 : 1.15);
      facade.p0 = static_cast<float>(rng_.Uniform(2.4, 3.6));
      facade.p1 = static_cast<float>(rng_.Uniform(2.9, 3.4));
      facade.p2 = static_cast<float>(rng_.Uniform(0.35, 0.55));
      facade.seed = rng_.Seed();
      const int f = scene_->AddMaterial(facade);
      const double height = rng_.Uniform(7.0, 24.0);
      const double depth = rng_.Uniform(10.0, 16.0);
      const double b0 = dir > 0 ? face : face - depth;
      const double b1 = dir > 0 ? face + depth : face;
      const std::array<int, 6> mats = {f, f, -1, roof_material_, f, f};
      if (along_z) {
        StaticBox(b0, b1, kCurbHeight, height, a, a + width, mats, PanopticId(kClassBuilding, 0));
      } else {
        StaticBox(a, a + width, kCurbHeight, height, b0, b1, mats, PanopticId(kClassBuilding, 0));
      }
      a += width;
    }
  }

  // Trees and lamp poles on a line at `line` (x if along_z else z) from a0 to
  // a1; `street` (±1) points towards the street.
  void Furniture(bool along_z,
                 double line,
                 double a0,
                 double a1,
                 double street,
                 const std::vector<Interval>& skip) {
    static const std::vector<Color> kLeaves = {
        Color(0.2f, 0.36f, 0.12f), Color(0.28f, 0.42f, 0.16f), Color(0.16f, 0.3f, 0.14f)};
    const int bark = AddMat(Pattern::kBark, Color(0.3f, 0.22f, 0.16f), Color(0.2f, 0.15f, 0.1f));
    const int metal = AddMat(Pattern::kMetal, Color(0.42f, 0.44f, 0.46f), Color(0.3f, 0.3f, 0.3f));
    double a = a0 + rng_.Uniform(0.0, 8.0);
    while (a < a1) {
      if (Overlaps(skip, a - 2.0, a + 2.0)) {
        a += 2.0;
        continue;
      }
      auto box = [&](double along0,
                     double along1,
                     double h0,
                     double h1,
                     double across0,
                     double across1,
                     std::array<int, 6> m,
                     uint16_t id) {
        if (along_z) {
          StaticBox(line + across0, line + across1, h0, h1, along0, along1, m, id);
        } else {
          StaticBox(along0, along1, h0, h1, line + across0, line + across1, m, id);
        }
      };
      if (rng_.Chance(0.55)) {
        const Color leaf = rng_.Pick(kLeaves);
        const int fol = AddMat(Pattern::kFoliage, leaf, leaf * 1.6f);
        const uint16_t veg = PanopticId(kClassVegetation, 0);
        box(a - 0.15,
            a + 0.15,
            kCurbHeight,
            3.0,
            -0.15,
            0.15,
            {bark, bark, -1, bark, bark, bark},
            veg);
        const double r = rng_.Uniform(1.1, 1.6);
        const double top = rng_.Uniform(4.6, 5.6);
        box(a - r, a + r, 2.4, top, -r, r, {fol, fol, fol, fol, fol, fol}, veg);
        const double r2 = 0.65 * r;
        box(a - r2 + 0.2,
            a + r2 + 0.2,
            top,
            top + 1.0,
            -r2,
            r2,
            {fol, fol, -1, fol, fol, fol},
            veg);
      } else {
        const uint16_t pole = PanopticId(kClassPole, 0);
        const std::array<int, 6> m = {metal, metal, metal, metal, metal, metal};
        box(a - 0.07, a + 0.07, kCurbHeight, 6.5, -0.07, 0.07, m, pole);
        const double arm0 = street > 0 ? 0.07 : -1.5, arm1 = street > 0 ? 1.5 : -0.07;
        box(a - 0.05, a + 0.05, 6.35, 6.45, arm0, arm1, m, pole);
        const double head = street > 0 ? 1.5 : -1.5;
        box(a - 0.15, a + 0.15, 6.15, 6.4, head - 0.35, head + 0.35, m, pole);
      }
      a += rng_.Uniform(9.0, 16.0);
    }
  }

  Scene* scene_;
  Rng rng_;
  int road_material_ = 0, curb_material_ = 0, roof_material_ = 0;
  int next_track_id_ = 1;
};

PlanarMotion CameraMotion(double speed, std::vector<PlanarSegment> segments) {
  return PlanarMotion(PlanarState{0.0, 0.0, 0.0, speed}, std::move(segments), 0.0);
}

// Main street along z from z0 to z1 with its markings, blocks on both sides.
void StraightStreet(Builder* b, double z0, double z1, std::vector<Interval> no_building = {}) {
  b->Road(-200.0, 200.0, z0 - 50.0, z1 + 400.0);
  b->Block(kRoadRight, 80.0, z0, z1, kWest, no_building);
  b->Block(-80.0, kRoadLeft, z0, z1, kEast);
  b->AddMarking({-1.75, z0}, {0, 1}, z1 - z0, 0.13, 12.0, 0.25);
  b->AddMarking({1.75, z0}, {0, 1}, z1 - z0, 0.15);
  b->AddMarking({-5.25, z0}, {0, 1}, z1 - z0, 0.15);
}

// Pedestrians walking along the sidewalks between z0 and z1: four walking
// lines (two per side, one per direction), one speed per line and at least
// 2 m between walkers of a line, so nobody walks into anybody.
void Walkers(Builder* b, int count, double z0, double z1) {
  const std::array<double, 4> line_x = {5.4, 6.3, -9.0, -9.9};
  const std::array<double, 4> line_yaw = {0.0, M_PI, 0.0, M_PI};
  std::array<double, 4> line_speed;
  for (double& v : line_speed) v = b->rng().Uniform(1.0, 1.6);
  std::array<std::vector<double>, 4> taken;
  for (int i = 0; i < count; ++i) {
    const int line = static_cast<int>(b->rng().Uniform(0.0, 4.0 - 1e-9));
    for (int attempt = 0; attempt < 20; ++attempt) {
      const double z = b->rng().Uniform(z0, z1);
      bool free = true;
      for (double other : taken[line]) free = free && std::abs(other - z) >= 2.0;
      if (!free) continue;
      taken[line].push_back(z);
      PlanarState s{line_x[line], z, line_yaw[line], line_speed[line]};
      b->AddPedestrian(PlanarMotion(s, {}, G - kCurbHeight));
      break;
    }
  }
}

// Walks `distance` metres from (x, z) along `yaw` at `speed`, then stops
// within 0.5 s.
PlanarMotion WalkAndStop(double x, double z, double yaw, double speed, double distance, double y) {
  const double stop_time = 0.5;
  const double stop_distance = 0.5 * speed * stop_time;
  return PlanarMotion(
      PlanarState{x, z, yaw, speed},
      {{(distance - stop_distance) / speed, 0.0, 0.0}, {stop_time, -speed / stop_time, 0.0}},
      y);
}

// Distance the camera travels in the sequence (to size the street).
double Travel(const PlanarMotion& m, double t_end) { return m.DistanceAt(t_end); }

void BuildStaticStreet(Scenario* sc, Builder* b) {
  sc->camera_motion = CameraMotion(8.0, {});
  const double z1 = Travel(sc->camera_motion, sc->TimeOf(sc->num_frames)) + 180.0;
  StraightStreet(b, -40.0, z1);
  b->ParkedRow(kParkRight, -30.0, z1 - 20.0, 0.0, 0.15, {});
  b->ParkedRow(kParkLeft, -30.0, z1 - 20.0, M_PI, 0.2, {});
}

void BuildDriving(Scenario* sc, Builder* b) {
  sc->camera_motion = CameraMotion(10.0, {});
  const double t_end = sc->TimeOf(sc->num_frames);
  const double z1 = Travel(sc->camera_motion, t_end) + 200.0;
  StraightStreet(b, -40.0, z1);
  // Leading cars in the camera's lane.
  b->AddCar(PlanarMotion(PlanarState{0.0, 18.0, 0.0, 10.0},
                         {{3.0, 0.5, 0.0}, {3.0, -0.8, 0.0}, {4.0, 0.0, 0.0}, {4.0, 0.3, 0.0}},
                         G));
  b->AddCar(
      PlanarMotion(PlanarState{0.1, 48.0, 0.0, 11.0}, {{5.0, 0.0, 0.0}, {5.0, -0.1, 0.0}}, G));
  // Oncoming traffic, spaced along the street, all at one speed.
  double z = 45.0;
  const double speed = b->rng().Uniform(8.0, 12.0);
  while (z < 10.0 * t_end + 150.0 && z < z1) {
    b->AddCar(PlanarMotion(
                  PlanarState{kOncomingLane + b->rng().Uniform(-0.2, 0.2), z, M_PI, speed}, {}, G),
              b->rng().Chance(0.15));
    z += b->rng().Uniform(25.0, 50.0);
  }
  b->ParkedRow(kParkRight, -30.0, z1 - 20.0, 0.0, 0.3, {});
  b->ParkedRow(kParkLeft, -30.0, z1 - 20.0, M_PI, 0.35, {});
  Walkers(b, 8, 0.0, std::min(z1 - 30.0, 10.0 * t_end + 60.0));
}

// The blocks and road markings of a four-way crossing of the main street
// (along z) with a cross street (along x) centred on z = zi.
void IntersectionStreets(Builder* b, double zi, double x_far, double z_far) {
  const double south = zi - kCrossHalf, north = zi + kCrossHalf;
  b->Block(kRoadRight, x_far, -40.0, south, kWest | kNorth);
  b->Block(kRoadRight, x_far, north, z_far, kWest | kSouth);
  b->Block(-x_far, kRoadLeft, -40.0, south, kEast | kNorth);
  b->Block(-x_far, kRoadLeft, north, z_far, kEast | kSouth);
  // Main street markings stop at the crossing; zebra crossings and a stop line.
  b->AddMarking({-1.75, -40.0}, {0, 1}, south - 4.5 + 40.0, 0.13, 12.0, 0.25);
  b->AddMarking({-1.75, north + 4.5}, {0, 1}, z_far - north, 0.13, 12.0, 0.25);
  b->AddMarking({1.75, -40.0}, {0, 1}, south - 4.0 + 40.0, 0.15);
  b->AddMarking({-5.25, -40.0}, {0, 1}, south - 4.0 + 40.0, 0.15);
  b->AddMarking({kRoadLeft, south - 2.0}, {1, 0}, kRoadRight - kRoadLeft, 3.0, 1.0, 0.5);
  b->AddMarking({-1.75, south - 4.0}, {1, 0}, 3.5, 0.4);
  // Cross street markings (along x), zebra on the east arm.
  b->AddMarking({kRoadRight + 4.5, zi}, {1, 0}, x_far, 0.13, 12.0, 0.25);
  b->AddMarking({-x_far, zi}, {1, 0}, x_far + kRoadLeft - 4.5, 0.13, 12.0, 0.25);
  b->AddMarking({kRoadRight + 2.0, south}, {0, 1}, 2.0 * kCrossHalf, 3.0, 1.0, 0.5);
}

void BuildIntersection(Scenario* sc, Builder* b) {
  const double zi = 45.0;
  const double turn_radius = 8.0;
  const double z_turn = zi - 1.75 - turn_radius;  // the turn ends in the cross street's right lane
  // 8 -> 5 m/s over 13 m, then 5 m/s to the turn, quarter circle, accelerate
  // to 9 m/s, the speed of the crossing cars it then follows.
  const double straight = z_turn - 13.0;
  sc->camera_motion = CameraMotion(8.0,
                                   {{2.0, -1.5, 0.0},
                                    {straight / 5.0, 0.0, 0.0},
                                    {M_PI / 2.0 * turn_radius / 5.0, 0.0, 1.0 / turn_radius},
                                    {4.0, 1.0, 0.0}});
  const double t_end = sc->TimeOf(sc->num_frames);
  const PlanarState end = sc->camera_motion.StateAt(t_end);
  const double x_far = std::max(120.0, end.x + 150.0);
  const double z_far = std::max(zi + 150.0, end.z + 150.0);
  b->Road(-x_far - 50.0, x_far + 300.0, -90.0, z_far + 300.0);
  IntersectionStreets(b, zi, x_far, z_far);
  const double south = zi - kCrossHalf, north = zi + kCrossHalf;
  // Crossing cars: one will lead the camera after its turn, one the other way.
  b->AddCar(PlanarMotion(PlanarState{-36.0, zi - 1.75, M_PI / 2.0, 9.0}, {}, G));
  b->AddCar(PlanarMotion(PlanarState{44.0, zi + 1.75, -M_PI / 2.0, 8.0}, {}, G));
  b->AddCar(PlanarMotion(PlanarState{-60.0, zi - 1.6, M_PI / 2.0, 9.0}, {}, G));
  // Oncoming car on the main street.
  b->AddCar(PlanarMotion(PlanarState{kOncomingLane, 70.0, M_PI, 9.0}, {}, G));
  const std::vector<Interval> keep_clear = {{south - 14.0, north + 10.0}};
  b->ParkedRow(kParkRight, -30.0, south - 10.0, 0.0, 0.2, keep_clear);
  b->ParkedRow(kParkLeft, -30.0, south - 10.0, M_PI, 0.25, keep_clear);
  b->ParkedRow(kParkLeft, north + 8.0, z_far - 10.0, M_PI, 0.25, {});
  // Parked along the cross street's east arm (south side, heading +x).
  for (double x = kRoadRight + 14.0; x < x_far - 10.0; x += b->rng().Uniform(5.5, 9.0)) {
    b->AddCar(PlanarMotion(PlanarState{x, south + 1.15, M_PI / 2.0, 0.0}, {}, G));
  }
  // Pedestrians on the corners.
  Walkers(b, 4, 0.0, south - 5.0);
  b->AddPedestrian(
      PlanarMotion(PlanarState{9.0, north + 1.5, M_PI / 2.0, 1.2}, {}, G - kCurbHeight));
  b->AddPedestrian(
      PlanarMotion(PlanarState{14.0, south - 1.6, M_PI / 2.0, 1.3}, {}, G - kCurbHeight));
}

void BuildTurningTraffic(Scenario* sc, Builder* b) {
  // The camera waits 18 m before a crossing while cars turn in front of it
  // (0.6-0.8 rad/s): the generator's only turning objects.
  const double zi = 24.0;
  sc->camera_motion = CameraMotion(0.0, {});
  const double x_far = 150.0, z_far = zi + 150.0;
  b->Road(-x_far - 50.0, x_far + 300.0, -90.0, z_far + 300.0);
  IntersectionStreets(b, zi, x_far, z_far);
  const double south = zi - kCrossHalf, north = zi + kCrossHalf;
  // From the west, right turn (R 9 m) into the oncoming lane, towards the camera.
  const double r1 = 9.0, v1 = 7.0, x1 = kOncomingLane - r1;
  b->AddCar(PlanarMotion(PlanarState{-45.0, zi - 1.75, M_PI / 2.0, v1},
                         {{(x1 + 45.0) / v1, 0.0, 0.0}, {M_PI / 2.0 * r1 / v1, 0.0, 1.0 / r1}},
                         G));
  // From the east, left turn (R 12 m) into the same lane, later.
  const double r2 = 12.0, v2 = 7.0, x2 = kOncomingLane + r2;
  b->AddCar(PlanarMotion(PlanarState{60.0, zi + 1.75, -M_PI / 2.0, v2},
                         {{(60.0 - x2) / v2, 0.0, 0.0}, {M_PI / 2.0 * r2 / v2, 0.0, -1.0 / r2}},
                         G));
  // Ahead in the camera's lane, right turn (R 7 m) into the cross street.
  const double r3 = 7.0, v3 = 5.0, z3 = zi - 1.75 - r3;
  b->AddCar(PlanarMotion(PlanarState{0.0, 8.0, 0.0, v3},
                         {{(z3 - 8.0) / v3, 0.0, 0.0}, {M_PI / 2.0 * r3 / v3, 0.0, 1.0 / r3}},
                         G));
  const std::vector<Interval> keep_clear = {{south - 14.0, north + 10.0}};
  b->ParkedRow(kParkRight, -30.0, south - 10.0, 0.0, 0.2, keep_clear);
  b->ParkedRow(kParkLeft, -30.0, south - 10.0, M_PI, 0.25, keep_clear);
  b->ParkedRow(kParkLeft, north + 8.0, z_far - 10.0, M_PI, 0.25, {});
  Walkers(b, 4, 0.0, south - 5.0);
}

void BuildStationaryThenAccelerating(Scenario* sc, Builder* b) {
  // Waiting at a crossing: still for 3 s, then 2 m/s² up to 10 m/s.
  sc->camera_motion = CameraMotion(0.0, {{3.0, 0.0, 0.0}, {5.0, 2.0, 0.0}});
  const double t_end = sc->TimeOf(sc->num_frames);
  const double z1 = Travel(sc->camera_motion, t_end) + 200.0;
  // One-way street with two lanes: the left lane carries a dense stream of
  // cars passing the camera close by (all at the same speed: no collisions).
  b->Road(-200.0, 200.0, -250.0, z1 + 400.0);
  b->Block(kRoadRight, 80.0, -60.0, z1, kWest);
  b->Block(-80.0, kRoadLeft, -60.0, z1, kEast);
  b->AddMarking({-1.75, -250.0}, {0, 1}, z1 + 250.0, 0.13, 6.0, 0.5);
  b->AddMarking({1.75, -250.0}, {0, 1}, z1 + 250.0, 0.15);
  b->AddMarking({-5.25, -250.0}, {0, 1}, z1 + 250.0, 0.15);
  b->AddMarking({kRoadLeft, 5.0}, {1, 0}, kRoadRight - kRoadLeft, 3.0, 1.0, 0.5);
  // The car ahead waits too and starts 0.8 s earlier.
  b->AddCar(PlanarMotion(PlanarState{0.0, 9.2, 0.0, 0.0}, {{2.2, 0.0, 0.0}, {5.0, 2.0, 0.0}}, G));
  const double stream_speed = 11.0;
  double start = 20.0;
  for (int i = 0; i < 16; ++i) {
    b->AddCar(
        PlanarMotion(
            PlanarState{kOncomingLane + b->rng().Uniform(-0.3, 0.1), start, 0.0, stream_speed},
            {},
            G),
        i % 5 == 2);
    start -= b->rng().Uniform(11.0, 17.0);
  }
  // Pedestrians cross the camera's lane between the camera and the car
  // ahead and wait on the lane divider (clear of the camera and the stream).
  b->AddPedestrian(WalkAndStop(3.4, 4.4, -M_PI / 2.0, 1.5, 5.0, G));
  b->AddPedestrian(WalkAndStop(4.4, 5.6, -M_PI / 2.0, 1.3, 5.8, G));
  b->ParkedRow(kParkRight, -30.0, 1.5, 0.0, 0.1, {});
  b->ParkedRow(kParkRight, 8.0, z1 - 20.0, 0.0, 0.25, {});
  b->ParkedRow(kParkLeft, 8.0, z1 - 20.0, 0.0, 0.3, {});
  Walkers(b, 5, -5.0, 60.0);
}

void BuildFollowBraking(Scenario* sc, Builder* b) {
  // Lead: 10 m/s, brakes at t = 2 s (-4 m/s²) to a stop, waits, restarts.
  // Camera: same profile 0.5 s later; the gap shrinks from 15 m to 10 m.
  sc->camera_motion =
      CameraMotion(10.0, {{2.5, 0.0, 0.0}, {2.5, -4.0, 0.0}, {2.0, 0.0, 0.0}, {5.0, 2.0, 0.0}});
  const double t_end = sc->TimeOf(sc->num_frames);
  const double z1 = Travel(sc->camera_motion, t_end) + 200.0;
  StraightStreet(b, -40.0, z1);
  b->AddCar(PlanarMotion(PlanarState{0.0, 15.0, 0.0, 10.0},
                         {{2.0, 0.0, 0.0}, {2.5, -4.0, 0.0}, {2.0, 0.0, 0.0}, {5.0, 2.0, 0.0}},
                         G));
  b->AddCar(PlanarMotion(PlanarState{kOncomingLane, 80.0, M_PI, 9.0}, {}, G));
  b->AddCar(PlanarMotion(PlanarState{kOncomingLane, 150.0, M_PI, 9.0}, {}, G));
  b->ParkedRow(kParkRight, -30.0, z1 - 20.0, 0.0, 0.03, {});
  b->ParkedRow(kParkLeft, -30.0, z1 - 20.0, M_PI, 0.03, {});
  Walkers(b, 4, 0.0, 80.0);
}

void BuildDoor(Scenario* sc, Builder* b) {
  sc->camera_motion = CameraMotion(0.3, {});
  const double t_end = sc->TimeOf(sc->num_frames);
  const double z1 = Travel(sc->camera_motion, t_end) + 150.0;
  const double door_z = 14.0;
  // The brick wall replaces the buildings of the right side around the door.
  const std::vector<Interval> wall_zone = {{door_z - 9.0, door_z + 10.0}};
  StraightStreet(b, -40.0, z1, wall_zone);
  // The door opens towards the street by 80° during the middle of the sequence.
  const double t0 = 0.2 * t_end, t1 = 0.7 * t_end;
  b->DoorWall(kRoadRight + kSidewalkWidth,
              door_z - 9.0,
              door_z + 10.0,
              door_z,
              -80.0 * M_PI / 180.0,
              t0,
              t1);
  b->ParkedRow(kParkRight, -30.0, z1 - 20.0, 0.0, 0.2, {{door_z - 12.0, door_z + 6.0}});
  b->ParkedRow(kParkLeft, -30.0, z1 - 20.0, M_PI, 0.2, {});
  b->AddPedestrian(PlanarMotion(PlanarState{-9.0, 6.0, 0.0, 1.1}, {}, G - kCurbHeight));
  b->AddPedestrian(PlanarMotion(PlanarState{-9.9, 30.0, M_PI, 1.3}, {}, G - kCurbHeight));
}

struct Entry {
  const char* name;
  const char* description;
  void (*build)(Scenario*, Builder*);
};
const Entry kEntries[] = {
    {"static_street",
     "camera drives along a street lined with parked cars, nothing moves",
     &BuildStaticStreet},
    {"driving", "camera at 10 m/s with leading and oncoming cars and pedestrians", &BuildDriving},
    {"intersection",
     "camera slows down and turns right at a crossing; crossing cars",
     &BuildIntersection},
    {"turning_traffic",
     "camera waiting before a crossing; cars turn in front of it (0.6-0.8 rad/s)",
     &BuildTurningTraffic},
    {"stationary_then_accelerating",
     "camera still for 3 s then accelerating; cars pass close (many dynamic pixels)",
     &BuildStationaryThenAccelerating},
    {"follow_braking",
     "following a car that brakes to a stop and restarts; many parked cars",
     &BuildFollowBraking},
    {"door",
     "a door on a revolute joint opens in a brick wall; camera creeping forward",
     &BuildDoor},
};

}  // namespace

geometry::StereoCamera KittiLikeCamera() {
  geometry::StereoCamera cam;
  cam.fx = 721.5377;
  cam.fy = 721.5377;
  cam.cx = 609.5593;
  cam.cy = 172.854;
  cam.baseline = 0.54;
  cam.width = 1242;
  cam.height = 375;
  return cam;
}

std::vector<ScenarioInfo> ListScenarios() {
  std::vector<ScenarioInfo> out;
  for (const Entry& e : kEntries) out.push_back({e.name, e.description});
  return out;
}

absl::StatusOr<Scenario> MakeScenario(const std::string& name, uint32_t seed, int num_frames) {
  if (num_frames < 1) {
    return absl::InvalidArgumentError(
        absl::StrCat("number of frames must be >= 1, got ", num_frames));
  }
  for (const Entry& e : kEntries) {
    if (name != e.name) continue;
    Scenario sc;
    sc.name = name;
    sc.seed = seed;
    sc.num_frames = num_frames;
    sc.camera = KittiLikeCamera();
    // Mix the scenario name into the seed so scenarios differ for one seed.
    uint32_t h = seed;
    for (char c : name) h = procedural::Hash(h ^ static_cast<uint8_t>(c));
    Builder builder(&sc, h);
    e.build(&sc, &builder);
    return sc;
  }
  std::string names;
  for (const Entry& e : kEntries) absl::StrAppend(&names, names.empty() ? "" : ", ", e.name);
  return absl::InvalidArgumentError(
      absl::StrCat("unknown scenario '", name, "' (known: ", names, ")"));
}

}  // namespace twist::sim
