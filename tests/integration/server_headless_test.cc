// The headless server as a user runs it: real process, real scene files.
#include <filesystem>
#include <fstream>
#include <string>

#include <gtest/gtest.h>

#include "common/mesh/mesh_io.h"
#include "tests/integration/subprocess.h"

namespace cutsim {
namespace {

using testing::BinPath;
using testing::RunProcess;
using testing::JsonNumber;
using testing::TempDir;
using namespace std::chrono_literals;

std::string Write(const TempDir& dir, const std::string& name, const std::string& text) {
  const std::string path = dir.path() + "/" + name;
  std::ofstream(path) << text;
  return path;
}

const char* kSmallBeam = R"pb(
name: "small-beam"
mesh { box { min { x: 0 y: 0 z: 0 } max { x: 0.05 y: 0.01 z: 0.01 } nx: 10 ny: 2 nz: 2 } }
materials { young_poisson { youngs_modulus: 200000 poisson_ratio: 0.3 } density: 1000 damping_psi: 50 }
boundary { plane { point { x: 0 y: 0 z: 0 } normal { x: 1 y: 0 z: 0 } } }
gravity { z: -9.81 }
)pb";

TEST(ServerHeadlessTest, RunsForDurationAndWritesVtu) {
  TempDir dir;
  const std::string scene = Write(dir, "beam.pbtxt", kSmallBeam);
  const std::string out = dir.path() + "/beam.vtu";
  const auto r = RunProcess({BinPath("cutsim-server"), "--headless", "--scene", scene, "--duration",
                      "0.05", "--out", out, "--no-progress"},
                     120s);
  ASSERT_EQ(r.exit_code, 0) << r.err;
  EXPECT_NEAR(JsonNumber(r.out, "sim_time"), 0.05, 1e-9) << r.out;
  EXPECT_GT(JsonNumber(r.out, "steps"), 0);
  EXPECT_GT(JsonNumber(r.out, "max_displacement"), 0.0);
  EXPECT_GT(JsonNumber(r.out, "tet_steps_per_s"), 0.0);
  EXPECT_EQ(JsonNumber(r.out, "tets"), 10 * 2 * 2 * 6);
  ASSERT_TRUE(std::filesystem::exists(out));
  const mesh::TetMesh m = mesh::ReadMesh(out);
  EXPECT_EQ(m.num_tets(), 10 * 2 * 2 * 6);
}

TEST(ServerHeadlessTest, BadSceneNamesFileAndLine) {
  TempDir dir;
  const std::string scene = Write(dir, "bad.pbtxt", std::string(kSmallBeam) + "\ngravity { z: oops }\n");
  const auto r = RunProcess({BinPath("cutsim-server"), "--headless", "--scene", scene, "--duration", "0.01"}, 60s);
  EXPECT_EQ(r.exit_code, 2);
  EXPECT_NE(r.err.find("bad.pbtxt:8:"), std::string::npos) << r.err;
}

TEST(ServerHeadlessTest, BadFlagsAreRejected) {
  EXPECT_NE(RunProcess({BinPath("cutsim-server"), "--headless", "--scene", "/nonexistent.pbtxt", "--duration", "1"}, 30s).exit_code, 0);
  TempDir dir;
  const std::string scene = Write(dir, "beam.pbtxt", kSmallBeam);
  EXPECT_NE(RunProcess({BinPath("cutsim-server"), "--headless", "--scene", scene, "--duration", "-1"}, 30s).exit_code, 0);
  EXPECT_NE(RunProcess({BinPath("cutsim-server"), "--headless", "--scene", scene, "--precision", "half", "--duration", "1"}, 30s).exit_code, 0);
}

TEST(ServerHeadlessTest, MissingMeshFileNamesIt) {
  TempDir dir;
  const std::string scene = Write(dir, "m.pbtxt", R"pb(
mesh { file: "nothere.msh" }
materials { lame { lambda: 1 mu: 1 } density: 1 }
)pb");
  const auto r = RunProcess({BinPath("cutsim-server"), "--headless", "--scene", scene, "--duration", "0.01"}, 30s);
  EXPECT_EQ(r.exit_code, 2);
  EXPECT_NE(r.err.find("nothere.msh"), std::string::npos) << r.err;
}

}  // namespace
}  // namespace cutsim
