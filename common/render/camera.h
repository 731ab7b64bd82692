#pragma once
/// @file
/// A pinhole camera and the helper that frames a scene when none is given.

#include <Eigen/Core>
#include <Eigen/Geometry>

#include "common/mesh/tet_mesh.h"

namespace cutsim::render {

/// A perspective camera looking from `eye` at `target`; image size in pixels.
struct Camera {
  Eigen::Vector3d eye{0.0, -1.0, 0.0};    ///< Camera centre, world frame, m.
  Eigen::Vector3d target{0.0, 0.0, 0.0};  ///< Point at the image centre, world frame, m.
  Eigen::Vector3d up{0.0, 0.0, 1.0};      ///< Approximate up direction (need not be ⟂ view).
  double fov_deg = 35.0;                  ///< Vertical field of view, degrees, in (0, 180).
  int width = 640;                        ///< Image width, pixels.
  int height = 480;                       ///< Image height, pixels.

  /// World → eye transform (OpenGL convention: camera looks down −z, y up).
  [[nodiscard]] Eigen::Matrix4d ViewMatrix() const;
  /// Eye → clip perspective projection for the given clip distances (m).
  [[nodiscard]] Eigen::Matrix4d ProjectionMatrix(double near_m, double far_m) const;
};

/// Throws `InputError` (field "camera.<name>") when the camera cannot render:
/// non-finite vectors, eye == target, up parallel to the view direction, fov
/// outside (0, 180), or a size outside [1, 16384].
void ValidateCamera(const Camera& camera);

/// The default viewing direction (from target towards eye): front-right,
/// above, so three faces of an axis-aligned box are visible with different
/// shading.
inline Eigen::Vector3d DefaultViewDirection() { return {1.0, -1.6, 1.2}; }

/// A camera that sees the whole of `box` from `view_direction` (target → eye)
/// with `fov_deg`: it aims at the box centre and backs off until the box's
/// bounding sphere fits both the vertical and the horizontal field of view,
/// with a 5% margin. An empty box frames the unit cube at the origin; a box
/// of zero size gets a 1 mm radius.
[[nodiscard]] Camera FrameBoundingBox(
    const Eigen::AlignedBox3d& box, int width, int height,
    const Eigen::Vector3d& view_direction = DefaultViewDirection(), double fov_deg = 35.0);

/// Bounding box of the finite rows of `positions` (non-finite rows skipped).
[[nodiscard]] Eigen::AlignedBox3d BoundingBox(const mesh::Positions& positions);

}  // namespace cutsim::render
