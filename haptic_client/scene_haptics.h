#pragma once
/// @file
/// The device workspace a scene asks for (`haptics.device_scale`,
/// `haptics.device_offset` of proto/cutsim/v1/scene.proto), read by
/// `cutsim-haptic --scene` without loading the rest of the scene (meshes,
/// materials) that only the server needs.

#include <filesystem>

#include <Eigen/Core>

namespace cutsim::haptic_client {

struct SceneWorkspace {
  double scale = 1.0;                                ///< tool = scale · device + offset
  Eigen::Vector3d offset = Eigen::Vector3d::Zero();  ///< m
};

/// Parses the scene (protobuf text format) and returns its haptics
/// workspace. Throws `InputError` naming file:line:column for a syntax error
/// and the field for a bad value.
[[nodiscard]] SceneWorkspace ReadSceneWorkspace(const std::filesystem::path& scene);

}  // namespace cutsim::haptic_client
