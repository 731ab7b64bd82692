#pragma once
/// @file
/// Meshes made in code: structured boxes and cylinders for tests and
/// benchmarks, and tetrahedralised smooth surfaces (via gmsh) for organ scenes.
/// Every generator returns a validated, positively oriented mesh.

#include <cstdint>
#include <string>

#include <Eigen/Core>
#include <Eigen/Geometry>

#include "common/core/error.h"
#include "common/mesh/cleanup.h"
#include "common/mesh/tet_mesh.h"

namespace cutsim::mesh {

/// Throws `InputError` at `where` if a generator would make more than
/// kMaxMeshNodes nodes or kMaxMeshTets tets (estimates in double, so no
/// integer overflows first). Every generator calls it before allocating.
void CheckGeneratedSize(const SourceRef& where, double nodes, double tets);

/// Axis-aligned box [lo, hi] with nx·ny·nz cells, each split into 6 tets
/// around its lo→hi diagonal (Kuhn/Freudenthal), so faces conform.
/// (nx+1)(ny+1)(nz+1) nodes, 6·nx·ny·nz tets.
TetMesh MakeBox(const Eigen::Vector3d& lo, const Eigen::Vector3d& hi, int nx, int ny, int nz);

/// Cylinder with axis from the origin along +x, `length` m long, `radius` m.
/// The cross-section has `rings` concentric rings (ring k has about
/// segments·k/rings nodes, the outer one exactly `segments`) around a centre
/// node; it is extruded in `slices` layers, and each prism is split into 3
/// tets by the global-index rule, which keeps faces conforming. Volume tends
/// to πr²L as segments grows.
TetMesh MakeCylinder(double radius, double length, int segments, int rings, int slices);

/// How a closed surface is filled with tets.
struct TetrahedralizeOptions {
  /// Run CleanupMesh (cleanup.h) on gmsh's output: deletes the flat boundary
  /// slivers gmsh leaves between kept surface triangles and smooths interior
  /// slivers. On by default: without it the organ's stable step is ~10×
  /// smaller. The surface may lose a few sliver tets (tiny volume).
  bool cleanup = true;
  CleanupOptions cleanup_options;
  /// gmsh's own tet optimiser pass threshold (Mesh.OptimizeThreshold).
  double gmsh_optimize_threshold = 0.3;
  /// Filled in if non-null: what the cleanup did.
  CleanupReport* report = nullptr;
};

/// Tetrahedralises the closed triangle surface in an STL (ASCII or binary) or
/// OBJ file with gmsh, keeping the input surface triangles; interior edges are
/// at most `max_edge_length` m. Throws `InputError` naming the file if gmsh
/// cannot fill it. Cleans the result up (TetrahedralizeOptions) by default.
TetMesh TetrahedralizeSurface(const std::string& path, double max_edge_length);
TetMesh TetrahedralizeSurface(const std::string& path, double max_edge_length,
                              const TetrahedralizeOptions& options);

/// Tetrahedralises a closed, outward-oriented triangle surface given in memory.
TetMesh TetrahedralizeSurface(const Positions& positions, const Triangles& tris, double max_edge_length,
                              const std::string& source_name = "<surface>");
TetMesh TetrahedralizeSurface(const Positions& positions, const Triangles& tris, double max_edge_length,
                              const std::string& source_name, const TetrahedralizeOptions& options);

/// A smooth organ-like lobe (a kidney-shaped deformed ellipsoid).
struct OrganOptions {
  Eigen::Vector3d semi_axes{0.06, 0.035, 0.03};  ///< Ellipsoid semi-axes before deformation, m.
  double edge_length = 0.004;                    ///< Target edge length, m.
  double bean_depth = 0.25;  ///< Depth of the kidney-like indentation, fraction of the y semi-axis.
  /// Filling options (cleanup of slivers on by default).
  TetrahedralizeOptions fill;
};

/// The organ's closed surface (subdivided icosahedron mapped through a smooth
/// radial function), deterministic. `positions` #V×3, `tris` #F×3.
void MakeOrganSurface(const OrganOptions& options, Positions& positions, Triangles& tris);

/// Tetrahedralised organ (defaults give ≥ 20 000 tets in a few seconds).
TetMesh MakeOrgan(const OrganOptions& options = {});

}  // namespace cutsim::mesh
