// The block cut end to end: the real server follows
// a scripted scalpel straight across a coarser copy of scenes/block.pbtxt
// and must leave exactly two face-connected parts, no inverted or
// zero-volume tet, the mass unchanged, nothing flying away, and the opened
// faces marked in the .vtu.
#include <cmath>
#include <filesystem>
#include <fstream>
#include <sstream>
#include <string>
#include <vector>

#include <gtest/gtest.h>

#include "common/cutting/cut_mesh.h"
#include "common/mesh/mesh_io.h"
#include "common/mesh/tet_mesh.h"
#include "tests/integration/subprocess.h"

namespace cutsim {
namespace {

using testing::BinPath;
using testing::JsonNumber;
using testing::RunProcess;
using testing::TempDir;
using namespace std::chrono_literals;

void Write(const std::string& path, const std::string& text) { std::ofstream(path) << text; }

// scenes/block.pbtxt with 12 × 6 × 3 cells (3.3 mm) instead of 16 × 8 × 4,
// so the whole 2.4 s path runs in seconds; the blade passes 0.1 mm beside a
// row of nodes (y = 10 mm), as in the full scene.
const char* kBlock = R"pb(
name: "block-test"
mesh { box { min { x: 0 y: 0 z: 0 } max { x: 0.04 y: 0.02 z: 0.01 } nx: 12 ny: 6 nz: 3 } }
materials { name: "tissue" young_poisson { youngs_modulus: 50000 poisson_ratio: 0.4 } density: 1000 damping_psi: 0.5 }
boundary { plane { point { x: 0 y: 0 z: 0 } normal { x: 0 y: 0 z: 1 } } kind: KIND_FIXED }
gravity { z: -9.81 }
time_step { frame_dt: 0.01 }
tool { path_file: "cut.path" blade_length: 0.025 }
cutting { enabled: true alpha: 0.4 kappa: 1.0 zeta: 1.0 critical_stress: 10000 }
)pb";

const char* kPath = R"(# as scenes/block-cut.path
0.00    -0.003 0.0101 -0.0010      0 0 1
2.20    0.043 0.0101 -0.0010       0 0 1
2.40    0.043 0.0101 0.0200        0 0 1
)";

/// Values of the ascii cell array `name` of a cutsim .vtu.
std::vector<double> CellArray(const std::string& vtu, const std::string& name) {
  std::ifstream in(vtu);
  std::stringstream ss;
  ss << in.rdbuf();
  const std::string text = ss.str();
  const size_t at = text.find("Name=\"" + name + "\"");
  if (at == std::string::npos) return {};
  const size_t begin = text.find('>', at) + 1;
  const size_t end = text.find("</DataArray>", begin);
  std::istringstream values(text.substr(begin, end - begin));
  std::vector<double> out;
  for (double v; values >> v;) out.push_back(v);
  return out;
}

TEST(BlockCutTest, StraightCutLeavesTwoSaneParts) {
  TempDir dir;
  const std::string scene = dir.path() + "/block.pbtxt";
  Write(scene, kBlock);
  Write(dir.path() + "/cut.path", kPath);
  const std::string out = dir.path() + "/block.vtu";
  const auto r = RunProcess({BinPath("cutsim-server"), "--headless", "--scene", scene, "--out", out,
                             "--no-progress", "--threads", "1"},
                            170s);
  ASSERT_EQ(r.exit_code, 0) << r.err;
  EXPECT_EQ(testing::JsonString(r.out, "status"), "ok") << r.out;
  EXPECT_NEAR(JsonNumber(r.out, "sim_time"), 2.4, 1e-9);
  EXPECT_EQ(JsonNumber(r.out, "components"), 2) << r.out;
  // Progressive: the blade's grip loads the tissue ahead of it until the
  // criterion passes, and each cut step opens the stretch swept since the
  // last one (3 to 4 node rows of the 13 here), not the whole line at once.
  EXPECT_GE(JsonNumber(r.out, "cuts"), 4) << r.out;
  EXPECT_LE(JsonNumber(r.out, "cuts_rejected"), 1) << r.out;
  EXPECT_GT(JsonNumber(r.out, "min_rest_volume"), 0.0);
  // 40 × 20 × 10 mm at 1000 kg/m³.
  EXPECT_NEAR(JsonNumber(r.out, "total_mass"), 0.008, 1e-12) << r.out;
  // The parts sag and spring back under the blade: millimetres, not metres.
  EXPECT_LT(JsonNumber(r.out, "max_displacement"), 0.005) << r.out;
  EXPECT_EQ(JsonNumber(r.out, "tets"), 12 * 6 * 3 * 6);
  // The opened faces are the two sides of the crack: one cut through the
  // whole 40 × 10 mm cross-section along a node plane (2 triangles per cell
  // face, 12 × 3 cell faces, both sides).
  EXPECT_EQ(JsonNumber(r.out, "opened_faces"), 2 * 2 * 12 * 3) << r.out;

  ASSERT_TRUE(std::filesystem::exists(out));
  const mesh::TetMesh world = mesh::ReadMesh(out);
  ASSERT_EQ(world.num_tets(), 12 * 6 * 3 * 6);
  for (int32_t t = 0; t < world.num_tets(); ++t) ASSERT_GT(mesh::SignedVolume(world, t), 0.0) << "tet " << t;
  int32_t parts = 0;
  const std::vector<int32_t> label = cutting::ConnectedComponents(world.tets, &parts);
  EXPECT_EQ(parts, 2);
  // Every tet is on the side of the blade its centroid is on.
  for (int32_t t = 0; t < world.num_tets(); ++t) {
    double y = 0.0;
    for (int c = 0; c < 4; ++c) y += world.nodes(world.tets(t, c), 1) / 4.0;
    const bool with_tet0 = label[static_cast<size_t>(t)] == label[0];
    ASSERT_EQ(with_tet0, y < 0.0101) << "tet " << t << " at y = " << y;
  }
  const std::vector<double> cut_faces = CellArray(out, "cut_faces");
  ASSERT_EQ(cut_faces.size(), static_cast<size_t>(world.num_tets()));
  double opened = 0.0;
  for (const double c : cut_faces) opened += c;
  EXPECT_EQ(opened, JsonNumber(r.out, "opened_faces"));
}

}  // namespace
}  // namespace cutsim
