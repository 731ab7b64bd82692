// The device workspace a scene sets (haptics.device_scale/device_offset),
// and what the trainee page draws of the scene (the planned incision, the
// blade), as cutsim-haptic --scene reads them.
#include <fstream>
#include <string>

#include <gtest/gtest.h>

#include "common/core/error.h"
#include "haptic_client/scene_haptics.h"

namespace cutsim::haptic_client {
namespace {

std::string WriteScene(const std::string& name, const std::string& text) {
  const std::string path = ::testing::TempDir() + name;
  std::ofstream(path) << text;
  return path;
}

TEST(SceneWorkspace, ReadsScaleAndOffset) {
  const std::string path = WriteScene("ws_ok.pbtxt",
                                      "name: \"x\"\nhaptics { max_force: 8 device_scale: 0.5 "
                                      "device_offset { x: 0.01 z: -0.02 } }\n");
  const SceneWorkspace w = ReadSceneWorkspace(path);
  EXPECT_EQ(w.scale, 0.5);
  EXPECT_EQ(w.offset, Eigen::Vector3d(0.01, 0.0, -0.02));
}

TEST(SceneWorkspace, DefaultsToIdentity) {
  const SceneWorkspace w = ReadSceneWorkspace(WriteScene("ws_none.pbtxt", "name: \"x\"\n"));
  EXPECT_EQ(w.scale, 1.0);
  EXPECT_EQ(w.offset, Eigen::Vector3d::Zero());
}

TEST(SceneWorkspace, ShippedLigamentSceneParses) {
  EXPECT_EQ(ReadSceneWorkspace(CUTSIM_SOURCE_DIR "/scenes/ligament.pbtxt").scale, 1.0);
}

TEST(SceneWorkspace, BadValuesAndSyntaxNameTheFileAndField) {
  const std::string bad = WriteScene("ws_bad.pbtxt", "haptics { device_scale: -2 }\n");
  try {
    (void)ReadSceneWorkspace(bad);
    FAIL() << "negative scale accepted";
  } catch (const InputError& e) {
    EXPECT_NE(std::string(e.what()).find("haptics.device_scale"), std::string::npos) << e.what();
    EXPECT_NE(std::string(e.what()).find(bad), std::string::npos) << e.what();
  }
  const std::string broken = WriteScene("ws_syntax.pbtxt", "name: \"x\"\nhaptics { device_scale: oops }\n");
  try {
    (void)ReadSceneWorkspace(broken);
    FAIL() << "syntax error accepted";
  } catch (const InputError& e) {
    EXPECT_NE(std::string(e.what()).find(broken + ":2:"), std::string::npos) << e.what();
  }
}

TEST(SceneWorkspace, ReadsThePlanAndTheBladeForThePage) {
  const SceneWorkspace w = ReadSceneWorkspace(CUTSIM_SOURCE_DIR "/scenes/ligament.pbtxt");
  ASSERT_EQ(w.planned_incision.size(), 2u);
  EXPECT_EQ(w.planned_incision[0], Eigen::Vector3d(0.015, -0.004, -0.004));
  EXPECT_EQ(w.blade_length, 0.02);
  const std::string far = WriteScene("ws_far.pbtxt",
                                     "planned_incision { points { x: 0 } points { x: 1e300 } depth: 0.001 }\n");
  try {
    (void)ReadSceneWorkspace(far);
    FAIL() << "a plan point at 1e300 m was accepted";
  } catch (const InputError& e) {
    EXPECT_NE(std::string(e.what()).find("planned_incision.points[1]"), std::string::npos) << e.what();
  }
}

}  // namespace
}  // namespace cutsim::haptic_client
