// CutMesh::ExecuteCut: one cut step (seed §3.2–3.3). The rules are stated in
// cut_mesh.h; comments here say why. Steps 1–2 are in cut_plane.cc.
#include <algorithm>
#include <atomic>
#include <cmath>
#include <limits>
#include <utility>
#include <vector>

#include <Eigen/LU>

#include "common/cutting/cut_mesh.h"
#include "common/cutting/cut_step_internal.h"
#include "common/mesh/quality.h"

namespace cutsim::cutting {
namespace {

using Eigen::Vector3d;
using internal::StepWorld;

}  // namespace

PreparedCut CutMesh::PrepareCut(const CutStep& step, const WorldAccess& world, const CutParams& params,
                                const std::atomic<bool>* cancel) {
  return PrepareOnPlane(step, world, params, /*blade_plane=*/true, cancel);
}

CutOutcome CutMesh::ExecuteCut(const CutStep& step, const WorldAccess& world, const CutParams& params,
                               const PreparedCut* prepared, const SeparatedCallback* on_separated) {
  CutOutcome out = ExecuteCutOnPlane(step, world, params, /*blade_plane=*/true, prepared, on_separated);
  // A blade plane that leaves a singularity the rules cannot remove (rolled
  // back, nothing changed) gets one more try on the seed's plane through
  // v0 and v1, which runs through existing vertices.
  if (out.status == CutStatus::kRejected && step.blade) {
    out = ExecuteCutOnPlane(step, world, params, false, nullptr, on_separated);
  }
  return out;
}

CutOutcome CutMesh::ExecuteCutOnPlane(const CutStep& step, const WorldAccess& world, const CutParams& params,
                                      bool blade_plane, const PreparedCut* prepared,
                                      const SeparatedCallback* on_separated) {
  CutOutcome out;
  // Steps 1–2 (plane, split set S in slab_): from `prepared` if it was made
  // for this step on this mesh (nothing changed since: same version, and no
  // other step took a new position generation), else now.
  const bool reuse = prepared != nullptr && prepared->valid && prepared->version == version_ &&
                     prepared->generation == pos_generation_ && prepared->v0 == step.v0 &&
                     prepared->v1 == step.v1 && prepared->blade_plane == blade_plane;
  const PreparedCut prep = reuse ? *prepared : PrepareOnPlane(step, world, params, blade_plane, nullptr);
  if (!prep.valid) return out;
  out.v2 = prep.v2;
  const int32_t n0 = num_nodes();
  TopologyEvent ev;
  StepWorld W(world, n0, ev, x_cache_, pos_generation_);
  const double h = prep.h;
  const double band = prep.band;
  const Vector3d m = prep.normal;
  const Vector3d origin = prep.origin;
  auto plane_dist = [&](const Vector3d& x) { return m.dot(x - origin); };
  std::vector<int32_t>& S = slab_;

  // ---- 3. sides: the farthest vertex from P decides --------------------------
  // `flipped` holds tets moved to the other side by the fragment guard (6).
  tet_marks_.Clear(kFlipped);
  tet_marks_.Clear(kSideKnown);
  auto side = [&](int32_t t) -> int8_t {
    if (tet_marks_.Contains(kSideKnown, t)) return tet_marks_.rows[Idx(t)].side;
    double far = 0.0;
    for (const int32_t a : recs_[Idx(t)].nodes) {
      const double da = plane_dist(W.Get(a));
      if (std::abs(da) > std::abs(far)) far = da;  // strict: ties keep the first corner
    }
    int8_t s = far < 0.0 ? int8_t{-1} : int8_t{1};
    if (tet_marks_.Contains(kFlipped, t)) s = static_cast<int8_t>(-s);
    tet_marks_.Insert(kSideKnown, t);
    tet_marks_.rows[Idx(t)].side = s;
    return s;
  };

  const size_t journal_mark = journal_.size();
  journaling_ = true;
  // FIFO of vertices to check: work_[work_head..).
  work_.clear();
  size_t work_head = 0;
  node_marks_.Clear(internal::kQueued);
  // After a split of w that moved `tets` to a copy, the vertices whose
  // star or link changed: the corners of the moved tets (the copy among
  // them) and w. A face changes only between a moved and an unmoved tet,
  // and all its nodes are corners of the moved one, so the other vertices
  // of w's star keep their star and their link: they were manifold when
  // the step began (every step leaves the mesh so) or were queued by the
  // split that changed them.
  auto enqueue_split = [&](int32_t w, std::span<const int32_t> tets) {
    for (const int32_t t : tets)
      for (const int32_t a : recs_[Idx(t)].nodes)
        if (node_marks_.Insert(internal::kQueued, a)) work_.push_back(a);
    if (node_marks_.Insert(internal::kQueued, w)) work_.push_back(w);
  };
  node_marks_.Clear(internal::kPlaneDone);
  auto plane_split = [&](int32_t w) -> bool {
    node_marks_.Insert(internal::kPlaneDone, w);
    std::vector<int32_t>& negative = negative_;
    negative.clear();
    bool has_positive = false;
    for (const int32_t t : Star(w)) {
      if (side(t) < 0) {
        negative.push_back(t);
      } else {
        has_positive = true;
      }
    }
    if (negative.empty() || !has_positive) return false;
    SplitNode(w, negative, &ev);
    enqueue_split(w, negative);
    return true;
  };

  // Steps 3–4 as one pass that the fragment guard may roll back and redo.
  auto separate = [&]() -> bool {
    node_marks_.Clear(internal::kLinkOk);
    for (const int32_t w : S) plane_split(w);
    // ---- 4. singularities ----------------------------------------------------
    while (work_head < work_.size()) {
      const int32_t v = work_[work_head++];
      node_marks_.Erase(internal::kQueued, v);
      if (static_cast<int32_t>(ev.splits.size()) > params.max_splits_per_step) return false;
      // The link of v in the surface (one edge per surface face through v)
      // decides most visits without the star's groups:
      // - Empty: the star is closed, every face through v is shared with
      //   another tet of its star, in the uncut mesh too (copies keep their
      //   origin's ids), so each group of the star is closed under the uncut
      //   star's face adjacency; if that star was one group, so is this one,
      //   and the edge rule has no candidate (about a third of the visits).
      // - One cycle (a manifold fan): if the uncut star was one group, so is
      //   this one. Every group then has a surface face through v (a group's
      //   uncut face to a tet outside it cannot still be shared: its mate
      //   would hold v, so be in the group); and the two surface faces at a
      //   link vertex q end the single fan of tets around edge (v, q) (a fan
      //   that is a path ends in two surface faces, and q has only two), so
      //   consecutive link edges lie in one group: all do. Every edge (v, u)
      //   then has exactly two surface faces: no edge-rule candidate.
      // Either way v is manifold now (kLinkOk), and the final check below
      // skips it: a later change to its star would have queued it again.
      BuildLink(v);
      const bool link_ok = link_.empty() || LinkIsOneCycle();
      if (link_ok) {
        node_marks_.Insert(internal::kLinkOk, v);
      } else {
        node_marks_.Erase(internal::kLinkOk, v);
      }
      if (link_ok && star_connected0_[Idx(origin_[Idx(v)])] != 0) continue;
      // Edge-rule candidates: the other two nodes of each surface face
      // through v (gathered before a split below changes the link).
      std::vector<int32_t>& nbrs = nbrs_;
      nbrs.clear();
      for (const auto& [p, q] : link_) {
        nbrs.push_back(p);
        nbrs.push_back(q);
      }
      // Vertex rule: parts of the star joined only through v. (A flood
      // answers the usual "one group" first; the groups only when split.)
      const int32_t num_groups = StarIsOneGroup(v) ? 1 : StarGroups(v);
      if (num_groups > 1) {
        for (int32_t g = 1; g < num_groups; ++g) {
          const std::span<const int32_t> group(group_tets_.data() + group_begin_[Idx(g)],
                                               Idx(group_begin_[Idx(g) + 1] - group_begin_[Idx(g)]));
          SplitNode(v, group, &ev);
          enqueue_split(v, group);
        }
        continue;
      }
      // Edge rule: parts around an edge joined only through the edge. The
      // star of each endpoint is connected (checked above), so no vertex copy
      // alone separates them; splitting an endpoint by the plane sides extends
      // the cut by one vertex, after which the vertex rule applies again.
      // Candidates: an edge (v, u) whose tets fall into k > 1 groups has 2k
      // surface faces through it (each group is a fan whose two end faces
      // are on the surface), so only u on ≥ 4 surface faces through v can
      // fail; the exact count (EdgeGroupCount) runs for those only (nbrs,
      // gathered above).
      std::sort(nbrs.begin(), nbrs.end());
      {
        size_t kept = 0;
        for (size_t i = 0; i < nbrs.size();) {
          size_t j = i;
          while (j < nbrs.size() && nbrs[j] == nbrs[i]) ++j;
          if (j - i >= 4) nbrs[kept++] = nbrs[i];
          i = j;
        }
        nbrs.resize(kept);
      }
      for (const int32_t u : nbrs) {
        if (EdgeGroupCount(v, u) <= 1) continue;
        std::array<int32_t, 2> cand{v, u};
        if (std::abs(plane_dist(W.Get(u))) < std::abs(plane_dist(W.Get(v)))) std::swap(cand[0], cand[1]);
        bool fixed = false;
        for (const int32_t c : cand) {
          if (!node_marks_.Contains(internal::kPlaneDone, c) && plane_split(c)) {
            fixed = true;
            break;
          }
        }
        if (fixed) {
          if (node_marks_.Insert(internal::kQueued, v)) work_.push_back(v);
          break;
        }
        // Otherwise the final check below decides (and rejects if needed).
      }
    }
    // Faces changed only on retargeted tets and on their neighbours across
    // the old faces, whose vertices are the split node and the other corners.
    // Every vertex here was queued by the split that last changed its star
    // and visited after it (the loop above ran dry), so a vertex whose link
    // was empty or one cycle at that visit is manifold now; the others (a
    // visit that found a singularity it could not remove) are checked again.
    auto manifold = [&](int32_t a) { return node_marks_.Contains(internal::kLinkOk, a) || SurfaceManifoldAt(a); };
    for (const Split& sp : ev.splits) {
      if (!manifold(sp.node)) return false;
      for (const int32_t t : sp.tets)
        for (const int32_t a : recs_[Idx(t)].nodes)
          if (!manifold(a)) return false;
    }
    return true;
  };

  // ---- 6. fragment guard ----------------------------------------------------
  // Tets cut loose into a piece of fewer than `min_fragment_tets` tets (a
  // tet whose farthest vertex put it on one side while its face neighbours
  // went to the other, or a corner the singularity rules severed) are
  // discretisation debris, not a cut: such a piece would fly off under the
  // blade. Roll back, move its tets to the other side, and separate again.
  // Local: flood fills stop at min_fragment_tets tets.
  auto find_fragments = [&]() -> const std::vector<int32_t>& {
    std::vector<int32_t>& small = fragments_;
    small.clear();
    const auto limit = static_cast<size_t>(params.min_fragment_tets);
    if (limit == 0 || static_cast<size_t>(num_tets()) < 4 * limit) return small;
    tet_marks_.Clear(kFloodDone);
    for (const Split& sp : ev.splits) {
      for (const int32_t start : sp.tets) {
        if (tet_marks_.Contains(kFloodDone, start)) continue;
        std::vector<int32_t>& comp = flood_;
        comp.assign(1, start);
        tet_marks_.Clear(kInFlood);
        tet_marks_.Insert(kInFlood, start);
        for (size_t i = 0; i < comp.size() && comp.size() < limit; ++i) {
          const int32_t t = comp[i];
          for (int f = 0; f < 4; ++f) {
            const int32_t u = recs_[Idx(t)].neighbour[Idx(f)];
            if (u >= 0 && tet_marks_.Insert(kInFlood, u)) comp.push_back(u);
          }
        }
        for (const int32_t t : comp) tet_marks_.Insert(kFloodDone, t);
        if (comp.size() < limit) small.insert(small.end(), comp.begin(), comp.end());
      }
    }
    return small;
  };
  bool separated = separate();
  for (int attempt = 0; separated && attempt < 3; ++attempt) {
    const std::vector<int32_t>& fragments = find_fragments();
    if (fragments.empty()) break;
    size_t newly = 0;
    for (const int32_t t : fragments) newly += tet_marks_.Insert(kFlipped, t) ? 1 : 0;
    if (newly == 0) break;  // flipping again would undo a flip: keep this result
    Rollback(journal_mark, n0);
    ev = TopologyEvent{};  // W reads `ev` by reference: copies are gone again
    tet_marks_.Clear(kSideKnown);
    node_marks_.Clear(internal::kPlaneDone);
    work_.clear();
    work_head = 0;
    node_marks_.Clear(internal::kQueued);
    separated = separate();
  }
  if (!separated) {
    Rollback(journal_mark, n0);
    journaling_ = false;
    journal_.resize(journal_mark);
    out.status = CutStatus::kRejected;
    return out;
  }
  journaling_ = false;
  journal_.resize(journal_mark);
  // The topology is final: the moves below change positions only.
  if (on_separated != nullptr && *on_separated) (*on_separated)(std::span<const Split>(ev.splits));

  // ---- 5. local remeshing -----------------------------------------------------
  auto move_group = [&](int32_t node, const Vector3d& target) {
    std::vector<int32_t>& group = move_twins_;
    TwinsInto(node, W, group);
    const Vector3d x_old = W.Get(node);
    const Vector3d u_old = rest_[Idx(node)];
    if (!((target - x_old).norm() > 1e-12 * h)) return;
    std::vector<int32_t>& star = move_star_;
    star.clear();
    for (const int32_t g : group) star.insert(star.end(), Star(g).begin(), Star(g).end());
    if (group.size() > 1) {  // one node's tets are sorted and unique already
      std::sort(star.begin(), star.end());
      star.erase(std::unique(star.begin(), star.end()), star.end());
    }
    // Rest preimage of the target: barycentric coordinates in the world tet
    // that contains it best (the largest smallest barycentric coordinate, a
    // score < 0 outside), mapped to rest. Ties go to the lowest tet id, as a
    // scan in ascending order keeping the first maximum would. Candidates:
    // the star, and those of its neighbours (gathered through a stamp set)
    // whose world bounding box, padded by 1e-6 of its size, holds the
    // target: outside the padded box the smallest coordinate is < −2.5e-7,
    // far beyond rounding, so a neighbour only counts if it holds the
    // target. A target outside every candidate (a surface vertex moved onto
    // P lies just outside the deformed body) is extrapolated affinely from
    // the star tet nearest to holding it: the map of the vertex's own
    // elements. (Scoring every neighbour too, ~100 3×3 inverses, was most of
    // the move's cost, for an extrapolation from a tet one ring away.) One
    // loop body serves both phases.
    double best_score = -1e300;
    int32_t best_tet = -1;
    Vector3d u_target = u_old;
    std::vector<int32_t>& search = search_;
    search.assign(star.begin(), star.end());
    tet_marks_.Clear(kInSearch);
    for (const int32_t t : star) tet_marks_.Insert(kInSearch, t);
    bool ring_added = false;
    for (size_t i = 0;; ++i) {
      if (i == search.size()) {  // the star is done: add its neighbours
        // A target strictly inside a star tet is in no other tet: the ring
        // cannot score higher (its scores are < 0).
        if (ring_added || best_score > 1e-9) break;
        ring_added = true;
        // Each corner's star once (a corner is in ~6 star tets); the group's
        // own stars are the star itself. The order of `search` does not
        // matter: the best score wins, ties go to the lowest id.
        node_marks_.Clear(internal::kRingNode);
        for (const int32_t g : group) node_marks_.Insert(internal::kRingNode, g);
        for (const int32_t st : star) {
          for (const int32_t a : recs_[Idx(st)].nodes) {
            if (!node_marks_.Insert(internal::kRingNode, a)) continue;
            for (const int32_t u : Star(a)) {
              if (!tet_marks_.Insert(kInSearch, u)) continue;
              const auto& un = recs_[Idx(u)].nodes;
              Vector3d lo = W.Get(un[0]), hi = lo;
              for (int c = 1; c < 4; ++c) {
                const Vector3d pc = W.Get(un[Idx(c)]);
                lo = lo.cwiseMin(pc);
                hi = hi.cwiseMax(pc);
              }
              const double pad = 1e-6 * (hi - lo).maxCoeff();
              if ((target.array() < lo.array() - pad).any() || (target.array() > hi.array() + pad).any()) continue;
              search.push_back(u);
            }
          }
        }
        if (i == search.size()) break;
      }
      const int32_t t = search[i];
      const auto& tn = recs_[Idx(t)].nodes;
      const Vector3d p0 = W.Get(tn[0]);
      Eigen::Matrix3d D;
      D << W.Get(tn[1]) - p0, W.Get(tn[2]) - p0, W.Get(tn[3]) - p0;
      const double det = D.determinant();
      if (!(std::abs(det) > 1e-30)) continue;
      const Vector3d lam = D.inverse() * (target - p0);
      const double b0 = 1.0 - lam.sum();
      const double score = std::min(b0, lam.minCoeff());
      if (score > best_score || (score == best_score && t < best_tet)) {
        best_score = score;
        best_tet = t;
        u_target = b0 * rest_[Idx(tn[0])] + lam[0] * rest_[Idx(tn[1])] + lam[1] * rest_[Idx(tn[2])] +
                   lam[2] * rest_[Idx(tn[3])];
      }
    }
    if (!u_target.allFinite()) return;
    auto in_group = [&](int32_t a) { return std::find(group.begin(), group.end(), a) != group.end(); };
    auto corners = [&](int32_t t, bool rest_config, const Vector3d* moved) {
      std::array<Vector3d, 4> p;
      for (int c = 0; c < 4; ++c) {
        const int32_t a = recs_[Idx(t)].nodes[Idx(c)];
        if (moved && in_group(a)) {
          p[Idx(c)] = *moved;
        } else {
          p[Idx(c)] = rest_config ? rest_[Idx(a)] : W.Get(a);
        }
      }
      return p;
    };
    // Mean-ratio quality cubed (no cbrt: every test below compares it with
    // a threshold, cubed too; the cube root was a third of the move's cost).
    auto quality = [](const std::array<Vector3d, 4>& p) { return mesh::MeanRatioCubed(p[0], p[1], p[2], p[3]); };
    // Qualities before the move, computed when first needed (NaN: not yet):
    // a tet at or above the floor after the move passes whatever it had.
    std::vector<double>& q_rest = q_rest_;
    std::vector<double>& q_world = q_world_;
    q_rest.assign(star.size(), std::numeric_limits<double>::quiet_NaN());
    q_world.assign(star.size(), std::numeric_limits<double>::quiet_NaN());
    auto before = [&](std::vector<double>& q, size_t i, bool rest_config) {
      if (std::isnan(q[i])) q[i] = quality(corners(star[i], rest_config, nullptr));
      return q[i];
    };
    // Sliver guard: the floor is keep_quality, not only min_quality (see
    // cut_mesh.h, step 5): v0 and v1 move at every step, passes over one
    // region move the same twins again and again, and with a floor of
    // min_quality alone each move may take a tet down to it.
    const double floor_q = std::max(params.min_quality, params.keep_quality);
    const double floor_quality = floor_q * floor_q * floor_q;  // cubed, as `quality`
    auto passes = [&](double q, size_t i, bool rest_config) {
      if (!(q > 0.0)) return false;
      if (q >= floor_quality) return true;
      return q >= std::min(floor_quality, before(rest_config ? q_rest : q_world, i, rest_config));
    };
    double f = 1.0;
    for (int k = 0; k <= params.max_move_halvings; ++k, f *= 0.5) {
      const Vector3d xn = x_old + f * (target - x_old);
      const Vector3d un = u_old + f * (u_target - u_old);
      bool ok = true;  // rest first: no world quality for a tet that fails in rest
      for (size_t i = 0; i < star.size() && ok; ++i) {
        ok = passes(quality(corners(star[i], true, &un)), i, true) &&
             passes(quality(corners(star[i], false, &xn)), i, false);
      }
      if (!ok) continue;
      for (const int32_t g : group) {
        rest_[Idx(g)] = un;
        W.Set(g, xn);
        ev.moves.push_back(Move{g, un, xn});
      }
      if (k > 0) ++out.moves_limited;
      return;
    }
    ++out.moves_skipped;
  };
  if (step.remesh && step.blade) {
    // With a blade, v0 and v1 move to the nearest point of P (if they are
    // near it): the crack then lies on the blade's plane. The seed moves
    // them to C_p(t0), C_p(t); the part of that move along the cut (up to
    // α·d_v) does not change the cut's profile, only shears the elements
    // around the vertex into slivers, which the quality rule then limits
    // or skips.
    for (const int32_t v : {step.v0, step.v1}) {
      const Vector3d xv = W.Get(v);
      const double dist = plane_dist(xv);
      if (std::abs(dist) <= band) move_group(v, xv - dist * m);
    }
  } else if (step.remesh) {
    move_group(step.v0, step.cp0);
    move_group(step.v1, step.cp);
  }

  // ---- event -------------------------------------------------------------------
  out.status = CutStatus::kExecuted;
  if (ev.empty()) return out;
  for (const Split& s : ev.splits) {
    ev.touched_tets.insert(ev.touched_tets.end(), s.tets.begin(), s.tets.end());
    ev.touched_nodes.push_back(s.node);
    ev.touched_nodes.push_back(s.new_node);
  }
  for (const Move& mv : ev.moves)
    ev.touched_tets.insert(ev.touched_tets.end(), Star(mv.node).begin(), Star(mv.node).end());
  for (auto* v : {&ev.touched_tets, &ev.touched_nodes}) {
    std::sort(v->begin(), v->end());
    v->erase(std::unique(v->begin(), v->end()), v->end());
  }
  ev.version = ++version_;
  out.event = std::move(ev);
  return out;
}

}  // namespace cutsim::cutting
