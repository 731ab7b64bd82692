#pragma once
/// @file
/// The renderer's fixed colours and the rules that classify a rendered pixel.
///
/// Lighting (see surface_renderer.cc) is white and purely ambient + diffuse,
/// with no specular term, and its total never exceeds 1, so every lit pixel is
/// its base colour times one factor k ∈ [kMinLight, 1] per pixel: lighting
/// changes brightness but never hue or saturation, and nothing clamps. The
/// classifiers below therefore test hue and saturation, not exact RGB.
///
/// Colour rule for faces opened by a cut (`IsCutFaceColour`): amber base
/// RGB (235, 185, 30), HSV hue ≈ 45°, saturation ≈ 0.87. A pixel is cut-face
/// coloured when its hue is in [30°, 65°], its saturation ≥ 0.6 and its
/// largest channel ≥ 40. Tissue (hue ≈ 7°, saturation ≈ 0.38), the stress map
/// (blue → grey → red, never amber) and the steel tool (saturation < 0.2)
/// all fall outside it.

#include <array>
#include <cstdint>

namespace cutsim::render {

/// An 8-bit RGB triple.
using Rgb = std::array<uint8_t, 3>;

/// Clear colour: dark slate blue-grey. Every lit surface has R ≥ B or a
/// different B−R gap, so no surface pixel equals it.
inline constexpr Rgb kBackgroundRgb{30, 34, 44};
/// Intact tissue: pink (hue ≈ 7°, saturation ≈ 0.38).
inline constexpr Rgb kTissueRgb{228, 152, 142};
/// Faces opened by a cut: amber (hue ≈ 45°, saturation ≈ 0.87).
inline constexpr Rgb kCutFaceRgb{235, 185, 30};
/// The cutting tool's blade: steel grey-blue (saturation ≈ 0.13).
inline constexpr Rgb kToolRgb{180, 188, 206};
/// The scalpel's handle: a darker, bluer anodised grey (hue ≈ 221°,
/// saturation 0.5, never the background at any light level), so the
/// bright blade reads apart from it.
inline constexpr Rgb kHandleRgb{70, 92, 140};
/// The force on the tool (arrow and gauge): green (hue ≈ 133°,
/// saturation ≈ 0.70), a hue no surface uses.
inline constexpr Rgb kForceRgb{60, 200, 90};
/// The force gauge's frame: light grey.
inline constexpr Rgb kGaugeFrameRgb{220, 220, 220};

/// Smallest lighting factor a surface pixel can get (the ambient term).
inline constexpr double kMinLight = 0.22;

/// True when (r, g, b) is the background colour (±2 per channel).
[[nodiscard]] bool IsBackground(uint8_t r, uint8_t g, uint8_t b);

/// True when (r, g, b) is a lit cut-face pixel (rule in the file comment).
[[nodiscard]] bool IsCutFaceColour(uint8_t r, uint8_t g, uint8_t b);

/// True when (r, g, b) is a force-arrow or gauge pixel: hue in [100°, 165°],
/// saturation ≥ 0.5 and largest channel ≥ 40.
[[nodiscard]] bool IsForceColour(uint8_t r, uint8_t g, uint8_t b);

/// HSV hue in degrees [0, 360) and saturation [0, 1] of an RGB triple (hue 0
/// for greys).
struct HueSaturation {
  double hue_deg = 0;
  double saturation = 0;
};
[[nodiscard]] HueSaturation ToHueSaturation(uint8_t r, uint8_t g, uint8_t b);

/// The stress colour map at t ∈ [0, 1] (clamped; NaN maps to 0): a diverging
/// blue → light grey → red ramp (Moreland's "cool to warm"), chosen because it
/// never passes through amber, so stress never reads as a cut.
[[nodiscard]] Rgb StressColour(double t);

}  // namespace cutsim::render
