#pragma once
/// @file
/// The cut topology: rest positions, tets, the abstract simplicial complex
/// (node → incident tets, face → tets) and the boundary surface with a
/// per-face "opened by a cut" flag, all maintained incrementally by the
/// three primitives a cut uses (copy a node, retarget a tet corner, move a
/// rest position). World positions belong to the FEM and are read through
/// `WorldAccess`.
///
/// Cut step (method paper §3.2–3.3), `ExecuteCut`; each numbered step below is
/// one function of the same name in cut_plane.cc (1–2), cut_separate.cc
/// (3–4b), cut_remesh.cc (5) and cut_step.cc (6):
/// 1. Plane P (ChoosePlane). With a blade: the plane the blade sweeps,
///    spanned by its direction d and the tool's motion since t0 (tip0 → tip,
///    else C_p(t0) → C_p(t)), through the tip, then snapped parallel to
///    itself onto the slab vertex nearest to it (in step 2). Tool positions,
///    not node positions: the method paper's s1 = x(v1) − x(v0) joins closest
///    vertices that jump between the two rows of nodes beside the blade and
///    are pushed around by the contact, which would swing P across the rows
///    and shatter the crack. Without a blade (or if the blade plane's step is
///    rejected, one retry): the method paper's plane through x(v1) spanned by the
///    facet normal n and s1, m = s1 × n / |s1 × n|.
/// 2. Split set S (CollectSplitSet). With a blade: every vertex in the swept
///    slab, |m·(x − origin)| ≤ band (band = band_fraction × the mean edge
///    length around v1, "half an element"), −band ≤ ŝ·(x − tip0) ≤ |motion| +
///    band (between the previous and the current tool position, with a band
///    behind, so the edge where the blade came in is taken, and ahead, the
///    vertex the tip is reaching), and 0 ≤ (x − tip)·d ≤ blade length; v1
///    only if it is in the band (the closest vertex may be on the far row).
///    The slab is found by a walk over the tets from v1 and v0; P is then
///    snapped onto the vertex of S nearest to it (a plane midway between two
///    layers of vertices would put both in the band and make their tets tie
///    on the farthest-vertex rule of step 3). Without a blade, {v1}.
///    Splitting a vertex opens the faces of its star, so the crack reaches up
///    to one element below the deepest split vertex. A blade longer than the
///    thickness hence cuts through; a shallower one leaves a slit.
/// 3. Plane sides (SplitByPlaneSides). Every tet around S gets a side: the
///    sign of the signed distance to P of its vertex farthest from P (crossed
///    tets go with their farthest vertex; exact ties keep the first vertex in
///    tet order; all-zero goes to the positive side). Each w in S whose star
///    holds tets of both sides is split: the negative side moves to the new
///    copy.
/// 4. Singularities (RemoveSingularities), on the complex, over every vertex
///    of a retargeted tet until none is left: (vertex rule) a vertex whose
///    incident tets fall into k > 1 face-connected groups gets k − 1 copies,
///    one per group (the group holding the lowest tet id keeps the vertex);
///    (edge rule) an edge whose tets fall into more than one face-connected
///    group around it has an endpoint that is not yet plane-split split by
///    the plane sides (then the vertex rule applies again), preferring the
///    endpoint nearer to P. A step that still leaves a non-manifold vertex or
///    edge on the surface, or needs more than max_splits_per_step copies, is
///    rolled back entirely (status kRejected, nothing changes, no event).
/// 4b. Fragment guard (GuardFragments): a step that cuts loose a piece of
///    fewer than min_fragment_tets tets (found by flood fills from the
///    retargeted tets, stopped at that size: local) is rolled back and redone
///    from step 3 with those tets on the other side (up to 3 times). Such a
///    piece is debris of the discretisation (a tet the farthest-vertex rule
///    put on the far side of its neighbours), not a cut, and would fly off
///    under the blade.
/// 5. Remeshing (Remesh). With a blade: the twins of v0 and of v1 (if within
///    the band) move onto P, to their nearest point (the method paper's move to C_p
///    also slides them along the cut by up to α·d_v, which does not change
///    the cut's profile but shears their elements into slivers). Without a
///    blade, the method paper's: the twins of v0 (coincident copies of the same
///    original vertex) move to C_p(t0) and those of v1 to C_p(t): world to
///    C_p, rest to the barycentric preimage of C_p in the world tet around
///    the vertex (or next to its star) that contains it best (largest
///    smallest barycentric coordinate; if none does, affine extrapolation
///    from the tet around the vertex nearest to holding it). A move is
///    accepted if every tet around the moved twins keeps positive volume and
///    mean-ratio quality ≥ min(max(min_quality, keep_quality), its quality
///    before the move), in rest and in world; otherwise the displacement is
///    halved (up to max_move_halvings times) and the move is skipped if no
///    fraction passes.
///    Sliver guard (keep_quality): a split never changes a tet's shape, so
///    the thin elements after many cuts come from these moves. In the sim
///    the contact pushes the nodes beside the blade apart by up to half a
///    cell, the move puts them back onto P and maps the target to rest
///    through the deformed tets, and passes over one region move the same
///    twins again and again; with the floor at min_quality alone each move
///    may take a tet down to it, and the stable time step with it. A tet
///    already below keep_quality may not get worse at all.
/// 6. Event (FinishEvent): the touched tets and nodes, sorted and unique,
///    and the new topology version.

#include <algorithm>
#include <array>
#include <atomic>
#include <cstdint>
#include <functional>
#include <optional>
#include <span>
#include <utility>
#include <vector>

#include <Eigen/Core>

#include "common/core/stamp_sets.h"
#include "common/cutting/cut_params.h"
#include "common/cutting/topology_event.h"
#include "common/cutting/world_access.h"
#include "common/mesh/tet_mesh.h"

namespace cutsim::cutting {

namespace internal {
/// Per-node scratch of a cut step (see CutMesh::node_marks_): the node
/// stamp sets, 10 bytes, so the rows of nearby nodes share cache lines
/// (the step visits a few hundred nodes on caches the FEM steps in between
/// have evicted).
enum NodeMark : uint8_t { kSeen, kQueued, kPlaneDone, kRingNode, kLinkOk, kNumNodeMarks };
struct NodeScratch {
  std::array<uint16_t, kNumNodeMarks> stamp{};
};
/// A world position cached for one step, valid where `generation` is the
/// step's (worlds without packed positions only, see WorldAccess::Xyz).
struct CachedPosition {
  Eigen::Vector3d x = Eigen::Vector3d::Zero();
  uint32_t generation = 0;
};
struct SweptSlab;  // steps 1–2's plane and slab (cut_step_internal.h)
class StepWorld;   // world positions during a step (cut_step_internal.h)
struct StepState;  // steps 3–6's shared state (cut_step_internal.h)
}  // namespace internal

/// The blade below the contact point, world.
struct Blade {
  Eigen::Vector3d tip = Eigen::Vector3d::Zero();             ///< m
  Eigen::Vector3d direction = Eigen::Vector3d::UnitZ();      ///< unit, tip → handle
  double length = 0.0;                                       ///< m
  /// Tip when t0 was set (the previous executed cut or the first contact).
  /// The blade's motion since then spans the cut plane with its direction;
  /// without it the motion of the contact point, C_p(t) − C_p(t0), is used.
  std::optional<Eigen::Vector3d> tip0;                       ///< m
};

/// One cut step's geometric input (from a `CutAttempt` plus the tool).
struct CutStep {
  int32_t v0 = -1;                                    ///< v_c(t0)
  int32_t v1 = -1;                                    ///< v_c(t)
  Eigen::Vector3d cp0 = Eigen::Vector3d::Zero();      ///< C_p(t0), world, m
  Eigen::Vector3d cp = Eigen::Vector3d::Zero();       ///< C_p(t), world, m
  Eigen::Vector3d normal = Eigen::Vector3d::UnitZ();  ///< Outward facet normal, world
  std::optional<Blade> blade;  ///< None: split v1 only (the method paper's surface cut).
  bool remesh = true;          ///< Move v0, v1 to the cut points (§3.3).
};

enum class CutStatus {
  kExecuted,      ///< Event applied (it may hold no split if P separated nothing).
  kRejected,      ///< A singularity could not be removed; rolled back, nothing changed.
  kInvalidInput,  ///< Bad node ids, v0 = v1, non-finite input, or s1 ∥ n.
};

/// Steps 1–2 of a cut step (plane P and the split set), made ahead by
/// CutMesh::PrepareCut, e.g. on a second thread while the stress criterion
/// decides whether to cut. Only the CutMesh reads it; ExecuteCut uses it if
/// it was made for that step on the mesh as it is, and ignores it otherwise.
struct PreparedCut {
  bool valid = false;
  uint64_t version = 0;     ///< CutMesh::version() it was made on
  uint32_t generation = 0;  ///< world-position generation it read
  int32_t v0 = -1, v1 = -1;
  bool blade_plane = true;
  int32_t v2 = -1;
  double h = 0.0;     ///< mean world edge length around v1, m
  double band = 0.0;  ///< m
  Eigen::Vector3d normal = Eigen::Vector3d::Zero();  ///< of P
  Eigen::Vector3d origin = Eigen::Vector3d::Zero();  ///< a point of P, m
};

/// Called by ExecuteCut once per executed step, as soon as its topology is
/// final (steps 3–4b), before the remeshing moves (step 5), which change
/// positions only: `splits` is the event's split list, complete, and stays
/// valid and unchanged in the event ExecuteCut returns. Work that needs the
/// new topology but no moved position may run beside the moves, on another
/// thread: it may read the tets, their face neighbours, the stars, the
/// surface slots and take the slot change log (TakeChangedSlots); it must not
/// change the complex, read rest positions or call ExecuteCut.
using SeparatedCallback = std::function<void(std::span<const Split> splits)>;

struct CutOutcome {
  CutStatus status = CutStatus::kInvalidInput;
  TopologyEvent event;      ///< Empty unless kExecuted.
  int32_t v2 = -1;          ///< Eq. (12): next cut-line vertex (−1 if none).
  int32_t moves_limited = 0;  ///< Moves shortened by the quality rule.
  int32_t moves_skipped = 0;  ///< Moves dropped by it.
};

/// Surface face: local face `local_face` (opposite that corner) of `tet`.
struct SurfaceFace {
  int32_t tet = -1;
  int8_t local_face = -1;
  bool opened = false;  ///< Exposed by a cut (interior in the uncut mesh).
  bool alive = false;   ///< Slot in use.
};

class CutMesh {
 public:
  /// Builds the complex and surface of `mesh` (positively oriented tets, as
  /// after ValidateTetMesh). `node_capacity` reserves room for copies
  /// (0: 2·N). O(N + T).
  explicit CutMesh(const mesh::TetMesh& mesh, int32_t node_capacity = 0);

  [[nodiscard]] int32_t num_nodes() const { return static_cast<int32_t>(rest_.size()); }
  [[nodiscard]] int32_t num_tets() const { return static_cast<int32_t>(recs_.size()); }
  /// Topology version: number of events applied (0 for the uncut mesh).
  [[nodiscard]] uint64_t version() const { return version_; }
  [[nodiscard]] const Eigen::Vector3d& rest(int32_t node) const { return rest_[Idx(node)]; }
  [[nodiscard]] const std::array<int32_t, 4>& tet(int32_t t) const { return recs_[Idx(t)].nodes; }
  /// Tets using `node`, ascending. Valid until the next topology change.
  [[nodiscard]] std::span<const int32_t> node_tets(int32_t node) const { return Star(node); }
  /// The uncut-mesh node this one descends from (itself for original nodes).
  [[nodiscard]] int32_t origin(int32_t node) const { return origin_[Idx(node)]; }
  /// Tets sharing the face {a, b, c}: {t0, t1} with −1 for none.
  [[nodiscard]] std::array<int32_t, 2> FaceTets(int32_t a, int32_t b, int32_t c) const;

  /// Rest mesh (copies out).
  [[nodiscard]] mesh::TetMesh RestMesh() const;
  [[nodiscard]] mesh::Tets TetsMatrix() const;

  /// Surface slots (some dead); iterate and skip !alive. Stable ids for
  /// renderers while a face lives.
  [[nodiscard]] const std::vector<SurfaceFace>& surface_slots() const { return surface_; }
  [[nodiscard]] int32_t num_surface_faces() const { return num_surface_; }
  /// Surface slot of local face `f` (opposite corner f) of tet `t`, −1 if
  /// the face is interior.
  [[nodiscard]] int32_t SurfaceSlot(int32_t t, int f) const { return slot_[Idx(t)][Idx(f)]; }
  /// The tet across local face `f` of tet `t`, −1 if that face is on the
  /// surface. O(1).
  [[nodiscard]] int32_t Neighbour(int32_t t, int f) const { return recs_[Idx(t)].neighbour[Idx(f)]; }
  /// Nodes of surface slot `slot` (alive), outward.
  [[nodiscard]] std::array<int32_t, 3> SurfaceTriangle(int32_t slot) const;
  /// Change log for incremental consumers (the sim's BVH and surface):
  /// while on, every slot created or freed is appended (duplicates
  /// possible); TakeChangedSlots hands the log over and clears it.
  void set_track_slot_changes(bool on) { track_slots_ = on; }
  void TakeChangedSlots(std::vector<int32_t>& out) {
    out.clear();
    out.swap(changed_slots_);
  }
  /// Live surface triangles, outward (counter-clockwise seen from outside),
  /// in slot order; `opened` (optional) receives the per-triangle flag.
  [[nodiscard]] mesh::Triangles SurfaceTriangles(std::vector<uint8_t>* opened = nullptr) const;

  /// Contact elements for the stress criterion: the tets around `node`
  /// (v_c) plus `facet_tet` if given. Sorted, unique.
  [[nodiscard]] std::vector<int32_t> ContactElements(int32_t node, int32_t facet_tet = -1) const;

  /// Coincident copies of `node` (same origin, same rest and world position),
  /// including `node`, ascending.
  [[nodiscard]] std::vector<int32_t> Twins(int32_t node, const WorldAccess& world) const;

  /// Eq. (12): among the surface neighbours of v1 (other than v0 and twins),
  /// the vertex whose direction from C_p, projected on the facet plane, makes
  /// the smallest angle with s1 = x(v1) − x(v0). −1 if none.
  [[nodiscard]] int32_t SelectV2(int32_t v0, int32_t v1, const Eigen::Vector3d& cp,
                                 const Eigen::Vector3d& normal, const WorldAccess& world) const;

  /// One cut step (see the file comment). On kExecuted the event is applied
  /// here already and its version is version(); the caller applies it to the
  /// FEM. `world` is only read: new nodes and moves reach the FEM through
  /// the event.
  /// `prepared`: from PrepareCut for the same step, with no cut or
  /// position read in between (else it is ignored and steps 1–2 run here).
  /// `on_separated`: see SeparatedCallback.
  CutOutcome ExecuteCut(const CutStep& step, const WorldAccess& world, const CutParams& params,
                        const PreparedCut* prepared = nullptr, const SeparatedCallback* on_separated = nullptr);

  /// Steps 1–2 of ExecuteCut on the blade's plane, without changing the
  /// mesh (only the step's scratch, so nothing else may use this CutMesh
  /// meanwhile; `world` is only read). Returns early, not valid, once
  /// `cancel` is set.
  PreparedCut PrepareCut(const CutStep& step, const WorldAccess& world, const CutParams& params,
                         const std::atomic<bool>* cancel = nullptr);

  /// Replays a recorded event (splits, then rest moves). Throws InputError
  /// (field "event…") and changes nothing if it does not fit this mesh.
  void ApplyEvent(const TopologyEvent& event);

  /// Checks the surface around `node` is a single closed, consistently
  /// oriented fan with every edge on exactly two surface faces (or that the
  /// node is interior). O(star).
  [[nodiscard]] bool SurfaceManifoldAt(int32_t node) const;

  /// Face-connected components of the tets: label per tet (0, 1, … in order
  /// of the lowest tet id) and their number.
  [[nodiscard]] std::vector<int32_t> ConnectedComponents(int32_t* count = nullptr) const;
  [[nodiscard]] int32_t NumConnectedComponents() const {
    int32_t k = 0;
    (void)ConnectedComponents(&k);
    return k;
  }

 private:
  struct Op {  ///< Journal entry for rollback.
    int32_t tet, from, to;
  };
  enum TetMark : uint8_t { kSlab, kSideKnown, kFlipped, kInStar, kInFlood, kFloodDone, kInSearch, kNumTetMarks };
  struct TetRow {  // 16 bytes: four to a line
    std::array<uint16_t, kNumTetMarks> stamp{};
    int8_t side = 0;  // step 3's side, valid where kSideKnown
  };
  static_assert(sizeof(TetRow) == 16);
  // MoveTetsToCopy's set of moving tets shares kInSearch's stamps: the
  // remeshing move's search runs only after every split of a step.
  static constexpr TetMark kMoving = kInSearch;
  using TetMarks = StampRows<TetRow, kNumTetMarks>;
  using NodeMarks = StampRows<internal::NodeScratch, internal::kNumNodeMarks>;

  static size_t Idx(int32_t i) { return static_cast<size_t>(i); }
  /// Face adjacency (recs_[t].neighbour) and surface slots of the tets.
  void BuildFaces();
  [[nodiscard]] std::span<const int32_t> Star(int32_t node) const {
    const StarBlock& b = star_block_[Idx(node)];
    return {star_pool_.data() + b.begin, Idx(b.size)};
  }
  /// Inserts `t` into the star of `node` (sorted), erases it.
  void StarInsert(int32_t node, int32_t t);
  void StarErase(int32_t node, int32_t t);
  /// Twins into a reused buffer (no allocation once warm).
  void TwinsInto(int32_t node, const WorldAccess& world, std::vector<int32_t>& out) const;
  /// The tet other than `t` holding the face of t opposite corner f
  /// (searched in the star of one of the face's nodes), −1 if none.
  [[nodiscard]] int32_t FindFaceMate(int32_t t, int f) const;
  /// Local face of `u` whose nodes are those of local face f of t.
  [[nodiscard]] int MatchingFace(int32_t u, int32_t t, int f) const;

  /// A copy of `node` with room for `star_capacity` tets.
  int32_t AddNodeCopy(int32_t node, int32_t star_capacity = 4);
  void RemoveLastNode();
  void RetargetTet(int32_t t, int32_t from, int32_t to);
  /// Re-points `moved` (distinct tets using `from`) at `to`, a copy with no
  /// tets yet, in one pass (see the definition); journaled per tet.
  void MoveTetsToCopy(std::span<const int32_t> moved, int32_t from, int32_t to);
  /// Attaches local face f of t (just re-pointed) to its mate or the surface.
  void AddFaceTet(int32_t t, int f, bool opened_if_boundary);
  /// Detaches local face f of t; returns the opened flag the face had if
  /// it was a surface face, or true if it was interior (a cut opens it).
  bool RemoveFaceTet(int32_t t, int f);
  int32_t NewSlot(int32_t t, int f, bool opened);
  void FreeSlot(int32_t slot);

  /// ExecuteCut on the blade's plane (`blade_plane`, if a blade is given)
  /// or on the method paper's plane: the numbered steps of the file comment.
  CutOutcome ExecuteCutOnPlane(const CutStep& step, const WorldAccess& world, const CutParams& params,
                               bool blade_plane, const PreparedCut* prepared, const SeparatedCallback* on_separated);
  /// True if `prepared` holds steps 1–2 of this step on the mesh as it is:
  /// same version, and no other step took a new position generation.
  [[nodiscard]] bool PreparedFits(const PreparedCut* prepared, const CutStep& step, bool blade_plane) const;

  // Steps 1–2 (cut_plane.cc).
  /// Asks for the cache lines of the last slab walk's tets and vertices
  /// (walked_tets_, slab_seen_): records, stamp rows, surface slots, stars,
  /// rest and world positions. Consecutive steps of one stroke walk
  /// overlapping slabs, and the FEM steps in between evict them. Changes
  /// nothing.
  void PrefetchLastWalk(const double* xyz) const;
  /// Steps 1–2 of ExecuteCutOnPlane (S into slab_).
  PreparedCut PrepareOnPlane(const CutStep& step, const WorldAccess& world, const CutParams& params,
                             bool blade_plane, const std::atomic<bool>* cancel);
  /// Steps 1–2 take a new position generation (x_cache_ entries go stale).
  void NextPositionGeneration();
  /// Mean world edge length around `node` at `x`, m; none if it has no
  /// edge or the mean is not positive.
  [[nodiscard]] std::optional<double> MeanEdgeLength(int32_t node, const Eigen::Vector3d& x,
                                                     const internal::StepWorld& world) const;
  /// Step 2: the split set S into slab_, snapping P (slab.origin) onto it.
  /// False if cancelled.
  bool CollectSplitSet(const CutStep& step, const internal::StepWorld& world, internal::SweptSlab& slab,
                       const std::atomic<bool>* cancel);
  /// Walks the tets from v1 and v0 through the walk's slab: S into slab_,
  /// every vertex seen with its level into slab_seen_, every tet looked at
  /// into walked_tets_. False if cancelled.
  bool WalkSlab(const CutStep& step, const internal::StepWorld& world, const internal::SweptSlab& slab,
                const std::atomic<bool>* cancel);
  /// v1 and v0 into slab_ where the slab takes them (queued by the walk
  /// whatever their level).
  void AddSlabEnds(const CutStep& step, const internal::SweptSlab& slab);
  /// Moves P parallel to itself onto the vertex of S nearest to it and
  /// updates S. False if cancelled.
  bool SnapPlane(const CutStep& step, const internal::StepWorld& world, internal::SweptSlab& slab,
                 const std::atomic<bool>* cancel);

  // Steps 3–4b (cut_separate.cc): the splits, under the journal.
  /// Starts the journal; no tet is flipped by the fragment guard yet.
  void BeginSeparation(internal::StepState& s);
  /// Stops the journal, rolling the splits back first if `roll_back`.
  void EndSeparation(const internal::StepState& s, bool roll_back);
  /// Step 3: splits every vertex of S (slab_) by the plane sides.
  void SplitByPlaneSides(internal::StepState& s);
  /// Step 3's side of tet `t` (−1 or 1), computed once per pass.
  int8_t Side(internal::StepState& s, int32_t t);
  /// Splits `w` by the plane sides (kPlaneDone); true if it was split.
  bool PlaneSplit(internal::StepState& s, int32_t w);
  /// Queues the vertices whose star or link a split of `w` that moved
  /// `tets` to a copy changed.
  void EnqueueSplit(int32_t w, std::span<const int32_t> tets);
  /// Step 4: false if the step must be rejected.
  bool RemoveSingularities(internal::StepState& s);
  /// Step 4 at one queued vertex: the vertex rule, else the edge rule.
  void VisitVertex(internal::StepState& s, int32_t v);
  /// Step 4's edge rule at `v` for the candidates in nbrs_.
  void ApplyEdgeRule(internal::StepState& s, int32_t v);
  /// True if the surface is manifold at every vertex of the splits' tets.
  [[nodiscard]] bool ManifoldAfterSplits(const TopologyEvent& ev) const;
  /// Step 4b: false if a redo of steps 3–4 must be rejected.
  bool GuardFragments(internal::StepState& s);
  /// The tets of pieces of fewer than min_fragment_tets tets that the
  /// splits cut loose, into fragments_.
  const std::vector<int32_t>& FindFragments(const TopologyEvent& ev, const CutParams& params);

  // Step 5 (cut_remesh.cc).
  /// Step 5: moves the twins of v0 and v1.
  void Remesh(internal::StepState& s);
  /// Moves the twins of `node` (move_twins_) towards world `target`, as far
  /// as the quality rule lets them.
  void MoveTwins(internal::StepState& s, int32_t node, const Eigen::Vector3d& target);
  /// The tets around move_twins_ into move_star_, sorted, unique.
  void GatherMoveStar();
  /// Rest preimage of world `target` (see the file comment, step 5);
  /// `fallback` if no tet is usable.
  Eigen::Vector3d RestPreimage(const internal::StepWorld& world, const Eigen::Vector3d& target,
                               const Eigen::Vector3d& fallback);
  /// Adds to search_ the tets next to move_star_ whose padded world
  /// bounding box holds `target`.
  void AddRingCandidates(const internal::StepWorld& world, const Eigen::Vector3d& target);
  /// Corners of tet `t` in rest or world, with the twins at `moved` if given.
  [[nodiscard]] std::array<Eigen::Vector3d, 4> MoveCorners(const internal::StepWorld& world, int32_t t,
                                                          bool rest_config, const Eigen::Vector3d* moved) const;
  /// Step 5's quality rule for move_star_[i] with the twins at `moved`
  /// (rest or world); `floor_quality` is cubed, as mesh::MeanRatioCubed.
  bool KeepsQuality(const internal::StepWorld& world, size_t i, bool rest_config, const Eigen::Vector3d& moved,
                    double floor_quality);

  /// Step 6 (cut_step.cc): completes the event and applies its version.
  void FinishEvent(internal::StepState& s);

  /// Splits `node` so that `moved` (subset of its tets) use a new copy.
  int32_t SplitNode(int32_t node, std::span<const int32_t> moved, TopologyEvent* event);
  /// Face-connected groups of the star of `node` into group_tets_ (group g
  /// is [group_begin_[g], group_begin_[g + 1]), groups in order of their
  /// lowest tet, tets ascending); returns the number of groups.
  int32_t StarGroups(int32_t node);
  /// True if the star of `node` is one face-connected group (StarGroups
  /// would return ≤ 1), without building the groups. O(star).
  [[nodiscard]] bool StarIsOneGroup(int32_t node);
  /// The node's link in the surface into link_: one directed edge p → q per
  /// surface triangle (node, p, q), outward. O(star).
  void BuildLink(int32_t node) const;
  /// True if link_ is one cycle through all its edges (false if empty).
  [[nodiscard]] bool LinkIsOneCycle() const;
  /// Number of face-connected groups of the tets around edge (a, b).
  [[nodiscard]] int EdgeGroupCount(int32_t a, int32_t b);
  void Rollback(size_t journal_mark, int32_t node_mark);

  std::vector<Eigen::Vector3d> rest_;            // #N, m
  // Per tet, in one 32-byte record: its nodes and its face adjacency,
  // neighbour[f] = the tet across local face f (opposite corner f), −1 on
  // the surface (a flat table, O(1) per face, no hashing). Together because
  // a cut step reads both for every tet it visits, on caches the FEM steps
  // in between have evicted: one line instead of two. slot_[t][f] is the
  // face's surface slot, −1 if interior (read only where the surface
  // changes).
  struct alignas(32) TetRecord {
    std::array<int32_t, 4> nodes;
    std::array<int32_t, 4> neighbour;
  };
  std::vector<TetRecord> recs_;                    // #T
  std::vector<std::array<int32_t, 4>> slot_;       // #T×4
  // Node → its tets, ascending: one pool with a block per node (CSR with
  // slack) instead of a vector per node, so a node's star is one load away
  // from its block record and the stars of nodes with nearby ids lie
  // nearby (a cut step walks a few dozen neighbouring nodes' stars). A
  // block that outgrows its capacity moves to the end of the pool.
  struct StarBlock {
    int32_t begin = 0, size = 0, capacity = 0;
  };
  std::vector<StarBlock> star_block_;            // #N
  std::vector<int32_t> star_pool_;
  std::vector<int32_t> origin_;                  // #N
  std::vector<std::vector<int32_t>> copies_;     // #N_uncut: origin → its copies, ascending
  std::vector<SurfaceFace> surface_;
  std::vector<int32_t> free_slots_;
  int32_t num_surface_ = 0;
  uint64_t version_ = 0;
  std::vector<Op> journal_;
  bool journaling_ = false;
  std::vector<int32_t> changed_slots_;
  bool track_slots_ = false;

  // Scratch of a cut step, cleared, never shrunk (no allocation once warm).
  std::vector<int32_t> ds_parent_, ds_label_, ds_root_label_;
  std::vector<int32_t> group_tets_, group_begin_, around_;
  mutable std::vector<std::pair<int32_t, int32_t>> link_;
  mutable std::vector<int32_t> heads_;
  TetMarks tet_marks_;                       // side valid where kSideKnown
  std::vector<int32_t> work_, negative_, nbrs_, flood_, fragments_, slab_, slab_queue_;
  std::vector<int32_t> star_queue_, search_;
  std::vector<std::pair<int32_t, int>> slab_seen_;  // vertex, slab level
  std::vector<int32_t> walked_tets_;                // the tets the last walk looked at
  // Remeshing move: the twins, their star, its qualities before the move.
  std::vector<int32_t> move_twins_, move_star_;
  std::vector<double> q_rest_, q_world_;
  // Node stamp sets (kLinkOk: nodes whose last visit in the singularity
  // pass found their surface link empty or one cycle).
  NodeMarks node_marks_;
  // World positions read during one step from a world without packed
  // positions (the FEM's float state, through a virtual call), valid where
  // their generation is pos_generation_ (a new one every step).
  std::vector<internal::CachedPosition> x_cache_;
  uint32_t pos_generation_ = 0;
  // Per uncut node: its uncut star is face-connected around it (one group).
  // Then a vertex with no surface face through it cannot have k > 1 star
  // groups (see StarIsOneGroup), and the singularity pass skips it.
  std::vector<uint8_t> star_connected0_;
};

/// Face-connected components of any tet list (two tets are connected when
/// they share a face): label per tet, 0, 1, … in order of the lowest tet id.
/// O(T) with a hash of sorted face keys.
std::vector<int32_t> ConnectedComponents(const mesh::Tets& tets, int32_t* count = nullptr);

}  // namespace cutsim::cutting
