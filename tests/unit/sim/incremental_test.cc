// The simulation's incremental upkeep after cuts against whole-mesh
// recomputation: a cut's topology event applied to the FEM (only the moved
// nodes' elements recomputed); the slot-indexed surface (fed to the BVH by
// Insert/Remove) after real cuts, compared with a fresh extraction, with
// one thread and with two; and the debris flags kept by local floods after
// each cut, compared with the connected components of the whole mesh.
#include <algorithm>
#include <array>
#include <map>
#include <numeric>
#include <random>
#include <span>
#include <string>
#include <vector>

#include <gtest/gtest.h>

#include "common/fem/model.h"
#include "common/fem/stable_dt.h"
#include "common/fem/state.h"
#include "common/mesh/generators.h"
#include "common/mesh/surface.h"
#include "common/sim/debris.h"
#include "common/sim/fem_event.h"
#include "common/sim/scene_loader.h"
#include "common/sim/simulation.h"
#include "tests/unit/cutting/cut_driver.h"
#include "tests/unit/cutting/test_util.h"

namespace cutsim {
namespace {

// Real cut events applied to the FEM the way the simulation applies them
// (sim::ApplyEventToFem: only the moved nodes' elements and stable-step
// leaves are recomputed): after every event the elements, node masses and
// stable-step leaves must equal a whole-mesh recomputation bit for bit,
// the world positions must follow the cut's world, and neither the mass
// nor the linear momentum may change beyond round-off (a split copies its
// node's velocity and the masses follow the tets).
TEST(IncrementalFem, EventsMatchAWholeMeshRecomputeAndKeepMassAndMomentum) {
  using Eigen::Vector3d;
  const mesh::TetMesh m = cutting::testing::KuhnBox(Vector3d::Zero(), Vector3d(0.06, 0.04, 0.02), 6, 4, 2, 0.2, 5);
  fem::ModelOptions options;
  options.node_capacity = 4 * m.num_nodes();
  const fem::Material tissue = fem::Material::FromYoungPoisson(5e4, 0.4, 1000, 2.0, 1.0);
  fem::Model<double> model(m, std::span(&tissue, 1), options);
  fem::State<double> state(model);
  std::mt19937 rng(9);
  std::uniform_real_distribution<double> u(-0.2, 0.2);
  for (int32_t i = 0; i < 3 * model.num_nodes(); ++i) state.v[static_cast<size_t>(i)] = u(rng);
  fem::RefreshStableStep(model, state, true, 1);
  auto momentum = [&] {
    Vector3d p = Vector3d::Zero();
    for (int32_t n = 0; n < model.num_nodes(); ++n) {
      const auto i = 3 * static_cast<size_t>(n);
      p += model.node_mass(n) * Vector3d(state.v[i], state.v[i + 1], state.v[i + 2]);
    }
    return p;
  };
  const double m0 = model.TotalMass();
  const Vector3d p0 = momentum();
  double speed_scale = 0.0;  // Σ m|v|: the round-off scale of the momentum sum
  for (int32_t n = 0; n < model.num_nodes(); ++n) {
    const auto i = 3 * static_cast<size_t>(n);
    speed_scale += model.node_mass(n) * Vector3d(state.v[i], state.v[i + 1], state.v[i + 2]).norm();
  }

  cutting::CutMesh cm(m);
  cutting::VectorWorld world = cutting::testing::WorldFromRest(m);
  std::vector<cutting::TopologyEvent> events;
  sim::FemEventScratch scratch;
  int applied = 0, with_moves = 0;
  auto check = [&](int) {
    if (static_cast<int>(events.size()) == applied) return;
    const cutting::TopologyEvent& e = events.back();
    ++applied;
    with_moves += e.moves.empty() ? 0 : 1;
    sim::ApplyEventToFem(e, model, state, true, scratch);
    ASSERT_EQ(model.num_nodes(), cm.num_nodes());
    for (int32_t n = 0; n < model.num_nodes(); ++n) {
      const auto i = 3 * static_cast<size_t>(n);
      ASSERT_EQ(Vector3d(state.x[i], state.x[i + 1], state.x[i + 2]), world.Get(n)) << "node " << n;
      ASSERT_EQ(model.rest_position(n), cm.rest(n)) << "node " << n;
    }
    EXPECT_NEAR(model.TotalMass(), m0, 1e-12 * m0);
    EXPECT_LT((momentum() - p0).norm(), 1e-13 * speed_scale) << "event " << applied;
    // Whole-mesh recomputation on copies.
    fem::Model<double> full = model;
    std::vector<int32_t> all_tets(static_cast<size_t>(model.num_tets()));
    std::vector<int32_t> all_nodes(static_cast<size_t>(model.num_nodes()));
    std::iota(all_tets.begin(), all_tets.end(), 0);
    std::iota(all_nodes.begin(), all_nodes.end(), 0);
    ASSERT_EQ(full.RecomputeElements(all_tets), 0);
    full.RecomputeNodeMasses(all_nodes);
    fem::State<double> fresh = state;
    fem::RefreshStableStep(model, fresh, true, 1);
    for (int32_t t = 0; t < model.num_tets(); ++t) {
      ASSERT_TRUE(model.DmInv(t) == full.DmInv(t)) << "tet " << t << ", event " << applied;
      ASSERT_EQ(model.rest_volume(t), full.rest_volume(t)) << "tet " << t;
      ASSERT_EQ(model.grad_sq_max(t), full.grad_sq_max(t)) << "tet " << t;
      ASSERT_EQ(state.element_dt[static_cast<size_t>(t)], fresh.element_dt[static_cast<size_t>(t)])
          << "stable step of tet " << t << ", event " << applied;
    }
    ASSERT_EQ(fem::StableStepBound(state), fem::StableStepBound(fresh));
    for (int32_t n = 0; n < model.num_nodes(); ++n) ASSERT_EQ(model.node_mass(n), full.node_mass(n)) << "node " << n;
  };
  cutting::CutParams params;
  // Along the block, then across it and the first cut (twins, singularities).
  (void)cutting::testing::DrivePath(cm, world, cutting::testing::Segment(Vector3d(0.001, 0.021, 0.02),
                                                                          Vector3d(0.059, 0.017, 0.02), 40),
                                    0.03, params, &events, check);
  ASSERT_FALSE(::testing::Test::HasFatalFailure());
  EXPECT_EQ(cm.NumConnectedComponents(), 2) << "a blade deeper than the block cuts it through";
  (void)cutting::testing::DrivePath(cm, world, cutting::testing::Segment(Vector3d(0.031, 0.001, 0.02),
                                                                          Vector3d(0.027, 0.039, 0.02), 30),
                                    0.03, params, &events, check);
  EXPECT_GE(applied, 8);
  EXPECT_GT(with_moves, 0) << "no event moved a node: the recompute was not exercised";
}


namespace {

// A block of `cells` (the mesh's box fields) on a fixed base, cut at
// K_I = 1 Pa by a blade longer than the block is thick, its tip 1 mm below
// the base and drawn from (x0, y0) to (x1, y1) in `seconds`.
std::string BladeScene(const std::string& cells, double x0, double y0, double x1, double y1, double seconds,
                       int threads) {
  auto tip = [](double x, double y) {
    return "tip { x: " + std::to_string(x) + " y: " + std::to_string(y) + " z: -0.001 } blade_dir { z: 1 }";
  };
  return "name: \"blade\"\nmesh { box { min { x: 0 y: 0 z: 0 } " + cells + " } }\n" + R"pb(
materials { name: "tissue" young_poisson { youngs_modulus: 50000 poisson_ratio: 0.4 } density: 1000 damping_psi: 0.5 }
boundary { plane { point { x: 0 y: 0 z: 0 } normal { x: 0 y: 0 z: 1 } } kind: KIND_FIXED }
cutting { enabled: true alpha: 0.4 kappa: 1.0 zeta: 1.0 critical_stress: 1 }
)pb" + "tool { blade_length: 0.025 keyframes { t: 0 " + tip(x0, y0) + " } keyframes { t: " + std::to_string(seconds) +
         " " + tip(x1, y1) + " } }\ntime_step { frame_dt: 0.002 threads: " + std::to_string(threads) + " }\n";
}

// A 6×4×2-cell block slit along x by a blade deeper than it.
std::string SlitScene(int threads) {
  return BladeScene("max { x: 0.015 y: 0.01 z: 0.005 } nx: 6 ny: 4 nz: 2", -0.002, 0.0051, 0.017, 0.0051, 0.12,
                    threads);
}

}  // namespace

// A block cut by a scripted blade: after every frame the simulation's
// surface (kept by slot, edited locally) must equal the surface extracted
// from its tets, and the opened flags must mark only faces absent from the
// uncut surface.
TEST(IncrementalSurface, MatchesExtractionAfterEveryCut) {
  const sim::LoadedScene scene = sim::ParseScene(SlitScene(1), "incremental.pbtxt", ".");
  auto sim = sim::Simulation::Create(scene);
  auto sorted_rows = [](const mesh::Triangles& tris) {
    std::vector<std::array<int32_t, 3>> rows;
    for (Eigen::Index f = 0; f < tris.rows(); ++f) {
      std::array<int32_t, 3> r = {tris(f, 0), tris(f, 1), tris(f, 2)};
      std::rotate(r.begin(), std::min_element(r.begin(), r.end()), r.end());  // keep orientation
      rows.push_back(r);
    }
    std::sort(rows.begin(), rows.end());
    return rows;
  };
  sim::MeshView view;
  sim->FillMeshView(view);
  const size_t uncut_faces = static_cast<size_t>(view.surface.rows());
  for (int frame = 0; frame < 60; ++frame) {
    ASSERT_EQ(sim->AdvanceFrame(), sim::SimStatus::kOk);
    if (!sim->Tool().cut_this_frame) continue;
    sim->FillMeshView(view);
    const mesh::Surface fresh = mesh::ExtractSurface(view.tets);
    ASSERT_EQ(sorted_rows(view.surface), sorted_rows(fresh.tris)) << "frame " << frame;
    const auto opened = static_cast<size_t>(std::count(view.opened.begin(), view.opened.end(), uint8_t{1}));
    EXPECT_EQ(opened, static_cast<size_t>(view.surface.rows()) - uncut_faces)
        << "a cut only adds faces, and exactly those are opened";
  }
  EXPECT_GE(sim->Summary().cuts, 4u);
  EXPECT_GE(sim->Summary().components, 2) << "the blade reaches below the block: through-cut";
  EXPECT_EQ(sim->CutTimings().size(), sim->Summary().cuts);
}

// With two threads a cut step runs its criterion beside the slab walk and
// its FEM half beside its surface half (cut_pipeline.h).
// Neither side may read what the other writes: after every frame, two
// threads must give what one gives, bit for bit (the FEM step's force sums
// are thread-count independent): world and rest positions, tets, surface
// and opened flags, and the contact found next.
TEST(IncrementalSurfaceSlow, TwoThreadsCutAsOneDoes) {
  auto one = sim::Simulation::Create(sim::ParseScene(SlitScene(1), "one.pbtxt", "."));
  auto two = sim::Simulation::Create(sim::ParseScene(SlitScene(2), "two.pbtxt", "."));
  sim::MeshView a, b;
  for (int frame = 0; frame < 60; ++frame) {
    SCOPED_TRACE("frame " + std::to_string(frame));
    ASSERT_EQ(one->AdvanceFrame(), sim::SimStatus::kOk);
    ASSERT_EQ(two->AdvanceFrame(), sim::SimStatus::kOk);
    one->FillMeshView(a);
    two->FillMeshView(b);
    ASSERT_EQ(a.tets, b.tets);
    ASSERT_EQ(a.world, b.world);
    ASSERT_EQ(a.rest, b.rest);
    ASSERT_EQ(a.surface, b.surface);
    ASSERT_EQ(a.opened, b.opened);
    const sim::ToolReport ta = one->Tool(), tb = two->Tool();
    ASSERT_EQ(ta.touching, tb.touching);
    ASSERT_EQ(ta.point, tb.point);
    ASSERT_EQ(ta.force_on_tool, tb.force_on_tool);
    ASSERT_EQ(ta.sigma_c, tb.sigma_c);
    // The stable-step estimate too, bit for bit (its sums run in a fixed order).
    ASSERT_EQ(one->Summary().stable_dt, two->Summary().stable_dt);
  }
  EXPECT_GE(two->Summary().cuts, 4u);
  for (const sim::CutStepTiming& t : two->CutTimings()) EXPECT_GT(t.apply, 0.0);
}


// The simulation's per-facet debris flags (the blade passes through those
// facets) after every cut step, against the whole-mesh rule on its own
// mesh view: a face-connected piece with < 1 % of the mass and < 64 tets
// (DebrisTracker::Limits' defaults, the simulation's) is debris. A blade
// drawn through the end of a 120-cell bar cuts off one cell column (12 of
// 1 440 tets, 0.8 % of the mass). With one thread and with two (the flood
// then runs beside the surface update, and the flags are set after both).
TEST(IncrementalDebrisSlow, SimulationFlagsTheFacetsOfACutOffPiece) {
  for (const int threads : {1, 2}) {
    SCOPED_TRACE(std::to_string(threads) + " threads");
    const std::string text = BladeScene("max { x: 0.24 y: 0.004 z: 0.002 } nx: 120 ny: 2 nz: 1", 0.0021, -0.002,
                                        0.0021, 0.006, 0.06, threads);
    auto engine = sim::Simulation::Create(sim::ParseScene(text, "bar-end.pbtxt", "."));
    sim::MeshView view;
    int32_t flagged = 0;
    for (int frame = 0; frame < 40; ++frame) {
      SCOPED_TRACE("frame " + std::to_string(frame));
      ASSERT_EQ(engine->AdvanceFrame(), sim::SimStatus::kOk);
      if (!engine->Tool().cut_this_frame) continue;
      engine->FillMeshView(view);
      ASSERT_EQ(view.debris.size(), static_cast<size_t>(view.surface.rows()));
      // The whole-mesh rule on the view: pieces, their masses and sizes.
      int32_t pieces = 0;
      const std::vector<int32_t> label = cutting::ConnectedComponents(view.tets, &pieces);
      const mesh::TetMesh rest{view.rest, view.tets};
      std::vector<double> mass(static_cast<size_t>(pieces), 0.0);
      std::vector<int32_t> count(static_cast<size_t>(pieces), 0);
      double total = 0.0;
      for (int32_t t = 0; t < rest.num_tets(); ++t) {
        const double m = 1000.0 * mesh::SignedVolume(rest, t);
        mass[static_cast<size_t>(label[static_cast<size_t>(t)])] += m;
        ++count[static_cast<size_t>(label[static_cast<size_t>(t)])];
        total += m;
      }
      // Each surface facet's tet, by its sorted node triple.
      std::map<std::array<int32_t, 3>, int32_t> owner;
      for (int32_t t = 0; t < rest.num_tets(); ++t) {
        for (int f = 0; f < 4; ++f) {
          std::array<int32_t, 3> key;
          for (int k = 0, j = 0; k < 4; ++k)
            if (k != f) key[static_cast<size_t>(j++)] = view.tets(t, k);
          std::sort(key.begin(), key.end());
          owner[key] = t;
        }
      }
      for (Eigen::Index f = 0; f < view.surface.rows(); ++f) {
        std::array<int32_t, 3> key = {view.surface(f, 0), view.surface(f, 1), view.surface(f, 2)};
        std::sort(key.begin(), key.end());
        const auto it = owner.find(key);
        ASSERT_NE(it, owner.end()) << "facet " << f;
        const auto piece = static_cast<size_t>(label[static_cast<size_t>(it->second)]);
        const uint8_t expected = mass[piece] < 0.01 * total && count[piece] < 64 ? 1 : 0;
        ASSERT_EQ(view.debris[static_cast<size_t>(f)], expected) << "facet " << f << " of tet " << it->second;
      }
      flagged = static_cast<int32_t>(std::count(view.debris.begin(), view.debris.end(), uint8_t{1}));
    }
    EXPECT_EQ(engine->Summary().components, 2);
    EXPECT_GT(flagged, 0) << "the cut-off column is debris";
  }
}

// Random strokes through the whole depth of a thin jittered block cut
// corners and strips loose. After every cut the tracker's local update must
// flag exactly what the whole-mesh rule (connected components, mass and tet
// count) flags. The mass bound is raised to 5 % so that pieces of a few
// cells count as debris on this small mesh; with a 90 % bound and 32 tets,
// the count alone decides (the floods then skip the masses, as on a fine
// mesh).
TEST(IncrementalDebris, LocalFloodsMatchTheWholeMeshRuleAfterEveryCut) {
  using Eigen::Vector3d;
  int32_t flagged_total = 0, flagged_by_count = 0;
  int cuts = 0;
  for (uint32_t seed = 1; seed <= 12; ++seed) {
    SCOPED_TRACE("seed " + std::to_string(seed));
    using Limits = sim::DebrisTracker::Limits;
    const Limits limits = seed <= 6 ? Limits{.mass_fraction = 0.05, .max_tets = 64}
                                    : Limits{.mass_fraction = 0.9, .max_tets = 32};
    const mesh::TetMesh m = cutting::testing::KuhnBox(Vector3d::Zero(), Vector3d(0.06, 0.04, 0.02), 6, 4, 2, 0.2, seed);
    cutting::CutMesh cm(m);
    cutting::VectorWorld world = cutting::testing::WorldFromRest(m);
    std::vector<double> mass(static_cast<size_t>(m.num_tets()));
    double total = 0.0;
    for (int32_t t = 0; t < m.num_tets(); ++t) {
      mass[static_cast<size_t>(t)] = 1000.0 * mesh::SignedVolume(m, t);
      total += mass[static_cast<size_t>(t)];
    }
    sim::DebrisTracker tracker(mass, total, limits);
    tracker.Reset(cm);
    ASSERT_EQ(tracker.num_debris_tets(), 0);
    std::mt19937 rng(seed);
    std::uniform_real_distribution<double> u(0.0, 1.0);
    cutting::CutParams params;
    std::vector<cutting::TopologyEvent> events;
    std::vector<int32_t> flagged;
    for (int stroke = 0; stroke < 6; ++stroke) {
      // A chord of the top face between two random points on its sides.
      auto on_side = [&](int side) {
        const double s = 0.05 + 0.9 * u(rng);
        switch (side) {
          case 0: return Vector3d(0.0005, 0.04 * s, 0.02);
          case 1: return Vector3d(0.0595, 0.04 * s, 0.02);
          case 2: return Vector3d(0.06 * s, 0.0005, 0.02);
          default: return Vector3d(0.06 * s, 0.0395, 0.02);
        }
      };
      const int a = static_cast<int>(4 * u(rng)) % 4;
      const int b = (a + 1 + static_cast<int>(3 * u(rng)) % 3) % 4;
      const Vector3d p = on_side(a), q = on_side(b);
      const int n = std::max(2, static_cast<int>((q - p).norm() / 0.0015));
      size_t seen_events = events.size();
      cuts += cutting::testing::DrivePath(cm, world, cutting::testing::Segment(p, q, n), 0.025, params, &events,
                                          [&](int) {
                                            if (events.size() == seen_events) return;  // nothing changed
                                            seen_events = events.size();
                                            flagged.clear();
                                            tracker.Update(cm, events.back().splits, &flagged);
                                            flagged_total += static_cast<int32_t>(flagged.size());
                                            if (seed > 6) flagged_by_count += static_cast<int32_t>(flagged.size());
                                            sim::DebrisTracker fresh(mass, total, limits);
                                            fresh.Reset(cm);
                                            ASSERT_EQ(tracker.num_debris_tets(), fresh.num_debris_tets());
                                            for (int32_t t = 0; t < cm.num_tets(); ++t) {
                                              ASSERT_EQ(tracker.is_debris(t), fresh.is_debris(t)) << "tet " << t;
                                            }
                                          })
                  .executed;
      if (::testing::Test::HasFatalFailure()) return;
    }
  }
  EXPECT_GE(cuts, 100);
  EXPECT_GT(flagged_total, 0) << "no piece came loose: the comparison above checked nothing";
  EXPECT_GT(flagged_by_count, 0) << "no piece came loose where the count alone decides";
}


}  // namespace
}  // namespace cutsim
