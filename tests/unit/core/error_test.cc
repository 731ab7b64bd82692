#include "common/core/error.h"

#include <gtest/gtest.h>

namespace cutsim {
namespace {

TEST(SourceRefTest, FormatsEveryPartThatIsPresent) {
  EXPECT_EQ((SourceRef{.file = "a.msh", .line = 12, .column = 3, .field = "tets"}).ToString(),
            "a.msh:12:3: tets");
  EXPECT_EQ((SourceRef{.file = "a.msh"}).ToString(), "a.msh");
  EXPECT_EQ((SourceRef{.line = 4}).ToString(), "line 4");
  EXPECT_EQ((SourceRef{.field = "material.density"}).ToString(), "material.density");
  EXPECT_EQ(SourceRef{}.ToString(), "<input>");
}

TEST(InputErrorTest, WhatNamesSourceAndMessage) {
  try {
    ThrowInputError({.file = "scene.pbtxt", .line = 7, .field = "gravity"}, "not finite");
    FAIL() << "no throw";
  } catch (const InputError& e) {
    EXPECT_STREQ(e.what(), "scene.pbtxt:7: gravity: not finite");
    EXPECT_EQ(e.source().file, "scene.pbtxt");
    EXPECT_EQ(e.message(), "not finite");
  }
}

TEST(InputErrorTest, FileErrorNamesFile) {
  EXPECT_THROW(ThrowFileError("missing.msh", "cannot open"), InputError);
}

TEST(CheckDeathTest, AbortsWithLocation) {
  EXPECT_DEATH(CUTSIM_CHECK(1 + 1 == 3, "arithmetic"), "invariant failed: 1 \\+ 1 == 3: arithmetic");
}

}  // namespace
}  // namespace cutsim
