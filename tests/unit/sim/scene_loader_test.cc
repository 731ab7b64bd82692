#include "common/sim/scene_loader.h"

#include <filesystem>
#include <string>

#include <gtest/gtest.h>

#include "common/core/error.h"

namespace cutsim::sim {
namespace {

const char* kMinimal = R"pb(
name: "t"
mesh { box { min { x: 0 y: 0 z: 0 } max { x: 0.1 y: 0.02 z: 0.02 } nx: 10 ny: 2 nz: 2 } }
materials { young_poisson { youngs_modulus: 20000 poisson_ratio: 0.45 } density: 1000 }
)pb";

std::string ErrorOf(const std::string& text) {
  try {
    ParseScene(text, "scene.pbtxt", ".");
  } catch (const InputError& e) {
    return e.what();
  }
  return "";
}

TEST(SceneLoaderTest, MinimalSceneGetsDefaults) {
  const LoadedScene s = ParseScene(kMinimal, "scene.pbtxt", ".");
  EXPECT_EQ(s.scene.name(), "t");
  EXPECT_DOUBLE_EQ(s.scene.time_step().safety_factor(), 0.85);
  EXPECT_DOUBLE_EQ(s.scene.time_step().frame_dt(), 0.01);
  EXPECT_DOUBLE_EQ(s.scene.mesh().scale(), 1.0);
}

TEST(SceneLoaderTest, DeviceWorkspaceIsChecked) {
  EXPECT_NE(ErrorOf(std::string(kMinimal) + "haptics { device_scale: -1 }\n").find("haptics.device_scale"),
            std::string::npos);
  EXPECT_NE(ErrorOf(std::string(kMinimal) + "haptics { device_offset { y: inf } }\n").find("haptics.device_offset.y"),
            std::string::npos);
  EXPECT_EQ(ErrorOf(std::string(kMinimal) + "haptics { device_scale: 0.5 device_offset { x: 0.01 } }\n"), "");
}

TEST(SceneLoaderTest, SyntaxErrorNamesLineAndColumn) {
  const std::string text = std::string(kMinimal) + "\ngravity { x: 0 y: oops }\n";
  const std::string err = ErrorOf(text);
  EXPECT_NE(err.find("scene.pbtxt:6:"), std::string::npos) << err;
}

TEST(SceneLoaderTest, UnknownFieldIsAnError) {
  const std::string err = ErrorOf(std::string(kMinimal) + "gravitee { x: 1 }\n");
  EXPECT_NE(err.find("scene.pbtxt:5:"), std::string::npos) << err;
  EXPECT_NE(err.find("gravitee"), std::string::npos) << err;
}

struct BadCase {
  const char* name;
  std::string text;
  const char* field;
};

TEST(SceneLoaderTest, BadValuesNameTheField) {
  const std::string mesh =
      "mesh { box { min { x: 0 y: 0 z: 0 } max { x: 1 y: 1 z: 1 } nx: 1 ny: 1 nz: 1 } }\n";
  const std::string mat = "materials { lame { lambda: 1 mu: 1 } density: 1000 }\n";
  const BadCase cases[] = {
      {"no mesh", mat, "mesh"},
      {"no material", mesh, "materials"},
      {"negative density", mesh + "materials { lame { lambda: 1 mu: 1 } density: -1 }", "materials[0].density"},
      {"poisson 0.5", mesh + "materials { young_poisson { youngs_modulus: 1 poisson_ratio: 0.5 } density: 1 }",
       "materials[0].young_poisson.poisson_ratio"},
      {"nan gravity", mesh + mat + "gravity { x: nan }", "gravity.x"},
      {"box inverted",
       "mesh { box { min { x: 1 y: 0 z: 0 } max { x: 0 y: 1 z: 1 } nx: 1 ny: 1 nz: 1 } }\n" + mat, "mesh.box"},
      {"zeta out of range", mesh + mat + "cutting { enabled: true alpha: 1 kappa: 1 zeta: 3 }", "cutting.zeta"},
      {"safety > 1", mesh + mat + "time_step { safety_factor: 2 }", "time_step.safety_factor"},
      {"negative force tolerance", mesh + mat + "time_step { implicit { force_tolerance: -1 } }",
       "time_step.implicit.force_tolerance"},
      {"linear tolerance 1", mesh + mat + "time_step { implicit { linear_tolerance: 1 } }",
       "time_step.implicit.linear_tolerance"},
      {"absurd newton cap", mesh + mat + "time_step { implicit { max_newton_iterations: 1000000 } }",
       "time_step.implicit.max_newton_iterations"},
      {"settle in float", mesh + mat + "settle: true time_step { precision: PRECISION_FLOAT }", "settle"},
      {"unknown element", mesh + mat + "element: 7", "element"},
      {"keyframes not increasing",
       mesh + mat + "tool { keyframes { t: 1 } keyframes { t: 1 } }", "tool.keyframes[1].t"},
      {"plane normal zero", mesh + mat + "boundary { plane { } }", "boundary[0].plane.normal"},
  };
  for (const auto& c : cases) {
    const std::string err = ErrorOf(c.text);
    EXPECT_NE(err.find(std::string("scene.pbtxt: ") + c.field), std::string::npos)
        << c.name << ": " << err;
  }
}

TEST(SceneLoaderTest, MissingFileNamesIt) {
  try {
    LoadScene("/nonexistent/x.pbtxt");
    FAIL();
  } catch (const InputError& e) {
    EXPECT_NE(std::string(e.what()).find("/nonexistent/x.pbtxt"), std::string::npos);
  }
}

TEST(SceneLoaderTest, ShippedScenesLoad) {
  const std::filesystem::path dir = std::filesystem::path(CUTSIM_SOURCE_DIR) / "scenes";
  if (!std::filesystem::exists(dir)) GTEST_SKIP() << "no scenes/ folder yet";
  int n = 0;
  for (const auto& entry : std::filesystem::directory_iterator(dir)) {
    if (entry.path().extension() != ".pbtxt") continue;
    EXPECT_NO_THROW(LoadScene(entry.path())) << entry.path();
    ++n;
  }
  EXPECT_GT(n, 0);
}

}  // namespace
}  // namespace cutsim::sim
