#include "common/sim/debris.h"

#include <algorithm>
#include <utility>

#include "common/core/error.h"

namespace cutsim::sim {

DebrisTracker::DebrisTracker(std::vector<double> element_mass, double total_mass, Limits limits)
    : element_mass_(std::move(element_mass)),
      limit_(limits.mass_fraction * total_mass),
      max_tets_(limits.max_tets),
      debris_(element_mass_.size(), 0) {
  marks_.rows.resize(element_mass_.size());
  // A flood stops at max_tets tets; if that many of the heaviest element
  // weigh less than the limit (a fine mesh: 64 of 100k tets against 1 % of
  // the mass), the mass never stops it first, and the flood need not read
  // the masses (one cold line per tet it walks). The margin covers the
  // rounding of the flood's running sum.
  const double heaviest = element_mass_.empty() ? 0.0 : *std::max_element(element_mass_.begin(), element_mass_.end());
  count_decides_ = static_cast<double>(max_tets_) * heaviest * (1.0 + 1e-9) < limit_;
}

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

void DebrisTracker::Update(const cutting::CutMesh& cut, std::span<const cutting::Split> splits,
                           std::vector<int32_t>* flagged) {
  if (splits.empty()) return;  // moves only: no piece can come loose
  marks_.Clear(kThisCut);
  for (const cutting::Split& split : splits) {
    for (const int32_t t : split.tets) FloodFrom(cut, t, flagged);
    for (const int32_t t : cut.node_tets(split.node)) FloodFrom(cut, t, flagged);
  }
}

// One flood, stopped once its piece weighs the limit or holds max_tets
// tets: O(max_tets). It also stops, as big, on reaching a tet an earlier
// flood of this cut reached: that flood was big (a small one took its
// whole piece, which would then hold `start`), and so is this piece. After
// a cut the tets around the slit are usually one piece: the first flood
// walks max_tets tets and the others stop within a few, instead of
// max_tets each.
void DebrisTracker::FloodFrom(const cutting::CutMesh& cut, int32_t start, std::vector<int32_t>* flagged) {
  if (debris_[static_cast<size_t>(start)] != 0 || marks_.Contains(kThisCut, start)) return;
  marks_.Clear(kThisFlood);
  flood_.clear();
  flood_.push_back(start);
  marks_.Insert(kThisFlood, start);
  marks_.Insert(kThisCut, start);
  double mass = 0.0;
  for (size_t i = 0; i < flood_.size(); ++i) {
    const int32_t t = flood_[i];
    if (!count_decides_) mass += element_mass_[static_cast<size_t>(t)];
    if (mass >= limit_ || static_cast<int32_t>(i) + 1 >= max_tets_) return;
    for (int f = 0; f < 4; ++f) {
      const int32_t u = cut.Neighbour(t, f);
      if (u < 0 || !marks_.Insert(kThisFlood, u)) continue;
      if (!marks_.Insert(kThisCut, u)) return;  // an earlier (big) flood's piece
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
