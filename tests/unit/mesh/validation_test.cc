#include "common/mesh/mesh_validation.h"

#include <cmath>
#include <limits>

#include <gtest/gtest.h>

#include "common/core/error.h"

namespace cutsim::mesh {
namespace {

// Two tets sharing face (0,1,2), positively oriented.
TetMesh TwoTets() {
  TetMesh m;
  m.nodes.resize(5, 3);
  m.nodes << 0, 0, 0, 1, 0, 0, 0, 1, 0, 0, 0, 1, 0, 0, -1;
  m.tets.resize(2, 4);
  m.tets << 0, 1, 2, 3, 0, 2, 1, 4;
  return m;
}

std::string ErrorOf(const TetMesh& m, const MeshOrigin& origin = {}) {
  try {
    ValidateTetMesh(m, "mesh.file", origin);
  } catch (const InputError& e) {
    return e.what();
  }
  return "";
}

TEST(ValidateTetMesh, AcceptsValidMesh) {
  const TetMesh m = TwoTets();
  EXPECT_GT(SignedVolume(m, 0), 0.0);
  EXPECT_GT(SignedVolume(m, 1), 0.0);
  EXPECT_NO_THROW(ValidateTetMesh(m, "x"));
}

TEST(ValidateTetMesh, RejectsBadInputNamingFileAndElement) {
  struct Case {
    const char* name;
    void (*edit)(TetMesh&);
    const char* expect;
  };
  const Case cases[] = {
      {"index out of range", [](TetMesh& m) { m.tets(1, 3) = 7; }, "element 2"},
      {"negative index", [](TetMesh& m) { m.tets(0, 0) = -1; }, "element 1"},
      {"nan", [](TetMesh& m) { m.nodes(3, 1) = std::nan(""); }, "node 4"},
      {"inf", [](TetMesh& m) { m.nodes(2, 0) = std::numeric_limits<double>::infinity(); }, "node 3"},
      {"inverted", [](TetMesh& m) { std::swap(m.tets(1, 1), m.tets(1, 2)); }, "element 2: inverted"},
      {"zero volume", [](TetMesh& m) { m.nodes.row(4) << 0.5, 0.5, 0.0; }, "element 2: zero-volume"},
      {"near-zero volume", [](TetMesh& m) { m.nodes.row(4) << 0.5, 0.5, -1e-14; }, "zero-volume"},
      {"repeated node", [](TetMesh& m) { m.tets(0, 3) = 0; }, "element 1: repeats"},
      {"dangling", [](TetMesh& m) {
         m.nodes.conservativeResize(6, 3);
         m.nodes.row(5) << 3, 3, 3;
       }, "node 6: dangling"},
      {"duplicate", [](TetMesh& m) {
         m.tets.conservativeResize(3, 4);
         m.tets.row(2) << 1, 2, 0, 3;
       }, "element 3: duplicate of element 1"},
      {"regions", [](TetMesh& m) { m.regions = {1}; }, "region"},
      {"no tets", [](TetMesh& m) { m.tets.resize(0, 4); }, "no tetrahedra"},
  };
  for (const auto& c : cases) {
    TetMesh m = TwoTets();
    c.edit(m);
    const std::string what = ErrorOf(m);
    EXPECT_NE(what.find("mesh.file"), std::string::npos) << c.name << ": " << what;
    EXPECT_NE(what.find(c.expect), std::string::npos) << c.name << ": " << what;
  }
}

TEST(ValidateTetMesh, UsesFileIdsAndLines) {
  TetMesh m = TwoTets();
  std::swap(m.tets(1, 1), m.tets(1, 2));
  MeshOrigin origin{.node_ids = {}, .tet_ids = {10, 20}, .tet_lines = {7, 8}};
  const std::string what = ErrorOf(m, origin);
  EXPECT_NE(what.find("mesh.file:8: element 20"), std::string::npos) << what;
}

TEST(ValidateTetMesh, RejectsFaceSharedByThreeTets) {
  TetMesh m = TwoTets();
  m.nodes.conservativeResize(6, 3);
  m.nodes.row(5) << 0.2, 0.2, 2.0;  // a third tet on face (0,1,2), overlapping tet 0
  m.tets.conservativeResize(3, 4);
  m.tets.row(2) << 0, 1, 2, 5;
  EXPECT_EQ(FindOvershardFace(m.tets), 2 * 4 + 3);
  EXPECT_NE(ErrorOf(m).find("more than two"), std::string::npos) << ErrorOf(m);
}

TEST(OrientTets, FlipsNegativeTets) {
  TetMesh m = TwoTets();
  std::swap(m.tets(0, 0), m.tets(0, 3));
  EXPECT_LT(SignedVolume(m, 0), 0.0);
  EXPECT_EQ(OrientTets(m), 1);
  EXPECT_GT(SignedVolume(m, 0), 0.0);
  EXPECT_NO_THROW(ValidateTetMesh(m, "x"));
}

}  // namespace
}  // namespace cutsim::mesh
