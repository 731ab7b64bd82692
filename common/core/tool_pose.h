#pragma once
/// @file
/// The cutting tool's pose, one type for every layer that handles one: the
/// simulation's tool, a tool path's samples, the haptic device and link, the
/// recorder and the renderer. Wire formats (protobuf) keep their own message
/// types and convert at the transport boundary.

#include <Eigen/Core>

namespace cutsim {

/// A tool pose: the blade tip and the unit direction from the tip toward the
/// handle, both in the world frame (SI).
struct ToolPose {
  Eigen::Vector3d tip = Eigen::Vector3d::Zero();         ///< Blade tip, m, world.
  Eigen::Vector3d blade_dir = Eigen::Vector3d::UnitZ();  ///< Unit, tip → handle.
};

}  // namespace cutsim
