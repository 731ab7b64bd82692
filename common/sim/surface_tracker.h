#pragma once
/// @file
/// The tissue's surface as the tool sees it: triangles by slot (with
/// cutting, the CutMesh's surface slots, stable ids; else the extracted
/// surface's rows), which of them a cut opened, the nodes on opened faces
/// (walls and lips of cuts), the facets of debris pieces, and the BVH over
/// a double copy of the world positions. Built from scratch at set-up and
/// after a restore; after a cut only the slots it changed are edited.

#include <array>
#include <cstdint>
#include <optional>
#include <span>
#include <vector>

#include "common/cutting/cut_mesh.h"
#include "common/cutting/topology_event.h"
#include "common/fem/model.h"
#include "common/mesh/bvh.h"
#include "common/mesh/tet_mesh.h"
#include "common/sim/debris.h"
#include "common/sim/stage.h"
#include "common/sim/types.h"

namespace cutsim::sim {

class SurfaceTracker final : public CheckpointedStage {
 public:
  /// Debris: a piece cut loose that the blade passes through rather than
  /// flings with a force sized for the body. Small in mass and in elements:
  /// what makes a crumb fly is a few elements (each node's mass is set by
  /// its elements, not by the piece), and the element bound keeps the flood
  /// that finds one local.
  static constexpr double kDebrisMassFraction = 0.01;
  static constexpr int32_t kDebrisMaxTets = 64;

  /// Surface triangles from the cut complex `cut` when cutting (else
  /// extracted from the model's tets), from scratch: at set-up and after a
  /// restore. `with_tool`: also the contact structures (wall nodes, debris
  /// flags, world copy, BVH), which serve only the tool.
  template <typename T>
  void Rebuild(const fem::Model<T>& model, const T* x, cutting::CutMesh* cut, bool with_tool);

  /// Copies the world positions `x` (#N·3) and refits the BVH to them:
  /// before each contact query.
  template <typename T>
  void RefreshWorld(const fem::Model<T>& model, const T* x);

  /// The surface half of a cut step whose `splits` `cut` has applied:
  /// edits the slots the cut created or freed (the CutMesh's change log),
  /// each removed from or inserted into the BVH, then floods for the debris
  /// it cut loose. Reads the topology (final once the splits are made) and
  /// the world copy, not the FEM's positions, so it may run beside the
  /// remeshing moves and the FEM half (cutting::SeparatedCallback). The
  /// boxes of the inserted faces are then those of the frame's start (a
  /// copy's row is its original's: a copy starts where its original is),
  /// not the moved ones: RefreshWorld refits every box before the next
  /// query, and the BVH's answers do not depend on how its tree was built
  /// (bvh.h), so the contact is the same.
  void UpdateAfterCut(cutting::CutMesh& cut, std::span<const cutting::Split> splits);

  /// After UpdateAfterCut: the debris flags of the slots the cut changed,
  /// and of every facet of the tets it made debris (a tet stays debris once
  /// it is, so this equals a rescan of those slots).
  void FlagDebrisFacets(const cutting::CutMesh& cut);

  /// The owning tet of surface slot `tri`, −1 if none.
  [[nodiscard]] int32_t SlotTet(int32_t tri) const;
  /// Slots a cut opened, among the live ones.
  [[nodiscard]] int OpenedFaces() const;
  /// Copies the live triangles (in slot order), their opened and debris
  /// flags into `view` (reusing its storage).
  void FillView(MeshView& view) const;

  [[nodiscard]] const mesh::TriangleBvh& bvh() const { return bvh_; }
  [[nodiscard]] const mesh::Positions& world() const { return world_; }
  [[nodiscard]] const mesh::Triangles& triangles() const { return surface_; }
  [[nodiscard]] const std::vector<uint8_t>& opened() const { return opened_; }  ///< #S: slot opened by a cut
  [[nodiscard]] const std::vector<uint8_t>& debris_facets() const { return debris_facet_; }
  [[nodiscard]] const std::vector<uint8_t>& wall_nodes() const { return wall_node_; }

  // ---- checkpoint part (stage.h): none -------------------------------------
  /// Everything here follows from the cut complex and the positions: the
  /// engine rebuilds it (Rebuild) once the other stages are restored.
  void Save(v1::CheckpointBody& /*body*/) const override {}
  void Check(const v1::CheckpointBody& /*body*/, const PartCheck& /*check*/) const override {}
  void Restore(const v1::CheckpointBody& /*body*/) override {}

 private:
  void RebuildFromCut(cutting::CutMesh& cut);
  void GrowSlots();
  void UpdateSlot(const cutting::CutMesh& cut, int32_t f);
  void FlagWallNodes(const std::array<int32_t, 3>& tri);
  template <typename T>
  void FlagDebris(const fem::Model<T>& model, const cutting::CutMesh* cut);
  template <typename T>
  void CopyWorld(const fem::Model<T>& model, const T* x);

  int32_t node_capacity_ = 0;
  // #S rows of capacity, the first num_slots_ used; dead slots are rows of
  // −1 (not in the BVH).
  mesh::Triangles surface_;             // #S×3
  int32_t num_slots_ = 0;
  std::vector<uint8_t> opened_;         // #S
  std::vector<int32_t> surface_tet_;    // #S owning tet (−1: dead)
  std::vector<uint8_t> wall_node_;      // #node_capacity (or empty): node on a face a cut opened
  std::vector<uint8_t> debris_facet_;   // #S (or empty): facet of a debris piece
  std::optional<DebrisTracker> debris_;  // with cutting only
  std::vector<int32_t> changed_slots_;  // scratch: the slots the last cut changed
  std::vector<int32_t> flagged_;        // scratch: the tets the last cut made debris
  mesh::Positions world_;               // #N_cap×3 double copy for the BVH (first #N rows current)
  mesh::TriangleBvh bvh_;
};

}  // namespace cutsim::sim
