#pragma once
/// @file
/// Test meshes: an nx×ny×nz box of lx×ly×lz metres (mesh::MakeBox, Kuhn
/// split) and a single right-angle tet.

#include "common/mesh/generators.h"
#include "common/mesh/tet_mesh.h"

namespace cutsim::fem::testing {

inline mesh::TetMesh MakeBoxMesh(int nx, int ny, int nz, double lx, double ly, double lz) {
  return mesh::MakeBox(Eigen::Vector3d::Zero(), Eigen::Vector3d(lx, ly, lz), nx, ny, nz);
}

/// A single right-angle tet with legs of length h.
inline mesh::TetMesh MakeUnitTet(double h = 1.0) {
  mesh::TetMesh m;
  m.nodes.resize(4, 3);
  m.nodes << 0, 0, 0, h, 0, 0, 0, h, 0, 0, 0, h;
  m.tets.resize(1, 4);
  m.tets << 0, 1, 2, 3;
  return m;
}

}  // namespace cutsim::fem::testing
