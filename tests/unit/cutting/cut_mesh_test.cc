// CutMesh and CutStepper: complex and surface bookkeeping, the straight cut
// through a box, singularity removal, event replay.
#include <algorithm>
#include <array>
#include <cmath>
#include <random>
#include <vector>

#include <gtest/gtest.h>

#include "common/core/error.h"
#include "common/cutting/cut_mesh.h"
#include "common/cutting/cut_stepper.h"
#include "tests/unit/cutting/cut_driver.h"
#include "tests/unit/cutting/test_util.h"

namespace cutsim::cutting {
namespace {

using Eigen::Vector3d;
using testing::ExpectInvariants;
using testing::KuhnBox;
using testing::Reference;
using testing::WorldFromRest;

constexpr double kCell = 0.01;  // cell size, m

mesh::TetMesh Box() { return KuhnBox(Vector3d::Zero(), Vector3d(4 * kCell, 3 * kCell, 2 * kCell), 4, 3, 2); }

TEST(CutMesh, UncutMeshHasTheExtractedSurfaceAndNoOpenedFace) {
  const mesh::TetMesh m = Box();
  ASSERT_NO_THROW(mesh::ValidateTetMesh(m, "box"));
  const CutMesh cm(m);
  const VectorWorld w = WorldFromRest(m);
  EXPECT_EQ(cm.version(), 0u);
  EXPECT_EQ(cm.num_surface_faces(), mesh::ExtractSurface(m.tets).tris.rows());
  ExpectInvariants(cm, w, Reference(m), "uncut");
  EXPECT_EQ(cm.NumConnectedComponents(), 1);
  for (int32_t v = 0; v < cm.num_nodes(); ++v) EXPECT_TRUE(cm.SurfaceManifoldAt(v));
}

TEST(CutMesh, ContactElementsAreTheStarOfTheClosestVertexPlusTheFacetTet) {
  const mesh::TetMesh m = Box();
  const CutMesh cm(m);
  const int32_t v = 0;
  std::vector<int32_t> expect(cm.node_tets(v).begin(), cm.node_tets(v).end());
  EXPECT_EQ(cm.ContactElements(v), expect);
  const int32_t other = cm.num_tets() - 1;
  expect.push_back(other);
  EXPECT_EQ(cm.ContactElements(v, other), expect);
}

// Eq. (12): the cutting line's end v2 is the surface neighbour of v1 whose
// direction from C_p(t), in the facet plane, is nearest to s1's. On the
// top of the box, a line along a row of nodes continues along the row.
TEST(CutMesh, SelectV2ContinuesAStraightCuttingLine) {
  const mesh::TetMesh m = Box();
  const CutMesh cm(m);
  const VectorWorld w = WorldFromRest(m);
  auto id = [](int i, int j, int k) { return i + 5 * (j + 4 * k); };
  const Vector3d up = Vector3d::UnitZ();
  const Vector3d cp = w.Get(id(2, 1, 2)) + Vector3d(0.1 * kCell, 0.05 * kCell, 0.0);
  EXPECT_EQ(cm.SelectV2(id(1, 1, 2), id(2, 1, 2), cp, up, w), id(3, 1, 2));
  EXPECT_EQ(cm.SelectV2(id(3, 1, 2), id(2, 1, 2), cp, up, w), id(1, 1, 2));
  EXPECT_EQ(cm.SelectV2(id(2, 0, 2), id(2, 1, 2), cp, up, w), id(2, 2, 2));
  // s1 ∥ n: no direction on the facet plane, no v2.
  VectorWorld stacked = w;
  stacked.Set(id(1, 1, 2), w.Get(id(2, 1, 2)) - kCell * up);
  EXPECT_EQ(cm.SelectV2(id(1, 1, 2), id(2, 1, 2), cp, up, stacked), -1);
}

// The same rule against a brute force over the extracted surface
// triangles, after cuts (so v1 may have twins, which are never v2), for
// random adjacent pairs on the top face and contact points near v1.
TEST(CutMesh, SelectV2MatchesABruteForceOverTheSurfaceAfterCuts) {
  const mesh::TetMesh m = KuhnBox(Vector3d::Zero(), Vector3d(6 * kCell, 4 * kCell, 2 * kCell), 6, 4, 2, 0.2, 3);
  CutMesh cm(m);
  VectorWorld w = WorldFromRest(m);
  CutParams params;
  const double top = 2 * kCell;
  const std::vector<Vector3d> path =
      testing::Segment(Vector3d(0.2 * kCell, 2.05 * kCell, top), Vector3d(3.5 * kCell, 1.6 * kCell, top), 12);
  (void)testing::DrivePath(cm, w, path, 0.6 * kCell, params, nullptr, [](int) {});
  ASSERT_GT(cm.version(), 0u) << "no cut: the check below would not meet twins";
  const Vector3d n = Vector3d::UnitZ();
  auto tangential = [&](const Vector3d& a) { return Vector3d(a - n.dot(a) * n); };
  const mesh::Triangles tris = cm.SurfaceTriangles();
  std::mt19937 rng(7);
  std::uniform_real_distribution<double> u(-0.3, 0.3);
  int checked = 0, with_twins = 0;
  for (int r = 0; r < tris.rows(); ++r) {
    const std::array<int32_t, 3> tri = {tris(r, 0), tris(r, 1), tris(r, 2)};
    bool on_top = true;
    for (const int32_t v : tri) on_top = on_top && std::abs(w.Get(v).z() - top) < 1e-9;
    if (!on_top) continue;
    for (int e = 0; e < 3; ++e) {
      const int32_t v0 = tri[static_cast<size_t>(e)], v1 = tri[static_cast<size_t>((e + 1) % 3)];
      const Vector3d cp = w.Get(v1) + kCell * Vector3d(u(rng), u(rng), 0.0);
      const Vector3d s1 = tangential(w.Get(v1) - w.Get(v0));
      int32_t best = -1;
      double best_cos = -2.0;
      for (int q = 0; q < tris.rows(); ++q) {
        for (int c = 0; c < 3; ++c) {
          if (tris(q, c) != v1) continue;
          for (int k = 1; k < 3; ++k) {
            const int32_t vi = tris(q, (c + k) % 3);
            if (cm.origin(vi) == cm.origin(v0) || cm.origin(vi) == cm.origin(v1)) continue;
            const Vector3d si = tangential(w.Get(vi) - cp);
            if (!(si.norm() > 0.0)) continue;
            const double cosine = s1.dot(si) / (s1.norm() * si.norm());
            if (cosine > best_cos || (cosine == best_cos && vi < best)) {
              best_cos = cosine;
              best = vi;
            }
          }
        }
      }
      ASSERT_EQ(cm.SelectV2(v0, v1, cp, n, w), best) << "v0 " << v0 << " v1 " << v1;
      ++checked;
      if (cm.Twins(v1, w).size() > 1) ++with_twins;
    }
  }
  EXPECT_GT(checked, 100);
  EXPECT_GT(with_twins, 0) << "no v1 on the cut: nothing was checked beside a slit";
}

TEST(CutMesh, InvalidStepChangesNothing) {
  const mesh::TetMesh m = Box();
  CutMesh cm(m);
  CutStepper stepper;
  const VectorWorld w = WorldFromRest(m);
  CutStep step;
  step.v0 = 0;
  step.v1 = 0;
  EXPECT_EQ(stepper.ExecuteCut(cm, step, w, CutParams{}).status, CutStatus::kInvalidInput);
  step.v1 = 1;  // s1 along x, normal along x: no plane
  step.normal = Vector3d::UnitX();
  EXPECT_EQ(stepper.ExecuteCut(cm, step, w, CutParams{}).status, CutStatus::kInvalidInput);
  step.normal = Vector3d::UnitZ();
  step.v1 = cm.num_nodes();
  EXPECT_EQ(stepper.ExecuteCut(cm, step, w, CutParams{}).status, CutStatus::kInvalidInput);
  EXPECT_EQ(cm.version(), 0u);
  EXPECT_EQ(cm.num_nodes(), m.num_nodes());
}

// Drives a straight cut along the top face at y = 1.2 h with a blade longer
// than the thickness. World = rest.
struct StraightCut {
  mesh::TetMesh m = Box();
  CutMesh cm{m};
  VectorWorld world = WorldFromRest(m);
  Reference ref{m};
  std::vector<TopologyEvent> events;
  testing::DriveStats stats;
  int components_before_last = 0;

  void Run(double y = 1.2 * kCell) {
    CutParams params;
    params.alpha = 0.5;
    const double top = 2 * kCell;
    const auto path = testing::Segment(Vector3d(0, y, top), Vector3d(4 * kCell, y, top), 80);
    stats = testing::DrivePath(cm, world, path, /*depth=*/top + 0.005, params, &events, [&](int step) {
      ExpectInvariants(cm, world, ref, "straight cut step " + std::to_string(step));
    });
  }
};

TEST(CutMesh, StraightCutWithALongBladeSeparatesTheBoxIntoTwo) {
  StraightCut sc;
  sc.Run();
  EXPECT_EQ(sc.stats.rejected, 0);
  EXPECT_GE(sc.stats.executed, 4) << "one step per top vertex along the line";
  int32_t k = 0;
  const std::vector<int32_t> labels = sc.cm.ConnectedComponents(&k);
  EXPECT_EQ(k, 2);
  int32_t k2 = 0;
  EXPECT_EQ(ConnectedComponents(sc.cm.TetsMatrix(), &k2), labels);
  // The two parts lie on either side of the cut: check by tet centroids (rest).
  const mesh::TetMesh rest = sc.cm.RestMesh();
  for (int32_t t = 0; t < rest.num_tets(); ++t) {
    Vector3d c = Vector3d::Zero();
    for (int i = 0; i < 4; ++i) c += rest.nodes.row(rest.tets(t, i)).transpose() / 4.0;
    EXPECT_EQ(labels[static_cast<size_t>(t)], labels[0] == 0 ? (c.y() < 1.2 * kCell ? 0 : 1) : (c.y() < 1.2 * kCell ? 1 : 0))
        << "tet " << t << " at y = " << c.y();
  }
  EXPECT_EQ(sc.cm.num_tets(), sc.m.num_tets());
  EXPECT_EQ(sc.cm.version(), sc.events.size());
}

TEST(CutMesh, BladePlaneIgnoresAClosestVertexJumpingBetweenRows) {
  // The blade passes 0.01 h beside the row y = h; the closest vertex given
  // to every other step is on the far row (y = 2h), as a contact facet's
  // largest barycentric can be. The crack must still be the y = h node
  // plane: two parts, no fragment, every opened face in that plane.
  const mesh::TetMesh m = Box();
  CutMesh cm(m);
  CutStepper stepper;
  VectorWorld world = WorldFromRest(m);
  const Reference ref(m);
  CutParams params;
  const double top = 2 * kCell, y = 1.01 * kCell;
  auto node_at = [&](int i, int j) { return static_cast<int32_t>(i + 5 * (j + 4 * 2)); };  // top layer
  int32_t v0 = node_at(0, 1);
  Vector3d tip0(-0.2 * kCell, y, -0.5 * kCell);
  for (int i = 1; i <= 4; ++i) {
    CutStep step;
    step.v0 = v0;
    step.v1 = node_at(i, i % 2 == 0 ? 2 : 1);
    step.cp0 = Vector3d(tip0.x(), y, top);
    step.cp = Vector3d(i * kCell, y, top);
    const Vector3d tip(i == 4 ? 4.2 * kCell : i * kCell, y, -0.5 * kCell);
    step.blade.emplace(Blade{tip, Vector3d::UnitZ(), 3 * kCell, tip0});
    const CutOutcome out = stepper.ExecuteCut(cm, step, world, params);
    ASSERT_EQ(out.status, CutStatus::kExecuted) << "step " << i;
    world.ApplyEvent(out.event);
    ExpectInvariants(cm, world, ref, "step " + std::to_string(i));
    v0 = step.v1;
    tip0 = tip;
  }
  EXPECT_EQ(cm.NumConnectedComponents(), 2);
  std::vector<uint8_t> opened;
  const mesh::Triangles tris = cm.SurfaceTriangles(&opened);
  int n_opened = 0;
  for (int r = 0; r < tris.rows(); ++r) {
    if (!opened[static_cast<size_t>(r)]) continue;
    ++n_opened;
    for (int k = 0; k < 3; ++k) EXPECT_NEAR(world.Get(tris(r, k)).y(), kCell, 0.02 * kCell) << "opened face off the plane";
  }
  EXPECT_EQ(n_opened, 2 * 2 * 4 * 2) << "both sides of the 4 × 2 cell faces";
}

// A world that holds its positions elsewhere (the FEM's float state):
// no packed doubles, every read through Get.
class UnpackedWorld final : public WorldAccess {
 public:
  explicit UnpackedWorld(VectorWorld& inner) : inner_(inner) {}
  [[nodiscard]] Vector3d Get(int32_t node) const override { return inner_.Get(node); }
  void Set(int32_t node, const Vector3d& x) override { inner_.Set(node, x); }

 private:
  VectorWorld& inner_;
};

TEST(CutMesh, AWorldWithoutPackedPositionsCutsTheSame) {
  // The cut step reads packed positions directly where a world has them
  // (Xyz) and through Get, cached, where it does not: same events.
  const mesh::TetMesh m = Box();
  CutMesh packed_mesh(m), unpacked_mesh(m);
  CutStepper packed_stepper, unpacked_stepper;
  VectorWorld packed = WorldFromRest(m), unpacked_store = WorldFromRest(m);
  UnpackedWorld unpacked(unpacked_store);
  ASSERT_NE(packed.Xyz(), nullptr);
  ASSERT_EQ(unpacked.Xyz(), nullptr);
  const CutParams params;
  const double top = 2 * kCell, y = 1.2 * kCell;
  auto node_at = [&](int i, int j) { return static_cast<int32_t>(i + 5 * (j + 4 * 2)); };  // top layer
  int32_t v0 = node_at(0, 1);
  Vector3d tip0(-0.2 * kCell, y, -0.5 * kCell);
  int splits = 0;
  for (int i = 1; i <= 4; ++i) {
    CutStep step;
    step.v0 = v0;
    step.v1 = node_at(i, 1);
    step.cp0 = Vector3d(tip0.x(), y, top);
    step.cp = Vector3d(i * kCell, y, top);
    const Vector3d tip(i == 4 ? 4.2 * kCell : i * kCell, y, -0.5 * kCell);
    step.blade.emplace(Blade{tip, Vector3d::UnitZ(), 3 * kCell, tip0});
    const CutOutcome a = packed_stepper.ExecuteCut(packed_mesh, step, packed, params);
    const CutOutcome b = unpacked_stepper.ExecuteCut(unpacked_mesh, step, unpacked, params);
    ASSERT_EQ(a.status, CutStatus::kExecuted) << "step " << i;
    ASSERT_EQ(b.status, a.status) << "step " << i;
    ASSERT_EQ(b.event.splits.size(), a.event.splits.size()) << "step " << i;
    for (size_t k = 0; k < a.event.splits.size(); ++k) {
      EXPECT_EQ(b.event.splits[k].node, a.event.splits[k].node);
      EXPECT_EQ(b.event.splits[k].tets, a.event.splits[k].tets);
    }
    ASSERT_EQ(b.event.moves.size(), a.event.moves.size()) << "step " << i;
    for (size_t k = 0; k < a.event.moves.size(); ++k) {
      EXPECT_EQ(b.event.moves[k].node, a.event.moves[k].node);
      EXPECT_TRUE(b.event.moves[k].rest == a.event.moves[k].rest);
      EXPECT_TRUE(b.event.moves[k].world == a.event.moves[k].world);
    }
    splits += static_cast<int>(a.event.splits.size());
    packed.ApplyEvent(a.event);
    unpacked_store.ApplyEvent(b.event);
    v0 = step.v1;
    tip0 = tip;
  }
  EXPECT_GT(splits, 0);
  EXPECT_TRUE(packed_mesh.TetsMatrix() == unpacked_mesh.TetsMatrix());
}

TEST(CutMesh, ShallowBladeDoesNotSeparate) {
  // A blade reaching half the thickness opens a slit but the bottom holds.
  const mesh::TetMesh m = Box();
  CutMesh cm(m);
  VectorWorld world = WorldFromRest(m);
  const Reference ref(m);
  CutParams params;
  const double top = 2 * kCell;
  const auto path = testing::Segment(Vector3d(0.5 * kCell, 1.2 * kCell, top), Vector3d(3.5 * kCell, 1.2 * kCell, top), 60);
  const auto stats = testing::DrivePath(cm, world, path, 0.6 * kCell, params, nullptr, [&](int step) {
    ExpectInvariants(cm, world, ref, "shallow step " + std::to_string(step));
  });
  EXPECT_GE(stats.executed, 2);
  EXPECT_GT(stats.splits, 0);
  EXPECT_EQ(cm.NumConnectedComponents(), 1);
  std::vector<uint8_t> opened;
  (void)cm.SurfaceTriangles(&opened);
  EXPECT_GT(std::count(opened.begin(), opened.end(), 1), 0) << "the slit's faces are flagged opened";
}

TEST(CutMesh, ReplayingRecordedEventsReproducesTheTopologyBitExactly) {
  StraightCut sc;
  sc.Run();
  ASSERT_FALSE(sc.events.empty());
  CutMesh replay(sc.m);
  VectorWorld world = WorldFromRest(sc.m);
  for (const TopologyEvent& e : sc.events) {
    replay.ApplyEvent(e);
    world.ApplyEvent(e);
  }
  EXPECT_EQ(replay.version(), sc.cm.version());
  ASSERT_EQ(replay.num_nodes(), sc.cm.num_nodes());
  EXPECT_TRUE(replay.TetsMatrix() == sc.cm.TetsMatrix());
  for (int32_t v = 0; v < replay.num_nodes(); ++v) {
    // Bit-exact: compare the doubles with ==, not a tolerance.
    EXPECT_TRUE(replay.rest(v) == sc.cm.rest(v)) << "node " << v;
    EXPECT_TRUE(world.Get(v) == sc.world.Get(v)) << "node " << v;
  }
  std::vector<uint8_t> fa, fb;
  const auto ta = replay.SurfaceTriangles(&fa), tb = sc.cm.SurfaceTriangles(&fb);
  EXPECT_EQ(testing::OrientedSet(ta), testing::OrientedSet(tb));
  EXPECT_EQ(std::count(fa.begin(), fa.end(), 1), std::count(fb.begin(), fb.end(), 1));
  ExpectInvariants(replay, world, sc.ref, "replayed");
}

TEST(CutMesh, BadEventThrowsAndChangesNothing) {
  StraightCut sc;
  sc.Run();
  ASSERT_GE(sc.events.size(), 2u);
  CutMesh replay(sc.m);
  replay.ApplyEvent(sc.events[0]);
  const mesh::Tets before = replay.TetsMatrix();
  const mesh::Triangles surface_before = replay.SurfaceTriangles();
  const int32_t nodes_before = replay.num_nodes();
  EXPECT_THROW(replay.ApplyEvent(sc.events[0]), InputError) << "version out of order";
  TopologyEvent bad = sc.events[1];
  ASSERT_FALSE(bad.splits.empty());
  bad.splits.back().tets.push_back(bad.splits.back().tets.front());  // already retargeted
  try {
    replay.ApplyEvent(bad);
    FAIL() << "expected InputError";
  } catch (const InputError& e) {
    EXPECT_NE(e.source().field.find("event.splits"), std::string::npos) << e.what();
    EXPECT_NE(std::string(e.what()).find("listed twice"), std::string::npos) << e.what();
  }
  EXPECT_TRUE(replay.TetsMatrix() == before);
  // The same surface faces (a rollback may put them in other free slots).
  auto sorted_rows = [](const mesh::Triangles& tris) {
    std::vector<std::array<int32_t, 3>> rows;
    for (Eigen::Index i = 0; i < tris.rows(); ++i) rows.push_back({tris(i, 0), tris(i, 1), tris(i, 2)});
    std::sort(rows.begin(), rows.end());
    return rows;
  };
  EXPECT_EQ(sorted_rows(replay.SurfaceTriangles()), sorted_rows(surface_before));
  EXPECT_EQ(replay.num_nodes(), nodes_before);
  EXPECT_EQ(replay.version(), 1u);
  replay.ApplyEvent(sc.events[1]);  // the good one still applies
  EXPECT_EQ(replay.version(), 2u);
}

TEST(CutMesh, PartsJoinedOnlyByAVertexAreSeparated) {
  // Four tets around the edge c0–c1, ring r0..r3 in the plane z = 0.5. The
  // plane y = 0 (spanned by n = x̂ and s1 = c1 − c0) puts the tets at r1 on
  // one side and those at r3 on the other. Splitting c1 alone leaves the two
  // halves joined only through c0, r0 and r2 (vertex singularities); they
  // must be split too, leaving two separate two-tet parts.
  mesh::TetMesh m;
  m.nodes.resize(6, 3);
  m.nodes << 0, 0, 0,  //
      0, 0, 1,         //
      1, 0, 0.5,       //
      0, 1, 0.5,       //
      -1, 0, 0.5,      //
      0, -1, 0.5;
  m.tets.resize(4, 4);
  for (int i = 0; i < 4; ++i) {
    m.tets.row(i) << 0, 1, 2 + i, 2 + (i + 1) % 4;
    if (mesh::SignedVolume(m, i) < 0) std::swap(m.tets(i, 2), m.tets(i, 3));
  }
  ASSERT_NO_THROW(mesh::ValidateTetMesh(m, "fan"));
  CutMesh cm(m);
  CutStepper stepper;
  const VectorWorld w = WorldFromRest(m);
  const Reference ref(m);
  CutStep step;
  step.v0 = 0;
  step.v1 = 1;
  step.normal = Vector3d::UnitX();
  step.remesh = false;
  const CutOutcome out = stepper.ExecuteCut(cm, step, w, CutParams{});
  ASSERT_EQ(out.status, CutStatus::kExecuted);
  // c1 by the plane, then c0, r0 and r2 by the vertex rule.
  ASSERT_EQ(out.event.splits.size(), 4u);
  EXPECT_EQ(out.event.splits[0].node, 1);
  std::vector<int32_t> split_nodes;
  for (const Split& s : out.event.splits) split_nodes.push_back(s.node);
  std::sort(split_nodes.begin(), split_nodes.end());
  EXPECT_EQ(split_nodes, (std::vector<int32_t>{0, 1, 2, 4}));
  VectorWorld w2 = w;
  w2.ApplyEvent(out.event);
  ExpectInvariants(cm, w2, ref, "fan");
  EXPECT_EQ(cm.NumConnectedComponents(), 2);
  int32_t k = 0;
  (void)ConnectedComponents(cm.TetsMatrix(), &k);
  EXPECT_EQ(k, 2);
  EXPECT_EQ(out.event.touched_nodes.size(), 8u);
}

}  // namespace
}  // namespace cutsim::cutting
