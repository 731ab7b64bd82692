#include "common/sim/debris.h"

#include <algorithm>
#include <utility>

#include "common/core/error.h"

namespace cutsim::sim {

DebrisTracker::DebrisTracker(std::vector<double> element_mass, double total_mass, Limits limits)
    : element_mass_(std::move(element_mass)),
      limit_(limits.mass_fraction * total_mass),
      max_tets_(limits.max_tets),
      debris_(element_mass_.size(), 0),
      stamp_of_(element_mass_.size(), 0) {}

void DebrisTracker::Reset(const cutting::CutMesh& cut) {
  CUTSIM_CHECK(static_cast<size_t>(cut.num_tets()) == element_mass_.size(), "DebrisTracker: tet count");
  std::fill(debris_.begin(), debris_.end(), uint8_t{0});
  num_debris_ = 0;
  int32_t count = 0;
  const std::vector<int32_t> label = cut.ConnectedComponents(&count);
  if (count <= 1) return;
  std::vector<double> mass(static_cast<size_t>(count), 0.0);
  std::vector<int32_t> size(static_cast<size_t>(count), 0);
  for (size_t t = 0; t < label.size(); ++t) {
    mass[static_cast<size_t>(label[t])] += element_mass_[t];
    ++size[static_cast<size_t>(label[t])];
  }
  for (size_t t = 0; t < label.size(); ++t) {
    const auto c = static_cast<size_t>(label[t]);
    debris_[t] = mass[c] < limit_ && size[c] < max_tets_ ? 1 : 0;
    num_debris_ += debris_[t];
  }
}

void DebrisTracker::Update(const cutting::CutMesh& cut, const cutting::TopologyEvent& event,
                           std::vector<int32_t>* flagged) {
  if (event.splits.empty()) return;  // moves only: no piece can come loose
  if (stamp_ > 0xF0000000u) {        // wrap-around guard, once in billions of floods
    std::fill(stamp_of_.begin(), stamp_of_.end(), 0u);
    stamp_ = 0;
  }
  const uint32_t first_stamp = stamp_ + 1;
  for (const cutting::Split& split : event.splits) {
    for (const int32_t t : split.tets) FloodFrom(cut, t, first_stamp, flagged);
    for (const int32_t t : cut.node_tets(split.node)) FloodFrom(cut, t, first_stamp, flagged);
  }
}

// One flood, stopped once its piece weighs the limit or holds max_tets
// tets: O(max_tets). It also stops, as big, on reaching a tet an earlier
// flood of this cut (stamp ≥ first_stamp) reached: that flood was big (a
// small one took its whole piece, which would then hold `start`), and so is
// this piece. After a cut the tets around the slit are usually one piece:
// the first flood walks max_tets tets and the others stop within a few,
// instead of max_tets each.
void DebrisTracker::FloodFrom(const cutting::CutMesh& cut, int32_t start, uint32_t first_stamp,
                              std::vector<int32_t>* flagged) {
  const auto s = static_cast<size_t>(start);
  if (debris_[s] != 0 || stamp_of_[s] >= first_stamp) return;  // debris already, or flooded this cut
  const uint32_t mark = ++stamp_;
  flood_.clear();
  flood_.push_back(start);
  stamp_of_[s] = mark;
  double mass = 0.0;
  for (size_t i = 0; i < flood_.size(); ++i) {
    const int32_t t = flood_[i];
    mass += element_mass_[static_cast<size_t>(t)];
    if (mass >= limit_ || static_cast<int32_t>(i) + 1 >= max_tets_) return;
    for (int f = 0; f < 4; ++f) {
      const int32_t u = cut.Neighbour(t, f);
      if (u < 0) continue;
      const uint32_t seen = stamp_of_[static_cast<size_t>(u)];
      if (seen == mark) continue;
      if (seen >= first_stamp) return;  // an earlier (big) flood's piece
      stamp_of_[static_cast<size_t>(u)] = mark;
      flood_.push_back(u);
    }
  }
  for (const int32_t t : flood_) {
    debris_[static_cast<size_t>(t)] = 1;
    ++num_debris_;
    if (flagged != nullptr) flagged->push_back(t);
  }
}

}  // namespace cutsim::sim
