// Deterministic, band-limited procedural texture primitives.
//
// Every function takes the footprint of the pixel on the surface (metres per
// pixel along each texture axis, `fw`) and removes the detail that the pixel
// cannot resolve: noise octaves whose wavelength is below ~2-4 pixels fade
// out, and hard-edged patterns (stripes, tiles, windows) are box-filtered
// analytically over the footprint. This is what keeps the rendered images
// free of aliasing, which would otherwise create false stereo matches.
//
// Integer hashing only (no std:: random engines), so the output is identical
// on every platform for a given seed.
#pragma once

#include <algorithm>
#include <cmath>
#include <cstdint>

namespace twist::sim::procedural {

inline uint32_t Hash(uint32_t x) {
  x ^= x >> 16;
  x *= 0x7feb352dU;
  x ^= x >> 15;
  x *= 0x846ca68bU;
  x ^= x >> 16;
  return x;
}
inline uint32_t Hash3(int32_t a, int32_t b, uint32_t seed) {
  return Hash(static_cast<uint32_t>(a) * 0x9e3779b1U ^
              Hash(static_cast<uint32_t>(b) * 0x85ebca77U ^ seed));
}
// Uniform in [0, 1).
inline float Unit(uint32_t h) { return static_cast<float>(h >> 8) * (1.0f / 16777216.0f); }
inline float UnitHash(int32_t a, int32_t b, uint32_t seed) { return Unit(Hash3(a, b, seed)); }

inline float Clamp01(float v) { return std::min(1.0f, std::max(0.0f, v)); }
inline float Lerp(float a, float b, float t) { return a + (b - a) * t; }
inline float Smooth(float t) { return t * t * t * (t * (t * 6.0f - 15.0f) + 10.0f); }

// Signed value noise in [-1, 1] on a unit lattice, C² interpolation.
inline float ValueNoise(float x, float y, uint32_t seed) {
  const float fx = std::floor(x), fy = std::floor(y);
  const int32_t ix = static_cast<int32_t>(fx), iy = static_cast<int32_t>(fy);
  const float tx = Smooth(x - fx), ty = Smooth(y - fy);
  const float a = UnitHash(ix, iy, seed), b = UnitHash(ix + 1, iy, seed);
  const float c = UnitHash(ix, iy + 1, seed), d = UnitHash(ix + 1, iy + 1, seed);
  return 2.0f * Lerp(Lerp(a, b, tx), Lerp(c, d, tx), ty) - 1.0f;
}

// Weight of a component with `cycles_per_pixel` (1 below 0.2, 0 above 0.45).
inline float BandWeight(float cycles_per_pixel) {
  return Clamp01((0.45f - cycles_per_pixel) * 4.0f);
}

// Fractal sum of value noise, base frequency `freq` (cycles/m), `octaves`
// octaves, amplitude ratio `gain`; `fw` = footprint in metres (the larger of
// the two axes). Roughly in [-1, 1].
inline float Fbm(float x, float y, float freq, int octaves, float gain, float fw, uint32_t seed) {
  float sum = 0.0f, amp = 1.0f, norm = 0.0f;
  for (int o = 0; o < octaves; ++o) {
    norm += amp;
    const float w = BandWeight(freq * fw);
    if (w <= 0.0f) break;
    sum += amp * w * ValueNoise(x * freq, y * freq, seed + 1013u * static_cast<uint32_t>(o));
    freq *= 2.03f;
    amp *= gain;
  }
  return norm > 0.0f ? sum / norm * 1.6f : 0.0f;
}

// Anisotropic variant for surfaces seen at grazing angles (the road): the
// footprint is fw_x along x and fw_y along y. Each octave is kept while the
// *smaller* footprint resolves it, and box-filtered along the longer axis by
// averaging up to `max_taps` samples spread over the footprint. Keeps the
// fine grain across the image rows that stereo matching needs.
inline float FbmAniso(float x,
                      float y,
                      float freq,
                      int octaves,
                      float gain,
                      float fw_x,
                      float fw_y,
                      uint32_t seed,
                      int max_taps = 8) {
  const float fmin = std::min(fw_x, fw_y), fmax = std::max(fw_x, fw_y);
  const bool major_x = fw_x >= fw_y;
  float sum = 0.0f, amp = 1.0f, norm = 0.0f;
  for (int o = 0; o < octaves; ++o) {
    norm += amp;
    const float w = BandWeight(freq * fmin);
    if (w <= 0.0f) break;
    const uint32_t oseed = seed + 1013u * static_cast<uint32_t>(o);
    const int taps =
        std::min(max_taps, std::max(1, static_cast<int>(std::ceil(freq * fmax / 0.3f))));
    float v = 0.0f;
    if (taps == 1) {
      v = ValueNoise(x * freq, y * freq, oseed);
    } else {
      const float step = fmax / static_cast<float>(taps);
      for (int k = 0; k < taps; ++k) {
        const float off = (static_cast<float>(k) + 0.5f) * step - 0.5f * fmax;
        v += major_x ? ValueNoise((x + off) * freq, y * freq, oseed)
                     : ValueNoise(x * freq, (y + off) * freq, oseed);
      }
      v /= static_cast<float>(taps);
      // What the taps cannot represent any more (wavelength < spacing) is gone.
      v *= BandWeight(freq * step);
    }
    sum += amp * w * v;
    freq *= 2.03f;
    amp *= gain;
  }
  return norm > 0.0f ? sum / norm * 1.6f : 0.0f;
}

// Integral of a pulse train of period `p` that is 1 on [0, duty*p) of each period.
inline float PulseIntegral(float x, float p, float duty) {
  const float n = std::floor(x / p);
  return n * duty * p + std::min(x - n * p, duty * p);
}
// Box-filtered pulse train over [x - fw/2, x + fw/2]: coverage in [0, 1].
inline float FilteredPulseTrain(float x, float p, float duty, float fw) {
  if (fw < 1e-6f) {
    const float f = x / p - std::floor(x / p);
    return f < duty ? 1.0f : 0.0f;
  }
  const float w = std::max(fw, 1e-6f);
  return (PulseIntegral(x + 0.5f * w, p, duty) - PulseIntegral(x - 0.5f * w, p, duty)) / w;
}
// Box-filtered indicator of [a, b] over [x - fw/2, x + fw/2].
inline float FilteredBox(float x, float a, float b, float fw) {
  const float w = std::max(fw, 1e-6f);
  const float lo = std::max(x - 0.5f * w, a), hi = std::min(x + 0.5f * w, b);
  return Clamp01((hi - lo) / w);
}

}  // namespace twist::sim::procedural
