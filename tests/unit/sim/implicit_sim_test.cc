// The simulation with the implicit integrator: AUTO's choice for the
// shipped scenes, cutting during implicit stepping (mesh validity and mass
// after every cut), the static equilibrium against the explicit one, and
// the haptic contact stiffness against finite differences of the contact
// force over one step.
#include <cmath>
#include <memory>
#include <string>
#include <vector>

#include <Eigen/Core>
#include <google/protobuf/text_format.h>
#include <gtest/gtest.h>

#include "common/core/error.h"
#include "common/mesh/tet_mesh.h"
#include "common/sim/integrator_choice.h"
#include "common/sim/scene_fem.h"
#include "common/sim/scene_loader.h"
#include "common/sim/simulation.h"

namespace cutsim::sim {
namespace {

std::string ScenePath(const std::string& name) { return std::string(CUTSIM_SOURCE_DIR) + "/scenes/" + name; }

std::unique_ptr<Simulation> Make(const std::string& text, const std::string& integrator) {
  const LoadedScene scene = ParseScene(text, "test.pbtxt", ".");
  return Simulation::Create(scene, {.threads = 1, .precision = "", .integrator = integrator});
}

TEST(IntegratorChoiceTest, AutoPicksPerShippedScene) {
  const std::vector<std::pair<std::string, std::string>> expected = {
      {"ligament.pbtxt", "explicit"}, {"block.pbtxt", "implicit"}, {"organ.pbtxt", "implicit"}};
  for (const auto& [file, kind] : expected) {
    const LoadedScene scene = LoadScene(ScenePath(file));
    const auto sim = Simulation::Create(scene, {.threads = 1, .precision = "", .integrator = "auto"});
    EXPECT_EQ(sim->QuickSummary().integrator, kind) << file;
  }
}

TEST(IntegratorChoiceTest, ShippedOrganAndBlockUseAuto) {
  for (const char* file : {"organ.pbtxt", "block.pbtxt"}) {
    EXPECT_EQ(LoadScene(ScenePath(file)).scene.time_step().integrator(), v1::TimeStepPolicy::INTEGRATOR_AUTO)
        << file;
  }
}

TEST(IntegratorChoiceTest, BadValuesAreErrorsNamingTheField) {
  const std::string base = R"pb(mesh { box { min {} max { x: 0.01 y: 0.01 z: 0.01 } nx: 1 ny: 1 nz: 1 } }
    materials { name: "m" young_poisson { youngs_modulus: 1e4 poisson_ratio: 0.3 } density: 1000 })pb";
  try {
    (void)ParseScene(base + " time_step { integrator: 7 }", "bad.pbtxt", ".");
    FAIL() << "accepted integrator 7";
  } catch (const InputError& e) {
    EXPECT_EQ(e.source().field, "time_step.integrator");
  }
  try {
    (void)Make(base + " time_step { integrator: INTEGRATOR_IMPLICIT precision: PRECISION_FLOAT }", "");
    FAIL() << "accepted implicit float";
  } catch (const InputError& e) {
    EXPECT_EQ(e.source().field, "time_step.integrator");
  }
  // AUTO in float stays explicit.
  EXPECT_EQ(Make(base + " time_step { integrator: INTEGRATOR_AUTO precision: PRECISION_FLOAT }", "")
                ->QuickSummary()
                .integrator,
            "explicit");
}

TEST(IntegratorChoiceTest, CostGrowsWithSubstepsAndSize) {
  const IntegratorCost a = EstimateFrameCost(1000, 100000, 0.01, 1e-3);
  const IntegratorCost b = EstimateFrameCost(1000, 100000, 0.01, 1e-4);
  EXPECT_NEAR(b.explicit_seconds, 10 * a.explicit_seconds, 1e-12);
  EXPECT_EQ(a.implicit_seconds, b.implicit_seconds);
  EXPECT_GT(EstimateFrameCost(2000, 200000, 0.01, 1e-3).implicit_seconds, a.implicit_seconds);
}

// A 20 × 10 × 6 mm block (8 × 4 × 3 cells) cut by a blade drawn along x
// through its whole height, as scenes/block.pbtxt at a coarser mesh.
// Checked as the explicit incremental tests check a cut: total mass and the
// rest mesh's validity after every topology change.
const char* kCutBlock = R"pb(
name: "implicit-cut"
mesh { box { min { x: 0 y: 0 z: 0 } max { x: 0.02 y: 0.01 z: 0.006 } nx: 8 ny: 4 nz: 3 } }
materials { name: "tissue" young_poisson { youngs_modulus: 50000 poisson_ratio: 0.4 } density: 1000 damping_psi: 0.5 }
boundary { plane { point { x: 0 y: 0 z: 0 } normal { x: 0 y: 0 z: 1 } } kind: KIND_FIXED }
gravity { z: -9.81 }
time_step { frame_dt: 0.01 }
tool {
  blade_length: 0.02
  keyframes { t: 0 tip { x: -0.002 y: 0.0051 z: -0.001 } blade_dir { z: 1 } }
  keyframes { t: 1.2 tip { x: 0.022 y: 0.0051 z: -0.001 } blade_dir { z: 1 } }
}
cutting { enabled: true alpha: 0.4 kappa: 1.0 zeta: 1.0 critical_stress: 10000 }
)pb";

TEST(ImplicitSimTest, CutsKeepTheMeshValidAndTheMass) {
  const auto sim = Make(kCutBlock, "implicit");
  const double mass = sim->Summary().total_mass;
  ASSERT_GT(mass, 0.0);
  uint64_t version = sim->topology_version();
  int cuts_seen = 0;
  while (sim->sim_time() < 1.2 - 1e-9) {
    ASSERT_EQ(sim->AdvanceFrame(), SimStatus::kOk) << sim->Summary().diagnosis;
    if (sim->topology_version() == version) continue;
    version = sim->topology_version();
    ++cuts_seen;
    const SimulationSummary s = sim->Summary();
    EXPECT_NEAR(s.total_mass, mass, 1e-12 * mass) << "after cut " << cuts_seen;
    EXPECT_GT(s.min_rest_volume, 0.0);
    // The cut complex's rest mesh stays valid: every tet positive, every
    // world position finite (the step followed the new topology).
    MeshView view;
    sim->FillMeshView(view);
    mesh::TetMesh rest;
    rest.nodes = view.rest;
    rest.tets = view.tets;
    for (int32_t t = 0; t < rest.num_tets(); ++t) {
      ASSERT_GT(mesh::SignedVolume(rest, t), 0.0) << "tet " << t << " after cut " << cuts_seen;
    }
    ASSERT_TRUE(view.world.allFinite()) << "after cut " << cuts_seen;
  }
  const SimulationSummary s = sim->Summary();
  EXPECT_EQ(s.integrator, "implicit");
  EXPECT_GT(cuts_seen, 0);
  EXPECT_GT(s.cuts, 0u);
  EXPECT_EQ(s.implicit.steps, s.frames);
  EXPECT_GT(s.implicit.newton_iterations, 0);
  EXPECT_GT(s.implicit.factorizations, 0);
}

// A cantilever under gravity, fixed at x = 0, with mass damping so the
// explicit run comes to rest quickly; tight rest tolerances.
const char* kBeam = R"pb(
name: "beam-eq"
mesh { box { min { x: 0 y: 0 z: 0 } max { x: 0.04 y: 0.01 z: 0.01 } nx: 4 ny: 1 nz: 1 } }
materials { name: "m" young_poisson { youngs_modulus: 1e5 poisson_ratio: 0.3 } density: 1000 }
mass_damping: 60
boundary { plane { point { x: 0 y: 0 z: 0 } normal { x: 1 y: 0 z: 0 } } kind: KIND_FIXED }
gravity { z: -9.81 }
time_step { frame_dt: 0.01 }
rest { kinetic_energy: 1e-20 residual_force: 1e-10 }
)pb";

Eigen::VectorXd RestDisplacement(Simulation& sim) {
  for (int frame = 0; frame < 20000 && !sim.AtRest(); ++frame) {
    EXPECT_EQ(sim.AdvanceFrame(), SimStatus::kOk);
  }
  EXPECT_TRUE(sim.AtRest()) << sim.QuickSummary().residual_force;
  MeshView view;
  sim.FillMeshView(view);
  const Eigen::MatrixXd u = view.world - view.rest;
  return Eigen::Map<const Eigen::VectorXd>(u.data(), u.size());
}

TEST(ImplicitSimTest, StaticEquilibriumMatchesExplicit) {
  const auto explicit_sim = Make(kBeam, "explicit");
  const auto implicit_sim = Make(kBeam, "implicit");
  const Eigen::VectorXd ue = RestDisplacement(*explicit_sim);
  const Eigen::VectorXd ui = RestDisplacement(*implicit_sim);
  ASSERT_GT(ue.norm(), 0.0);
  EXPECT_LT((ui - ue).norm() / ue.norm(), 1e-4);
  EXPECT_EQ(implicit_sim->QuickSummary().implicit.unconverged_steps, 0);
}

// `settle` starts a scene at the equilibrium the explicit run comes to
// rest at, with zero velocity: the first frames then stay put.
TEST(ImplicitSimTest, SettleStartsAtTheExplicitEquilibrium) {
  const auto explicit_sim = Make(kBeam, "explicit");
  const Eigen::VectorXd ue = RestDisplacement(*explicit_sim);
  std::string settled = kBeam;
  const std::string ts = "time_step { frame_dt: 0.01 }";
  settled.replace(settled.find(ts), ts.size(),
                  "time_step { frame_dt: 0.01 implicit { force_tolerance: 1e-10 } }\nsettle: true");
  for (const std::string integrator : {"explicit", "implicit"}) {
    const auto sim = Make(settled, integrator);
    MeshView view;
    sim->FillMeshView(view);
    const Eigen::MatrixXd u = view.world - view.rest;
    const Eigen::VectorXd us = Eigen::Map<const Eigen::VectorXd>(u.data(), u.size());
    EXPECT_LT((us - ue).norm() / ue.norm(), 1e-4) << integrator;
    EXPECT_EQ(sim->sim_time(), 0.0);
    for (int frame = 0; frame < 10; ++frame) ASSERT_EQ(sim->AdvanceFrame(), SimStatus::kOk);
    const SimulationSummary s = sim->Summary();
    // A millionth of the sag's strain energy is left to move.
    EXPECT_GT(s.strain_energy, 0.0) << integrator;
    EXPECT_LT(s.kinetic_energy, 1e-6 * s.strain_energy) << integrator;
  }
}

TEST(ImplicitSimTest, SettleNeedsDoublePrecision) {
  std::string settled = kBeam;
  settled += "settle: true\n";
  const LoadedScene scene = ParseScene(settled, "test.pbtxt", ".");
  try {
    (void)Simulation::Create(scene, {.threads = 1, .precision = "float", .integrator = ""});
    FAIL() << "float precision with settle was accepted";
  } catch (const InputError& e) {
    EXPECT_EQ(e.source().field, "settle");
  }
}

// The nodal-pressure element runs with the implicit integrator and is
// refused, naming the field, with the explicit one.
TEST(ImplicitSimTest, NodalPressureElementRunsWithEitherIntegrator) {
  std::string text = kBeam;
  text += "element: ELEMENT_NODAL_PRESSURE\n";
  for (const char* integrator : {"implicit", "explicit"}) {
    const auto sim = Make(text, integrator);
    for (int frame = 0; frame < 5; ++frame) ASSERT_EQ(sim->AdvanceFrame(), SimStatus::kOk) << integrator;
    EXPECT_GT(sim->Summary().strain_energy, 0.0) << integrator;
  }
}

TEST(ImplicitSimTest, AutoElementFollowsPoissonsRatio) {
  const auto scene_with = [](const std::string& material, const std::string& element) {
    v1::Scene scene;
    const std::string text = "materials { name: \"m\" " + material + " density: 1000 }\n" + element;
    EXPECT_TRUE(google::protobuf::TextFormat::ParseFromString(text, &scene)) << text;
    return scene;
  };
  const std::string soft = "young_poisson { youngs_modulus: 1e4 poisson_ratio: 0.45 }";
  const std::string beam = "young_poisson { youngs_modulus: 1e6 poisson_ratio: 0.3 }";
  const std::string ligament = "lame { lambda: 140000 mu: 11000 }";  // ν = 0.46
  const std::string firm = "lame { lambda: 10000 mu: 11000 }";       // ν = 0.24
  EXPECT_EQ(ChooseElement(scene_with(soft, "")), fem::ElementKind::kNodalPressure);
  EXPECT_EQ(ChooseElement(scene_with(ligament, "")), fem::ElementKind::kNodalPressure);
  EXPECT_EQ(ChooseElement(scene_with(beam, "")), fem::ElementKind::kLinear);
  EXPECT_EQ(ChooseElement(scene_with(firm, "")), fem::ElementKind::kLinear);
  EXPECT_EQ(ChooseElement(scene_with(soft, "element: ELEMENT_LINEAR")), fem::ElementKind::kLinear);
  EXPECT_EQ(ChooseElement(scene_with(beam, "element: ELEMENT_NODAL_PRESSURE")), fem::ElementKind::kNodalPressure);
}

// A block pressed from above by the blade's tip; the tool is driven by
// SetToolPose so the last frame's tip can be varied.
const char* kPress = R"pb(
name: "press"
mesh { box { min { x: 0 y: 0 z: 0 } max { x: 0.02 y: 0.02 z: 0.01 } nx: 4 ny: 4 nz: 2 } }
materials { name: "m" young_poisson { youngs_modulus: 2e4 poisson_ratio: 0.4 } density: 1000 }
mass_damping: 20
boundary { plane { point { x: 0 y: 0 z: 0 } normal { x: 0 y: 0 z: 1 } } kind: KIND_FIXED }
time_step { frame_dt: 0.01 integrator: INTEGRATOR_IMPLICIT }
tool { blade_length: 0.01 }
)pb";

/// The force on the tool after 30 frames at tip `a` and one at `b`; the
/// contact stiffness after that last frame into `stiffness` (if not null).
Eigen::Vector3d ForceAfter(const Eigen::Vector3d& a, const Eigen::Vector3d& b, Eigen::Matrix3d* stiffness) {
  const auto sim = Make(kPress, "");
  for (int f = 0; f < 30; ++f) {
    sim->SetToolPose({a, Eigen::Vector3d::UnitZ()});
    EXPECT_EQ(sim->AdvanceFrame(), SimStatus::kOk);
  }
  sim->SetToolPose({b, Eigen::Vector3d::UnitZ()});
  EXPECT_EQ(sim->AdvanceFrame(), SimStatus::kOk);
  EXPECT_TRUE(sim->Tool().touching);
  if (stiffness) *stiffness = sim->ContactStiffness();
  return sim->Tool().force_on_tool;
}

TEST(ImplicitSimTest, ContactStiffnessMatchesFiniteDifferences) {
  // The tip 0.4 mm into the top face, off the nodes.
  const Eigen::Vector3d tip(0.0093, 0.0108, 0.0096);
  const double delta = 1e-6;  // m
  // K of the last step, linearised at the tip it ended with: the derivative
  // of that step's force in the tip, K = −∂f_tool/∂x_tool.
  Eigen::Matrix3d k;
  (void)ForceAfter(tip, tip, &k);
  const Eigen::Vector3d up = tip + delta * Eigen::Vector3d::UnitZ();
  const Eigen::Vector3d down = tip - delta * Eigen::Vector3d::UnitZ();
  const Eigen::Vector3d fd = -(ForceAfter(tip, up, nullptr) - ForceAfter(tip, down, nullptr)) / (2 * delta);
  ASSERT_GT(k(2, 2), 0.0);
  EXPECT_NEAR(fd.z(), k(2, 2), 2e-2 * k(2, 2)) << "K =\n" << k;
}

}  // namespace
}  // namespace cutsim::sim
