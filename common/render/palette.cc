#include "common/render/palette.h"

#include <algorithm>
#include <cmath>
#include <cstdlib>

namespace cutsim::render {

bool IsBackground(uint8_t r, uint8_t g, uint8_t b) {
  constexpr int kTolerance = 2;  // the clear colour is exact; ±2 survives lossy round trips
  return std::abs(int{r} - kBackgroundRgb[0]) <= kTolerance &&
         std::abs(int{g} - kBackgroundRgb[1]) <= kTolerance &&
         std::abs(int{b} - kBackgroundRgb[2]) <= kTolerance;
}

HueSaturation ToHueSaturation(uint8_t r, uint8_t g, uint8_t b) {
  const int hi = std::max({int{r}, int{g}, int{b}});
  const int lo = std::min({int{r}, int{g}, int{b}});
  HueSaturation out;
  if (hi == 0 || hi == lo) return out;
  const double delta = hi - lo;
  out.saturation = delta / hi;
  double hue = 0;
  if (hi == r) {
    hue = 60.0 * (g - b) / delta;
  } else if (hi == g) {
    hue = 60.0 * (2.0 + (b - r) / delta);
  } else {
    hue = 60.0 * (4.0 + (r - g) / delta);
  }
  if (hue < 0) hue += 360.0;
  out.hue_deg = hue;
  return out;
}

bool IsCutFaceColour(uint8_t r, uint8_t g, uint8_t b) {
  // kCutFaceRgb is hue 45.4°, saturation 0.87; lighting only scales it by
  // k ∈ [kMinLight, 1], so the darkest cut pixel has max channel ≈ 52. The
  // ±15° hue window absorbs 8-bit rounding at that darkest level.
  if (std::max({r, g, b}) < 40) return false;
  const HueSaturation hs = ToHueSaturation(r, g, b);
  return hs.hue_deg >= 30.0 && hs.hue_deg <= 65.0 && hs.saturation >= 0.6;
}

bool IsForceColour(uint8_t r, uint8_t g, uint8_t b) {
  if (std::max({r, g, b}) < 40) return false;
  const HueSaturation hs = ToHueSaturation(r, g, b);
  return hs.hue_deg >= 100.0 && hs.hue_deg <= 165.0 && hs.saturation >= 0.5;
}

Rgb StressColour(double t) {
  if (!(t > 0.0)) t = 0.0;  // also maps NaN to 0
  if (t > 1.0) t = 1.0;
  // Moreland (2009) cool-to-warm control points, sRGB.
  struct Stop {
    double t;
    double r, g, b;
  };
  static constexpr Stop kStops[] = {
      {0.00, 59, 76, 192},   {0.25, 124, 159, 249}, {0.50, 221, 221, 221},
      {0.75, 238, 133, 104}, {1.00, 180, 4, 38},
  };
  size_t i = 0;
  while (i + 2 < std::size(kStops) && t > kStops[i + 1].t) ++i;
  const Stop& a = kStops[i];
  const Stop& b = kStops[i + 1];
  const double s = (t - a.t) / (b.t - a.t);
  auto mix = [s](double x, double y) { return static_cast<uint8_t>(std::lround(x + (y - x) * s)); };
  return {mix(a.r, b.r), mix(a.g, b.g), mix(a.b, b.b)};
}

}  // namespace cutsim::render
