// The score against a planned incision (common/sim/incision_score.h): the
// geometry against distances worked by hand, then scripted cuts of the block
// with known offsets from the plan, scored as the offsets say; a checkpoint
// keeps the score's series.

#include <cmath>
#include <filesystem>
#include <string>
#include <utility>
#include <vector>

#include <fmt/format.h>
#include <gtest/gtest.h>

#include "common/core/error.h"
#include "common/mesh/generators.h"
#include "common/sim/incision_score.h"
#include "common/sim/scene_loader.h"
#include "common/sim/simulation.h"
#include "cutsim/v1/checkpoint.pb.h"

namespace cutsim::sim {
namespace {

PlannedIncision LPlan() {
  // An L on the plane z = 0.01: along x, then along y.
  return {.points = {{0, 0, 0.01}, {0.02, 0, 0.01}, {0.02, 0.01, 0.01}}, .normal = {0, 0, 1}, .depth = 0.005,
          .tolerance = 0.001};
}

TEST(IncisionScorer, DeviationIsTheDistanceAcrossTheSurface) {
  const IncisionScorer s(LPlan());
  EXPECT_NEAR(s.Deviation({0.01, 0.003, 0.01}), 0.003, 1e-15);
  // Height along the normal does not count: a point below the plan is on it.
  EXPECT_NEAR(s.Deviation({0.01, 0.0, 0.002}), 0.0, 1e-15);
  // Beyond the corner: the distance to the nearest segment.
  EXPECT_NEAR(s.Deviation({0.023, 0.005, 0.01}), 0.003, 1e-15);
  // Past the end: the distance to the end point.
  EXPECT_NEAR(s.Deviation({-0.003, -0.004, 0.01}), 0.005, 1e-15);
}

TEST(IncisionScorer, MeanAndMaxFollowTheCutPoints) {
  IncisionScorer s(LPlan());
  // Cut points along the first half of the x leg at 0.5 mm off, one stray.
  for (int i = 0; i <= 20; ++i) s.AddCutPoint(0.1 * i, {0.0005 * i, 0.0005, 0.01});
  s.AddCutPoint(2.2, {0.015, 0.004, 0.01});
  const mesh::Triangles none(0, 3);
  const std::vector<double> rest;
  const IncisionScore score = s.Score<double>(rest.data(), none, {}, SessionMetrics{}, 2.2);
  EXPECT_EQ(score.cut_points(), 22);
  EXPECT_NEAR(score.mean_deviation(), (21 * 0.0005 + 0.004) / 22, 1e-12);
  EXPECT_NEAR(score.max_deviation(), 0.004, 1e-12);
  // Coverage is what is opened, not where the blade touched: nothing yet.
  EXPECT_EQ(score.coverage(), 0.0);
}

/// Walls y = `y` (rest frame) over x ∈ [x0, x1], z ∈ [z0, z1], two
/// triangles each, all opened, scored against a straight 30 mm plan along
/// x on the top z = 10 mm of a block, 10 mm deep.
struct Wall {
  double x0, x1, z0, z1, y;
};
IncisionScore ScoreWalls(const std::vector<Wall>& walls, const mesh::TetMesh* tissue = nullptr) {
  IncisionScorer s({.points = {{0, 0, 0.01}, {0.03, 0, 0.01}}, .normal = {0, 0, 1}, .depth = 0.01, .tolerance = 0.002});
  if (tissue != nullptr) s.SetTissue(*tissue);
  std::vector<double> rest;
  mesh::Triangles tri(static_cast<Eigen::Index>(2 * walls.size()), 3);
  for (size_t w = 0; w < walls.size(); ++w) {
    const Wall& q = walls[w];
    const auto base = static_cast<int32_t>(rest.size() / 3);
    for (const auto& [x, z] : {std::pair{q.x0, q.z0}, std::pair{q.x1, q.z0}, std::pair{q.x1, q.z1}, std::pair{q.x0, q.z1}}) {
      rest.insert(rest.end(), {x, q.y, z});
    }
    tri.row(static_cast<Eigen::Index>(2 * w)) << base, base + 1, base + 2;
    tri.row(static_cast<Eigen::Index>(2 * w + 1)) << base, base + 2, base + 3;
  }
  const std::vector<uint8_t> opened(2 * walls.size(), 1);
  return s.Score<double>(rest.data(), tri, opened, SessionMetrics{}, 1.0);
}

TEST(IncisionScorer, CoverageIsTheOpenedShareOfThePlannedCutSurface) {
  // A complete transection on the line, and the same wall opened on both
  // sides of the cut (both count once).
  EXPECT_DOUBLE_EQ(ScoreWalls({{0, 0.03, 0, 0.01, 0.0005}}).coverage(), 1.0);
  EXPECT_DOUBLE_EQ(ScoreWalls({{0, 0.03, 0, 0.01, 0.0005}, {0, 0.03, 0, 0.01, -0.0005}}).coverage(), 1.0);
  // Half the depth, half the length, a quarter.
  EXPECT_DOUBLE_EQ(ScoreWalls({{0, 0.03, 0.005, 0.01, 0.0005}}).coverage(), 0.5);
  EXPECT_DOUBLE_EQ(ScoreWalls({{0, 0.015, 0, 0.01, 0.0005}}).coverage(), 0.5);
  EXPECT_DOUBLE_EQ(ScoreWalls({{0.015, 0.03, 0.005, 0.01, 0.0005}}).coverage(), 0.25);
  // Two strokes that together open the whole wall.
  EXPECT_DOUBLE_EQ(ScoreWalls({{0, 0.016, 0, 0.01, 0.0005}, {0.014, 0.03, 0, 0.01, 0.0005}}).coverage(), 1.0);
  // Off the band: nothing covered, all of it opened outside.
  const IncisionScore off = ScoreWalls({{0, 0.03, 0, 0.01, 0.003}});
  EXPECT_EQ(off.coverage(), 0.0);
  EXPECT_NEAR(off.opened_area_outside(), 0.03 * 0.01, 1e-12);
}

TEST(IncisionScorer, CoverageCountsOnlyThePlannedSurfaceInTheTissue) {
  // The tissue ends halfway along the plan: cutting all of it is complete.
  const mesh::TetMesh half = mesh::MakeBox({0, -0.01, 0}, {0.015, 0.01, 0.01}, 3, 4, 2);
  EXPECT_DOUBLE_EQ(ScoreWalls({{0, 0.015, 0, 0.01, 0.0005}}, &half).coverage(), 1.0);
  EXPECT_DOUBLE_EQ(ScoreWalls({{0, 0.015, 0.005, 0.01, 0.0005}}, &half).coverage(), 0.5);
  EXPECT_DOUBLE_EQ(ScoreWalls({{0.015, 0.03, 0, 0.01, 0.0005}}, &half).coverage(), 0.0);
}

TEST(IncisionScorer, DepthAndOpenedAreaComeFromTheOpenedFaces) {
  IncisionScorer s(LPlan());
  // Rest nodes: a wall in the band reaching 4 mm below the plan, a face outside.
  const std::vector<double> rest = {0.005, 0.0002, 0.01,  0.010, 0.0002, 0.01,  0.0075, 0.0002, 0.006,
                                    0.005, 0.004,  0.01,  0.007, 0.004,  0.01,  0.005,  0.006,  0.01};
  mesh::Triangles tri(3, 3);
  tri << 0, 1, 2, 3, 4, 5, -1, -1, -1;  // the last slot is dead
  const std::vector<uint8_t> opened = {1, 1, 1};
  const IncisionScore score = s.Score<double>(rest.data(), tri, opened, SessionMetrics{}, 1.0);
  EXPECT_NEAR(score.depth_reached(), 0.004, 1e-12);
  EXPECT_NEAR(score.depth_error(), -0.001, 1e-12);
  EXPECT_NEAR(score.opened_area_outside(), 0.5 * 0.002 * 0.002, 1e-15);
}

// ---- scripted cuts of the block --------------------------------------------

/// The block of scenes/block.pbtxt (coarser), with a plan along x at
/// y = 10.1 mm through its 10 mm, and an inline straight cut at y = 10.1 mm +
/// `offset`, the blade's tip under the block.
std::string BlockScene(double offset) {
  const double y = 0.0101 + offset;
  return fmt::format(R"(
name: "score-block"
mesh {{ box {{ min {{ x: 0 y: 0 z: 0 }} max {{ x: 0.04 y: 0.02 z: 0.01 }} nx: 16 ny: 8 nz: 4 }} }}
materials {{ young_poisson {{ youngs_modulus: 50000 poisson_ratio: 0.4 }} density: 1000 damping_psi: 0.5 }}
boundary {{ plane {{ point {{ z: 0 }} normal {{ z: 1 }} }} kind: KIND_FIXED }}
gravity {{ z: -9.81 }}
time_step {{ frame_dt: 0.01 integrator: INTEGRATOR_IMPLICIT implicit {{ force_tolerance: 1e-5 linear_tolerance: 0.1 }} }}
settle: true
tool {{
  blade_length: 0.025
  keyframes {{ t: 0 tip {{ x: -0.003 y: {0} z: -0.001 }} blade_dir {{ z: 1 }} }}
  keyframes {{ t: 2.2 tip {{ x: 0.043 y: {0} z: -0.001 }} blade_dir {{ z: 1 }} }}
  keyframes {{ t: 2.4 tip {{ x: 0.043 y: {0} z: 0.02 }} blade_dir {{ z: 1 }} }}
}}
cutting {{ enabled: true alpha: 0.4 kappa: 1.0 zeta: 1.0 critical_stress: 10000 }}
planned_incision {{
  points {{ x: 0 y: 0.0101 z: 0.01 }}
  points {{ x: 0.04 y: 0.0101 z: 0.01 }}
  depth: 0.01
  tolerance: 0.002
}}
)",
                     y);
}

struct Scored {
  IncisionScore score;
  std::unique_ptr<Simulation> sim;
  double cutting_time = 0.0;  ///< s, summed here over the frames whose cut count grew
};

Scored CutBlock(double offset) {
  Scored r;
  r.sim = Simulation::Create(ParseScene(BlockScene(offset), "score-block.pbtxt", "."), {.threads = 1});
  while (r.sim->sim_time() < 2.4 - 1e-9) {
    const uint64_t cuts = r.sim->Tool().cuts;
    const double t = r.sim->sim_time();
    EXPECT_EQ(r.sim->AdvanceFrame(), SimStatus::kOk);
    if (r.sim->Tool().cuts > cuts) r.cutting_time += r.sim->sim_time() - t;
  }
  r.score = *r.sim->Score();
  return r;
}

TEST(IncisionScoreSession, ScriptedCutsScoreAsTheirOffsets) {
  const Scored on = CutBlock(0.0);
  const Scored off = CutBlock(0.003);
  // On the line: every cut step within the mesh's half-spacing of it, the
  // full depth reached, most of the line covered, nothing opened outside.
  EXPECT_GT(on.score.cut_points(), 4);
  EXPECT_LT(on.score.mean_deviation(), 0.0005);
  EXPECT_LT(on.score.max_deviation(), 0.001);
  EXPECT_NEAR(on.score.depth_error(), 0.0, 0.001);
  EXPECT_GT(on.score.coverage(), 0.9);
  EXPECT_EQ(on.score.opened_area_outside(), 0.0);
  // 3 mm off: the deviation is the offset (the tissue is scored at rest, so
  // the drag of the blade does not count), the cut's walls lie outside the
  // band, and the plan is not covered.
  EXPECT_GT(off.score.cut_points(), 4);
  EXPECT_NEAR(off.score.mean_deviation(), 0.003, 0.0005);
  EXPECT_GT(off.score.opened_area_outside(), 1e-4);
  EXPECT_EQ(off.score.coverage(), 0.0);
  EXPECT_LT(off.score.depth_reached(), on.score.depth_reached());
  // The session's measures are in the score.
  EXPECT_EQ(on.score.peak_force(), on.sim->Metrics().peak_force());
  EXPECT_GT(on.score.contact_time(), 1.0);
  EXPECT_NEAR(on.score.duration(), 2.4, 1e-9);
  // The blade's cutting time is the time of the frames in which a cut step
  // ran, within the time in contact.
  for (const Scored* s : {&on, &off}) {
    const SessionMetrics& m = s->sim->Metrics();
    EXPECT_GE(s->cutting_time, 0.05 - 1e-9);  // the scored cut points: more than four frames of 10 ms
    EXPECT_NEAR(m.cutting_time(), s->cutting_time, 1e-9);
    EXPECT_LE(m.cutting_time(), m.contact_time() + 1e-9);
  }

  // A checkpoint keeps the series: a restored simulation scores the same.
  auto restored = Simulation::Create(ParseScene(BlockScene(0.0), "score-block.pbtxt", "."), {.threads = 1});
  restored->RestoreCheckpointState(on.sim->CheckpointState(), "score.ckpt");
  const IncisionScore again = *restored->Score();
  EXPECT_EQ(again.cut_points(), on.score.cut_points());
  EXPECT_EQ(again.mean_deviation(), on.score.mean_deviation());
  EXPECT_EQ(again.coverage(), on.score.coverage());
  EXPECT_EQ(restored->ForceSeries().size(), on.sim->ForceSeries().size());
}

TEST(IncisionScoreSession, BadPlansAreRefusedNamingTheField) {
  const auto refuse = [](const std::string& plan, const std::string& field) {
    const std::string text = "name: \"p\" mesh { box { max { x: 0.01 y: 0.01 z: 0.01 } nx: 1 ny: 1 nz: 1 } } " +
                             std::string("materials { young_poisson { youngs_modulus: 1e4 poisson_ratio: 0.3 } density: 1000 } ") +
                             "planned_incision { " + plan + " }";
    try {
      (void)ParseScene(text, "plan.pbtxt", ".");
      ADD_FAILURE() << "accepted: " << plan;
    } catch (const InputError& e) {
      EXPECT_NE(std::string(e.what()).find(field), std::string::npos) << e.what();
    }
  };
  refuse("points { x: 0 } depth: 0.01", "planned_incision.points");
  refuse("points { x: 0 } points { x: 0 } depth: 0.01", "planned_incision.points");
  refuse("points { x: 0 } points { x: 0.01 } depth: 0", "planned_incision.depth");
  refuse("points { x: 0 } points { x: 0.01 } depth: 0.01 normal { }", "planned_incision.normal");
  refuse("points { x: nan } points { x: 0.01 } depth: 0.01", "planned_incision.points[0].x");
  refuse("points { x: 0 } points { x: 0.01 } depth: 0.01 tolerance: -1", "planned_incision.tolerance");

  // A checkpoint with broken series is refused before anything applies.
  auto sim = Simulation::Create(ParseScene(BlockScene(0.0), "score-block.pbtxt", "."), {.threads = 1});
  v1::CheckpointBody good = sim->CheckpointState();
  good.add_cut_points(1.0);  // not a whole row of 5
  EXPECT_THROW(sim->RestoreCheckpointState(good, "bad.ckpt"), InputError);
}

}  // namespace
}  // namespace cutsim::sim
