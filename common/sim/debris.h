#pragma once
// Debris: pieces a cut has separated that are too small to cut further. The
// blade passes through them (tool_contact.h) instead of pushing a crumb of a
// few tets ahead of it. Kept apart from the Simulation so its incremental
// rule can be checked against the whole-mesh one.

#include <array>
#include <cstdint>
#include <span>
#include <vector>

#include "common/core/stamp_sets.h"
#include "common/cutting/cut_mesh.h"
#include "common/cutting/topology_event.h"

namespace cutsim::sim {

/// Which tets belong to debris: face-connected pieces with less than
/// `mass_fraction` of the body's mass and fewer than `max_tets` tets. A
/// crumb flies because it has few elements (a node's mass comes from its
/// elements, not from its piece), so the element bound is the one that
/// matters at fine resolutions. Pieces never rejoin, so a tet stays debris
/// once it is.
class DebrisTracker {
 public:
  struct Limits {
    double mass_fraction = 0.01;  ///< of the total mass
    int32_t max_tets = 64;
  };

  /// `element_mass`: #T, kg (frozen at load: cuts keep the elements and
  /// their masses). `total_mass`: kg, the body's.
  DebrisTracker(std::vector<double> element_mass, double total_mass, Limits limits);

  /// Flags from the connected components of the whole mesh: at set-up and
  /// after a restore. O(T).
  void Reset(const cutting::CutMesh& cut);

  /// After one cut, whose `splits` `cut` has already applied: floods from
  /// each tet a split moved to a copy and from the tets left on the split
  /// node, and flags the pieces found small. O(touched + max_tets) whatever
  /// the mesh size. Reads only the complex's topology (not positions), so
  /// it may run beside the cut's remeshing moves (SeparatedCallback).
  /// Appends the tets it flags to `flagged` (not cleared).
  /// Allocation-free once the scratch has grown.
  void Update(const cutting::CutMesh& cut, std::span<const cutting::Split> splits, std::vector<int32_t>* flagged);

  [[nodiscard]] bool is_debris(int32_t t) const { return debris_[static_cast<size_t>(t)] != 0; }
  [[nodiscard]] int32_t num_debris_tets() const { return num_debris_; }

 private:
  void FloodFrom(const cutting::CutMesh& cut, int32_t start, std::vector<int32_t>* flagged);

  // Tets reached by any flood of the current cut, and by the current flood.
  enum Mark : uint8_t { kThisCut, kThisFlood, kNumMarks };
  struct Row {
    std::array<uint16_t, kNumMarks> stamp{};
  };

  std::vector<double> element_mass_;  // #T, kg
  double limit_;                      // kg: mass_fraction × total mass
  int32_t max_tets_;
  bool count_decides_ = false;        // max_tets_ of the heaviest tets weigh < limit_: floods skip masses
  std::vector<uint8_t> debris_;       // #T
  int32_t num_debris_ = 0;
  StampRows<Row, kNumMarks> marks_;   // #T rows
  std::vector<int32_t> flood_;        // scratch: the current flood's tets
};

}  // namespace cutsim::sim
