#pragma once
/// @file
/// One observable frame of the simulated mesh: what the simulation shows
/// (`sim::Simulation::FillMeshView`) and what the server streams to viewers
/// (`transport::MeshStreamPublisher`). One type for both, so the server
/// fills the publisher's frame in place and the mesh is copied once.

#include <cstdint>
#include <vector>

#include "common/mesh/tet_mesh.h"

namespace cutsim::mesh {

/// A frame of the mesh: world and rest positions, tets, the boundary surface
/// with its per-face flags, and the frame's identity in time and topology.
///
/// The simulation fills the mesh fields (`world` to `debris`); the server
/// adds `frame`, `sim_time`, `topology_version` and `stress` before the
/// frame goes to viewers. Fillers resize in place, so a frame reused from
/// one call to the next allocates nothing once its sizes are reached.
struct MeshFrame {
  uint64_t frame = 0;             ///< Physics frame number.
  double sim_time = 0.0;          ///< Simulated time, s.
  uint64_t topology_version = 0;  ///< Bumped by every topology change.
  Positions world;                ///< #N×3 world positions, m.
  Positions rest;                 ///< #N×3 rest positions, m.
  Tets tets;                      ///< #T×4 node indices.
  Triangles surface;              ///< #F×3 boundary triangles (live faces only).
  /// #F, non-zero = the face was opened by a cut; empty = none opened.
  std::vector<uint8_t> opened;
  /// #F with cutting, else empty: 1 on a facet of a piece cut loose
  /// (debris). The simulation's own; viewers do not receive it.
  std::vector<uint8_t> debris;
  /// #N optional per-node scalar (e.g. von Mises stress, Pa); may be empty.
  std::vector<double> stress;
};

}  // namespace cutsim::mesh
