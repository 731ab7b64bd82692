#pragma once
/// @file
/// The cut step: `CutStepper` runs one step of the cut on a `CutMesh`
/// (cut_mesh.h), the complex, which it reads through its queries and
/// changes through its primitives only (SplitNode under a journal,
/// SetRest, CommitEvent). The stepper owns the step's scratch (stamp sets,
/// queues, the world-position cache), so one stepper serves any number of
/// steps without allocating once warm, and the complex stays what other
/// code reads.
///
/// Cut step (method paper §3.2–3.3), `CutStepper::ExecuteCut`; each
/// numbered step below is one function of the same name in cut_plane.cc
/// (1–2), cut_separate.cc (3–4b), cut_remesh.cc (5) and cut_step.cc (6):
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

#include <array>
#include <atomic>
#include <cstdint>
#include <functional>
#include <optional>
#include <span>
#include <utility>
#include <vector>

#include <Eigen/Core>

#include "common/core/disjoint_sets.h"
#include "common/core/stamp_sets.h"
#include "common/cutting/cut_mesh.h"
#include "common/cutting/cut_params.h"
#include "common/cutting/topology_event.h"
#include "common/cutting/world_access.h"

namespace cutsim::cutting {

namespace internal {
/// Per-node scratch of a cut step (see CutStepper::node_marks_): the node
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
/// CutStepper::PrepareCut, e.g. on a second thread while the stress
/// criterion decides whether to cut. Only the stepper that made it reads
/// it; ExecuteCut uses it if it was made for that step on the complex as it
/// is, and ignores it otherwise.
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

/// Runs cut steps (see the file comment) on a CutMesh given per call. Holds
/// no state of the complex between calls but the position generation that
/// ties a PreparedCut to its step; its scratch grows to the largest complex
/// it has served and is reused.
class CutStepper {
 public:
  CutStepper() = default;

  /// One cut step on `mesh` (see the file comment). On kExecuted the event
  /// is applied to `mesh` already and its version is mesh.version(); the
  /// caller applies it to the FEM. `world` is only read: new nodes and
  /// moves reach the FEM through the event.
  /// `prepared`: from PrepareCut of this stepper for the same step on the
  /// same mesh, with no cut or position read in between (else it is
  /// ignored and steps 1–2 run here). `on_separated`: see
  /// SeparatedCallback.
  CutOutcome ExecuteCut(CutMesh& mesh, const CutStep& step, const WorldAccess& world, const CutParams& params,
                        const PreparedCut* prepared = nullptr, const SeparatedCallback* on_separated = nullptr);

  /// Steps 1–2 of ExecuteCut on the blade's plane, without changing `mesh`
  /// (only this stepper's scratch, so nothing else may use the stepper
  /// meanwhile; `mesh` and `world` are only read). Returns early, not
  /// valid, once `cancel` is set.
  PreparedCut PrepareCut(const CutMesh& mesh, const CutStep& step, const WorldAccess& world,
                         const CutParams& params, const std::atomic<bool>* cancel = nullptr);

 private:
  enum TetMark : uint8_t { kSlab, kSideKnown, kFlipped, kInFlood, kFloodDone, kInSearch, kNumTetMarks };
  struct alignas(16) TetRow {  // 16 bytes: four to a line
    std::array<uint16_t, kNumTetMarks> stamp{};
    int8_t side = 0;  // step 3's side, valid where kSideKnown
  };
  static_assert(sizeof(TetRow) == 16);
  using TetMarks = StampRows<TetRow, kNumTetMarks>;
  using NodeMarks = StampRows<internal::NodeScratch, internal::kNumNodeMarks>;

  static size_t Idx(int32_t i) { return static_cast<size_t>(i); }
  /// Makes `mesh` the complex of the call in progress and sizes the
  /// per-tet and per-node scratch for it.
  void Bind(const CutMesh& mesh);
  [[nodiscard]] const CutMesh& mesh() const { return *mesh_; }

  /// ExecuteCut on the blade's plane (`blade_plane`, if a blade is given)
  /// or on the method paper's plane: the numbered steps of the file comment.
  CutOutcome ExecuteCutOnPlane(CutMesh& mesh, const CutStep& step, const WorldAccess& world,
                               const CutParams& params, bool blade_plane, const PreparedCut* prepared,
                               const SeparatedCallback* on_separated);
  /// True if `prepared` holds steps 1–2 of this step on the mesh as it is:
  /// same version, and no other step took a new position generation.
  [[nodiscard]] bool PreparedFits(const PreparedCut* prepared, const CutStep& step, bool blade_plane) const;

  // Steps 1–2 (cut_plane.cc).
  /// Asks for the cache lines of the last slab walk's tets and vertices
  /// (walked_tets_, slab_seen_): the complex's records, stars and rest
  /// positions, the stamp rows, the world positions. Consecutive steps of
  /// one stroke walk overlapping slabs, and the FEM steps in between evict
  /// them. Changes nothing.
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

  // Steps 3–4b (cut_separate.cc): the splits, under the complex's journal.
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
  /// Face-connected groups of the star of `node` into group_tets_ (group g
  /// is [group_begin_[g], group_begin_[g + 1]), groups in order of their
  /// lowest tet, tets ascending); returns the number of groups.
  int32_t StarGroups(int32_t node);
  /// Face-connected groups of `tets` (ascending, each holding a and b):
  /// two join across a face that holds both a and b (a = b: a node's
  /// star); the group of tets[i] in face_group_[i], groups numbered in
  /// order of first appearance. Returns the count.
  int32_t FaceGroups(std::span<const int32_t> tets, int32_t a, int32_t b);
  /// Number of face-connected groups of the tets around edge (a, b).
  [[nodiscard]] int EdgeGroupCount(int32_t a, int32_t b);

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

  /// Step 6 (cut_step.cc): completes the event and gives it its version.
  void FinishEvent(internal::StepState& s);

  // The complex of the call in progress (Bind); read through it, changed
  // through StepState::mesh.
  const CutMesh* mesh_ = nullptr;

  // Scratch of a cut step, cleared, never shrunk (no allocation once warm).
  DisjointSets face_sets_;
  std::vector<int32_t> face_group_, group_fill_;
  std::vector<int32_t> group_tets_, group_begin_, around_;
  SurfaceLink link_;
  std::vector<int32_t> heads_;
  TetMarks tet_marks_;                       // #T; side valid where kSideKnown
  std::vector<int32_t> work_, negative_, nbrs_, flood_, fragments_, slab_, slab_queue_;
  std::vector<int32_t> search_;
  std::vector<std::pair<int32_t, int>> slab_seen_;  // vertex, slab level
  std::vector<int32_t> walked_tets_;                // the tets the last walk looked at
  // Remeshing move: the twins, their star, its qualities before the move.
  std::vector<int32_t> move_twins_, move_star_;
  std::vector<double> q_rest_, q_world_;
  // Node stamp sets (kLinkOk: nodes whose last visit in the singularity
  // pass found their surface link empty or one cycle).
  NodeMarks node_marks_;                     // #N
  // World positions read during one step from a world without packed
  // positions (the FEM's float state, through a virtual call), valid where
  // their generation is pos_generation_ (a new one every step).
  std::vector<internal::CachedPosition> x_cache_;
  uint32_t pos_generation_ = 0;
};

}  // namespace cutsim::cutting
