// The randomized stroke suite (tests/support/stroke_suite.h) in short, on
// the block: straight draws, sawing and plunges with a tilted blade at
// random speeds; after every cut frame the run is ok, the mesh valid and
// the mass unchanged. The bench runs 100 strokes on each shipped scene.
#include <string>

#include <gtest/gtest.h>

#include "common/core/log.h"
#include "tests/support/stroke_suite.h"

namespace cutsim::support::strokes {
namespace {

TEST(StrokeSuite, RandomStrokesOnTheBlockNeitherStopNorBreakIt) {
  InitLogging("stroke_suite_test", "error");
  const SuiteResult r = RunStrokes(std::string(CUTSIM_SOURCE_DIR) + "/scenes/block.pbtxt", 6, 39, 1);
  EXPECT_EQ(r.strokes, 6);
  EXPECT_EQ(r.stopped, 0) << r.first_failure;
  EXPECT_EQ(r.invalid_meshes, 0) << r.first_failure;
  EXPECT_EQ(r.mass_changes, 0) << r.first_failure;
  EXPECT_GT(r.cut_frames, 0);  // the strokes cut, so the checks ran
}

}  // namespace
}  // namespace cutsim::support::strokes
