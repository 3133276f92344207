#include "slam/sim/texture.h"

#include <algorithm>
#include <cmath>

#include "slam/sim/procedural.h"

namespace twist::sim {
namespace {

using procedural::BandWeight;
using procedural::Clamp01;
using procedural::Fbm;
using procedural::FilteredBox;
using procedural::FilteredPulseTrain;
using procedural::Hash3;
using procedural::UnitHash;
using Color = Eigen::Vector3f;

Color Mix(const Color& a, const Color& b, float t) { return a + (b - a) * t; }

// Round spots scattered on a grid of `cell` metres: each cell holds a spot with
// probability `prob`, radius in [rmin, rmax]. Returns the box-filtered coverage
// and the spot's random value in *value.
float Spots(float x,
            float y,
            float cell,
            float prob,
            float rmin,
            float rmax,
            float fw,
            uint32_t seed,
            float* value) {
  const float cx = std::floor(x / cell), cy = std::floor(y / cell);
  const int32_t ix = static_cast<int32_t>(cx), iy = static_cast<int32_t>(cy);
  if (UnitHash(ix, iy, seed) >= prob) return 0.0f;
  const float r = rmin + (rmax - rmin) * UnitHash(ix, iy, seed + 7u);
  const float margin = r / cell;
  const float px = (cx + margin + (1.0f - 2.0f * margin) * UnitHash(ix, iy, seed + 11u)) * cell;
  const float py = (cy + margin + (1.0f - 2.0f * margin) * UnitHash(ix, iy, seed + 13u)) * cell;
  if (value != nullptr) *value = UnitHash(ix, iy, seed + 17u);
  const float dist = std::hypot(x - px, y - py);
  const float w = std::max(fw, 1e-4f);
  const float area_fade = std::min(1.0f, (2.0f * r / w) * (2.0f * r / w));
  return Clamp01((r - dist) / w + 0.5f) * std::min(1.0f, area_fade);
}

// A rectangle [x0,x1]x[y0,y1] filtered over the footprint.
float Rect(float x, float y, float x0, float x1, float y0, float y1, float fx, float fy) {
  return FilteredBox(x, x0, x1, fx) * FilteredBox(y, y0, y1, fy);
}

// Random "characters" (licence plates, shop signs): blocks of cells on/off.
float Glyphs(float x, float y, float cell, float fw, uint32_t seed) {
  const float ix = std::floor(x / cell), iy = std::floor(y / cell);
  const float on =
      UnitHash(static_cast<int32_t>(ix), static_cast<int32_t>(iy), seed) < 0.45f ? 1.0f : 0.0f;
  // Fade to the mean when the cells are not resolved.
  return procedural::Lerp(0.45f, on, BandWeight(fw / (2.0f * cell)));
}

Color Asphalt(const Material& m, const SurfaceSample& p, const std::vector<Marking>& markings) {
  const float x = static_cast<float>(p.p_in_world.x()), z = static_cast<float>(p.p_in_world.z());
  const float fw = std::max(p.fw_s, p.fw_t);
  const float patches = Fbm(x, z, 0.08f, 3, 0.5f, fw, m.seed);
  const float grain = Fbm(x, z, 2.5f, 4, 0.62f, fw, m.seed + 100u);
  // Gravel: strong fine grain (centimetre scale), faded out with distance.
  const float gravel = procedural::FbmAniso(x, z, 5.0f, 6, 0.85f, p.fw_s, p.fw_t, m.seed + 150u);
  float spot_value = 0.0f;
  const float spot = Spots(x, z, 0.9f, 0.35f, 0.04f, 0.16f, fw, m.seed + 200u, &spot_value);
  Color c = m.color * (1.0f + 0.10f * patches + 0.12f * grain + 0.3f * gravel);
  c = Mix(c, m.color * (spot_value < 0.5f ? 0.55f : 1.35f), 0.8f * spot);
  for (const Marking& mk : markings) {
    const float rx = x - static_cast<float>(mk.start.x()),
                rz = z - static_cast<float>(mk.start.y());
    const float dx = static_cast<float>(mk.dir.x()), dz = static_cast<float>(mk.dir.y());
    const float along = rx * dx + rz * dz;
    const float across = -rx * dz + rz * dx;
    const float hw = static_cast<float>(0.5 * mk.width);
    if (std::abs(across) > hw + fw || along < -fw || along > mk.length + fw) continue;
    const float fw_along = std::abs(dx) * p.fw_s + std::abs(dz) * p.fw_t;
    const float fw_across = std::abs(dz) * p.fw_s + std::abs(dx) * p.fw_t;
    float cov = FilteredBox(across, -hw, hw, fw_across) *
                FilteredBox(along, 0.0f, static_cast<float>(mk.length), fw_along);
    if (mk.duty < 1.0) {
      cov *= FilteredPulseTrain(
          along, static_cast<float>(mk.period), static_cast<float>(mk.duty), fw_along);
    }
    // Worn paint.
    cov *= Clamp01(0.85f + 0.3f * Fbm(x, z, 4.0f, 3, 0.5f, fw, m.seed + 300u));
    c = Mix(c, mk.color * (1.0f + 0.06f * grain), cov);
  }
  return c;
}

Color Paving(const Material& m, const SurfaceSample& p) {
  const float x = p.u0 + p.s, y = p.v0 + p.t;
  const float tile = m.p0 > 0.0f ? m.p0 : 0.4f;
  const float duty = 1.0f - 0.02f / tile;
  const float cover =
      FilteredPulseTrain(x, tile, duty, p.fw_s) * FilteredPulseTrain(y, tile, duty, p.fw_t);
  const float fw = std::max(p.fw_s, p.fw_t);
  const float var = (UnitHash(static_cast<int32_t>(std::floor(x / tile)),
                              static_cast<int32_t>(std::floor(y / tile)),
                              m.seed) -
                     0.5f) *
                    BandWeight(fw / tile * 0.5f);
  const float grain = Fbm(x, y, 3.0f, 5, 0.6f, fw, m.seed + 5u);
  const Color tile_color = m.color * (1.0f + 0.25f * var + 0.12f * grain);
  return Mix(m.color2, tile_color, cover);
}

Color Concrete(const Material& m, const SurfaceSample& p) {
  const float x = p.u0 + p.s, y = p.v0 + p.t;
  const float fw = std::max(p.fw_s, p.fw_t);
  float v = 0.0f;
  const float spot = Spots(x, y, 0.5f, 0.3f, 0.03f, 0.1f, fw, m.seed + 3u, &v);
  const Color c = m.color * (1.0f + 0.14f * Fbm(x, y, 1.5f, 6, 0.6f, fw, m.seed));
  return Mix(c, c * (0.6f + 0.6f * v), spot);
}

Color Facade(const Material& m, const SurfaceSample& p) {
  const float x = p.u0 + p.s, h = p.v0 + p.t;
  const float fw = std::max(p.fw_s, p.fw_t);
  const float period = m.p0 > 0.0f ? m.p0 : 3.0f;
  const float floor_h = m.p1 > 0.0f ? m.p1 : 3.2f;
  const float duty = m.p2 > 0.0f ? m.p2 : 0.45f;
  const float ground = 4.2f;
  Color c = m.color * (1.0f + 0.08f * Fbm(x, h, 0.7f, 6, 0.6f, fw, m.seed));
  // Cornices between floors.
  if (h > ground - 0.3f) {
    const float band = FilteredPulseTrain(h - ground + 0.3f, floor_h, 0.18f / floor_h, p.fw_t);
    c = Mix(c, m.color2, 0.8f * band);
  }
  if (h >= ground) {
    const float xo = x - 0.5f * period * (1.0f - duty);
    const float yo = h - ground - 0.9f;
    const float outer = FilteredPulseTrain(xo, period, duty, p.fw_s) *
                        FilteredPulseTrain(yo, floor_h, 1.6f / floor_h, p.fw_t);
    const float frame = 0.09f;
    const float inner =
        FilteredPulseTrain(xo - frame, period, duty - 2.0f * frame / period, p.fw_s) *
        FilteredPulseTrain(yo - frame, floor_h, (1.6f - 2.0f * frame) / floor_h, p.fw_t);
    const int32_t wi = static_cast<int32_t>(std::floor(xo / period));
    const int32_t wj = static_cast<int32_t>(std::floor(yo / floor_h));
    const float fade = BandWeight(fw / period);
    const float r = UnitHash(wi, wj, m.seed + 31u);
    // Glass: dark, per-window brightness, reflections, some with curtains.
    Color glass = Color(0.10f, 0.13f, 0.17f) * (0.7f + 0.9f * (0.5f + (r - 0.5f) * fade));
    glass *= 1.0f + 0.5f * Fbm(x * 0.5f + h, h * 0.3f, 1.2f, 3, 0.5f, fw, m.seed + 41u);
    const float local_y = yo - std::floor(yo / floor_h) * floor_h;
    if (r > 0.6f) {
      const float curtain = FilteredBox(local_y, 0.9f, 1.6f - frame, p.fw_t) * fade;
      glass = Mix(glass, Color(0.75f, 0.7f, 0.6f) * (0.8f + 0.4f * r), curtain);
    }
    const Color frame_color(0.85f, 0.85f, 0.82f);
    c = Mix(c, frame_color, outer);
    c = Mix(c, glass, inner);
  } else {
    // Ground floor: shop windows with a sign band.
    const float shop = 4.5f;
    const float xo = x + 0.3f * shop;
    const float glass_cov =
        FilteredPulseTrain(xo, shop, 0.72f, p.fw_s) * FilteredBox(h, 0.45f, 3.1f, p.fw_t);
    const int32_t si = static_cast<int32_t>(std::floor(xo / shop));
    const float fade = BandWeight(fw / shop);
    Color inside = Color(0.12f, 0.12f, 0.13f) *
                   (1.0f + 1.6f * std::max(0.0f, Fbm(x, h, 1.3f, 5, 0.65f, fw, m.seed + 51u)));
    // Shelves and goods.
    inside = Mix(inside,
                 Color(0.6f, 0.45f, 0.3f),
                 0.5f * FilteredPulseTrain(h, 0.55f, 0.12f, p.fw_t) * fade);
    const float sign = FilteredBox(h, 3.3f, 3.9f, p.fw_t);
    const Color sign_color(UnitHash(si, 1, m.seed) * 0.8f + 0.1f,
                           UnitHash(si, 2, m.seed) * 0.8f + 0.1f,
                           UnitHash(si, 3, m.seed) * 0.8f + 0.1f);
    const float letters = Glyphs(x, h - 3.42f, 0.12f, fw, m.seed + static_cast<uint32_t>(si)) *
                          FilteredBox(h, 3.42f, 3.78f, p.fw_t) *
                          FilteredPulseTrain(xo, shop, 0.6f, p.fw_s);
    c = Mix(c, Color(0.2f, 0.2f, 0.22f), FilteredBox(h, 0.0f, 0.35f, p.fw_t));  // plinth
    c = Mix(c, Mix(Color::Constant(0.3f), sign_color, fade), sign);
    c = Mix(c, Color(0.95f, 0.95f, 0.9f), 0.9f * letters);
    c = Mix(c, inside, glass_cov);
  }
  return c;
}

Color Brick(const Material& m, const SurfaceSample& p) {
  const float x = p.u0 + p.s, y = p.v0 + p.t;
  const float fw = std::max(p.fw_s, p.fw_t);
  const float bh = 0.085f, bw = 0.26f, mortar = 0.013f;
  const float row = std::floor(y / bh);
  const float xs = x + (static_cast<int>(row) % 2 != 0 ? 0.5f * bw : 0.0f);
  const float cover = FilteredPulseTrain(xs, bw, 1.0f - mortar / bw, p.fw_s) *
                      FilteredPulseTrain(y, bh, 1.0f - mortar / bh, p.fw_t);
  const float var =
      (UnitHash(static_cast<int32_t>(std::floor(xs / bw)), static_cast<int32_t>(row), m.seed) -
       0.5f) *
      BandWeight(fw / bh * 0.5f);
  const float grain = Fbm(x, y, 4.0f, 5, 0.6f, fw, m.seed + 9u);
  const float dirt = Fbm(x, y, 0.3f, 3, 0.5f, fw, m.seed + 19u);
  const Color brick = m.color * (1.0f + 0.35f * var + 0.1f * grain + 0.12f * dirt);
  return Mix(m.color2 * (1.0f + 0.1f * grain), brick, cover);
}

Color Door(const Material& m, const SurfaceSample& p) {
  const float s = p.s, t = p.t;
  const float fw = std::max(p.fw_s, p.fw_t);
  const float grain = Fbm(s * 6.0f, t * 0.4f, 2.0f, 5, 0.6f, fw * 3.0f, m.seed);
  Color c = m.color * (1.0f + 0.18f * grain);
  if (p.su > 0.4f && p.sv > 1.0f) {
    // Four recessed panels, frame lines darker.
    const float b = 0.14f;
    const float mid_s = 0.5f * p.su, mid_t = 0.55f * p.sv;
    float panel = 0.0f;
    panel += Rect(s, t, b, mid_s - 0.5f * b, b, mid_t - 0.5f * b, p.fw_s, p.fw_t);
    panel += Rect(s, t, mid_s + 0.5f * b, p.su - b, b, mid_t - 0.5f * b, p.fw_s, p.fw_t);
    panel += Rect(s, t, b, mid_s - 0.5f * b, mid_t + 0.5f * b, p.sv - b, p.fw_s, p.fw_t);
    panel += Rect(s, t, mid_s + 0.5f * b, p.su - b, mid_t + 0.5f * b, p.sv - b, p.fw_s, p.fw_t);
    const float edge =
        Rect(s, t, b - 0.03f, p.su - b + 0.03f, b - 0.03f, p.sv - b + 0.03f, p.fw_s, p.fw_t);
    c = Mix(c, c * 0.6f, edge - panel);
    c = Mix(c, m.color2, Clamp01(panel) * 0.3f);
    // Handle and lock plate.
    const float handle = Rect(s, t, p.su - 0.16f, p.su - 0.06f, 0.95f, 1.15f, p.fw_s, p.fw_t);
    c = Mix(c, Color(0.8f, 0.75f, 0.5f), handle);
  }
  return c;
}

Color CarPaint(const Material& m, const SurfaceSample& p) {
  const float s = p.s, t = p.t;
  const float x = p.u0 + s, y = p.v0 + t;
  const float fw = std::max(p.fw_s, p.fw_t);
  // Sky reflection: brighter on the upper part, soft noise.
  Color c = m.color * (0.85f + 0.25f * Clamp01(t / std::max(p.sv, 0.1f)) +
                       0.06f * Fbm(x, y, 0.8f, 4, 0.5f, fw, m.seed));
  float dirt_v = 0.0f;
  const float dirt = Spots(x, y, 0.35f, 0.25f, 0.02f, 0.06f, fw, m.seed + 3u, &dirt_v);
  c = Mix(c, c * (0.5f + 0.3f * dirt_v), 0.7f * dirt);
  if (m.p0 > 0.5f) {
    // Side: door seams, handles, a body line.
    const float seams = FilteredBox(s, 0.30f * p.su - 0.012f, 0.30f * p.su + 0.012f, p.fw_s) +
                        FilteredBox(s, 0.56f * p.su - 0.012f, 0.56f * p.su + 0.012f, p.fw_s);
    c = Mix(c, c * 0.35f, Clamp01(seams) * FilteredBox(t, 0.05f, p.sv - 0.02f, p.fw_t));
    const float handles =
        Rect(s, t, 0.33f * p.su, 0.33f * p.su + 0.14f, p.sv - 0.17f, p.sv - 0.12f, p.fw_s, p.fw_t) +
        Rect(s, t, 0.59f * p.su, 0.59f * p.su + 0.14f, p.sv - 0.17f, p.sv - 0.12f, p.fw_s, p.fw_t);
    c = Mix(c, Color(0.08f, 0.08f, 0.08f), Clamp01(handles));
    const float line = FilteredBox(t, 0.42f * p.sv, 0.42f * p.sv + 0.03f, p.fw_t);
    c = Mix(c, c * 1.3f, line);
    const float sill = FilteredBox(t, 0.0f, 0.1f, p.fw_t);
    c = Mix(c, Color(0.08f, 0.08f, 0.09f), sill);
  }
  return c;
}

Color CarGlass(const Material& m, const SurfaceSample& p) {
  const float s = p.s, t = p.t;
  const float x = p.u0 + s, y = p.v0 + t;
  const float fw = std::max(p.fw_s, p.fw_t);
  Color glass =
      Color(0.07f, 0.09f, 0.11f) *
      (1.0f + 1.2f * std::max(0.0f, Fbm(x * 0.7f + y, y, 1.5f, 4, 0.55f, fw, m.seed + 9u)));
  // Pillars at both ends and in the middle (body colour), frame at the bottom.
  const float pillar =
      FilteredBox(s, -1.0f, 0.08f, p.fw_s) + FilteredBox(s, p.su - 0.08f, p.su + 1.0f, p.fw_s) +
      (p.su > 1.6f ? FilteredBox(s, 0.47f * p.su, 0.47f * p.su + 0.09f, p.fw_s) : 0.0f);
  const float frame =
      FilteredBox(t, -1.0f, 0.06f, p.fw_t) + FilteredBox(t, p.sv - 0.05f, p.sv + 1.0f, p.fw_t);
  return Mix(glass, m.color2, Clamp01(pillar + frame));
}

Color CarEnd(const Material& m, const SurfaceSample& p, bool front) {
  const float s = p.s, t = p.t;
  const float fw = std::max(p.fw_s, p.fw_t);
  Color c = m.color * (0.9f + 0.06f * Fbm(s, t, 1.0f, 3, 0.5f, fw, m.seed));
  const float w = p.su, h = p.sv;
  // Bumper.
  c = Mix(c, Color(0.1f, 0.1f, 0.11f), FilteredBox(t, 0.0f, 0.16f, p.fw_t));
  const Color light = front ? Color(0.95f, 0.93f, 0.8f) : Color(0.75f, 0.06f, 0.05f);
  const float lights = Rect(s, t, 0.06f, 0.34f, h - 0.22f, h - 0.06f, p.fw_s, p.fw_t) +
                       Rect(s, t, w - 0.34f, w - 0.06f, h - 0.22f, h - 0.06f, p.fw_s, p.fw_t);
  c = Mix(c, light, Clamp01(lights));
  if (front) {
    const float grille = Rect(s, t, 0.42f, w - 0.42f, h - 0.25f, h - 0.08f, p.fw_s, p.fw_t);
    const float slats = FilteredPulseTrain(t, 0.04f, 0.5f, p.fw_t);
    c = Mix(c, Color::Constant(0.05f + 0.12f * slats), grille);
  }
  const float plate = Rect(s, t, 0.5f * w - 0.26f, 0.5f * w + 0.26f, 0.2f, 0.32f, p.fw_s, p.fw_t);
  const float glyph = Glyphs(s - 0.5f * w + 0.22f, t - 0.22f, 0.045f, fw, m.seed + 77u) *
                      Rect(s, t, 0.5f * w - 0.22f, 0.5f * w + 0.22f, 0.22f, 0.3f, p.fw_s, p.fw_t);
  c = Mix(c, Color(0.92f, 0.92f, 0.88f), plate);
  c = Mix(c, Color(0.05f, 0.05f, 0.05f), glyph);
  return c;
}

Color Tire(const Material& m, const SurfaceSample& p) {
  const float fw = std::max(p.fw_s, p.fw_t);
  Color c = Color::Constant(0.06f) * (1.0f + 0.3f * Fbm(p.s, p.t, 6.0f, 3, 0.5f, fw, m.seed));
  const float r = 0.5f * std::min(p.su, p.sv);
  if (r > 0.15f) {
    const float d = std::hypot(p.s - 0.5f * p.su, p.t - 0.5f * p.sv);
    const float rim = Clamp01((0.6f * r - d) / std::max(fw, 1e-3f) + 0.5f);
    const float hub = Clamp01((0.18f * r - d) / std::max(fw, 1e-3f) + 0.5f);
    c = Mix(c, Color::Constant(0.55f), rim);
    c = Mix(c, Color::Constant(0.2f), hub);
  }
  return c;
}

Color Foliage(const Material& m, const SurfaceSample& p) {
  const float x = p.u0 + p.s, y = p.v0 + p.t;
  const float fw = std::max(p.fw_s, p.fw_t);
  const float n = Fbm(x, y, 1.2f, 7, 0.7f, fw, m.seed);
  float v = 0.0f;
  const float leaf = Spots(x, y, 0.2f, 0.6f, 0.03f, 0.07f, fw, m.seed + 5u, &v);
  Color c = m.color * (0.75f + 0.55f * n);
  return Mix(c, v < 0.5f ? m.color * 0.4f : m.color2, 0.8f * leaf);
}

}  // namespace

Eigen::Vector3f ShadeSurface(const Material& m,
                             const SurfaceSample& p,
                             const std::vector<Marking>& markings) {
  const float fw = std::max(p.fw_s, p.fw_t);
  switch (m.pattern) {
    case Pattern::kAsphalt:
      return Asphalt(m, p, markings);
    case Pattern::kPaving:
      return Paving(m, p);
    case Pattern::kConcrete:
      return Concrete(m, p);
    case Pattern::kFacade:
      return Facade(m, p);
    case Pattern::kBrick:
      return Brick(m, p);
    case Pattern::kRoof:
      return m.color * (1.0f + 0.2f * Fbm(p.u0 + p.s, p.v0 + p.t, 0.5f, 5, 0.6f, fw, m.seed));
    case Pattern::kDoor:
      return Door(m, p);
    case Pattern::kInterior:
      return m.color * (1.0f + 0.8f * Fbm(p.u0 + p.s, p.v0 + p.t, 0.8f, 5, 0.6f, fw, m.seed));
    case Pattern::kCarPaint:
      return CarPaint(m, p);
    case Pattern::kCarGlass:
      return CarGlass(m, p);
    case Pattern::kCarFront:
      return CarEnd(m, p, true);
    case Pattern::kCarBack:
      return CarEnd(m, p, false);
    case Pattern::kTire:
      return Tire(m, p);
    case Pattern::kMetal:
      return m.color *
             (1.0f +
              0.15f *
                  Fbm((p.u0 + p.s) * 8.0f, (p.v0 + p.t) * 0.5f, 1.0f, 4, 0.5f, fw * 8.0f, m.seed));
    case Pattern::kBark:
      return m.color *
             (1.0f +
              0.3f *
                  Fbm((p.u0 + p.s) * 6.0f, (p.v0 + p.t) * 0.8f, 1.5f, 5, 0.6f, fw * 6.0f, m.seed));
    case Pattern::kFoliage:
      return Foliage(m, p);
    case Pattern::kCloth: {
      const float stripes = m.p0 > 0.0f ? FilteredPulseTrain(p.v0 + p.t, m.p0, 0.5f, p.fw_t) : 0.0f;
      const Color c = Mix(m.color, m.color2, stripes);
      return c * (1.0f + 0.15f * Fbm(p.u0 + p.s, p.v0 + p.t, 4.0f, 4, 0.6f, fw, m.seed));
    }
    case Pattern::kSkin: {
      const float hair = FilteredBox(p.t, p.sv - 0.09f, p.sv + 1.0f, p.fw_t);
      return Mix(m.color, m.color2, hair) *
             (1.0f + 0.08f * Fbm(p.s, p.t, 8.0f, 3, 0.5f, fw, m.seed));
    }
  }
  return m.color;
}

Eigen::Vector3f ShadeSky(const Eigen::Vector3d& dir_in_world, uint32_t seed) {
  const Eigen::Vector3d d = dir_in_world.normalized();
  const float elevation = static_cast<float>(-d.y());  // y points down
  const Color horizon(0.82f, 0.86f, 0.90f), zenith(0.36f, 0.55f, 0.84f);
  Color c = Mix(horizon, zenith, Clamp01(elevation * 2.2f));
  if (elevation > 0.02f) {
    // Clouds on a plane 1 km up; only low frequencies (sky has no stereo
    // texture worth matching at infinity).
    const float k = 1000.0f / elevation;
    const float x = static_cast<float>(d.x()) * k, z = static_cast<float>(d.z()) * k;
    const float n = Fbm(x, z, 0.0015f, 4, 0.5f, 0.0f, seed);
    const float cover = Clamp01((n - 0.05f) * 2.5f) * Clamp01((elevation - 0.02f) * 8.0f);
    c = Mix(c, Color(0.95f, 0.95f, 0.96f), 0.8f * cover);
  }
  return c;
}

}  // namespace twist::sim
