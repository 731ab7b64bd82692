#pragma once
/// @file
/// Test-only mesh generator until common/mesh's MakeBox lands: an
/// nx×ny×nz grid of cubes, each Kuhn-split into 6 positively oriented tets
/// (conforming across cubes because every cube uses the same diagonal).

#include <array>
#include <utility>

#include "common/mesh/tet_mesh.h"

namespace cutsim::fem::testing {

inline mesh::TetMesh MakeBoxMesh(int nx, int ny, int nz, double lx, double ly, double lz) {
  mesh::TetMesh m;
  const auto id = [&](int i, int j, int k) { return (k * (ny + 1) + j) * (nx + 1) + i; };
  m.nodes.resize((nx + 1) * (ny + 1) * (nz + 1), 3);
  for (int k = 0; k <= nz; ++k) {
    for (int j = 0; j <= ny; ++j) {
      for (int i = 0; i <= nx; ++i) {
        m.nodes.row(id(i, j, k)) << lx * i / nx, ly * j / ny, lz * k / nz;
      }
    }
  }
  m.tets.resize(6 * nx * ny * nz, 4);
  int t = 0;
  static constexpr std::array<std::array<int, 3>, 6> kPerms = {
      {{0, 1, 2}, {0, 2, 1}, {1, 0, 2}, {1, 2, 0}, {2, 0, 1}, {2, 1, 0}}};
  for (int k = 0; k < nz; ++k) {
    for (int j = 0; j < ny; ++j) {
      for (int i = 0; i < nx; ++i) {
        for (const auto& p : kPerms) {
          std::array<int, 3> c = {i, j, k};
          std::array<int32_t, 4> tet{};
          tet[0] = id(c[0], c[1], c[2]);
          for (int s = 0; s < 3; ++s) {
            ++c[static_cast<size_t>(p[static_cast<size_t>(s)])];
            tet[static_cast<size_t>(s) + 1] = id(c[0], c[1], c[2]);
          }
          m.tets.row(t) << tet[0], tet[1], tet[2], tet[3];
          if (mesh::SignedVolume(m, t) < 0) std::swap(m.tets(t, 2), m.tets(t, 3));
          ++t;
        }
      }
    }
  }
  return m;
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
