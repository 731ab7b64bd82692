#pragma once
/// @file
/// The cut complex: rest positions, tets, the abstract simplicial complex
/// (node → incident tets, face → tets) and the boundary surface with a
/// per-face "opened by a cut" flag, all maintained incrementally by the
/// primitives a cut uses (copy a node with some of its tets, move a rest
/// position, roll a journal of retargets back). World positions belong to
/// the FEM and are read through `WorldAccess`.
///
/// `CutMesh` is what the rest of the simulator reads (the sim's surface,
/// debris and checkpoints, the debrief, tests). The cut step that decides
/// which nodes to split and where to move them is `CutStepper`
/// (cut_stepper.h), which changes a `CutMesh` through the primitives below
/// and keeps its own scratch.

#include <array>
#include <cstdint>
#include <span>
#include <utility>
#include <vector>

#include <Eigen/Core>

#include "common/core/stamp_sets.h"
#include "common/cutting/topology_event.h"
#include "common/cutting/world_access.h"
#include "common/mesh/tet_mesh.h"

namespace cutsim::cutting {

/// Surface face: local face `local_face` (opposite that corner) of `tet`.
struct SurfaceFace {
  int32_t tet = -1;
  int8_t local_face = -1;
  bool opened = false;  ///< Exposed by a cut (interior in the uncut mesh).
  bool alive = false;   ///< Slot in use.
};

/// A node's link in the surface: one directed edge p → q per surface
/// triangle (node, p, q), outward.
using SurfaceLink = std::vector<std::pair<int32_t, int32_t>>;

class CutMesh {
 public:
  /// Builds the complex and surface of `mesh` (positively oriented tets, as
  /// after ValidateTetMesh). `node_capacity` reserves room for copies
  /// (0: 2·N). O(N + T).
  explicit CutMesh(const mesh::TetMesh& mesh, int32_t node_capacity = 0);

  // ---- Topology and rest positions ------------------------------------------

  [[nodiscard]] int32_t num_nodes() const { return static_cast<int32_t>(rest_.size()); }
  [[nodiscard]] int32_t num_tets() const { return static_cast<int32_t>(recs_.size()); }
  /// Nodes the complex has room for without reallocating (copies included).
  [[nodiscard]] int32_t node_capacity() const { return static_cast<int32_t>(rest_.capacity()); }
  /// Topology version: number of events applied (0 for the uncut mesh).
  [[nodiscard]] uint64_t version() const { return version_; }
  [[nodiscard]] const Eigen::Vector3d& rest(int32_t node) const { return rest_[Idx(node)]; }
  [[nodiscard]] const std::array<int32_t, 4>& tet(int32_t t) const { return recs_[Idx(t)].nodes; }
  /// Tets using `node`, ascending. Valid until the next topology change.
  [[nodiscard]] std::span<const int32_t> node_tets(int32_t node) const {
    const StarBlock& b = star_block_[Idx(node)];
    return {star_pool_.data() + b.begin, Idx(b.size)};
  }
  /// The uncut-mesh node this one descends from (itself for original nodes).
  [[nodiscard]] int32_t origin(int32_t node) const { return origin_[Idx(node)]; }
  /// The tet across local face `f` of tet `t`, −1 if that face is on the
  /// surface. O(1).
  [[nodiscard]] int32_t Neighbour(int32_t t, int f) const { return recs_[Idx(t)].neighbour[Idx(f)]; }
  /// The four face neighbours of tet `t` (Neighbour for f = 0…3).
  [[nodiscard]] const std::array<int32_t, 4>& neighbours(int32_t t) const { return recs_[Idx(t)].neighbour; }
  /// Tets sharing the face {a, b, c}: {t0, t1} with −1 for none.
  [[nodiscard]] std::array<int32_t, 2> FaceTets(int32_t a, int32_t b, int32_t c) const;

  /// Rest mesh (copies out).
  [[nodiscard]] mesh::TetMesh RestMesh() const;
  [[nodiscard]] mesh::Tets TetsMatrix() const;

  // ---- Surface ----------------------------------------------------------------

  /// Surface slots (some dead); iterate and skip !alive. Stable ids for
  /// renderers while a face lives.
  [[nodiscard]] const std::vector<SurfaceFace>& surface_slots() const { return surface_; }
  [[nodiscard]] int32_t num_surface_faces() const { return num_surface_; }
  /// Surface slot of local face `f` (opposite corner f) of tet `t`, −1 if
  /// the face is interior.
  [[nodiscard]] int32_t SurfaceSlot(int32_t t, int f) const { return slot_[Idx(t)][Idx(f)]; }
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
  /// The link of `node` in the surface into `link` (empty for an interior
  /// node). O(star).
  void SurfaceLinkInto(int32_t node, SurfaceLink& link) const;
  /// True if `link` is one cycle through all its edges (false if empty):
  /// the surface around its node is a single closed, consistently oriented
  /// fan. Reorders `link`; `heads` is scratch. O(k log k) for k edges.
  static bool LinkIsOneCycle(SurfaceLink& link, std::vector<int32_t>& heads);
  /// Checks the surface around `node` is a single closed, consistently
  /// oriented fan with every edge on exactly two surface faces (or that the
  /// node is interior). O(star).
  [[nodiscard]] bool SurfaceManifoldAt(int32_t node) const;

  // ---- Queries ----------------------------------------------------------------

  /// Contact elements for the stress criterion: the tets around `node`
  /// (v_c) plus `facet_tet` if given. Sorted, unique.
  [[nodiscard]] std::vector<int32_t> ContactElements(int32_t node, int32_t facet_tet = -1) const;

  /// Coincident copies of `node` (same origin, same rest and world position),
  /// including `node`, ascending.
  [[nodiscard]] std::vector<int32_t> Twins(int32_t node, const WorldAccess& world) const;
  /// Twins into a reused buffer (no allocation once warm).
  void TwinsInto(int32_t node, const WorldAccess& world, std::vector<int32_t>& out) const;

  /// Eq. (12): among the surface neighbours of v1 (other than v0 and twins),
  /// the vertex whose direction from C_p, projected on the facet plane, makes
  /// the smallest angle with s1 = x(v1) − x(v0). −1 if none.
  [[nodiscard]] int32_t SelectV2(int32_t v0, int32_t v1, const Eigen::Vector3d& cp,
                                 const Eigen::Vector3d& normal, const WorldAccess& world) const;

  /// True if the tets around `node` form one group connected across the
  /// faces through `node`. O(star).
  [[nodiscard]] bool StarIsOneGroup(int32_t node) const;
  /// StarIsOneGroup of the uncut node `node` descends from, in the uncut
  /// mesh. Then a vertex with no surface face through it cannot have more
  /// than one star group (its star's faces are those of the uncut star).
  [[nodiscard]] bool UncutStarIsOneGroup(int32_t node) const {
    return star_connected0_[Idx(origin_[Idx(node)])] != 0;
  }

  /// Face-connected components of the tets: label per tet (0, 1, … in order
  /// of the lowest tet id) and their number.
  [[nodiscard]] std::vector<int32_t> ConnectedComponents(int32_t* count = nullptr) const;
  [[nodiscard]] int32_t NumConnectedComponents() const {
    int32_t k = 0;
    (void)ConnectedComponents(&k);
    return k;
  }

  // ---- Changes ----------------------------------------------------------------

  /// Replays a recorded event (splits, then rest moves). Throws InputError
  /// (field "event…") and changes nothing if it does not fit this mesh.
  void ApplyEvent(const TopologyEvent& event);

  /// Splits `node`: a new copy (the next node id) takes `moved`, distinct
  /// tets of its star, with their faces re-paired and the surface updated.
  /// Appends the split to `event` if given. Returns the copy. O(moved ·
  /// star).
  int32_t SplitNode(int32_t node, std::span<const int32_t> moved, TopologyEvent* event);
  /// Moves the rest position of `node` (a remeshing move), m.
  void SetRest(int32_t node, const Eigen::Vector3d& rest) { rest_[Idx(node)] = rest; }
  /// Starts journaling the splits, so RollBack can undo them; returns the
  /// mark to roll back to.
  size_t BeginJournal();
  /// Undoes the splits journaled since `journal_mark`, removing the copies
  /// from node `node_mark` on. The journal stays on.
  void RollBack(size_t journal_mark, int32_t node_mark);
  /// Stops journaling and drops the entries since `journal_mark`.
  void EndJournal(size_t journal_mark);
  /// Gives `event`, made on this complex by SplitNode and SetRest, the next
  /// topology version, which becomes version().
  void CommitEvent(TopologyEvent& event) { event.version = ++version_; }

  /// Asks for the cache lines a cut step reads of tet `t` (record, surface
  /// slots) or of node `node` (star record, rest position, origin, and with
  /// `star`, the star itself). Changes nothing; ids out of range are
  /// ignored.
  void PrefetchTet(int32_t t) const {
    if (t >= num_tets()) return;
    __builtin_prefetch(&recs_[Idx(t)]);
    __builtin_prefetch(&slot_[Idx(t)]);
  }
  void PrefetchNode(int32_t node) const {
    if (node >= num_nodes()) return;
    __builtin_prefetch(&star_block_[Idx(node)]);
    __builtin_prefetch(&rest_[Idx(node)]);
    __builtin_prefetch(&origin_[Idx(node)]);
  }
  void PrefetchStar(int32_t node) const {
    if (node < num_nodes()) __builtin_prefetch(star_pool_.data() + star_block_[Idx(node)].begin);
  }
  /// As PrefetchTet and PrefetchNode, the records only (a walk's next tets
  /// and vertex, ids known valid).
  void PrefetchTetRecord(int32_t t) const { __builtin_prefetch(&recs_[Idx(t)]); }
  void PrefetchStarRecord(int32_t node) const { __builtin_prefetch(&star_block_[Idx(node)]); }

 private:
  struct Op {  ///< Journal entry for rollback.
    int32_t tet, from, to;
  };
  // Per-tet stamp sets of the complex's own passes: the tets moving to a
  // copy (MoveTetsToCopy, ApplyEvent's check) and StarIsOneGroup's flood.
  enum TetMark : uint8_t { kMoving, kInStar, kNumTetMarks };
  struct TetStamps {
    std::array<uint16_t, kNumTetMarks> stamp{};
  };

  static size_t Idx(int32_t i) { return static_cast<size_t>(i); }
  /// Face adjacency (recs_[t].neighbour) and surface slots of the tets.
  void BuildFaces();
  /// Inserts `t` into the star of `node` (sorted), erases it.
  void StarInsert(int32_t node, int32_t t);
  void StarErase(int32_t node, int32_t t);
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
  // Per uncut node: its uncut star is one face-connected group around it
  // (UncutStarIsOneGroup).
  std::vector<uint8_t> star_connected0_;         // #N_uncut

  // Scratch of the queries and primitives, cleared, never shrunk (no
  // allocation once warm); the const queries that use it are not to be
  // called from two threads at once.
  mutable StampRows<TetStamps, kNumTetMarks> tet_marks_;  // #T
  mutable std::vector<int32_t> star_queue_;
  mutable SurfaceLink link_;
  mutable std::vector<int32_t> heads_;
};

/// Face-connected components of any tet list (two tets are connected when
/// they share a face): label per tet, 0, 1, … in order of the lowest tet id.
/// O(T) with a hash of sorted face keys.
std::vector<int32_t> ConnectedComponents(const mesh::Tets& tets, int32_t* count = nullptr);

}  // namespace cutsim::cutting
