#include "common/render/camera.h"

#include <algorithm>
#include <cmath>
#include <numbers>

#include "common/core/error.h"

namespace cutsim::render {
namespace {

constexpr double kDegToRad = std::numbers::pi / 180.0;

void Fail(const char* field, const char* message) {
  ThrowInputError(SourceRef{.field = field}, message);
}

}  // namespace

Eigen::Matrix4d Camera::ViewMatrix() const {
  // gluLookAt: rows are the camera axes (right, up, back) in world coordinates.
  const Eigen::Vector3d f = (target - eye).normalized();
  const Eigen::Vector3d s = f.cross(up).normalized();
  const Eigen::Vector3d u = s.cross(f);
  Eigen::Matrix4d m = Eigen::Matrix4d::Identity();
  m.block<1, 3>(0, 0) = s.transpose();
  m.block<1, 3>(1, 0) = u.transpose();
  m.block<1, 3>(2, 0) = -f.transpose();
  m(0, 3) = -s.dot(eye);
  m(1, 3) = -u.dot(eye);
  m(2, 3) = f.dot(eye);
  return m;
}

Eigen::Matrix4d Camera::ProjectionMatrix(double near_m, double far_m) const {
  // gluPerspective.
  const double aspect = static_cast<double>(width) / static_cast<double>(height);
  const double f = 1.0 / std::tan(0.5 * fov_deg * kDegToRad);
  Eigen::Matrix4d m = Eigen::Matrix4d::Zero();
  m(0, 0) = f / aspect;
  m(1, 1) = f;
  m(2, 2) = (far_m + near_m) / (near_m - far_m);
  m(2, 3) = 2.0 * far_m * near_m / (near_m - far_m);
  m(3, 2) = -1.0;
  return m;
}

void ValidateCamera(const Camera& camera) {
  if (!camera.eye.allFinite()) Fail("camera.eye", "must be finite");
  if (!camera.target.allFinite()) Fail("camera.target", "must be finite");
  if (!camera.up.allFinite()) Fail("camera.up", "must be finite");
  const Eigen::Vector3d view = camera.target - camera.eye;
  if (!(view.norm() > 0.0)) Fail("camera.target", "must differ from camera.eye");
  if (!(camera.up.norm() > 0.0) || view.normalized().cross(camera.up.normalized()).norm() < 1e-6) {
    Fail("camera.up", "must be non-zero and not parallel to the view direction");
  }
  if (!(camera.fov_deg > 0.0 && camera.fov_deg < 180.0)) {
    Fail("camera.fov_deg", "must be in (0, 180) degrees");
  }
  if (camera.width < 1 || camera.width > 16384)
    Fail("camera.width", "must be in [1, 16384] pixels");
  if (camera.height < 1 || camera.height > 16384) {
    Fail("camera.height", "must be in [1, 16384] pixels");
  }
}

Camera FrameBoundingBox(const Eigen::AlignedBox3d& box, int width, int height,
                        const Eigen::Vector3d& view_direction, double fov_deg) {
  Eigen::AlignedBox3d framed = box;
  if (framed.isEmpty())
    framed = Eigen::AlignedBox3d(Eigen::Vector3d::Zero(), Eigen::Vector3d::Ones());
  const Eigen::Vector3d centre = framed.center();
  const double radius = std::max(0.5 * framed.diagonal().norm(), 1e-3);

  Camera camera;
  camera.width = width;
  camera.height = height;
  camera.fov_deg = fov_deg;
  // The tightest half-angle of the two fields of view must hold the sphere.
  const double aspect =
      static_cast<double>(std::max(width, 1)) / static_cast<double>(std::max(height, 1));
  const double half_v = 0.5 * fov_deg * kDegToRad;
  const double half_h = std::atan(aspect * std::tan(half_v));
  const double half = std::min(half_v, half_h);
  const double distance = 1.05 * radius / std::sin(half);

  Eigen::Vector3d dir = view_direction;
  if (!(dir.norm() > 0.0) || !dir.allFinite()) dir = DefaultViewDirection();
  dir.normalize();
  camera.target = centre;
  camera.eye = centre + distance * dir;
  // World z is up unless we look along it; then y.
  camera.up = std::abs(dir.z()) > 0.99 ? Eigen::Vector3d::UnitY() : Eigen::Vector3d::UnitZ();
  return camera;
}

Eigen::AlignedBox3d BoundingBox(const mesh::Positions& positions) {
  Eigen::AlignedBox3d box;  // empty
  for (Eigen::Index i = 0; i < positions.rows(); ++i) {
    const Eigen::Vector3d p = positions.row(i).transpose();
    if (p.allFinite()) box.extend(p);
  }
  return box;
}

}  // namespace cutsim::render
