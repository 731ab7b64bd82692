// DisjointSets (common/core/disjoint_sets.h) against a brute-force closure
// of random unions: the same classes, compact labels numbered in order of
// first appearance, roots at the smallest id, buffers reused across resets.
#include <algorithm>
#include <cstddef>
#include <cstdint>
#include <numeric>
#include <random>
#include <utility>
#include <vector>

#include <gtest/gtest.h>

#include "common/core/disjoint_sets.h"

namespace cutsim {
namespace {

using Pairs = std::vector<std::pair<int32_t, int32_t>>;

// The class of each id under the closure of `unions`, named by its smallest
// id: every id starts as its own name and takes the smaller name across each
// union until nothing changes (no union–find in the reference).
std::vector<int32_t> ReferenceClasses(size_t n, const Pairs& unions) {
  std::vector<int32_t> name(n);
  std::iota(name.begin(), name.end(), 0);
  for (bool changed = true; changed;) {
    changed = false;
    for (const auto& [a, b] : unions) {
      int32_t& na = name[static_cast<size_t>(a)];
      int32_t& nb = name[static_cast<size_t>(b)];
      if (na != nb) {
        na = nb = std::min(na, nb);
        changed = true;
      }
    }
  }
  return name;
}

Pairs RandomUnions(std::mt19937& rng, size_t n, size_t count) {
  std::uniform_int_distribution<int32_t> id(0, static_cast<int32_t>(n) - 1);
  Pairs unions(count);
  for (auto& [a, b] : unions) {
    a = id(rng);
    b = id(rng);
  }
  return unions;
}

// The properties of Label's output for the classes `reference`, given the
// number of sets `count` it returned.
void ExpectLabelsOf(const std::vector<int32_t>& reference, const std::vector<int32_t>& labels, int32_t count) {
  const size_t n = reference.size();
  ASSERT_EQ(labels.size(), n);
  // Same classes: two ids share a label exactly when they share a class.
  for (size_t i = 0; i < n; ++i)
    for (size_t j = 0; j < n; ++j)
      ASSERT_EQ(labels[i] == labels[j], reference[i] == reference[j]) << "ids " << i << " and " << j;
  // Compact, in order of first appearance: scanning the ids upwards, each
  // label not seen before is the number of labels seen so far.
  int32_t seen = 0;
  for (size_t i = 0; i < n; ++i) {
    ASSERT_GE(labels[i], 0);
    ASSERT_LE(labels[i], seen) << "id " << i << " has a label beyond the next new one";
    if (labels[i] == seen) ++seen;
  }
  EXPECT_EQ(count, seen);
  std::vector<int32_t> names = reference;
  std::sort(names.begin(), names.end());
  EXPECT_EQ(count, std::unique(names.begin(), names.end()) - names.begin());
}

TEST(DisjointSets, RandomUnionsGiveTheClosureWithLabelsInOrderOfFirstAppearance) {
  std::mt19937 rng(20260);
  DisjointSets sets;  // one object for every case: Reset reuses its buffers
  std::vector<int32_t> labels;
  for (int trial = 0; trial < 200; ++trial) {
    const size_t n = std::uniform_int_distribution<size_t>(1, 60)(rng);
    // From no unions (all singletons) to about 2n (one or a few classes).
    const size_t count = std::uniform_int_distribution<size_t>(0, 2 * n)(rng);
    const Pairs unions = RandomUnions(rng, n, count);
    sets.Reset(n);
    for (const auto& [a, b] : unions) sets.Union(a, b);
    const std::vector<int32_t> reference = ReferenceClasses(n, unions);
    ASSERT_EQ(sets.size(), n);
    for (size_t i = 0; i < n; ++i)
      ASSERT_EQ(sets.Find(static_cast<int32_t>(i)), reference[i]) << "the root is the smallest id of the class";
    const int32_t k = sets.Label(&labels);
    SCOPED_TRACE(::testing::Message() << "trial " << trial << ", n " << n << ", unions " << count);
    ExpectLabelsOf(reference, labels, k);
  }
}

TEST(DisjointSets, LabelsDependOnThePartitionOnly) {
  // The same unions in another order and with their ends swapped: the
  // roots may be reached along other paths, the labels are the same.
  std::mt19937 rng(7);
  const size_t n = 40;
  Pairs unions = RandomUnions(rng, n, 30);
  DisjointSets forward(n);
  for (const auto& [a, b] : unions) forward.Union(a, b);
  std::vector<int32_t> first;
  const int32_t k = forward.Label(&first);
  std::shuffle(unions.begin(), unions.end(), rng);
  DisjointSets shuffled(n);
  for (const auto& [a, b] : unions) shuffled.Union(b, a);
  std::vector<int32_t> second;
  EXPECT_EQ(shuffled.Label(&second), k);
  EXPECT_EQ(second, first);
}

TEST(DisjointSets, ResetMakesSingletonsAgain) {
  DisjointSets sets(5);
  sets.Union(0, 4);
  sets.Union(1, 2);
  std::vector<int32_t> labels;
  EXPECT_EQ(sets.Label(&labels), 3);
  EXPECT_EQ(labels, (std::vector<int32_t>{0, 1, 1, 2, 0}));
  for (const size_t n : {size_t{3}, size_t{8}, size_t{0}}) {
    sets.Reset(n);
    std::vector<int32_t> singletons(n);
    std::iota(singletons.begin(), singletons.end(), 0);
    EXPECT_EQ(sets.Label(&labels), static_cast<int32_t>(n));
    EXPECT_EQ(labels, singletons) << "n " << n;
  }
}

}  // namespace
}  // namespace cutsim
