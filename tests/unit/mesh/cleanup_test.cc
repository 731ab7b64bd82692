#include "common/mesh/cleanup.h"

#include <algorithm>
#include <cmath>
#include <vector>

#include <gtest/gtest.h>

#include "common/mesh/generators.h"
#include "common/mesh/mesh_validation.h"
#include "common/mesh/quality.h"
#include "common/mesh/surface.h"

namespace cutsim::mesh {
namespace {

double Volume(const TetMesh& m) {
  double v = 0;
  for (int32_t t = 0; t < m.num_tets(); ++t) v += SignedVolume(m, t);
  return v;
}

double MinQuality(const TetMesh& m) {
  const TetQuality q = ComputeTetQuality(m);
  return *std::min_element(q.mean_ratio.begin(), q.mean_ratio.end());
}

void ExpectClosedSurface(const TetMesh& m) {
  const Surface s = ExtractSurface(m.tets);
  const ManifoldCheck c = CheckClosedManifold(s.tris);
  EXPECT_TRUE(c.ok) << c.problem;
  EXPECT_EQ(c.euler_characteristic(), 2);
}

// A unit cube (6 Kuhn tets) with a flat sliver glued on its top face: the
// sliver shares the top triangle (a, b, c) and has its apex ε above it, so it
// has 3 boundary faces and all 4 nodes on the surface.
TetMesh CubeWithCap(double eps) {
  TetMesh m = MakeBox(Eigen::Vector3d::Zero(), Eigen::Vector3d::Ones(), 1, 1, 1);
  const Surface s = ExtractSurface(m.tets);
  int32_t f = -1;
  for (int32_t i = 0; i < s.tris.rows(); ++i) {
    bool top = true;
    for (int k = 0; k < 3; ++k) top = top && m.nodes(s.tris(i, k), 2) == 1.0;
    if (top) f = i;
  }
  EXPECT_GE(f, 0);
  Eigen::Vector3d c = Eigen::Vector3d::Zero();
  for (int k = 0; k < 3; ++k) c += m.nodes.row(s.tris(f, k)).transpose() / 3.0;
  m.nodes.conservativeResize(m.num_nodes() + 1, 3);
  m.nodes.row(m.num_nodes() - 1) = (c + Eigen::Vector3d(0, 0, eps)).transpose();
  m.tets.conservativeResize(m.num_tets() + 1, 4);
  m.tets.row(m.num_tets() - 1) << s.tris(f, 0), s.tris(f, 1), s.tris(f, 2), m.num_nodes() - 1;
  OrientTets(m);
  ValidateTetMesh(m, "cube+cap");
  return m;
}

TEST(RemoveBoundarySlivers, DeletesCapAndItsApexNode) {
  TetMesh m = CubeWithCap(1e-3);
  ExpectClosedSurface(m);
  EXPECT_LT(MinQuality(m), 0.05);
  double vol = 0;
  int32_t nodes = 0;
  EXPECT_EQ(RemoveBoundarySlivers(m, 0.3, &vol, &nodes), 1);
  EXPECT_EQ(nodes, 1);
  EXPECT_EQ(m.num_tets(), 6);
  EXPECT_EQ(m.num_nodes(), 8);
  EXPECT_NEAR(Volume(m), 1.0, 1e-12);
  EXPECT_GT(vol, 0.0);
  ExpectClosedSurface(m);
}

TEST(RemoveBoundarySlivers, KeepsGoodTetsAndTheLastTet) {
  TetMesh box = MakeBox(Eigen::Vector3d::Zero(), Eigen::Vector3d::Ones(), 2, 2, 2);
  const TetMesh before = box;
  EXPECT_EQ(RemoveBoundarySlivers(box, 0.3), 0);  // Kuhn tets have mean ratio ≈ 0.72
  EXPECT_EQ(box.tets, before.tets);
  TetMesh one;
  one.nodes.resize(4, 3);
  one.nodes << 0, 0, 0, 1, 0, 0, 0, 1, 0, 0.3, 0.3, 1e-3;
  one.tets.resize(1, 4);
  one.tets << 0, 1, 2, 3;
  EXPECT_EQ(RemoveBoundarySlivers(one, 0.3), 0);  // never empties the mesh
}

TEST(SmoothInteriorNodes, RepairsAPerturbedInteriorNodeAndKeepsTheSurface) {
  TetMesh m = MakeBox(Eigen::Vector3d::Zero(), Eigen::Vector3d::Ones(), 2, 2, 2);
  // The centre node (1,1,1)/2 pushed almost onto a face of its star.
  int32_t centre = -1;
  for (int32_t n = 0; n < m.num_nodes(); ++n) {
    if ((m.nodes.row(n).transpose() - Eigen::Vector3d::Constant(0.5)).norm() < 1e-12) centre = n;
  }
  ASSERT_GE(centre, 0);
  m.nodes.row(centre) += Eigen::RowVector3d(0.42, 0.38, 0.4);
  ValidateTetMesh(m, "perturbed");
  const double q0 = MinQuality(m);
  const TetMesh before = m;
  EXPECT_GT(SmoothInteriorNodes(m, 0.5, 8), 0);
  EXPECT_GT(MinQuality(m), q0 + 0.1);
  ValidateTetMesh(m, "smoothed");
  EXPECT_NEAR(Volume(m), 1.0, 1e-12);
  for (int32_t n = 0; n < m.num_nodes(); ++n) {
    if (n != centre) {
      EXPECT_EQ(m.nodes.row(n), before.nodes.row(n));
    }
  }
}

TEST(CleanupMesh, OrganMeetsTheStableStepTargets) {
  OrganOptions raw_opt;
  raw_opt.fill.cleanup = false;
  const TetMesh raw = MakeOrgan(raw_opt);
  OrganOptions opt;
  CleanupReport rep;
  opt.fill.report = &rep;
  const TetMesh organ = MakeOrgan(opt);
  EXPECT_GE(organ.num_tets(), 20000);
  ExpectClosedSurface(organ);
  const TetQuality q = ComputeTetQuality(organ);
  const double min_q = *std::min_element(q.mean_ratio.begin(), q.mean_ratio.end());
  std::vector<double> alt = q.shortest_altitude;
  std::nth_element(alt.begin(), alt.begin() + static_cast<long>(alt.size() / 2), alt.end());
  const double median_alt = alt[alt.size() / 2];
  const double min_alt = *std::min_element(alt.begin(), alt.end());
  EXPECT_GE(min_q, 0.3);
  EXPECT_LE(median_alt / min_alt, 4.0);
  EXPECT_GT(rep.removed_tets, 0);
  EXPECT_LT(MinQuality(raw), 0.1);  // what the cleanup is for
  // The deleted slivers are a negligible part of the volume.
  EXPECT_LT(std::abs(Volume(organ) - Volume(raw)), 1e-4 * Volume(raw));
  // Deterministic.
  const TetMesh again = MakeOrgan(opt);
  EXPECT_EQ(again.nodes, organ.nodes);
  EXPECT_EQ(again.tets, organ.tets);
}

TEST(SortTetsByNodes, OrdersBySmallestNodeAndKeepsTheMesh) {
  TetMesh m = MakeBox(Eigen::Vector3d::Zero(), Eigen::Vector3d::Ones(), 3, 2, 2);
  m.regions.resize(static_cast<size_t>(m.num_tets()));
  for (int32_t t = 0; t < m.num_tets(); ++t) m.regions[static_cast<size_t>(t)] = t;
  const TetMesh before = m;
  const std::vector<int32_t> order = SortTetsByNodes(m);
  ASSERT_EQ(static_cast<int32_t>(order.size()), m.num_tets());
  for (int32_t t = 0; t < m.num_tets(); ++t) {
    EXPECT_EQ(m.tets.row(t), before.tets.row(order[static_cast<size_t>(t)]));
    EXPECT_EQ(m.regions[static_cast<size_t>(t)], order[static_cast<size_t>(t)]);
    if (t > 0) {
      EXPECT_LE(m.tets.row(t - 1).minCoeff(), m.tets.row(t).minCoeff());
    }
  }
  EXPECT_NEAR(Volume(m), 1.0, 1e-12);
}

}  // namespace
}  // namespace cutsim::mesh
