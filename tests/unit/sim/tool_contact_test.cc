// Tool contact (common/sim/tool_contact.h): the edge coupling of a blade
// inside the tissue, alone and in a Simulation drawing a blade through the
// block. Properties, not golden values: the force acts across the blade
// only, is continuous, bounded by k·limit, opposes the blade's sideways
// motion, gives way when the tissue is cut, and in the blade's own slit
// comes only from tissue not yet cut.
#include <algorithm>
#include <cmath>
#include <memory>
#include <string>
#include <vector>

#include <Eigen/Core>
#include <gtest/gtest.h>

#include "common/sim/scene_loader.h"
#include "common/sim/simulation.h"
#include "common/sim/tool_contact.h"

namespace cutsim::sim {
namespace {

using Eigen::Vector3d;

// A facet in the z = 0 plane; the grip sits at its centroid.
struct Fixture {
  Vector3d x0{0, 0, 0}, x1{0.004, 0, 0}, x2{0, 0.004, 0};
  ContactFacet facet;
  Fixture() {
    facet.touching = true;
    facet.nodes = {0, 1, 2};
    facet.bary = Vector3d::Constant(1.0 / 3.0);
    facet.point = (x0 + x1 + x2) / 3.0;
    facet.normal = Vector3d::UnitZ();
  }
};

constexpr double kK = 200.0;       // N/m
constexpr double kLimit = 0.002;   // m
const Vector3d kUp = Vector3d::UnitZ();  // blade direction, tip → handle

TEST(EdgeGrip, ActsOnlyAcrossTheBladeAndPullsTheTissueAfterIt) {
  Fixture f;
  EdgeGrip grip = MakeGrip(f.facet, f.facet.point, 1);
  const Vector3d c = f.facet.point;
  // The blade slid along itself (deeper or out): no force.
  EXPECT_LT(EdgeGripForce(grip, f.x0, f.x1, f.x2, c - 0.005 * kUp, kUp, kK, kLimit).norm(), 1e-12);
  EXPECT_LT(EdgeGripForce(grip, f.x0, f.x1, f.x2, c + 0.003 * kUp, kUp, kK, kLimit).norm(), 1e-12);
  // Drawn 1 mm along +x (any depth): the tissue is pulled along +x by k·1 mm.
  const Vector3d F = EdgeGripForce(grip, f.x0, f.x1, f.x2, c + Vector3d(0.001, 0, -0.004), kUp, kK, kLimit);
  EXPECT_NEAR(F.x(), kK * 0.001, 1e-12);
  EXPECT_NEAR(F.y(), 0.0, 1e-12);
  EXPECT_NEAR(F.z(), 0.0, 1e-12);
  EXPECT_LT(grip.offset.norm(), 1e-15);  // under the cap nothing slides
}

TEST(EdgeGrip, BeyondTheCapTheGripSlidesAndTheForceFallsBackContinuously) {
  Fixture f;
  EdgeGrip grip = MakeGrip(f.facet, f.facet.point, 1);
  const Vector3d c = f.facet.point;
  // Drawn 5 mm along +y: force capped at k·limit, the tissue end slid 3 mm.
  Vector3d F = EdgeGripForce(grip, f.x0, f.x1, f.x2, c + Vector3d(0, 0.005, 0), kUp, kK, kLimit);
  EXPECT_NEAR(F.norm(), kK * kLimit, 1e-12);
  EXPECT_GT(F.y(), 0.0);
  EXPECT_NEAR(grip.offset.y(), 0.003, 1e-12);
  // Back by 0.5 mm: the force falls by k·0.5 mm (elastic unloading), no jump.
  F = EdgeGripForce(grip, f.x0, f.x1, f.x2, c + Vector3d(0, 0.0045, 0), kUp, kK, kLimit);
  EXPECT_NEAR(F.y(), kK * 0.0015, 1e-12);
  // Back past the tissue end: the push reverses, still capped.
  F = EdgeGripForce(grip, f.x0, f.x1, f.x2, c - Vector3d(0, 0.004, 0), kUp, kK, kLimit);
  EXPECT_NEAR(F.norm(), kK * kLimit, 1e-12);
  EXPECT_LT(F.y(), 0.0);
}

TEST(EdgeGrip, RegrippingAtTheSameWorldPointKeepsTheForce) {
  Fixture f;
  EdgeGrip grip = MakeGrip(f.facet, f.facet.point, 1);
  const Vector3d tip = f.facet.point + Vector3d(0.0015, 0.0007, -0.003);
  const Vector3d before = EdgeGripForce(grip, f.x0, f.x1, f.x2, tip, kUp, kK, kLimit);
  // Another facet point (a vertex), holding the old grip's world point.
  ContactFacet other = f.facet;
  other.bary = Vector3d(0, 1, 0);
  other.point = f.x1;
  EdgeGrip moved = MakeGrip(other, GripPoint(grip, f.x0, f.x1, f.x2), 1);
  const Vector3d after = EdgeGripForce(moved, f.x0, f.x1, f.x2, tip, kUp, kK, kLimit);
  EXPECT_LT((after - before).norm(), 1e-12);
}

TEST(CutSweep, BehindTheFrontInThePlaneOfTheCutOnly) {
  // A blade along +z drawn from x = 0 to x = 0.01 cut the plane y = 0.
  const std::vector<CutSweep> sweeps{{Vector3d(0, 0, -0.001), Vector3d(0.01, 0, -0.001), kUp}};
  const double tol = 0.001;
  EXPECT_TRUE(InSweptArea(sweeps, Vector3d(0.005, 0, 0.004), tol));       // in the slit
  EXPECT_TRUE(InSweptArea(sweeps, Vector3d(0.0099, 0.0009, 0.004), tol)); // at the front, off by < tol
  EXPECT_FALSE(InSweptArea(sweeps, Vector3d(0.0101, 0, 0.004), tol));     // ahead of the front
  EXPECT_FALSE(InSweptArea(sweeps, Vector3d(-0.0001, 0, 0.004), tol));    // before its start
  EXPECT_FALSE(InSweptArea(sweeps, Vector3d(0.005, 0.0011, 0.004), tol)); // beside the slit
  // A blade slid along itself sweeps no area.
  EXPECT_FALSE(InSweptArea({{Vector3d::Zero(), Vector3d(0, 0, 0.005), kUp}}, Vector3d(0, 0, 0.002), tol));
  EXPECT_FALSE(InSweptArea({}, Vector3d::Zero(), tol));
}

// scenes/block.pbtxt with a path given inline; a coarse copy keeps it quick.
std::unique_ptr<Simulation> Block(const std::string& keyframes, double critical_stress) {
  const std::string text = R"pb(name: "contact-block"
mesh { box { min { x: 0 y: 0 z: 0 } max { x: 0.04 y: 0.02 z: 0.01 } nx: 10 ny: 5 nz: 2 } }
materials { name: "tissue" young_poisson { youngs_modulus: 50000 poisson_ratio: 0.4 } density: 1000 damping_psi: 0.5 }
boundary { plane { point { x: 0 y: 0 z: 0 } normal { x: 0 y: 0 z: 1 } } kind: KIND_FIXED }
time_step { frame_dt: 0.01 threads: 1 }
tool { blade_length: 0.025 )pb" + keyframes + R"pb( }
cutting { enabled: true alpha: 0.4 kappa: 1.0 zeta: 1.0 critical_stress: )pb" +
                           std::to_string(critical_stress) + " }\n";
  return Simulation::Create(ParseScene(text, "contact-block.pbtxt", std::filesystem::temp_directory_path()));
}

std::string Key(double t, double x, double y, double z) {
  return "keyframes { t: " + std::to_string(t) + " tip { x: " + std::to_string(x) + " y: " + std::to_string(y) +
         " z: " + std::to_string(z) + " } blade_dir { z: 1 } } ";
}

TEST(ToolContact, BladeDrawnThroughUncuttableTissueIsResistedAlongItsMotion) {
  // Tip 1 mm below the base, drawn along +x through the block; K_I out of reach.
  auto sim = Block(Key(0, -0.003, 0.0101, -0.001) + Key(0.6, 0.025, 0.0101, -0.001), 1e12);
  const double k_limit_bound = 2.0;  // N: k = E·h̄ ≈ 240 N/m times one mean edge ≈ 4.3 mm is ≈ 1 N
  int resisted = 0;
  double peak = 0;
  while (sim->sim_time() < 0.6 - 1e-9) {
    ASSERT_EQ(sim->AdvanceFrame(), SimStatus::kOk);
    const ToolReport tool = sim->Tool();
    const Vector3d F = tool.force_on_tool;
    EXPECT_NEAR(F.z(), 0.0, 1e-9 + 1e-6 * F.norm()) << "only across the blade, t=" << sim->sim_time();
    EXPECT_LE(F.x(), 1e-3) << "never pulls the blade along its motion, t=" << sim->sim_time();
    if (F.x() < -0.05) ++resisted;
    peak = std::max(peak, F.norm());
    if (tool.touching && F.norm() > 0) {
      EXPECT_NEAR(tool.normal.dot(F / F.norm()), 1.0, 1e-9);
    }
  }
  EXPECT_EQ(sim->Summary().cuts, 0u);
  EXPECT_GT(resisted, 20);  // inside the tissue the blade is held back frame after frame
  EXPECT_LT(peak, k_limit_bound);
  // Held still inside, lowered along itself: the grip neither grows nor pulls.
  const Vector3d held = sim->Tool().force_on_tool;
  sim->SetToolPose({Vector3d(0.025, 0.0101, -0.003), Vector3d::UnitZ()});
  ASSERT_EQ(sim->AdvanceFrame(), SimStatus::kOk);
  EXPECT_LE(sim->Tool().force_on_tool.norm(), held.norm() * 1.05 + 1e-6);
}

TEST(ToolContact, TheForceGivesWayWhenTheTissueIsCut) {
  auto sim = Block(Key(0, -0.003, 0.0101, -0.001) + Key(0.8, 0.043, 0.0101, -0.001), 10000);
  double before = 0;
  int cuts = 0, drops = 0;
  while (sim->sim_time() < 0.8 - 1e-9) {
    ASSERT_EQ(sim->AdvanceFrame(), SimStatus::kOk);
    const ToolReport tool = sim->Tool();
    if (tool.cut_this_frame) {
      ++cuts;
      before = tool.force_on_tool.norm();
      ASSERT_EQ(sim->AdvanceFrame(), SimStatus::kOk);  // the grip is re-taken unloaded
      drops += sim->Tool().force_on_tool.norm() < 0.8 * before ? 1 : 0;
    }
  }
  EXPECT_GE(cuts, 2);
  EXPECT_EQ(drops, cuts);
}

// In its own cut (tool_contact.h): walls and lips are touched, never
// gripped; only tissue not yet cut resists the edge.
TEST(ToolContact, ABladeThatHasSeveredTheTissueDragsNoStump) {
  // The shipped ligament and stroke: the blade cuts through mid-stroke, then
  // is drawn on beside the stumps and lifted out.
  auto sim = Simulation::Create(LoadScene(std::string(CUTSIM_SOURCE_DIR) + "/scenes/ligament.pbtxt"));
  const double end = sim->path_end_time();
  double severed_at = -1, cut_force = 0, after = 0, peak_before = 0;
  while (sim->sim_time() < end - 1e-9) {
    ASSERT_EQ(sim->AdvanceFrame(), SimStatus::kOk);
    const ToolReport tool = sim->Tool();
    const double f = tool.force_on_tool.norm();
    if (severed_at < 0) {
      peak_before = std::max(peak_before, f);
      if (tool.cut_this_frame && sim->Summary().components >= 2) {
        severed_at = sim->sim_time();
        cut_force = f;
      }
    } else if (sim->sim_time() > severed_at + 0.05) {  // past the release transient
      after = std::max(after, f);
    }
  }
  ASSERT_GT(severed_at, 0) << "the stroke still cuts through (sigma_c reached K_I)";
  EXPECT_GT(peak_before, 0.1);  // the edge was resisted while cutting
  // The old in-cut grip dragged a stump after the blade at about half the
  // cutting force until it was lifted out.
  EXPECT_LT(after, 0.1 * cut_force) << "severed at t=" << severed_at;
  EXPECT_EQ(sim->Summary().components, 2);
}

TEST(ToolContact, InItsSlitOnlyUncutTissueResistsTheEdge) {
  // Drawn along +x into the block (cutting), then back along its own slit.
  auto sim = Block(Key(0, -0.003, 0.0101, -0.001) + Key(0.6, 0.028, 0.0101, -0.001) +
                       Key(1.2, 0.002, 0.0101, -0.001),
                   10000);
  int cuts = 0, resisted_after_cut = 0, in_slit = 0;
  double front = -1, back = 0;
  while (sim->sim_time() < 1.2 - 1e-9) {
    ASSERT_EQ(sim->AdvanceFrame(), SimStatus::kOk);
    const ToolReport tool = sim->Tool();
    const double x = tool.pose.tip.x();
    if (sim->sim_time() <= 0.6) {
      if (tool.cut_this_frame) {
        ++cuts;
        front = x;  // the cut reaches the blade: behind it the tissue is cut
      }
      // Drawn on after a cut: the tissue ahead of the front holds the edge.
      if (cuts > 0 && tool.force_on_tool.x() < -0.05) ++resisted_after_cut;
    } else if (x < front - 0.002 && x > 0.002) {  // back inside the slit
      ++in_slit;
      back = std::max(back, tool.force_on_tool.norm());
    }
  }
  ASSERT_GE(cuts, 1);
  EXPECT_GT(resisted_after_cut, 10);
  EXPECT_GT(in_slit, 10);
  // Only its own walls and lips there: the old in-cut grip dragged them back.
  EXPECT_LT(back, 0.01);
}

TEST(ToolContact, PressingOnTheTopFaceIsAPenaltyAlongTheNormal) {
  // Tip 0.5 mm into the top face (under the indentation limit): the tip pushes.
  auto sim = Block(Key(0, 0.0201, 0.0101, 0.0095) + Key(1, 0.0201, 0.0101, 0.0095), 1e12);
  for (int f = 0; f < 20; ++f) ASSERT_EQ(sim->AdvanceFrame(), SimStatus::kOk);
  const ToolReport tool = sim->Tool();
  ASSERT_TRUE(tool.touching);
  EXPECT_GT(tool.force_on_tool.z(), 0.0);
  EXPECT_LT(std::abs(tool.force_on_tool.x()) + std::abs(tool.force_on_tool.y()), 0.2 * tool.force_on_tool.z());
  EXPECT_GT(tool.depth, 0.0);
}

}  // namespace
}  // namespace cutsim::sim
