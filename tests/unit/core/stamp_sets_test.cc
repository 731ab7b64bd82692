// StampRows (common/core/stamp_sets.h): O(1) clears that survive the
// stamps wrapping.
#include <array>
#include <cstdint>

#include <gtest/gtest.h>

#include "common/core/stamp_sets.h"

namespace cutsim {
namespace {

TEST(StampRows, SetsClearInOneStepAndSurviveTheStampWrapping) {
  // 16-bit stamps wrap after 65 535 clears of a set. A stale stamp must not
  // come back into the set when the generation passes its value again, and
  // the other sets of the rows keep their members.
  struct Row {
    std::array<uint16_t, 2> stamp{};
  };
  StampRows<Row, 2> sets;
  EXPECT_TRUE(sets.Insert(0, 3));
  EXPECT_FALSE(sets.Insert(0, 3));
  EXPECT_TRUE(sets.Insert(1, 3));
  EXPECT_TRUE(sets.Contains(0, 3));
  EXPECT_FALSE(sets.Contains(0, 4));
  sets.Clear(0);
  EXPECT_FALSE(sets.Contains(0, 3));
  EXPECT_TRUE(sets.Contains(1, 3));
  EXPECT_TRUE(sets.Insert(0, 7));
  // Clear set 0 until its generation has gone once round all 65 535 values
  // (0 is never one): without the reset at the wrap, 7 would be back in it.
  for (int i = 0; i < 65535; ++i) {
    sets.Clear(0);
    ASSERT_FALSE(sets.Contains(0, 7)) << "after " << i + 1 << " clears";
  }
  EXPECT_TRUE(sets.Contains(1, 3)) << "set 1 keeps its member";
  const auto view = sets.View(0);
  EXPECT_TRUE(view.Insert(7));
  EXPECT_FALSE(view.Insert(7));
  EXPECT_TRUE(sets.Contains(0, 7));
  sets.Erase(0, 7);
  EXPECT_FALSE(sets.Contains(0, 7));
}

}  // namespace
}  // namespace cutsim
