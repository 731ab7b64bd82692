#include "common/sim/fem_event.h"

#include "common/core/error.h"
#include "common/fem/stable_dt.h"

namespace cutsim::sim {

template <typename T>
void ApplyEventNodesToFem(const cutting::TopologyEvent& event, fem::Model<T>& model, fem::State<T>& state) {
  for (const cutting::Split& split : event.splits) {
    const int32_t copy = model.AddNodeCopy(split.node, state);
    CUTSIM_CHECK(copy == split.new_node, "FEM and cut complex disagree on new node ids");
    for (const int32_t t : split.tets) {
      int corner = 0;
      while (corner < 4 && model.tet_node(t, corner) != split.node) ++corner;
      CUTSIM_CHECK(corner < 4, "retargeted tet does not use the split node");
      model.RetargetTet(t, corner, copy);
    }
  }
  for (const cutting::Move& move : event.moves) {
    model.SetRestPosition(move.node, move.rest.template cast<T>());
    const auto i = 3 * static_cast<size_t>(move.node);
    for (size_t k = 0; k < 3; ++k) state.x[i + k] = static_cast<T>(move.world[static_cast<Eigen::Index>(k)]);
  }
}

template <typename T>
void RecomputeAfterEvent(const cutting::TopologyEvent& event, fem::Model<T>& model, fem::State<T>& state,
                         bool explicit_viscous, FemEventScratch& scratch) {
  // An element depends on its corners' rest positions only
  // (fem::Model::ComputeElement), and a split copy starts at its
  // original's: a tet only re-pointed to a copy is unchanged, bit for bit.
  // The same holds for its stable step (its rest shape, its frozen mass
  // and its corners' world positions, which a copy shares with its
  // original). Only the stars of moved nodes are recomputed.
  scratch.moved_nodes.clear();
  for (const cutting::Move& move : event.moves) scratch.moved_nodes.push_back(move.node);
  model.IncidentTets(scratch.moved_nodes, scratch.moved_tets);
  model.RecomputeElements(scratch.moved_tets);
  model.RecomputeNodeMasses(event.touched_nodes);
  model.CommitTopology();
  fem::UpdateStableStep(model, state, scratch.moved_tets, explicit_viscous);
}

template <typename T>
void ApplyEventToFem(const cutting::TopologyEvent& event, fem::Model<T>& model, fem::State<T>& state,
                     bool explicit_viscous, FemEventScratch& scratch) {
  ApplyEventNodesToFem(event, model, state);
  RecomputeAfterEvent(event, model, state, explicit_viscous, scratch);
}

template void ApplyEventNodesToFem<float>(const cutting::TopologyEvent&, fem::Model<float>&, fem::State<float>&);
template void ApplyEventNodesToFem<double>(const cutting::TopologyEvent&, fem::Model<double>&, fem::State<double>&);
template void RecomputeAfterEvent<float>(const cutting::TopologyEvent&, fem::Model<float>&, fem::State<float>&, bool,
                                         FemEventScratch&);
template void RecomputeAfterEvent<double>(const cutting::TopologyEvent&, fem::Model<double>&, fem::State<double>&,
                                          bool, FemEventScratch&);
template void ApplyEventToFem<float>(const cutting::TopologyEvent&, fem::Model<float>&, fem::State<float>&, bool,
                                     FemEventScratch&);
template void ApplyEventToFem<double>(const cutting::TopologyEvent&, fem::Model<double>&, fem::State<double>&, bool,
                                      FemEventScratch&);

}  // namespace cutsim::sim
