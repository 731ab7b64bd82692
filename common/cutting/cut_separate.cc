// Steps 3–4b of a cut step (cut_stepper.h): split S by the plane sides,
// remove the singularities the splits leave, and guard against fragments.
// They change the complex under its journal, so a rejected step rolls back.
#include <algorithm>
#include <array>
#include <cmath>
#include <iterator>
#include <span>
#include <utility>
#include <vector>

#include "common/cutting/cut_stepper.h"
#include "common/cutting/cut_step_internal.h"

namespace cutsim::cutting {

void CutStepper::BeginSeparation(internal::StepState& s) {
  tet_marks_.Clear(kFlipped);  // tets the fragment guard moved to the other side
  s.journal_mark = s.mesh.BeginJournal();
}

void CutStepper::EndSeparation(const internal::StepState& s, bool roll_back) {
  if (roll_back) s.mesh.RollBack(s.journal_mark, s.n0);
  s.mesh.EndJournal(s.journal_mark);
}

// ---- 3. plane sides --------------------------------------------------------

void CutStepper::SplitByPlaneSides(internal::StepState& s) {
  // A new pass: no side known, no vertex split or queued yet.
  tet_marks_.Clear(kSideKnown);
  work_.clear();
  s.work_head = 0;
  node_marks_.Clear(internal::kQueued);
  node_marks_.Clear(internal::kPlaneDone);
  for (const int32_t w : slab_) PlaneSplit(s, w);
}

int8_t CutStepper::Side(internal::StepState& s, int32_t t) {
  if (tet_marks_.Contains(kSideKnown, t)) return tet_marks_.rows[Idx(t)].side;
  double far = 0.0;
  for (const int32_t a : mesh().tet(t)) {
    const double da = s.PlaneDistance(s.world.Get(a));
    if (std::abs(da) > std::abs(far)) far = da;  // strict: ties keep the first corner
  }
  int8_t side = far < 0.0 ? int8_t{-1} : int8_t{1};
  if (tet_marks_.Contains(kFlipped, t)) side = static_cast<int8_t>(-side);
  tet_marks_.Insert(kSideKnown, t);
  tet_marks_.rows[Idx(t)].side = side;
  return side;
}

bool CutStepper::PlaneSplit(internal::StepState& s, int32_t w) {
  node_marks_.Insert(internal::kPlaneDone, w);
  std::vector<int32_t>& negative = negative_;
  negative.clear();
  bool has_positive = false;
  for (const int32_t t : mesh().node_tets(w)) {
    if (Side(s, t) < 0) {
      negative.push_back(t);
    } else {
      has_positive = true;
    }
  }
  if (negative.empty() || !has_positive) return false;
  s.mesh.SplitNode(w, negative, &s.ev);
  EnqueueSplit(w, negative);
  return true;
}

void CutStepper::EnqueueSplit(int32_t w, std::span<const int32_t> tets) {
  // The vertices whose star or link changed: the corners of the moved tets
  // (the copy among them) and w. A face changes only between a moved and an
  // unmoved tet, and all its nodes are corners of the moved one, so the
  // other vertices of w's star keep their star and their link: they were
  // manifold when the step began (every step leaves the mesh so) or were
  // queued by the split that changed them.
  for (const int32_t t : tets)
    for (const int32_t a : mesh().tet(t))
      if (node_marks_.Insert(internal::kQueued, a)) work_.push_back(a);
  if (node_marks_.Insert(internal::kQueued, w)) work_.push_back(w);
}

// ---- 4. singularities ------------------------------------------------------

bool CutStepper::RemoveSingularities(internal::StepState& s) {
  node_marks_.Clear(internal::kLinkOk);
  while (s.work_head < work_.size()) {
    const int32_t v = work_[s.work_head++];
    node_marks_.Erase(internal::kQueued, v);
    if (static_cast<int32_t>(s.ev.splits.size()) > s.params.max_splits_per_step) return false;
    VisitVertex(s, v);
  }
  return ManifoldAfterSplits(s.ev);
}

void CutStepper::VisitVertex(internal::StepState& s, int32_t v) {
  // The link of v in the surface (one edge per surface face through v)
  // decides most visits without the star's groups:
  // - Empty: the star is closed, every face through v is shared with
  //   another tet of its star, in the uncut mesh too (copies keep their
  //   origin's ids), so each group of the star is closed under the uncut
  //   star's face adjacency; if that star was one group, so is this one,
  //   and the edge rule has no candidate.
  // - One cycle (a manifold fan): if the uncut star was one group, so is
  //   this one. Every group then has a surface face through v (a group's
  //   uncut face to a tet outside it cannot still be shared: its mate
  //   would hold v, so be in the group); and the two surface faces at a
  //   link vertex q end the single fan of tets around edge (v, q) (a fan
  //   that is a path ends in two surface faces, and q has only two), so
  //   consecutive link edges lie in one group: all do. Every edge (v, u)
  //   then has exactly two surface faces: no edge-rule candidate.
  // Either way v is manifold (kLinkOk), and ManifoldAfterSplits skips it:
  // a later change to its star would queue it again.
  mesh().SurfaceLinkInto(v, link_);
  const bool link_ok = link_.empty() || CutMesh::LinkIsOneCycle(link_, heads_);
  if (link_ok) {
    node_marks_.Insert(internal::kLinkOk, v);
  } else {
    node_marks_.Erase(internal::kLinkOk, v);
  }
  if (link_ok && mesh().UncutStarIsOneGroup(v)) return;
  // Edge-rule candidates: the other two nodes of each surface face through
  // v (gathered before a split below changes the link).
  nbrs_.clear();
  for (const auto& [p, q] : link_) {
    nbrs_.push_back(p);
    nbrs_.push_back(q);
  }
  // Vertex rule: parts of the star joined only through v. (A flood answers
  // the usual "one group" first; the groups only when split.)
  const int32_t num_groups = mesh().StarIsOneGroup(v) ? 1 : StarGroups(v);
  if (num_groups > 1) {
    for (int32_t g = 1; g < num_groups; ++g) {
      const std::span<const int32_t> group(group_tets_.data() + group_begin_[Idx(g)],
                                           Idx(group_begin_[Idx(g) + 1] - group_begin_[Idx(g)]));
      s.mesh.SplitNode(v, group, &s.ev);
      EnqueueSplit(v, group);
    }
    return;
  }
  ApplyEdgeRule(s, v);
}

void CutStepper::ApplyEdgeRule(internal::StepState& s, int32_t v) {
  // Parts around an edge joined only through the edge. The star of each
  // endpoint is connected (the vertex rule found one group), so no vertex
  // copy alone separates them; splitting an endpoint by the plane sides
  // extends the cut by one vertex, after which the vertex rule applies
  // again. Candidates: an edge (v, u) whose tets fall into k > 1 groups has
  // 2k surface faces through it (each group is a fan whose two end faces
  // are on the surface), so only u on ≥ 4 surface faces through v can fail;
  // the exact count (EdgeGroupCount) runs for those only.
  std::vector<int32_t>& nbrs = nbrs_;
  std::sort(nbrs.begin(), nbrs.end());
  size_t kept = 0;
  for (size_t i = 0; i < nbrs.size();) {
    size_t j = i;
    while (j < nbrs.size() && nbrs[j] == nbrs[i]) ++j;
    if (j - i >= 4) nbrs[kept++] = nbrs[i];
    i = j;
  }
  nbrs.resize(kept);
  for (const int32_t u : nbrs) {
    if (EdgeGroupCount(v, u) <= 1) continue;
    std::array<int32_t, 2> cand{v, u};  // the endpoint nearer to P first
    if (std::abs(s.PlaneDistance(s.world.Get(u))) < std::abs(s.PlaneDistance(s.world.Get(v)))) {
      std::swap(cand[0], cand[1]);
    }
    for (const int32_t c : cand) {
      if (!node_marks_.Contains(internal::kPlaneDone, c) && PlaneSplit(s, c)) {
        if (node_marks_.Insert(internal::kQueued, v)) work_.push_back(v);
        return;
      }
    }
    // Neither endpoint splits: ManifoldAfterSplits decides (and rejects if
    // needed).
  }
}

bool CutStepper::ManifoldAfterSplits(const TopologyEvent& ev) const {
  // Faces change only on retargeted tets and on their neighbours across the
  // old faces, whose vertices are the split node and the other corners.
  // Every vertex here was queued by the split that last changed its star
  // and visited after it (the queue ran dry), so a vertex whose link was
  // empty or one cycle at that visit is manifold; the others (a visit that
  // found a singularity it could not remove) are checked again.
  auto manifold = [&](int32_t a) { return node_marks_.Contains(internal::kLinkOk, a) || mesh().SurfaceManifoldAt(a); };
  for (const Split& sp : ev.splits) {
    if (!manifold(sp.node)) return false;
    for (const int32_t t : sp.tets)
      for (const int32_t a : mesh().tet(t))
        if (!manifold(a)) return false;
  }
  return true;
}

// ---- 4b. fragment guard ----------------------------------------------------

bool CutStepper::GuardFragments(internal::StepState& s) {
  // Tets cut loose into a piece of fewer than min_fragment_tets tets (a tet
  // whose farthest vertex put it on one side while its face neighbours went
  // to the other, or a corner the singularity rules severed) are
  // discretisation debris, not a cut: such a piece would fly off under the
  // blade. Roll back, move its tets to the other side, and separate again.
  for (int attempt = 0; attempt < 3; ++attempt) {
    const std::vector<int32_t>& fragments = FindFragments(s.ev, s.params);
    if (fragments.empty()) break;
    size_t newly = 0;
    for (const int32_t t : fragments) newly += tet_marks_.Insert(kFlipped, t) ? 1 : 0;
    if (newly == 0) break;  // flipping again would undo a flip: keep this result
    s.mesh.RollBack(s.journal_mark, s.n0);
    s.ev = TopologyEvent{};  // s.world reads it by reference: the copies are gone again
    SplitByPlaneSides(s);
    if (!RemoveSingularities(s)) return false;
  }
  return true;
}

const std::vector<int32_t>& CutStepper::FindFragments(const TopologyEvent& ev, const CutParams& params) {
  // Local: flood fills from the retargeted tets stop at min_fragment_tets.
  std::vector<int32_t>& small = fragments_;
  small.clear();
  const auto limit = static_cast<size_t>(params.min_fragment_tets);
  if (limit == 0 || static_cast<size_t>(mesh().num_tets()) < 4 * limit) return small;
  tet_marks_.Clear(kFloodDone);
  for (const Split& sp : ev.splits) {
    for (const int32_t start : sp.tets) {
      if (tet_marks_.Contains(kFloodDone, start)) continue;
      std::vector<int32_t>& piece = flood_;
      piece.assign(1, start);
      tet_marks_.Clear(kInFlood);
      tet_marks_.Insert(kInFlood, start);
      for (size_t i = 0; i < piece.size() && piece.size() < limit; ++i) {
        const int32_t t = piece[i];
        for (int f = 0; f < 4; ++f) {
          const int32_t u = mesh().Neighbour(t, f);
          if (u >= 0 && tet_marks_.Insert(kInFlood, u)) piece.push_back(u);
        }
      }
      for (const int32_t t : piece) tet_marks_.Insert(kFloodDone, t);
      if (piece.size() < limit) small.insert(small.end(), piece.begin(), piece.end());
    }
  }
  return small;
}

// ---- star and edge groups (step 4) ----------------------------------------

int32_t CutStepper::FaceGroups(std::span<const int32_t> tets, int32_t a, int32_t b) {
  face_sets_.Reset(tets.size());
  for (size_t i = 0; i < tets.size(); ++i) {
    const int32_t t = tets[i];
    const auto& n = mesh().tet(t);
    for (int f = 0; f < 4; ++f) {
      if (n[Idx(f)] == a || n[Idx(f)] == b) continue;  // a face without both pivots
      const int32_t u = mesh().Neighbour(t, f);
      if (u < 0) continue;
      const auto j = std::lower_bound(tets.begin(), tets.end(), u) - tets.begin();
      face_sets_.Union(static_cast<int32_t>(i), static_cast<int32_t>(j));
    }
  }
  return face_sets_.Label(&face_group_);
}

int32_t CutStepper::StarGroups(int32_t node) {
  const std::span<const int32_t> star = mesh().node_tets(node);
  const int32_t k = FaceGroups(star, node, node);
  // Counting sort by label: groups in label order, tets ascending within.
  group_begin_.assign(Idx(k) + 1, 0);
  for (size_t i = 0; i < star.size(); ++i) ++group_begin_[Idx(face_group_[i]) + 1];
  for (int32_t g = 0; g < k; ++g) group_begin_[Idx(g) + 1] += group_begin_[Idx(g)];
  group_tets_.resize(star.size());
  group_fill_.assign(group_begin_.begin(), group_begin_.end() - 1);  // fill cursor per group
  for (size_t i = 0; i < star.size(); ++i) group_tets_[Idx(group_fill_[Idx(face_group_[i])]++)] = star[i];
  return k;
}

int CutStepper::EdgeGroupCount(int32_t a, int32_t b) {
  const std::span<const int32_t> sa = mesh().node_tets(a);
  const std::span<const int32_t> sb = mesh().node_tets(b);
  around_.clear();
  std::set_intersection(sa.begin(), sa.end(), sb.begin(), sb.end(), std::back_inserter(around_));
  if (around_.size() <= 1) return static_cast<int>(around_.size());
  return FaceGroups(around_, a, b);
}

}  // namespace cutsim::cutting
