#pragma once
// Union–find over small integer ids, with labels numbered in order of first
// appearance, for the connected pieces and face groups of a cut complex.

#include <cstddef>
#include <cstdint>
#include <numeric>
#include <utility>
#include <vector>

namespace cutsim {

/// Disjoint sets of the ids 0..n−1 (union–find with path halving). Of two
/// joined roots the smaller id becomes the root, so Find(i) is the smallest
/// id of i's set. Reset keeps the buffers: one object reused for pass after
/// pass (a cut step's face groups) does not allocate once warm.
class DisjointSets {
 public:
  DisjointSets() = default;
  /// Every id of 0..n−1 in a set of its own.
  explicit DisjointSets(size_t n) { Reset(n); }

  /// Makes every id of 0..n−1 a set of its own again; keeps the capacity.
  void Reset(size_t n) {
    parent_.resize(n);
    std::iota(parent_.begin(), parent_.end(), 0);
  }

  /// Number of ids.
  [[nodiscard]] size_t size() const { return parent_.size(); }

  /// The root of i's set: the smallest id in it.
  int32_t Find(int32_t i) {
    while (parent_[Idx(i)] != i) {
      int32_t& p = parent_[Idx(i)];
      p = parent_[Idx(p)];  // path halving
      i = p;
    }
    return i;
  }

  /// Joins the sets of a and b.
  void Union(int32_t a, int32_t b) {
    a = Find(a);
    b = Find(b);
    if (a == b) return;
    if (a < b) std::swap(a, b);
    parent_[Idx(a)] = b;  // the smaller id is the root
  }

  /// Writes to (*labels)[i] the label of i's set, for every id: the sets
  /// numbered 0, 1, … in order of their first appearance in 0..n−1 (that
  /// is, of their smallest ids), so the labels depend on the partition only,
  /// not on the order of the unions. Returns the number of sets.
  int32_t Label(std::vector<int32_t>* labels) {
    const size_t n = parent_.size();
    labels->resize(n);
    root_label_.assign(n, -1);
    int32_t count = 0;
    for (size_t i = 0; i < n; ++i) {
      const size_t r = Idx(Find(static_cast<int32_t>(i)));
      if (root_label_[r] < 0) root_label_[r] = count++;
      (*labels)[i] = root_label_[r];
    }
    return count;
  }

 private:
  static size_t Idx(int32_t i) { return static_cast<size_t>(i); }

  std::vector<int32_t> parent_;
  std::vector<int32_t> root_label_;  // Label's scratch: a root's label or −1
};

}  // namespace cutsim
