#pragma once
/// @file
/// The device workspace a scene asks for (`haptics.device_scale`,
/// `haptics.device_offset` of proto/cutsim/v1/scene.proto), and what the
/// trainee page draws of it (the planned incision, the blade), read by
/// `cutsim-haptic --scene` without loading the rest of the scene (meshes,
/// materials) that only the server needs.

#include <filesystem>
#include <vector>

#include <Eigen/Core>

namespace cutsim::haptic_client {

struct SceneWorkspace {
  double scale = 1.0;                                ///< tool = scale · device + offset
  Eigen::Vector3d offset = Eigen::Vector3d::Zero();  ///< m
  /// What the trainee page draws: the planned incision's points (m, as
  /// written in the scene) and the tool's blade length (m, 0 = unset).
  std::vector<Eigen::Vector3d> planned_incision;
  double blade_length = 0.0;
};

/// Parses the scene (protobuf text format) and returns its haptics
/// workspace. Throws `InputError` naming file:line:column for a syntax error
/// and the field for a bad value.
[[nodiscard]] SceneWorkspace ReadSceneWorkspace(const std::filesystem::path& scene);

}  // namespace cutsim::haptic_client
