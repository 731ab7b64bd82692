// Steps 1–2 of a cut step (cut_stepper.h): the cut plane P and the split set
// S, found by a walk through the slab the blade swept. They change no
// topology, so PrepareCut may run them ahead of ExecuteCut.
#include <algorithm>
#include <atomic>
#include <cmath>
#include <optional>
#include <span>
#include <utility>
#include <vector>

#include "common/core/error.h"
#include "common/cutting/cut_stepper.h"
#include "common/cutting/cut_step_internal.h"

namespace cutsim::cutting {
namespace {

using Eigen::Vector3d;

void SortUnique(std::vector<int32_t>& v) {
  std::sort(v.begin(), v.end());
  v.erase(std::unique(v.begin(), v.end()), v.end());
}

// Node ids in range and distinct, every position and direction finite, a
// nonzero facet normal and blade direction, a blade length ≥ 0.
bool StepInputValid(const CutStep& step, int32_t num_nodes) {
  const bool ids_ok =
      step.v0 >= 0 && step.v0 < num_nodes && step.v1 >= 0 && step.v1 < num_nodes && step.v0 != step.v1;
  const bool blade_ok = !step.blade || (step.blade->tip.allFinite() && step.blade->direction.allFinite() &&
                                        step.blade->direction.norm() > 0.0 && std::isfinite(step.blade->length) &&
                                        step.blade->length >= 0.0);
  return ids_ok && blade_ok && step.cp0.allFinite() && step.cp.allFinite() && step.normal.allFinite() &&
         step.normal.norm() > 0.0;
}

// Step 1 on the blade's plane: through the tip, spanned by the blade
// direction d and the part of the tool's motion since t0 that sweeps (the
// tip's if the caller gives tip0, else the contact point's: tool positions,
// never node ones). The method paper's s1 = x(v1) − x(v0) joins two closest
// vertices, which on a blade passing between two rows of nodes (or past the
// twins of an earlier split) jump from row to row; a plane along s1 would
// swing across the rows and chop the crack into a zig-zag that sheds
// fragments. Leaves the normal zero if the blade moves only along itself.
void BladePlane(const CutStep& step, double h, internal::SweptSlab& slab) {
  const Blade& blade = *step.blade;
  const Vector3d& d = slab.direction;
  const Vector3d tip0 = blade.tip0 ? *blade.tip0 : Vector3d(blade.tip - (step.cp - step.cp0));
  Vector3d motion = blade.tip - tip0;
  motion -= d.dot(motion) * d;  // the part of the motion that sweeps
  if (motion.allFinite() && motion.norm() > 1e-6 * h) {
    slab.normal = d.cross(motion).normalized();
    slab.origin = blade.tip;
    slab.sweep_from = tip0;
    slab.sweep_len = motion.norm();
    slab.sweep_dir = motion / slab.sweep_len;
  }
}

// Step 1 on the method paper's plane: through x(v1), spanned by the facet normal n
// and s1 = x(v1) − x(v0) (for twins, which coincide, the tool's motion).
// False if s1 ∥ n.
bool MethodPaperPlane(const CutStep& step, const Vector3d& n, internal::SweptSlab& slab) {
  Vector3d s1 = slab.x1 - slab.x0;
  if (!(s1.norm() > 0.0)) s1 = step.cp - step.cp0;
  Vector3d m = s1.cross(n);
  if (!(m.norm() > 1e-9 * s1.norm()) || !m.allFinite()) return false;
  m.normalize();
  slab.normal = m;
  slab.sweep_len = s1.norm();
  slab.sweep_dir = s1 / slab.sweep_len;
  slab.sweep_from = slab.x0;
  return true;
}

// Step 1: plane P into `slab` (which holds x0, x1 and band), on the blade's
// plane if `blade_plane` and a blade is given and moves across itself,
// else on the method paper's. False if there is no plane.
bool ChoosePlane(const CutStep& step, const Vector3d& n, double h, bool blade_plane, internal::SweptSlab& slab) {
  slab.blade_plane = blade_plane;
  slab.origin = slab.x1;
  slab.sweep_from = slab.x0;
  if (step.blade) {
    slab.direction = step.blade->direction.normalized();
    slab.tip = step.blade->tip;
    slab.length = step.blade->length;
  }
  if (step.blade && blade_plane) BladePlane(step, h, slab);
  if (slab.normal == Vector3d::Zero()) return MethodPaperPlane(step, n, slab);
  return true;
}

}  // namespace

void CutStepper::PrefetchLastWalk(const double* xyz) const {
  // Asked for all at once, the misses overlap; the walk itself takes them
  // nearly one by one (its next vertex comes out of the last one's tets).
  // The ids come from an earlier step: checked against the mesh as it is.
  const CutMesh& m = mesh();
  for (const int32_t t : walked_tets_) {
    if (t >= m.num_tets()) continue;
    m.PrefetchTet(t);
    __builtin_prefetch(&tet_marks_.rows[Idx(t)]);
  }
  const int32_t n = m.num_nodes();
  for (const auto& [a, level] : slab_seen_) {
    if (a >= n) continue;
    m.PrefetchNode(a);
    __builtin_prefetch(&node_marks_.rows[Idx(a)]);
    if (xyz != nullptr) __builtin_prefetch(xyz + 3 * Idx(a));
  }
  // The stars themselves: the loop above has asked for their block records.
  for (const auto& [a, level] : slab_seen_) m.PrefetchStar(a);
}

void CutStepper::NextPositionGeneration() {
  if (++pos_generation_ == 0) {  // wrap-around, once in 4 billion steps
    for (auto& c : x_cache_) c.generation = 0;
    pos_generation_ = 1;
  }
}

std::optional<double> CutStepper::MeanEdgeLength(int32_t node, const Vector3d& x,
                                              const internal::StepWorld& world) const {
  double h = 0.0;
  int edges = 0;
  for (const int32_t t : mesh().node_tets(node)) {
    for (const int32_t a : mesh().tet(t)) {
      if (a == node) continue;
      h += (world.Get(a) - x).norm();
      ++edges;
    }
  }
  if (edges == 0 || !(h > 0.0)) return std::nullopt;
  return h / edges;
}

PreparedCut CutStepper::PrepareOnPlane(const CutStep& step, const WorldAccess& world, const CutParams& params,
                                    bool blade_plane, const std::atomic<bool>* cancel) {
  const int32_t n0 = mesh().num_nodes();
  if (!StepInputValid(step, n0)) return {};
  NextPositionGeneration();
  if (blade_plane) PrefetchLastWalk(world.Xyz());
  const TopologyEvent no_splits;
  const internal::StepWorld w(world, n0, no_splits, x_cache_, pos_generation_);
  internal::SweptSlab slab;
  slab.x0 = w.Get(step.v0);
  slab.x1 = w.Get(step.v1);
  const Vector3d n = step.normal.normalized();
  const std::optional<double> h = MeanEdgeLength(step.v1, slab.x1, w);  // local element size
  if (!h) return {};
  slab.band = params.band_fraction * *h;
  if (!ChoosePlane(step, n, *h, blade_plane, slab)) return {};  // 1
  const int32_t v2 = mesh().SelectV2(step.v0, step.v1, step.cp, n, world);
  if (!CollectSplitSet(step, w, slab, cancel)) return {};  // 2
  return PreparedCut{.valid = true,
                     .version = mesh().version(),
                     .generation = pos_generation_,
                     .v0 = step.v0,
                     .v1 = step.v1,
                     .blade_plane = blade_plane,
                     .v2 = v2,
                     .h = *h,
                     .band = slab.band,
                     .normal = slab.normal,
                     .origin = slab.origin};
}

bool CutStepper::CollectSplitSet(const CutStep& step, const internal::StepWorld& world, internal::SweptSlab& slab,
                              const std::atomic<bool>* cancel) {
  slab_.clear();
  if (!step.blade) {
    slab_.push_back(step.v1);
    return true;
  }
  if (!WalkSlab(step, world, slab, cancel)) return false;
  // On the method paper's plane, which holds v1, there is nothing to snap.
  return !slab.blade_plane || SnapPlane(step, world, slab, cancel);
}

void CutStepper::AddSlabEnds(const CutStep& step, const internal::SweptSlab& slab) {
  // v1 only if it is near P: the closest vertex of the contact facet may
  // lie on the far row of a blade passing between two rows of nodes.
  if (!slab.blade_plane || std::abs(slab.Distance(slab.x1)) <= slab.band) slab_.push_back(step.v1);
  if (slab.blade_plane && slab.Level(slab.x0) == 1) slab_.push_back(step.v0);
}

bool CutStepper::WalkSlab(const CutStep& step, const internal::StepWorld& world, const internal::SweptSlab& slab,
                       const std::atomic<bool>* cancel) {
  std::vector<int32_t>& S = slab_;
  S.clear();
  AddSlabEnds(step, slab);
  slab_seen_.clear();
  walked_tets_.clear();
  // Every tet is looked at once (kSlab): the vertices seen, hence S (sorted
  // below), do not depend on the walk's order. No copies exist yet (step 3
  // makes them), and the node rows are sized for every node: unchecked
  // stamp sets.
  CUTSIM_CHECK(tet_marks_.rows.size() >= Idx(mesh().num_tets()), "step scratch");
  node_marks_.Clear(internal::kSeen);
  tet_marks_.Clear(kSlab);
  const auto seen = node_marks_.View(internal::kSeen);
  const auto slab_tets = tet_marks_.View(kSlab);
  seen.Insert(step.v1);
  seen.Insert(step.v0);
  slab_queue_.assign({step.v1, step.v0});
  for (size_t head = 0; head < slab_queue_.size(); ++head) {
    if (cancel != nullptr && cancel->load(std::memory_order_relaxed)) return false;
    const int32_t u = slab_queue_[head];
    // The step runs on caches the FEM steps in between have evicted: ask
    // for the star's tets (and the next vertex's star record) before
    // walking them, so the misses overlap.
    if (head + 1 < slab_queue_.size()) mesh().PrefetchStarRecord(slab_queue_[head + 1]);
    const std::span<const int32_t> star = mesh().node_tets(u);
    for (const int32_t t : star) {
      mesh().PrefetchTetRecord(t);
      __builtin_prefetch(&tet_marks_.rows[Idx(t)]);
    }
    for (const int32_t t : star) {
      if (!slab_tets.Insert(t)) continue;
      walked_tets_.push_back(t);
      for (const int32_t a : mesh().tet(t)) {
        if (!seen.Insert(a)) continue;
        const int k = slab.Level(world.Get(a));
        slab_seen_.emplace_back(a, k);
        if (k == 0) continue;
        slab_queue_.push_back(a);
        if (k == 1) S.push_back(a);
      }
    }
  }
  SortUnique(S);
  return true;
}

bool CutStepper::SnapPlane(const CutStep& step, const internal::StepWorld& world, internal::SweptSlab& slab,
                        const std::atomic<bool>* cancel) {
  // Not snapped onto v1: the vertices under the blade are pushed around by
  // the contact, and a plane through v1 drifts onto the next layer below
  // the surface.
  int32_t nearest = -1;
  for (const int32_t a : slab_) {
    if (nearest < 0 || std::abs(slab.Distance(world.Get(a))) < std::abs(slab.Distance(world.Get(nearest)))) {
      nearest = a;
    }
  }
  if (nearest < 0 || slab.Distance(world.Get(nearest)) == 0.0) return true;
  slab.origin += slab.Distance(world.Get(nearest)) * slab.normal;
  // The snap moves P by less than a band. If every vertex the walk saw
  // keeps its level, a second walk would take the same tets from the same
  // queued vertices and see the same vertices: the same S, but for v0 and
  // v1 (queued whatever their level), which are tested again. Only if a
  // level changes is the walk redone.
  for (const auto& [a, k] : slab_seen_) {
    if (slab.Level(world.Get(a)) != k) return WalkSlab(step, world, slab, cancel);
  }
  slab_.clear();
  AddSlabEnds(step, slab);
  for (const auto& [a, k] : slab_seen_)
    if (k == 1) slab_.push_back(a);
  SortUnique(slab_);
  return true;
}

}  // namespace cutsim::cutting
