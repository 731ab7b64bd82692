#pragma once
/// @file
/// Turns a scene's `mesh` source into a TetMesh: generator or file, scale and
/// translation, and the cache-friendly node order (keeping the permutation so
/// user node ids still mean the file's nodes).

#include "common/mesh/reorder.h"
#include "common/mesh/tet_mesh.h"
#include "common/sim/scene_loader.h"

namespace cutsim::sim {

struct SceneMesh {
  mesh::TetMesh mesh;               ///< Validated, positively oriented, reordered.
  mesh::NodePermutation permutation; ///< Identity when `no_reorder`.
};

/// Builds the scene's mesh; throws InputError naming the scene field or the
/// mesh file.
SceneMesh BuildSceneMesh(const LoadedScene& scene);

}  // namespace cutsim::sim
