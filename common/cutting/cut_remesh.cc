// Step 5 of a cut step (cut_stepper.h): the local remeshing moves of v0 and
// v1, limited by the quality rule (with the sliver guard). They change
// positions only, after the topology is final.
#include <algorithm>
#include <array>
#include <cmath>
#include <limits>
#include <span>
#include <vector>

#include <Eigen/LU>

#include "common/cutting/cut_stepper.h"
#include "common/cutting/cut_step_internal.h"
#include "common/mesh/quality.h"

namespace cutsim::cutting {
namespace {

using Eigen::Vector3d;

// Mean-ratio quality cubed (no cube root: every test compares it with a
// threshold, cubed too).
double QualityCubed(const std::array<Vector3d, 4>& p) { return mesh::MeanRatioCubed(p[0], p[1], p[2], p[3]); }

}  // namespace

void CutStepper::Remesh(internal::StepState& s) {
  const CutStep& step = s.step;
  if (!step.remesh) return;
  if (!step.blade) {  // the method paper's moves: to C_p(t0) and C_p(t)
    MoveTwins(s, step.v0, step.cp0);
    MoveTwins(s, step.v1, step.cp);
    return;
  }
  // With a blade, v0 and v1 move to the nearest point of P (if they are
  // near it): the crack then lies on the blade's plane. The method paper moves them
  // to C_p(t0), C_p(t); the part of that move along the cut (up to α·d_v)
  // does not change the cut's profile, only shears the elements around the
  // vertex into slivers, which the quality rule then limits or skips.
  for (const int32_t v : {step.v0, step.v1}) {
    const Vector3d xv = s.world.Get(v);
    const double dist = s.PlaneDistance(xv);
    if (std::abs(dist) <= s.plane.band) MoveTwins(s, v, xv - dist * s.plane.normal);
  }
}

void CutStepper::MoveTwins(internal::StepState& s, int32_t node, const Vector3d& target) {
  const std::vector<int32_t>& group = move_twins_;
  mesh().TwinsInto(node, s.world, move_twins_);
  const Vector3d x_old = s.world.Get(node);
  const Vector3d u_old = mesh().rest(node);
  if (!((target - x_old).norm() > 1e-12 * s.plane.h)) return;
  GatherMoveStar();
  const Vector3d u_target = RestPreimage(s.world, target, u_old);
  if (!u_target.allFinite()) return;
  // Qualities before the move, computed when first needed (NaN: not yet):
  // a tet at or above the floor after the move passes whatever it had.
  q_rest_.assign(move_star_.size(), std::numeric_limits<double>::quiet_NaN());
  q_world_.assign(move_star_.size(), std::numeric_limits<double>::quiet_NaN());
  // Sliver guard: the floor is keep_quality, not only min_quality (see
  // cut_stepper.h, step 5): v0 and v1 move at every step, passes over one
  // region move the same twins again and again, and with a floor of
  // min_quality alone each move may take a tet down to it.
  const double floor_q = std::max(s.params.min_quality, s.params.keep_quality);
  const double floor_quality = floor_q * floor_q * floor_q;  // cubed, as QualityCubed
  double f = 1.0;
  for (int k = 0; k <= s.params.max_move_halvings; ++k, f *= 0.5) {
    const Vector3d xn = x_old + f * (target - x_old);
    const Vector3d un = u_old + f * (u_target - u_old);
    bool ok = true;  // rest first: no world quality for a tet that fails in rest
    for (size_t i = 0; i < move_star_.size() && ok; ++i) {
      ok = KeepsQuality(s.world, i, true, un, floor_quality) && KeepsQuality(s.world, i, false, xn, floor_quality);
    }
    if (!ok) continue;
    for (const int32_t g : group) {
      s.mesh.SetRest(g, un);
      s.world.Set(g, xn);
      s.ev.moves.push_back(Move{g, un, xn});
    }
    if (k > 0) ++s.out.moves_limited;
    return;
  }
  ++s.out.moves_skipped;
}

void CutStepper::GatherMoveStar() {
  std::vector<int32_t>& star = move_star_;
  star.clear();
  for (const int32_t g : move_twins_) {
    const std::span<const int32_t> tets = mesh().node_tets(g);
    star.insert(star.end(), tets.begin(), tets.end());
  }
  if (move_twins_.size() > 1) {  // one node's tets are sorted and unique already
    std::sort(star.begin(), star.end());
    star.erase(std::unique(star.begin(), star.end()), star.end());
  }
}

Vector3d CutStepper::RestPreimage(const internal::StepWorld& world, const Vector3d& target, const Vector3d& fallback) {
  // Barycentric coordinates of the target in the world tet that contains it
  // best (the largest smallest barycentric coordinate, a score < 0 outside),
  // mapped to rest. Ties go to the lowest tet id, as a scan in ascending
  // order keeping the first maximum would. Candidates: move_star_, then
  // (AddRingCandidates) those of its neighbours that may hold the target. A
  // target outside every candidate (a surface vertex moved onto P lies just
  // outside the deformed body) is extrapolated affinely from the star tet
  // nearest to holding it: the map of the vertex's own elements. One loop
  // body serves both phases.
  double best_score = -1e300;
  int32_t best_tet = -1;
  Vector3d u_target = fallback;
  std::vector<int32_t>& search = search_;
  search.assign(move_star_.begin(), move_star_.end());
  tet_marks_.Clear(kInSearch);
  for (const int32_t t : move_star_) tet_marks_.Insert(kInSearch, t);
  bool ring_added = false;
  for (size_t i = 0;; ++i) {
    if (i == search.size()) {  // the star is done: add its neighbours
      // A target strictly inside a star tet is in no other tet: the ring
      // cannot score higher (its scores are < 0).
      if (ring_added || best_score > 1e-9) break;
      ring_added = true;
      AddRingCandidates(world, target);
      if (i == search.size()) break;
    }
    const int32_t t = search[i];
    const auto& tn = mesh().tet(t);
    const Vector3d p0 = world.Get(tn[0]);
    Eigen::Matrix3d D;  // edge vectors from corner 0, one per column
    D << world.Get(tn[1]) - p0, world.Get(tn[2]) - p0, world.Get(tn[3]) - p0;
    const double det = D.determinant();
    if (!(std::abs(det) > 1e-30)) continue;
    const Vector3d lam = D.inverse() * (target - p0);
    const double b0 = 1.0 - lam.sum();
    const double score = std::min(b0, lam.minCoeff());
    if (score > best_score || (score == best_score && t < best_tet)) {
      best_score = score;
      best_tet = t;
      u_target = b0 * mesh().rest(tn[0]) + lam[0] * mesh().rest(tn[1]) + lam[1] * mesh().rest(tn[2]) +
                 lam[2] * mesh().rest(tn[3]);
    }
  }
  return u_target;
}

void CutStepper::AddRingCandidates(const internal::StepWorld& world, const Vector3d& target) {
  // The tets around the corners of move_star_ (each corner's star once, a
  // corner is in several star tets; the twins' own stars are the star
  // itself) whose world bounding box, padded by 1e-6 of its size, holds the
  // target: outside the padded box the smallest barycentric coordinate is
  // < −2.5e-7, far beyond rounding, so a neighbour only counts if it holds
  // the target, and the others need no 3×3 inverse. The order of search_
  // does not matter: the best score wins, ties go to the lowest id.
  node_marks_.Clear(internal::kRingNode);
  for (const int32_t g : move_twins_) node_marks_.Insert(internal::kRingNode, g);
  for (const int32_t st : move_star_) {
    for (const int32_t a : mesh().tet(st)) {
      if (!node_marks_.Insert(internal::kRingNode, a)) continue;
      for (const int32_t u : mesh().node_tets(a)) {
        if (!tet_marks_.Insert(kInSearch, u)) continue;
        const auto& un = mesh().tet(u);
        Vector3d lo = world.Get(un[0]), hi = lo;
        for (int c = 1; c < 4; ++c) {
          const Vector3d pc = world.Get(un[Idx(c)]);
          lo = lo.cwiseMin(pc);
          hi = hi.cwiseMax(pc);
        }
        const double pad = 1e-6 * (hi - lo).maxCoeff();
        if ((target.array() < lo.array() - pad).any() || (target.array() > hi.array() + pad).any()) continue;
        search_.push_back(u);
      }
    }
  }
}

std::array<Vector3d, 4> CutStepper::MoveCorners(const internal::StepWorld& world, int32_t t, bool rest_config,
                                             const Vector3d* moved) const {
  std::array<Vector3d, 4> p;
  for (int c = 0; c < 4; ++c) {
    const int32_t a = mesh().tet(t)[Idx(c)];
    if (moved != nullptr && std::find(move_twins_.begin(), move_twins_.end(), a) != move_twins_.end()) {
      p[Idx(c)] = *moved;
    } else {
      p[Idx(c)] = rest_config ? mesh().rest(a) : world.Get(a);
    }
  }
  return p;
}

bool CutStepper::KeepsQuality(const internal::StepWorld& world, size_t i, bool rest_config, const Vector3d& moved,
                           double floor_quality) {
  const double q = QualityCubed(MoveCorners(world, move_star_[i], rest_config, &moved));
  if (!(q > 0.0)) return false;
  if (q >= floor_quality) return true;
  std::vector<double>& q_before = rest_config ? q_rest_ : q_world_;
  if (std::isnan(q_before[i])) q_before[i] = QualityCubed(MoveCorners(world, move_star_[i], rest_config, nullptr));
  return q >= std::min(floor_quality, q_before[i]);
}

}  // namespace cutsim::cutting
