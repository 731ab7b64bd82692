#include <algorithm>
#include <numeric>
#include <random>
#include <utility>
#include <vector>

#include <gtest/gtest.h>

#include "common/core/log.h"
#include "common/mesh/generators.h"
#include "common/mesh/mesh_validation.h"
#include "common/mesh/quality.h"
#include "common/mesh/reorder.h"

namespace cutsim::mesh {
namespace {

using Eigen::Vector3d;

TEST(ReverseCuthillMcKee, KeepsVolumesAndReducesBandwidth) {
  TetMesh mesh = MakeBox({0, 0, 0}, {1, 1, 1}, 8, 8, 8);
  // Scramble the numbering first, as a mesher's output might be.
  std::vector<int32_t> shuffle(static_cast<size_t>(mesh.num_nodes()));
  std::iota(shuffle.begin(), shuffle.end(), 0);
  std::shuffle(shuffle.begin(), shuffle.end(), std::mt19937(3));
  NodePermutation scramble{shuffle, std::vector<int32_t>(shuffle.size())};
  for (size_t i = 0; i < shuffle.size(); ++i) scramble.old_to_new[static_cast<size_t>(shuffle[i])] = static_cast<int32_t>(i);
  ApplyNodePermutation(mesh, scramble);

  std::vector<double> volumes;
  for (int32_t t = 0; t < mesh.num_tets(); ++t) volumes.push_back(SignedVolume(mesh, t));
  const TetMesh before = mesh;
  const int32_t bw_before = Bandwidth(mesh.tets);
  const NodePermutation perm = ReverseCuthillMcKee(mesh);
  ApplyNodePermutation(mesh, perm);
  const int32_t bw_after = Bandwidth(mesh.tets);
  Log().info("RCM on an 8×8×8 box (729 nodes): bandwidth {} → {}", bw_before, bw_after);
  EXPECT_LT(bw_after, bw_before / 4);
  EXPECT_LE(bw_after, 2 * 9 * 9 + 20);  // about two node layers of the box
  for (int32_t t = 0; t < mesh.num_tets(); ++t) EXPECT_DOUBLE_EQ(SignedVolume(mesh, t), volumes[static_cast<size_t>(t)]);
  // The kept permutation maps user node sets.
  const std::vector<int32_t> fixed{0, 5, 100};
  const auto mapped = MapNodeIndices(fixed, perm);
  for (size_t i = 0; i < fixed.size(); ++i) {
    EXPECT_EQ(mesh.nodes.row(mapped[i]), before.nodes.row(fixed[i]));
  }
  EXPECT_NO_THROW(ValidateTetMesh(mesh, "rcm"));
}

TEST(Quality, RegularTetIsOneAndScaleInvariant) {
  const Vector3d a(1, 1, 1), b(-1, 1, -1), c(1, -1, -1), d(-1, -1, 1);  // positively oriented
  EXPECT_NEAR(MeanRatio(a, b, c, d), 1.0, 1e-14);
  EXPECT_NEAR(MeanRatio(1e-3 * a, 1e-3 * b, 1e-3 * c, 1e-3 * d), 1.0, 1e-12);
  EXPECT_EQ(MeanRatio(a, c, b, d), 0.0);  // inverted
  // Regular tet with edge 2√2: altitude = edge·√(2/3).
  EXPECT_NEAR(ShortestEdge(a, b, c, d), 2.0 * std::sqrt(2.0), 1e-14);
  EXPECT_NEAR(ShortestAltitude(a, b, c, d), 2.0 * std::sqrt(2.0) * std::sqrt(2.0 / 3.0), 1e-14);
}

TEST(Quality, SliverTendsToZero) {
  const Vector3d a(0, 0, 0), b(1, 0, 0), c(0.5, 0.5, 0), d(0.5, 0.0, 0.0);
  for (double h : {1e-1, 1e-3, 1e-6}) {
    const double q = MeanRatio(a, b, Vector3d(0, 1, h), Vector3d(1, 1, -h));
    EXPECT_LT(q, 10 * h);
    EXPECT_GE(q, 0.0);
  }
  EXPECT_EQ(MeanRatio(a, b, c, d), 0.0);  // flat
}

TEST(Quality, CubedMeanRatioIsTheCubeAndKeepsTheOrder) {
  // Random tets of both orientations and every shape from sliver to regular.
  std::mt19937 rng(7);
  std::uniform_real_distribution<double> u(-1.0, 1.0);
  auto random_point = [&] { return Vector3d(u(rng), u(rng), u(rng)); };
  std::vector<std::pair<double, double>> q;  // (η, η³ computed directly)
  for (int i = 0; i < 500; ++i) {
    const Vector3d a = random_point(), b = random_point(), c = random_point(), d = random_point();
    const double eta = MeanRatio(a, b, c, d);
    const double eta3 = MeanRatioCubed(a, b, c, d);
    if (eta == 0.0) {
      EXPECT_EQ(eta3, 0.0);  // inverted or flat
      continue;
    }
    EXPECT_NEAR(eta3, eta * eta * eta, 1e-13 * eta * eta * eta);
    q.emplace_back(eta, eta3);
  }
  ASSERT_GT(q.size(), 100u);
  std::sort(q.begin(), q.end());
  for (size_t i = 1; i < q.size(); ++i) EXPECT_LE(q[i - 1].second, q[i].second * (1.0 + 1e-13));
  const Vector3d a(1, 1, 1), b(-1, 1, -1), c(1, -1, -1), d(-1, -1, 1);
  EXPECT_NEAR(MeanRatioCubed(a, b, c, d), 1.0, 1e-14);
}

TEST(Quality, BoxElementsHaveKnownQuality) {
  const TetMesh mesh = MakeBox({0, 0, 0}, {1, 1, 1}, 2, 2, 2);
  const TetQuality q = ComputeTetQuality(mesh);
  for (size_t t = 0; t < q.mean_ratio.size(); ++t) {
    EXPECT_GT(q.mean_ratio[t], 0.5);
    EXPECT_LE(q.mean_ratio[t], 1.0);
    EXPECT_NEAR(q.shortest_edge[t], 0.5, 1e-15);
    EXPECT_GT(q.shortest_altitude[t], 0.0);
    EXPECT_LE(q.shortest_altitude[t], q.shortest_edge[t]);
  }
}

}  // namespace
}  // namespace cutsim::mesh
