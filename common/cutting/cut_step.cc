// CutStepper::ExecuteCut: one cut step (method paper §3.2–3.3) as the list
// of its numbered steps (cut_stepper.h states the rules; the steps live in
// cut_plane.cc, cut_separate.cc and cut_remesh.cc), and step 6, the event.
#include <algorithm>
#include <atomic>
#include <span>
#include <utility>
#include <vector>

#include "common/cutting/cut_step_internal.h"
#include "common/cutting/cut_stepper.h"

namespace cutsim::cutting {

void CutStepper::Bind(const CutMesh& mesh) {
  mesh_ = &mesh;
  // Stamp rows for every tet and every node there is (the slab walk's
  // stamp sets are unchecked), room reserved for the copies to come.
  if (tet_marks_.rows.size() < Idx(mesh.num_tets())) tet_marks_.rows.resize(Idx(mesh.num_tets()));
  if (node_marks_.rows.capacity() < Idx(mesh.node_capacity())) node_marks_.rows.reserve(Idx(mesh.node_capacity()));
  if (node_marks_.rows.size() < Idx(mesh.num_nodes())) node_marks_.rows.resize(Idx(mesh.num_nodes()));
}

PreparedCut CutStepper::PrepareCut(const CutMesh& mesh, const CutStep& step, const WorldAccess& world,
                                   const CutParams& params, const std::atomic<bool>* cancel) {
  Bind(mesh);
  return PrepareOnPlane(step, world, params, /*blade_plane=*/true, cancel);
}

CutOutcome CutStepper::ExecuteCut(CutMesh& mesh, const CutStep& step, const WorldAccess& world,
                                  const CutParams& params, const PreparedCut* prepared,
                                  const SeparatedCallback* on_separated) {
  Bind(mesh);
  CutOutcome out = ExecuteCutOnPlane(mesh, step, world, params, /*blade_plane=*/true, prepared, on_separated);
  // A blade plane that leaves a singularity the rules cannot remove (rolled
  // back, nothing changed) gets one more try on the method paper's plane through
  // v0 and v1, which runs through existing vertices.
  if (out.status == CutStatus::kRejected && step.blade) {
    out = ExecuteCutOnPlane(mesh, step, world, params, false, nullptr, on_separated);
  }
  return out;
}

bool CutStepper::PreparedFits(const PreparedCut* prepared, const CutStep& step, bool blade_plane) const {
  return prepared != nullptr && prepared->valid && prepared->version == mesh().version() &&
         prepared->generation == pos_generation_ && prepared->v0 == step.v0 && prepared->v1 == step.v1 &&
         prepared->blade_plane == blade_plane;
}

CutOutcome CutStepper::ExecuteCutOnPlane(CutMesh& mesh, const CutStep& step, const WorldAccess& world,
                                         const CutParams& params, bool blade_plane, const PreparedCut* prepared,
                                         const SeparatedCallback* on_separated) {
  CutOutcome out;
  // Steps 1–2: plane P and split set S (into slab_), from PrepareCut or here.
  const PreparedCut plane = PreparedFits(prepared, step, blade_plane)
                                ? *prepared
                                : PrepareOnPlane(step, world, params, blade_plane, nullptr);
  if (!plane.valid) return out;
  out.v2 = plane.v2;
  internal::StepState s(mesh, step, params, plane, world, x_cache_, pos_generation_, out);
  BeginSeparation(s);
  SplitByPlaneSides(s);                                                // 3
  const bool separated = RemoveSingularities(s) && GuardFragments(s);  // 4, 4b
  EndSeparation(s, /*roll_back=*/!separated);
  if (!separated) {
    out.status = CutStatus::kRejected;
    return out;
  }
  // The topology is final: step 5 changes positions only.
  if (on_separated != nullptr && *on_separated) (*on_separated)(std::span<const Split>(s.ev.splits));
  Remesh(s);       // 5
  FinishEvent(s);  // 6
  return out;
}

void CutStepper::FinishEvent(internal::StepState& s) {
  s.out.status = CutStatus::kExecuted;
  TopologyEvent& ev = s.ev;
  if (ev.empty()) return;
  for (const Split& sp : ev.splits) {
    ev.touched_tets.insert(ev.touched_tets.end(), sp.tets.begin(), sp.tets.end());
    ev.touched_nodes.push_back(sp.node);
    ev.touched_nodes.push_back(sp.new_node);
  }
  for (const Move& mv : ev.moves) {
    const std::span<const int32_t> star = s.mesh.node_tets(mv.node);
    ev.touched_tets.insert(ev.touched_tets.end(), star.begin(), star.end());
  }
  for (auto* v : {&ev.touched_tets, &ev.touched_nodes}) {
    std::sort(v->begin(), v->end());
    v->erase(std::unique(v->begin(), v->end()), v->end());
  }
  s.mesh.CommitEvent(ev);
  s.out.event = std::move(ev);
}

}  // namespace cutsim::cutting
