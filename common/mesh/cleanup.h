#pragma once
/// @file
/// Post-processing of generated tet meshes for the explicit FEM, whose stable
/// time step is set by the worst element (its shortest altitude): removal of
/// boundary slivers and quality-driven smoothing of interior nodes.
///
/// Why: gmsh keeps the input surface triangles of a discrete surface, so
/// nearly coplanar neighbouring surface triangles get closed by flat tets
/// whose four nodes all lie on the surface (two boundary faces, mean ratio
/// down to ~0.06). They carry almost no volume but shrink the stable step by
/// an order of magnitude. Deleting such a tet is a legal surface edit when
/// the surface stays a closed 2-manifold (checked locally); the removed
/// volume is tiny (a sliver's). Interior slivers cannot be deleted; they are
/// repaired by moving their interior nodes ("smart" Laplacian: a move is
/// accepted only if the worst quality of the node's star improves).
///
/// Everything here is deterministic (fixed visiting orders, no hashing of
/// pointers, no threads).

#include <cstdint>
#include <vector>

#include "common/mesh/tet_mesh.h"

namespace cutsim::mesh {

struct CleanupOptions {
  /// Boundary tets (≥ 2 faces on the surface) with mean ratio below this are
  /// deleted where the surface stays a closed 2-manifold. 0 disables.
  double sliver_quality = 0.3;
  /// Interior nodes of tets with mean ratio below this are smoothed. 0
  /// disables.
  double smooth_quality = 0.5;
  /// Smoothing sweeps (each visits every node of a bad tet once).
  int smooth_passes = 8;
};

struct CleanupReport {
  int32_t removed_tets = 0;
  int32_t removed_nodes = 0;
  int32_t moved_nodes = 0;           ///< Accepted smoothing moves (all sweeps).
  double min_quality_before = 0;     ///< Min mean ratio before cleanup.
  double min_quality_after = 0;      ///< Min mean ratio after cleanup.
  double removed_volume = 0;         ///< Volume of the deleted tets, m³.
};

/// Deletes tets with ≥ 2 boundary faces and mean ratio < `min_quality` when
/// the boundary surface stays a closed, edge- and vertex-manifold surface
/// (checked on the stars of the tet's vertices), worst tet first, and
/// repeats until nothing changes (a deletion can expose a new candidate).
/// Nodes no longer used by any tet are dropped (indices compacted in order).
/// Regions follow their tets. Returns the number of deleted tets.
int32_t RemoveBoundarySlivers(TetMesh& mesh, double min_quality, double* removed_volume = nullptr,
                              int32_t* removed_nodes = nullptr);

/// Moves interior nodes (not on the boundary surface) of tets with mean ratio
/// < `min_quality` towards the centroid of their neighbours (step 1, ½, ¼, ⅛),
/// accepting a move only when the minimum mean ratio over the node's incident
/// tets increases. Boundary nodes never move, so the surface is unchanged.
/// Returns the number of accepted moves.
int32_t SmoothInteriorNodes(TetMesh& mesh, double min_quality, int passes);

/// RemoveBoundarySlivers then SmoothInteriorNodes (then slivers again, since
/// smoothing never touches the boundary), with a report. Requires a valid,
/// positively oriented mesh; the result is valid and positively oriented.
CleanupReport CleanupMesh(TetMesh& mesh, const CleanupOptions& options = {});

/// Reorders tets by (smallest node index, then the others) so element
/// order follows node order: after a node renumbering (RCM) this makes the
/// force kernel's node gathers and the node pass's element reads nearly
/// sequential. Regions follow their tets. Returns new_to_old tet indices.
std::vector<int32_t> SortTetsByNodes(TetMesh& mesh);

}  // namespace cutsim::mesh
