// Prescribed displacements (KIND_DISPLACEMENT): the ramp, the scene's
// checks, the settle stage under a prescribed stretch against the analytic
// St. Venant–Kirchhoff stress (uniaxial through a scene, biaxial through the
// stage), the ramp in a running simulation, and node copies made by a cut.
#include <cmath>
#include <span>
#include <string>
#include <vector>

#include <Eigen/Core>
#include <Eigen/Dense>
#include <gtest/gtest.h>

#include "common/core/error.h"
#include "common/cutting/topology_event.h"
#include "common/fem/forces.h"
#include "common/fem/model.h"
#include "common/fem/state.h"
#include "common/mesh/generators.h"
#include "common/sim/dynamics.h"
#include "common/sim/prescribed_motion.h"
#include "common/sim/scene_fem.h"
#include "common/sim/scene_loader.h"
#include "common/sim/scene_mesh.h"
#include "common/sim/settle.h"
#include "common/sim/simulation.h"

namespace cutsim::sim {
namespace {

TEST(RampTest, SmoothFromZeroToOne) {
  constexpr double kRamp = 0.4;
  EXPECT_EQ(RampFactor(-1.0, kRamp), 0.0);
  EXPECT_EQ(RampFactor(0.0, kRamp), 0.0);
  EXPECT_DOUBLE_EQ(RampFactor(0.5 * kRamp, kRamp), 0.5);
  EXPECT_EQ(RampFactor(kRamp, kRamp), 1.0);
  EXPECT_EQ(RampFactor(10.0, kRamp), 1.0);
  // Without a ramp the full value holds from t = 0.
  EXPECT_EQ(RampFactor(0.0, 0.0), 1.0);
  EXPECT_EQ(RampRate(0.0, 0.0), 0.0);
  // Monotone, and the rate is the factor's derivative (zero at both ends).
  double prev = 0.0;
  for (int i = 1; i < 100; ++i) {
    const double t = kRamp * i / 100.0;
    const double s = RampFactor(t, kRamp);
    EXPECT_GT(s, prev);
    prev = s;
    const double h = 1e-7;
    const double fd = (RampFactor(t + h, kRamp) - RampFactor(t - h, kRamp)) / (2 * h);
    EXPECT_NEAR(RampRate(t, kRamp), fd, 1e-6);
  }
  EXPECT_EQ(RampRate(0.0, kRamp), 0.0);
  EXPECT_EQ(RampRate(kRamp, kRamp), 0.0);
}

constexpr double kLength = 0.02;  // m, block along x
constexpr double kMu = 1000.0;    // Pa

/// A 20 × 10 × 10 mm block, clamped at x = 0 and moved by `stretch`·L along
/// x at x = L; `extra` adds to the boundary condition of x = L.
std::string StretchedBlock(double lambda, double stretch, const std::string& extra = "") {
  return "name: 'stretch'\n"
         "mesh { box { min { x: 0 y: 0 z: 0 } max { x: 0.02 y: 0.01 z: 0.01 } nx: 4 ny: 2 nz: 2 } }\n"
         "materials { lame { lambda: " + std::to_string(lambda) + " mu: " + std::to_string(kMu) +
         " } density: 1000 }\n"
         "element: ELEMENT_LINEAR\n"
         "boundary { plane { point { x: 0 } normal { x: 1 } } kind: KIND_FIXED }\n"
         "boundary { plane { point { x: 0.02 } normal { x: 1 } } kind: KIND_DISPLACEMENT displacement { x: " +
         std::to_string(stretch * kLength) + " } " + extra + "}\n"
         "settle: true\n";
}

std::string LoadError(const std::string& text) {
  try {
    const LoadedScene scene = ParseScene(text, "bc.pbtxt", ".");
    (void)Simulation::Create(scene, {.threads = 1});
  } catch (const InputError& e) {
    return e.what();
  }
  return "";
}

TEST(DisplacementBoundaryTest, BadValuesAreRefusedByName) {
  const std::string fixed_plane = "plane { point { x: 0 } normal { x: 1 } }";
  struct Case {
    std::string text;
    std::string field;
  };
  const std::vector<Case> cases = {
      {StretchedBlock(0, 0.1, "ramp_time: -1"), "boundary[1].ramp_time"},
      {StretchedBlock(0, 0.1, "ramp_time: 1e9"), "boundary[1].ramp_time"},
      {StretchedBlock(0, 0.1, "force { x: 1 }"), "boundary[1].force"},
      {StretchedBlock(0, 1e300), "boundary[1].displacement.x"},
      {StretchedBlock(0, 0.1) + "boundary { " + fixed_plane + " kind: KIND_FIXED displacement { y: 0.001 } }",
       "boundary[2].displacement"},
      {StretchedBlock(0, 0.1) + "boundary { " + fixed_plane + " kind: KIND_FIXED ramp_time: 1 }",
       "boundary[2].ramp_time"},
      // Fixed and displaced at once: the x = 0 face is both.
      {StretchedBlock(0, 0.1) + "boundary { " + fixed_plane + " kind: KIND_DISPLACEMENT displacement { y: 0.001 } }",
       "boundary[2]"},
  };
  for (const Case& c : cases) {
    const std::string error = LoadError(c.text);
    EXPECT_NE(error.find(c.field), std::string::npos) << c.field << ": " << error;
  }
  EXPECT_EQ(LoadError(StretchedBlock(0, 0.1, "ramp_time: 0.5")), "");
}

/// A face driven through the clamped one inverts the nodal volumes beside
/// it: the implicit step meets the volumetric barrier (energy +∞) at every
/// trial, even in substeps, and the run stops. Every value of the state is
/// finite, so the status says the step failed, never "non_finite", and the
/// diagnosis names no element or node it does not have.
TEST(DisplacementBoundaryTest, AnInvertingDriveStopsAsAFailedStepNotANonFiniteOne) {
  std::string text = StretchedBlock(4000.0, -0.8);
  const std::string linear = "element: ELEMENT_LINEAR\n";
  text.replace(text.find(linear), linear.size(), "element: ELEMENT_NODAL_PRESSURE\n");
  const std::string settle = "settle: true\n";
  text.replace(text.find(settle), settle.size(), "time_step { integrator: INTEGRATOR_IMPLICIT }\n");
  const LoadedScene scene = ParseScene(text, "bc.pbtxt", ".");
  const auto sim = Simulation::Create(scene, {.threads = 1});
  SimStatus status = SimStatus::kOk;
  for (int frame = 0; frame < 10 && status == SimStatus::kOk; ++frame) status = sim->AdvanceFrame(0.0);
  EXPECT_EQ(status, SimStatus::kStepFailed);
  const SimulationSummary s = sim->QuickSummary();
  EXPECT_EQ(s.status, "step_failed") << s.diagnosis;
  EXPECT_NE(s.diagnosis.find("implicit step"), std::string::npos) << s.diagnosis;
  EXPECT_EQ(s.diagnosis.find("-1"), std::string::npos) << s.diagnosis;
  MeshView view;
  sim->FillMeshView(view);
  EXPECT_TRUE(view.world.allFinite());
}

/// Uniaxial stretch with λ = 0: no lateral contraction, so the clamped
/// block's exact solution is homogeneous, F = diag(1 + ε, 1, 1), and the
/// reaction at the moved face is P_xx·A with P = F·S, S = 2μE.
TEST(DisplacementBoundaryTest, SettledUniaxialStretchMatchesStVK) {
  constexpr double kStretch = 0.1;
  const LoadedScene scene = ParseScene(StretchedBlock(0.0, kStretch), "bc.pbtxt", ".");
  const SceneMesh mesh = BuildSceneMesh(scene);
  SceneFem<double> fem(scene, mesh, {.threads = 1});
  fem.PrescribeMotion(0.0, {});
  const SettleResult r = Settle(fem.model(), fem.state(), ImplicitOptionsFor(scene.scene, 1));
  ASSERT_TRUE(r.converged);
  const fem::Model<double>& model = fem.model();
  const std::vector<double>& x = fem.state().x;
  for (int32_t n = 0; n < model.num_nodes(); ++n) {
    const Eigen::Vector3d rest = model.rest_position(n);
    EXPECT_NEAR(x[3 * n], (1 + kStretch) * rest.x(), 1e-7) << n;
    EXPECT_NEAR(x[3 * n + 1], rest.y(), 1e-7) << n;
    EXPECT_NEAR(x[3 * n + 2], rest.z(), 1e-7) << n;
  }
  std::vector<double> f(x.size());
  ASSERT_EQ(fem::ComputeInternalForces(model, fem.state(), fem::ForceMode::kElastic, f.data(), 1), -1);
  Eigen::Vector3d reaction = Eigen::Vector3d::Zero();
  for (int32_t n = 0; n < model.num_nodes(); ++n) {
    if (std::abs(model.rest_position(n).x() - kLength) < 1e-12) reaction -= Eigen::Vector3d(f[3 * n], f[3 * n + 1], f[3 * n + 2]);
  }
  const double exx = 0.5 * ((1 + kStretch) * (1 + kStretch) - 1);
  const double p_xx = (1 + kStretch) * 2 * kMu * exx;
  const double area = 0.01 * 0.01;
  EXPECT_NEAR(reaction.x(), p_xx * area, 1e-4 * p_xx * area);
  EXPECT_NEAR(reaction.y(), 0.0, 1e-4 * p_xx * area);
  EXPECT_NEAR(reaction.z(), 0.0, 1e-4 * p_xx * area);
}

/// Biaxial stretch F = diag(1.1, 1.05, 1) prescribed on the whole surface
/// of a block with λ > 0: the settled interior follows the affine field and
/// every element carries σ = (1/J)·F·S·Fᵀ with S = λ tr(E) I + 2μE.
TEST(DisplacementBoundaryTest, BiaxialPatchTestGivesTheAnalyticStress) {
  constexpr double kLambda = 4000.0;
  const mesh::TetMesh mesh = mesh::MakeBox({0, 0, 0}, {0.02, 0.02, 0.01}, 4, 4, 2);
  const fem::Material material{.lambda = kLambda, .mu = kMu, .density = 1000};
  fem::Model<double> model(mesh, std::span(&material, 1));
  fem::State<double> state(model);
  const Eigen::Matrix3d F = Eigen::Vector3d(1.1, 1.05, 1.0).asDiagonal();
  PrescribedMotion<double> motion;
  const Eigen::Vector3d lo(0, 0, 0), hi(0.02, 0.02, 0.01);
  int interior = 0;
  for (int32_t n = 0; n < model.num_nodes(); ++n) {
    const Eigen::Vector3d p = model.rest_position(n);
    const bool surface = ((p - lo).cwiseAbs().minCoeff() < 1e-12) || ((p - hi).cwiseAbs().minCoeff() < 1e-12);
    if (surface) {
      motion.Add(model, n, (F - Eigen::Matrix3d::Identity()) * p, 0.0);
    } else {
      ++interior;
    }
  }
  ASSERT_GT(interior, 0);
  motion.Apply(model, state, 0.0);
  fem::ImplicitOptions options;
  options.num_threads = 1;
  const SettleResult r = Settle(model, state, options);
  ASSERT_TRUE(r.converged);
  const Eigen::Matrix3d E = 0.5 * (F.transpose() * F - Eigen::Matrix3d::Identity());
  const Eigen::Matrix3d S = kLambda * E.trace() * Eigen::Matrix3d::Identity() + 2 * kMu * E;
  const Eigen::Matrix3d sigma = F * S * F.transpose() / F.determinant();
  for (int32_t t = 0; t < model.num_tets(); ++t) {
    const Eigen::Matrix3d got = fem::ElementCauchyStress(model, state.x.data(), t);
    EXPECT_LT((got - sigma).norm(), 1e-4 * sigma.norm()) << "tet " << t << "\n" << got << "\nvs\n" << sigma;
  }
}

/// The ramp in a running simulation: the moved face is at X + s(t)·u after
/// each frame (the frame's end time), then stays at X + u.
TEST(DisplacementBoundaryTest, RampedFaceFollowsTheRampFrameByFrame) {
  constexpr double kRamp = 0.05;
  std::string text = StretchedBlock(0.0, 0.1, "ramp_time: 0.05");
  text.replace(text.find("settle: true"), 12, "time_step { frame_dt: 0.01 }");
  const auto sim = Simulation::Create(ParseScene(text, "bc.pbtxt", "."), {.threads = 1});
  for (int frame = 1; frame <= 7; ++frame) {
    ASSERT_EQ(sim->AdvanceFrame(), SimStatus::kOk);
    const double expected = kLength + 0.1 * kLength * RampFactor(sim->sim_time(), kRamp);
    const mesh::TetMesh world = sim->WorldMesh();
    const double right = world.nodes.col(0).maxCoeff();
    EXPECT_NEAR(right, expected, 1e-12) << "frame " << frame;
    int on_face = 0;
    for (Eigen::Index n = 0; n < world.nodes.rows(); ++n) on_face += std::abs(world.nodes(n, 0) - expected) < 1e-12;
    EXPECT_EQ(on_face, 3 * 3) << "frame " << frame;  // (ny + 1)·(nz + 1) nodes on the face
  }
}

TEST(PrescribedMotionTest, NodeCopiesMadeByACutMoveWithTheirOriginal) {
  const mesh::TetMesh mesh = mesh::MakeBox({0, 0, 0}, {0.01, 0.01, 0.01}, 1, 1, 1);
  const fem::Material material{.lambda = 0, .mu = kMu, .density = 1000};
  fem::ModelOptions options;
  options.node_capacity = 2 * mesh.num_nodes();
  fem::Model<double> model(mesh, std::span(&material, 1), options);
  fem::State<double> state(model);
  PrescribedMotion<double> motion;
  motion.Add(model, 3, {0.001, 0, 0}, 0.0);
  motion.Add(model, 3, {0, 0.002, 0}, 0.0);
  std::vector<cutting::TopologyEvent> events(1);
  events[0].splits.push_back({.node = 3, .new_node = model.num_nodes(), .tets = {}});
  events[0].splits.push_back({.node = 5, .new_node = model.num_nodes() + 1, .tets = {}});
  const int32_t copy = model.AddNodeCopy(3, state);
  (void)model.AddNodeCopy(5, state);
  motion.Follow(events);
  motion.Follow(events);  // events already seen are not taken in twice
  ASSERT_EQ(motion.entries().size(), 4u);
  motion.Apply(model, state, 1.0);
  for (const int32_t n : {3, copy}) {
    const Eigen::Vector3d rest = model.rest_position(n);
    EXPECT_DOUBLE_EQ(state.x[3 * n] - rest.x(), 0.001) << n;
    EXPECT_DOUBLE_EQ(state.x[3 * n + 1] - rest.y(), 0.002) << n;
  }
}

}  // namespace
}  // namespace cutsim::sim
