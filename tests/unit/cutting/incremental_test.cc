// The cut step's local bookkeeping against whole-mesh recomputation: the
// FEM's node → element incidence after splits (including its compaction);
// and the cut complex's prepared cut and separation callback, which the
// simulation's cut pipeline relies on. The simulation's own incremental
// upkeep (FEM events, surface, debris) is tested in tests/unit/sim.
#include <algorithm>
#include <array>
#include <atomic>
#include <map>
#include <numeric>
#include <random>
#include <span>
#include <string>
#include <vector>

#include <gtest/gtest.h>

#include "common/fem/model.h"
#include "common/fem/state.h"
#include "common/mesh/generators.h"
#include "common/mesh/surface.h"
#include "tests/unit/cutting/cut_driver.h"
#include "tests/unit/cutting/test_util.h"

namespace cutsim {
namespace {

// Incidence as the gather loop reads it, per node, sorted.
std::vector<std::vector<int32_t>> Incidence(const fem::Model<double>& model) {
  std::vector<std::vector<int32_t>> out(static_cast<size_t>(model.num_nodes()));
  for (int32_t n = 0; n < model.num_nodes(); ++n) {
    for (int32_t k = model.incidence_begin(n); k < model.incidence_end(n); ++k) {
      out[static_cast<size_t>(n)].push_back(model.incidence_slots()[k]);
    }
    EXPECT_TRUE(std::is_sorted(out[static_cast<size_t>(n)].begin(), out[static_cast<size_t>(n)].end()))
        << "node " << n << ": slots must stay ascending";
  }
  return out;
}

std::vector<std::vector<int32_t>> BruteIncidence(const fem::Model<double>& model) {
  std::vector<std::vector<int32_t>> out(static_cast<size_t>(model.num_nodes()));
  for (int32_t t = 0; t < model.num_tets(); ++t) {
    for (int c = 0; c < 4; ++c) out[static_cast<size_t>(model.tet_node(t, c))].push_back(12 * t + 3 * c);
  }
  return out;  // tets ascending, so already sorted
}

TEST(IncrementalIncidence, RandomSplitsMatchRebuildAndKeepMass) {
  const mesh::TetMesh box = mesh::MakeBox(Eigen::Vector3d::Zero(), Eigen::Vector3d(0.02, 0.01, 0.01), 6, 3, 3);
  fem::ModelOptions options;
  options.node_capacity = 8 * box.num_nodes();  // room for many copies
  const fem::Material tissue = fem::Material::FromYoungPoisson(5e4, 0.4, 1000);
  fem::Model<double> model(box, std::span(&tissue, 1), options);
  fem::State<double> state(model);
  const double m0 = model.TotalMass();
  std::mt19937 rng(3);
  // Enough retargets to fill the append region (2·T slots) several times.
  for (int round = 0; round < 600 && model.num_nodes() < model.node_capacity(); ++round) {
    const int32_t t = std::uniform_int_distribution<int32_t>(0, model.num_tets() - 1)(rng);
    const int corner = std::uniform_int_distribution<int>(0, 3)(rng);
    const int32_t node = model.tet_node(t, corner);
    const int32_t copy = model.AddNodeCopy(node, state);
    // Move every tet of the node on one side of a random plane through it.
    std::vector<int32_t> moved;
    const Eigen::Vector3d axis = Eigen::Vector3d::Random().normalized();
    const Eigen::Vector3d p = model.rest_position(node);
    for (int32_t u = 0; u < model.num_tets(); ++u) {
      for (int c = 0; c < 4; ++c) {
        if (model.tet_node(u, c) != node) continue;
        Eigen::Vector3d centroid = Eigen::Vector3d::Zero();
        for (int k = 0; k < 4; ++k) centroid += model.rest_position(model.tet_node(u, k)) / 4;
        if ((centroid - p).dot(axis) > 0) {
          model.RetargetTet(u, c, copy);
          moved.push_back(u);
        }
      }
    }
    const std::vector<int32_t> nodes = {node, copy};
    model.RecomputeNodeMasses(nodes);
    model.CommitTopology();
    if (round % 50 == 0) {
      ASSERT_EQ(Incidence(model), BruteIncidence(model)) << "round " << round;
    }
  }
  EXPECT_EQ(Incidence(model), BruteIncidence(model));
  EXPECT_GT(model.incidence_compactions(), 0) << "the append region filled up at least once";
  EXPECT_NEAR(model.TotalMass(), m0, 1e-12 * m0);
}

// CutStepper::PrepareCut (steps 1–2 ahead, as the simulation runs them beside
// the criterion with two threads) then ExecuteCut must cut exactly as
// ExecuteCut alone: strokes along, across and diagonally through a jittered
// block (twins, snaps, singularities), every event equal. A prepared cut
// made before another cut changed the mesh must be ignored, and a cancelled
// one is not valid.
TEST(PreparedCut, CutsAsExecuteCutAlone) {
  using Eigen::Vector3d;
  using cutting::testing::Segment;
  const mesh::TetMesh m = cutting::testing::KuhnBox(Vector3d::Zero(), Vector3d(0.06, 0.04, 0.02), 6, 4, 2, 0.2, 7);
  cutting::CutMesh plain(m), prepared(m);
  cutting::VectorWorld world_plain = cutting::testing::WorldFromRest(m);
  cutting::VectorWorld world_prepared = world_plain;
  std::vector<cutting::TopologyEvent> ev_plain, ev_prepared;
  const cutting::CutParams params;
  const std::vector<std::vector<Vector3d>> strokes = {
      Segment(Vector3d(0.001, 0.021, 0.02), Vector3d(0.059, 0.017, 0.02), 40),
      Segment(Vector3d(0.031, 0.001, 0.02), Vector3d(0.027, 0.039, 0.02), 30),
      Segment(Vector3d(0.005, 0.035, 0.02), Vector3d(0.052, 0.004, 0.02), 40)};
  for (const auto& stroke : strokes) {
    (void)cutting::testing::DrivePath(plain, world_plain, stroke, 0.012, params, &ev_plain, [](int) {});
    (void)cutting::testing::DrivePath(prepared, world_prepared, stroke, 0.012, params, &ev_prepared, [](int) {},
                                      /*prepare=*/true);
  }
  ASSERT_GE(ev_plain.size(), 10u);
  ASSERT_EQ(ev_prepared.size(), ev_plain.size());
  for (size_t i = 0; i < ev_plain.size(); ++i) {
    SCOPED_TRACE("event " + std::to_string(i));
    const cutting::TopologyEvent &a = ev_plain[i], &b = ev_prepared[i];
    EXPECT_EQ(a.version, b.version);
    ASSERT_EQ(a.splits.size(), b.splits.size());
    for (size_t k = 0; k < a.splits.size(); ++k) {
      EXPECT_EQ(a.splits[k].node, b.splits[k].node);
      EXPECT_EQ(a.splits[k].new_node, b.splits[k].new_node);
      EXPECT_EQ(a.splits[k].tets, b.splits[k].tets);
    }
    ASSERT_EQ(a.moves.size(), b.moves.size());
    for (size_t k = 0; k < a.moves.size(); ++k) {
      EXPECT_EQ(a.moves[k].node, b.moves[k].node);
      EXPECT_EQ(a.moves[k].rest, b.moves[k].rest);
      EXPECT_EQ(a.moves[k].world, b.moves[k].world);
    }
    EXPECT_EQ(a.touched_tets, b.touched_tets);
  }
  EXPECT_EQ(plain.TetsMatrix(), prepared.TetsMatrix());

  // Stale: prepared for one step, then another cut executed first.
  cutting::CutMesh fresh(m), stale(m);
  cutting::CutStepper fresh_stepper, stale_stepper;
  cutting::VectorWorld world_fresh = cutting::testing::WorldFromRest(m);
  cutting::VectorWorld world_stale = world_fresh;
  const auto first = Segment(Vector3d(0.001, 0.021, 0.02), Vector3d(0.03, 0.019, 0.02), 20);
  (void)cutting::testing::DrivePath(fresh, world_fresh, first, 0.012, params, nullptr, [](int) {});
  (void)cutting::testing::DrivePath(stale, world_stale, first, 0.012, params, nullptr, [](int) {});
  cutting::CutStep next;
  next.v1 = cutting::testing::ClosestTopVertex(fresh, world_fresh, Vector3d(0.036, 0.019, 0.02));
  next.v0 = cutting::testing::ClosestTopVertex(fresh, world_fresh, Vector3d(0.03, 0.019, 0.02));
  next.cp0 = Vector3d(0.03, 0.019, 0.02);
  next.cp = Vector3d(0.036, 0.019, 0.02);
  next.normal = Vector3d::UnitZ();
  next.blade.emplace(cutting::Blade{next.cp - 0.012 * Vector3d::UnitZ(), Vector3d::UnitZ(), 0.022});
  cutting::CutStep other = next;
  other.cp0 = Vector3d(0.015, 0.03, 0.02);
  other.cp = Vector3d(0.015, 0.036, 0.02);
  other.v0 = cutting::testing::ClosestTopVertex(fresh, world_fresh, other.cp0);
  other.v1 = cutting::testing::ClosestTopVertex(fresh, world_fresh, other.cp);
  other.blade.emplace(cutting::Blade{other.cp - 0.012 * Vector3d::UnitZ(), Vector3d::UnitZ(), 0.022});
  const cutting::PreparedCut old = stale_stepper.PrepareCut(stale, next, world_stale, params);
  ASSERT_TRUE(old.valid);
  for (auto* pair : {&fresh, &stale}) {
    cutting::VectorWorld& w = pair == &fresh ? world_fresh : world_stale;
    cutting::CutStepper& stepper = pair == &fresh ? fresh_stepper : stale_stepper;
    const cutting::CutOutcome o = stepper.ExecuteCut(*pair, other, w, params);
    ASSERT_EQ(o.status, cutting::CutStatus::kExecuted);
    w.ApplyEvent(o.event);
  }
  const cutting::CutOutcome a = fresh_stepper.ExecuteCut(fresh, next, world_fresh, params);
  const cutting::CutOutcome b = stale_stepper.ExecuteCut(stale, next, world_stale, params, &old);
  ASSERT_EQ(a.status, b.status);
  ASSERT_EQ(a.event.splits.size(), b.event.splits.size());
  for (size_t k = 0; k < a.event.splits.size(); ++k) EXPECT_EQ(a.event.splits[k].tets, b.event.splits[k].tets);
  EXPECT_EQ(fresh.TetsMatrix(), stale.TetsMatrix());

  const std::atomic<bool> cancel{true};
  EXPECT_FALSE(fresh_stepper.PrepareCut(fresh, next, world_fresh, params, &cancel).valid);
}

// ExecuteCut's SeparatedCallback (the sim updates the surface beside the
// remeshing moves on it): called once per executed step, when the topology
// is final and before the moves. The splits it gets are the event's, the
// tets are already the final ones, and the rest positions are still those
// before the moves. Fails if it is called before the splits are done or
// after the moves.
TEST(SeparatedCallback, SeesTheFinalTopologyBeforeTheMoves) {
  using Eigen::Vector3d;
  using cutting::testing::Segment;
  const mesh::TetMesh m = cutting::testing::KuhnBox(Vector3d::Zero(), Vector3d(0.06, 0.04, 0.02), 6, 4, 2, 0.2, 7);
  cutting::CutMesh cm(m);
  cutting::VectorWorld world = cutting::testing::WorldFromRest(m);
  const cutting::CutParams params;
  (void)cutting::testing::DrivePath(cm, world, Segment(Vector3d(0.001, 0.021, 0.02), Vector3d(0.03, 0.019, 0.02), 20),
                                    0.012, params, nullptr, [](int) {});
  cutting::CutStep next;
  next.cp0 = Vector3d(0.03, 0.019, 0.02);
  next.cp = Vector3d(0.036, 0.019, 0.02);
  next.v0 = cutting::testing::ClosestTopVertex(cm, world, next.cp0);
  next.v1 = cutting::testing::ClosestTopVertex(cm, world, next.cp);
  next.normal = Vector3d::UnitZ();
  next.blade.emplace(cutting::Blade{next.cp - 0.012 * Vector3d::UnitZ(), Vector3d::UnitZ(), 0.022});

  int calls = 0;
  std::vector<cutting::Split> seen;
  mesh::Tets tets_then;
  mesh::TetMesh rest_then;
  const cutting::SeparatedCallback hook = [&](std::span<const cutting::Split> splits) {
    ++calls;
    seen.assign(splits.begin(), splits.end());
    tets_then = cm.TetsMatrix();
    rest_then = cm.RestMesh();
  };
  const cutting::CutOutcome o = cutting::CutStepper().ExecuteCut(cm, next, world, params, nullptr, &hook);
  ASSERT_EQ(o.status, cutting::CutStatus::kExecuted);
  EXPECT_EQ(calls, 1);
  ASSERT_FALSE(o.event.splits.empty());
  ASSERT_FALSE(o.event.moves.empty());
  ASSERT_EQ(seen.size(), o.event.splits.size());
  for (size_t k = 0; k < seen.size(); ++k) {
    EXPECT_EQ(seen[k].node, o.event.splits[k].node);
    EXPECT_EQ(seen[k].new_node, o.event.splits[k].new_node);
    EXPECT_EQ(seen[k].tets, o.event.splits[k].tets);
  }
  EXPECT_EQ(tets_then, cm.TetsMatrix());
  const mesh::TetMesh rest_now = cm.RestMesh();
  ASSERT_EQ(rest_then.num_nodes(), rest_now.num_nodes());
  std::vector<uint8_t> moved(static_cast<size_t>(rest_now.num_nodes()), 0);
  int moved_later = 0;
  for (const cutting::Move& mv : o.event.moves) {
    moved[static_cast<size_t>(mv.node)] = 1;
    EXPECT_EQ(Vector3d(rest_now.nodes.row(mv.node)), mv.rest);
    if (Vector3d(rest_then.nodes.row(mv.node)) != mv.rest) ++moved_later;
  }
  EXPECT_GT(moved_later, 0) << "the callback ran after the moves";
  for (int32_t n = 0; n < rest_now.num_nodes(); ++n) {
    if (moved[static_cast<size_t>(n)] != 0) continue;
    EXPECT_EQ(rest_then.nodes.row(n), rest_now.nodes.row(n)) << "node " << n;
  }
}

}  // namespace
}  // namespace cutsim
