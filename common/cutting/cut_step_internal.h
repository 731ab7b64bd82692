#pragma once
// Internal to the cut step (cut_step.cc, cut_plane.cc, cut_separate.cc,
// cut_remesh.cc): the step's view of world positions and the state its
// numbered steps (cut_stepper.h) share. Not part of the library's interface.

#include <cmath>
#include <cstdint>
#include <utility>
#include <vector>

#include <Eigen/Core>

#include "common/cutting/cut_mesh.h"
#include "common/cutting/cut_stepper.h"

namespace cutsim::cutting::internal {

// World positions during a step: the FEM's for nodes that existed before,
// the source's for copies made in this step (a copy starts where its
// source is), and staged moves. Nothing is written to the FEM: the event
// carries it.
class StepWorld final : public WorldAccess {
 public:
  // `cache`/`generation`: for a base without packed positions, a per-node
  // cache of base_.Get (a virtual call into the FEM state, read many times
  // per step), valid where an entry's generation is `generation`; the
  // caller takes a new one per step.
  StepWorld(const WorldAccess& base, int32_t base_nodes, const TopologyEvent& event,
            std::vector<CachedPosition>& cache, uint32_t generation)
      : base_(base),
        xyz_(base.Xyz()),
        base_nodes_(base_nodes),
        event_(event),
        cache_(cache),
        generation_(generation) {
    if (xyz_ == nullptr && cache_.size() < static_cast<size_t>(base_nodes_)) {
      cache_.resize(static_cast<size_t>(base_nodes_));
    }
  }
  [[nodiscard]] Eigen::Vector3d Get(int32_t node) const override {
    // Fast path (most reads: a node that existed before the step, nothing
    // moved yet): the FEM position.
    if (moved_.empty() && node < base_nodes_) return Base(node);
    if (const Eigen::Vector3d* x = Find(node)) return *x;
    while (node >= base_nodes_) node = event_.splits[static_cast<size_t>(node - base_nodes_)].node;
    if (const Eigen::Vector3d* x = Find(node)) return *x;
    return Base(node);
  }
  void Set(int32_t node, const Eigen::Vector3d& x) override {
    for (auto& [k, v] : moved_) {
      if (k == node) {
        v = x;
        return;
      }
    }
    moved_.emplace_back(node, x);
  }

 private:
  const WorldAccess& base_;
  const double* xyz_;  // the base's packed positions, or nullptr (then read through Get, cached)
  int32_t base_nodes_;
  const TopologyEvent& event_;
  std::vector<CachedPosition>& cache_;
  uint32_t generation_;
  // Staged moves: a handful per step (the twins of v0 and v1), so a list.
  std::vector<std::pair<int32_t, Eigen::Vector3d>> moved_;
  [[nodiscard]] Eigen::Vector3d Base(int32_t node) const {
    if (xyz_ != nullptr) {
      const double* p = xyz_ + 3 * static_cast<size_t>(node);
      return {p[0], p[1], p[2]};
    }
    return Cached(node);
  }
  [[nodiscard]] const Eigen::Vector3d& Cached(int32_t node) const {
    CachedPosition& c = cache_[static_cast<size_t>(node)];
    if (c.generation != generation_) [[unlikely]] {
      c.x = base_.Get(node);
      c.generation = generation_;
    }
    return c.x;
  }
  [[nodiscard]] const Eigen::Vector3d* Find(int32_t node) const {
    for (const auto& [k, v] : moved_)
      if (k == node) return &v;
    return nullptr;
  }
};

// Steps 1–2: the cut plane P (normal, origin) and the slab around it that
// the blade swept since t0, whose vertices make the split set S.
struct SweptSlab {
  Eigen::Vector3d normal = Eigen::Vector3d::Zero();      // of P, unit
  Eigen::Vector3d origin = Eigen::Vector3d::Zero();      // a point of P, m
  Eigen::Vector3d sweep_from = Eigen::Vector3d::Zero();  // tool position at t0, m
  Eigen::Vector3d sweep_dir = Eigen::Vector3d::Zero();   // unit, along the sweep
  double sweep_len = 0.0;                                // m
  Eigen::Vector3d direction = Eigen::Vector3d::UnitZ();  // blade d, unit, tip → handle
  Eigen::Vector3d tip = Eigen::Vector3d::Zero();         // blade tip, m (with a blade)
  double length = 0.0;                                   // blade length, m (with a blade)
  double band = 0.0;                                     // half-width, m
  bool blade_plane = true;                               // P is the blade's plane
  Eigen::Vector3d x0 = Eigen::Vector3d::Zero();          // world position of v0, m
  Eigen::Vector3d x1 = Eigen::Vector3d::Zero();          // world position of v1, m

  // Signed distance of x to P, m.
  [[nodiscard]] double Distance(const Eigen::Vector3d& x) const { return normal.dot(x - origin); }

  // 1 if x is in the swept slab (split), 2 if only in the walk's wider one
  // (walked through, not split), else 0. The split slab: within a band of
  // P, from a band behind the tool's position at t0 (the edge where the
  // blade came in) to a band ahead of its current one (the vertex the tip
  // is reaching), and from the tip to the handle end. No band below the
  // tip: splitting a vertex opens the faces of its star, so the crack
  // already reaches an element below the deepest split vertex. Tool
  // positions, not node positions, bound it, so a closest vertex on the
  // far row of nodes cannot stretch it. The walk's slab bridges split
  // vertices that share no tet: up to 1.5 bands from P and a band below
  // the tip, over the same stretch along the sweep.
  [[nodiscard]] int Level(const Eigen::Vector3d& x) const {
    const double dist = std::abs(Distance(x));
    const double along = sweep_dir.dot(x - sweep_from);
    const double depth = direction.dot(x - tip);
    if (!(dist <= 1.5 * band && (blade_plane ? along >= -band : along > -band) && along <= sweep_len + band &&
          depth >= -band && depth <= length)) {
      return 0;
    }
    const bool in1 =
        dist <= band && (blade_plane ? along >= -band : along > 0.0) && along <= sweep_len + band && depth >= 0.0;
    return in1 ? 1 : 2;
  }
};

// Steps 3–6 of one ExecuteCutOnPlane: its input, plane, event and
// outcome, passed by reference from step to step.
struct StepState {
  StepState(CutMesh& mesh_in, const CutStep& step_in, const CutParams& params_in, const PreparedCut& plane_in,
            const WorldAccess& base, std::vector<CachedPosition>& cache, uint32_t generation, CutOutcome& out_in)
      : mesh(mesh_in),
        step(step_in),
        params(params_in),
        plane(plane_in),
        n0(mesh_in.num_nodes()),
        out(out_in),
        world(base, n0, ev, cache, generation) {}

  CutMesh& mesh;             // the complex the step changes
  const CutStep& step;
  const CutParams& params;
  const PreparedCut& plane;  // P (normal, origin), h, band
  const int32_t n0;          // nodes before the step
  CutOutcome& out;
  TopologyEvent ev;          // what the step did so far (world reads it: declared first)
  StepWorld world;
  size_t journal_mark = 0;   // journal size before step 3
  size_t work_head = 0;      // step 4's FIFO of vertices to check: work_[work_head..)

  // Signed distance of x to P, m.
  [[nodiscard]] double PlaneDistance(const Eigen::Vector3d& x) const {
    return plane.normal.dot(x - plane.origin);
  }
};

}  // namespace cutsim::cutting::internal
