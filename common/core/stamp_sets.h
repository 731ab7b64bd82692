#pragma once
// Sets of small integer ids cleared in O(1) by a generation stamp, for
// graph walks (cut steps, floods) that must not allocate or clear O(N)
// arrays per pass.

#include <array>
#include <cstddef>
#include <cstdint>
#include <type_traits>
#include <utility>
#include <vector>

namespace cutsim {

/// kSets sets of small integer ids, each cleared in O(1): id i is in set m
/// while rows[i].stamp[m] equals generation[m]. `Row` has `stamp`, an
/// array of kSets unsigned stamps, and may carry other per-id scratch: the
/// sets over one kind of id share a row per id, so an id visited by
/// several passes costs one cache line (cut steps visit a few hundred
/// scattered tets and nodes on caches the FEM steps in between evicted).
/// Grows on demand and never shrinks, so a pass does not allocate once
/// warm. With 16-bit stamps rows stay small (nearby ids share a line) and
/// a set's stamps are reset once in 65 535 clears of it (O(rows)).
template <typename Row, size_t kSets>
struct StampRows {
  // The rows' stamp type: the generation wraps where the stamps do.
  using Stamp = std::remove_cvref_t<decltype(std::declval<Row&>().stamp[0])>;
  static_assert(std::is_unsigned_v<Stamp>);
  std::vector<Row> rows;
  std::array<Stamp, kSets> generation = MakeGenerations();
  void Clear(size_t m) {
    if (++generation[m] == 0) {  // wrap-around
      for (Row& r : rows) r.stamp[m] = 0;
      generation[m] = 1;
    }
  }
  [[nodiscard]] bool Contains(size_t m, int32_t i) const {
    return static_cast<size_t>(i) < rows.size() && rows[static_cast<size_t>(i)].stamp[m] == generation[m];
  }
  /// True if `i` was not in set `m`.
  bool Insert(size_t m, int32_t i) {
    const auto k = static_cast<size_t>(i);
    if (k >= rows.size()) [[unlikely]] Grow(k);
    if (rows[k].stamp[m] == generation[m]) return false;
    rows[k].stamp[m] = generation[m];
    return true;
  }
  /// Set m for a hot loop over ids below rows.size() (no growth check,
  /// the generation and the rows' address held in registers: with the
  /// member functions every stamp store may alias them).
  struct Unchecked {
    Row* rows;
    Stamp generation;
    size_t m;
    bool Insert(int32_t i) const {
      Stamp& s = rows[static_cast<size_t>(i)].stamp[m];
      if (s == generation) return false;
      s = generation;
      return true;
    }
  };
  [[nodiscard]] Unchecked View(size_t m) { return {rows.data(), generation[m], m}; }
  void Erase(size_t m, int32_t i) {
    if (static_cast<size_t>(i) < rows.size()) rows[static_cast<size_t>(i)].stamp[m] = 0;
  }
  // The vector's capacity doubles, so growing one id at a time is
  // amortised O(1); a user can also size `rows` up front.
  [[gnu::noinline]] void Grow(size_t k) { rows.resize(k + 1); }
  static std::array<Stamp, kSets> MakeGenerations() {
    std::array<Stamp, kSets> g{};
    g.fill(Stamp{1});
    return g;
  }
};

}  // namespace cutsim
