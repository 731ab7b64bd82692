#pragma once
/// @file
/// Eigen vectors to and from the wire's `Vec3` (geometry.proto).

#include <Eigen/Core>

#include "cutsim/v1/geometry.pb.h"

namespace cutsim::transport {

[[nodiscard]] inline Eigen::Vector3d FromVec3(const v1::Vec3& v) { return {v.x(), v.y(), v.z()}; }

inline void SetVec3(const Eigen::Vector3d& e, v1::Vec3* v) {
  v->set_x(e.x());
  v->set_y(e.y());
  v->set_z(e.z());
}

}  // namespace cutsim::transport
