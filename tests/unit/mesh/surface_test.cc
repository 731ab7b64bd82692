#include "common/mesh/surface.h"

#include <gtest/gtest.h>

#include "common/mesh/generators.h"

namespace cutsim::mesh {
namespace {

TEST(ExtractSurface, SingleTetIsOutwardClosedSphere) {
  Tets tets(1, 4);
  tets << 0, 1, 2, 3;
  Positions x(4, 3);
  x << 0, 0, 0, 1, 0, 0, 0, 1, 0, 0, 0, 1;
  const Surface s = ExtractSurface(tets);
  ASSERT_EQ(s.tris.rows(), 4);
  const Eigen::Vector3d centroid = x.colwise().mean();
  for (Eigen::Index f = 0; f < 4; ++f) {
    const Eigen::Vector3d a = x.row(s.tris(f, 0)), b = x.row(s.tris(f, 1)), c = x.row(s.tris(f, 2));
    EXPECT_GT((b - a).cross(c - a).dot(a - centroid), 0.0) << "face " << f << " points inward";
    EXPECT_EQ(s.tet[static_cast<size_t>(f)], 0);
    // The local face is the one opposite the node not on the triangle.
    const int32_t opposite = tets(0, s.local_face[static_cast<size_t>(f)]);
    EXPECT_NE(s.tris(f, 0), opposite);
    EXPECT_NE(s.tris(f, 1), opposite);
    EXPECT_NE(s.tris(f, 2), opposite);
  }
  const ManifoldCheck m = CheckClosedManifold(s.tris);
  EXPECT_TRUE(m.ok) << m.problem;
  EXPECT_EQ(m.euler_characteristic(), 2);
}

TEST(ExtractSurface, BoxSurfaceIsClosedManifoldWithOutwardNormals) {
  const TetMesh box = MakeBox({0, 0, 0}, {1, 2, 3}, 3, 4, 5);
  const Surface s = ExtractSurface(box.tets);
  // 2 triangles per boundary quad.
  EXPECT_EQ(s.tris.rows(), 2 * 2 * (3 * 4 + 4 * 5 + 3 * 5));
  const ManifoldCheck m = CheckClosedManifold(s.tris);
  EXPECT_TRUE(m.ok) << m.problem;
  EXPECT_EQ(m.euler_characteristic(), 2);
  // Σ area·normal·x over a closed outward surface = volume (divergence theorem).
  double flux = 0.0;
  for (Eigen::Index f = 0; f < s.tris.rows(); ++f) {
    const Eigen::Vector3d a = box.nodes.row(s.tris(f, 0)), b = box.nodes.row(s.tris(f, 1)),
                          c = box.nodes.row(s.tris(f, 2));
    flux += 0.5 * (b - a).cross(c - a).x() * (a.x() + b.x() + c.x()) / 3.0;
  }
  EXPECT_NEAR(flux, 6.0, 1e-12);
}

TEST(CheckClosedManifold, DetectsProblems) {
  Triangles open(1, 3);
  open << 0, 1, 2;
  EXPECT_FALSE(CheckClosedManifold(open).ok);
  EXPECT_NE(CheckClosedManifold(open).problem.find("boundary edge"), std::string::npos);

  Tets tets(1, 4);
  tets << 0, 1, 2, 3;
  Triangles flipped = ExtractSurface(tets).tris;
  std::swap(flipped(0, 1), flipped(0, 2));
  EXPECT_NE(CheckClosedManifold(flipped).problem.find("same direction"), std::string::npos);

  // Two tets touching only at node 0: edge-manifold but vertex 0 is pinched.
  Tets two(2, 4);
  two << 0, 1, 2, 3, 0, 4, 5, 6;
  const ManifoldCheck pinched = CheckClosedManifold(ExtractSurface(two).tris);
  EXPECT_FALSE(pinched.ok);
  EXPECT_NE(pinched.problem.find("vertex 0"), std::string::npos) << pinched.problem;
}

}  // namespace
}  // namespace cutsim::mesh
