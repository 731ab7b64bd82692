#pragma once
/// @file
/// Draws a boundary surface (positions + triangles) offscreen: flat-shaded,
/// two-sided lit tissue, faces opened by cuts in their own colour, optional
/// per-vertex stress colouring and the cutting tool. Independent of how the
/// surface was extracted: it takes plain arrays.

#include <Eigen/Core>
#include <cstdint>
#include <memory>
#include <optional>
#include <span>
#include <vector>

#include "common/core/tool_pose.h"
#include "common/mesh/tet_mesh.h"
#include "common/render/camera.h"
#include "common/render/image.h"

namespace cutsim::render {

class OsMesaContext;

/// The surface to draw. Non-owning: the arrays must outlive the `Render` call.
struct SurfaceInput {
  const mesh::Positions& positions;  ///< #N×3 vertex positions, world frame, m.
  const mesh::Triangles& triangles;  ///< #F×3 vertex indices (any winding: lighting is two-sided).
  /// #F flags or empty; non-zero marks a face opened by a cut.
  std::span<const uint8_t> opened = {};
  /// #N per-vertex scalar (e.g. von Mises stress, Pa) or empty.
  std::span<const double> vertex_scalar = {};
};

/// The cutting tool, drawn as a scalpel: a flat, pointed steel blade from
/// the pose's tip along its blade direction (toward the handle) for
/// `length`, its cutting edge bellied toward `edge_dir`, then a darker flat
/// handle kHandleLengths × `length` long.
struct ToolSegment {
  /// The handle's length in blade lengths.
  static constexpr double kHandleLengths = 2.0;

  ToolPose pose;        ///< Tip and blade direction, world frame.
  double length = 0.0;  ///< Blade length (the cutting part), m; ≤ 0 draws nothing.
  /// Half the handle's width, m; ≤ 0 picks 0.1 × `length`. The blade is up
  /// to 2.2 times as wide at its belly.
  double radius = 0.0;
  /// The direction the cutting edge faces (the way the blade cuts), world;
  /// only its part across the blade direction counts. Zero: the blade turns
  /// its flat side to the camera.
  Eigen::Vector3d edge_dir = Eigen::Vector3d::Zero();

  /// Where the blade meets the handle, m.
  [[nodiscard]] Eigen::Vector3d base() const { return pose.tip + length * pose.blade_dir; }
  /// The handle's far end, m.
  [[nodiscard]] Eigen::Vector3d end() const { return pose.tip + (1.0 + kHandleLengths) * length * pose.blade_dir; }
};

/// The force on the tool, drawn as a green arrow from `at` along `force` and
/// as a gauge bar at the image's left edge.
struct ForceOverlay {
  Eigen::Vector3d at = Eigen::Vector3d::Zero();     ///< Arrow base (the tool's tip), m, world.
  Eigen::Vector3d force = Eigen::Vector3d::Zero();  ///< Force on the tool, N, world.
  /// Magnitude that fills the gauge and draws an arrow half the scene's
  /// bounding radius long, N (> 0). Larger forces fill the gauge to the top
  /// and draw the arrow at most 1.5 times that long.
  double full_scale = 1.0;
};

/// Closed range of the scalar mapped onto the stress colour map.
struct ScalarRange {
  double min = 0.0;  ///< Maps to the blue end.
  double max = 1.0;  ///< Maps to the red end.
};

/// How to draw.
struct RenderOptions {
  /// Colour intact faces by `vertex_scalar` (ignored when it is empty).
  bool colour_by_scalar = true;
  /// Scalar range for the colour map; unset = the data's finite min..max.
  std::optional<ScalarRange> scalar_range;
  /// The tool, when it should appear.
  std::optional<ToolSegment> tool;
  /// The force on the tool, when it should appear.
  std::optional<ForceOverlay> force;
};

/// Renders surfaces with OSMesa. Owns its context, recreated when the camera's
/// image size changes. Not thread-safe; one renderer per thread.
///
/// Shading: flat per-face normals (a cut's new faces read as crisp facets),
/// white ambient + two diffuse lights fixed to the camera, two-sided so faces
/// seen from behind (e.g. the inside of an opened cut) are lit too. Opened
/// faces are always `kCutFaceRgb`, also when stress colouring is on.
class SurfaceRenderer {
 public:
  SurfaceRenderer();
  ~SurfaceRenderer();
  SurfaceRenderer(const SurfaceRenderer&) = delete;
  SurfaceRenderer& operator=(const SurfaceRenderer&) = delete;

  /// Draws `surface` seen by `camera` and returns the top-down image
  /// (camera.width × camera.height). Throws `InputError` naming the field for
  /// an invalid camera, an out-of-range triangle index, or `opened` /
  /// `vertex_scalar` of the wrong length; `std::runtime_error` if OSMesa fails.
  [[nodiscard]] Image Render(const Camera& camera, const SurfaceInput& surface,
                             const RenderOptions& options = {});

 private:
  void EnsureContext(int width, int height);
  void BuildVertexArrays(const SurfaceInput& surface, const RenderOptions& options,
                         const Eigen::Vector3d& origin);
  void DrawTool(const ToolSegment& tool, const Eigen::Vector3d& eye);
  void DrawForceArrow(const ForceOverlay& force, double scene_radius);
  void DrawForceGauge(const ForceOverlay& force, int width, int height);

  std::unique_ptr<OsMesaContext> context_;
  // Unindexed vertex arrays, 3 vertices per triangle, reused across frames.
  std::vector<float> vertices_;   // (3·#F)×3, m
  std::vector<float> normals_;    // (3·#F)×3, unit face normals
  std::vector<uint8_t> colours_;  // (3·#F)×4, RGBA
};

}  // namespace cutsim::render
