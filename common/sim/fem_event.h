#pragma once
/// @file
/// A cut's topology event applied to the FEM (the simulation's half of a
/// cut step; the cut complex applies its own half in common/cutting).
/// Local: its cost does not depend on the mesh size.

#include <cstdint>
#include <vector>

#include "common/cutting/topology_event.h"
#include "common/fem/model.h"
#include "common/fem/state.h"

namespace cutsim::sim {

/// Scratch reused across events (no allocation once warm).
struct FemEventScratch {
  std::vector<int32_t> moved_nodes;
  std::vector<int32_t> moved_tets;  ///< After a call: the elements recomputed.
};

/// Applies `event` to `model` and `state` in the order topology_event.h
/// documents: node copies (rest, x and v of their originals) and re-pointed
/// tets, then moves (rest and world positions), then the elements, node
/// masses and stable-step leaves that depend on them. An element and its
/// stable step depend only on its corners' rest and world positions, its
/// frozen mass and its material; a split copy starts where its original
/// is, so only the elements around moved nodes are recomputed (a re-pointed
/// tet is unchanged bit for bit). Velocities are copied, masses follow
/// their tets: linear momentum is unchanged up to round-off. Throws
/// (CUTSIM_CHECK) if the event does not fit the model (ids out of step).
template <typename T>
void ApplyEventToFem(const cutting::TopologyEvent& event, fem::Model<T>& model, fem::State<T>& state,
                     bool explicit_viscous, FemEventScratch& scratch);

/// ApplyEventToFem in two halves, for a caller that overlaps the second
/// with other work. The first makes the node copies, re-points the tets and
/// applies the moves: after it, every node's rest and world position (state.x)
/// and the tets' nodes are final. The second recomputes what depends on
/// them (elements, node masses, stable-step leaves) and commits the
/// topology; it writes neither state.x nor the tets' nodes, so work that
/// only reads those may run beside it.
template <typename T>
void ApplyEventNodesToFem(const cutting::TopologyEvent& event, fem::Model<T>& model, fem::State<T>& state);
template <typename T>
void RecomputeAfterEvent(const cutting::TopologyEvent& event, fem::Model<T>& model, fem::State<T>& state,
                         bool explicit_viscous, FemEventScratch& scratch);

}  // namespace cutsim::sim
