// Model construction, input errors, cutting mutations and mass conservation.
#include <cmath>
#include <numeric>

#include <gtest/gtest.h>

#include "common/core/error.h"
#include "common/fem/forces.h"
#include "common/fem/model.h"
#include "common/fem/stable_dt.h"
#include "common/fem/state.h"
#include "tests/unit/fem/test_meshes.h"

namespace cutsim::fem {
namespace {

const Material kTissue{.lambda = 140000, .mu = 11000, .psi = 0, .phi = 0, .density = 1000};

TEST(FemModel, LumpedMassIsRhoVolOverFour) {
  const mesh::TetMesh mesh = testing::MakeBoxMesh(2, 3, 4, 0.02, 0.03, 0.04);
  Model<double> model(mesh, std::span(&kTissue, 1));
  EXPECT_NEAR(model.TotalMass(), 1000 * 0.02 * 0.03 * 0.04, 1e-15);
  double vol = 0;
  for (int t = 0; t < model.num_tets(); ++t) vol += model.rest_volume(t);
  EXPECT_NEAR(vol, 0.02 * 0.03 * 0.04, 1e-15);
  // Corner node of a Kuhn grid on the main diagonal: in 6 tets → 6·m_e/4.
  EXPECT_NEAR(model.node_mass(0), 6 * (1000 * 1e-6 / 6) / 4, 1e-15);
}

TEST(FemModel, BadInputNamesTheTet) {
  mesh::TetMesh mesh = testing::MakeBoxMesh(1, 1, 1, 1, 1, 1);
  std::swap(mesh.tets(3, 0), mesh.tets(3, 1));  // inverted
  try {
    Model<double> model(mesh, std::span(&kTissue, 1), {.source = "box.msh"});
    FAIL() << "expected InputError";
  } catch (const InputError& e) {
    EXPECT_EQ(e.source().file, "box.msh");
    // A tet index is a field, never a line of the file.
    EXPECT_FALSE(e.source().line.has_value());
    EXPECT_EQ(e.source().field, "tet 4");
  }
  mesh = testing::MakeBoxMesh(1, 1, 1, 1, 1, 1);
  mesh.tets(2, 1) = 99;
  EXPECT_THROW(Model<double>(mesh, std::span(&kTissue, 1)), InputError);
  mesh = testing::MakeBoxMesh(1, 1, 1, 1, 1, 1);
  Material bad = kTissue;
  bad.mu = -1;
  EXPECT_THROW(Model<double>(mesh, std::span(&bad, 1)), InputError);
  const std::vector<Material> two(2, kTissue);
  EXPECT_THROW(Model<double>(mesh, two), InputError);  // neither 1 nor #T nor regions
}

TEST(FemModel, PerRegionMaterials) {
  mesh::TetMesh mesh = testing::MakeBoxMesh(1, 1, 1, 1, 1, 1);
  mesh.regions = {0, 0, 0, 1, 1, 1};
  Material soft = kTissue;
  soft.mu = 5000;
  const std::vector<Material> mats = {kTissue, soft};
  Model<double> model(mesh, mats);
  EXPECT_EQ(model.mus()[0], 11000);
  EXPECT_EQ(model.mus()[5], 5000);
}

// The sim recomputes only the elements of moved nodes after a cut
// (simulation.cc, ApplyEvent): a tet re-pointed to a fresh split copy must
// keep its element data bit for bit, since the copy starts at its
// original's rest position and the corner order is kept. So must its stable
// step (the sim updates the stable-step tree from the same stars): the copy
// also shares its original's world position, and element masses are frozen.
TEST(FemModel, RetargetingToAFreshCopyLeavesTheElementUnchanged) {
  const mesh::TetMesh mesh = testing::MakeBoxMesh(3, 3, 3, 0.03, 0.03, 0.03);
  Model<double> model(mesh, std::span(&kTissue, 1), {.node_capacity = mesh.num_nodes() + 8});
  State<double> state(model);
  // A deformed state, so the stable step reads a non-trivial F.
  for (size_t i = 0; i < state.x.size(); ++i) state.x[i] += 1e-3 * std::sin(1.7 * static_cast<double>(i));
  const int node = (1 * 4 + 1) * 4 + 1 + 1;
  std::vector<int32_t> retargeted;
  std::vector<Mat3<double>> dm_inv;
  std::vector<double> volume, grad, stable;
  const int copy = model.AddNodeCopy(node, state);
  for (int t = 0; t < model.num_tets(); ++t) {
    for (int c = 0; c < 4; ++c) {
      if (model.tet_node(t, c) != node || t % 2 != 0) continue;
      retargeted.push_back(t);
      dm_inv.push_back(model.DmInv(t));
      volume.push_back(model.rest_volume(t));
      grad.push_back(model.grad_sq_max(t));
      stable.push_back(ElementStableStep(model, state.x.data(), t, true));
      model.RetargetTet(t, c, copy);
    }
  }
  ASSERT_GE(retargeted.size(), 2u);
  std::vector<int32_t> incident;
  const std::vector<int32_t> copies = {copy, copy};  // listed twice: still each tet once
  model.IncidentTets(copies, incident);
  EXPECT_EQ(incident, retargeted);
  ASSERT_EQ(model.RecomputeElements(retargeted), 0);
  const std::vector<int32_t> split_nodes = {node, copy};  // as the sim does after a split
  model.RecomputeNodeMasses(split_nodes);
  model.CommitTopology();
  for (size_t i = 0; i < retargeted.size(); ++i) {
    const int32_t t = retargeted[i];
    EXPECT_TRUE(model.DmInv(t) == dm_inv[i]) << "tet " << t;
    EXPECT_EQ(model.rest_volume(t), volume[i]) << "tet " << t;
    EXPECT_EQ(model.grad_sq_max(t), grad[i]) << "tet " << t;
    EXPECT_EQ(ElementStableStep(model, state.x.data(), t, true), stable[i]) << "tet " << t;
  }
}

TEST(FemModel, SplitConservesMassExactly) {
  const mesh::TetMesh mesh = testing::MakeBoxMesh(3, 3, 3, 0.03, 0.03, 0.03);
  Model<double> model(mesh, std::span(&kTissue, 1), {.node_capacity = mesh.num_nodes() + 8});
  State<double> state(model);
  const double m0 = model.TotalMass();
  // Split a central node: tets with centroid x < node.x keep it, the others
  // move to the copy (what a vertex split does).
  const int node = (1 * 4 + 1) * 4 + 1 + 1;  // (2,1,1)
  const Vec3<double> p = model.rest_position(node);
  state.v[3 * node] = 0.25;
  const int copy = model.AddNodeCopy(node, state);
  EXPECT_EQ(model.rest_position(copy), p);
  EXPECT_EQ(state.v[3 * copy], 0.25);
  std::vector<int32_t> touched;
  for (int t = 0; t < model.num_tets(); ++t) {
    for (int c = 0; c < 4; ++c) {
      if (model.tet_node(t, c) != node) continue;
      Vec3<double> centroid = Vec3<double>::Zero();
      for (int k = 0; k < 4; ++k) centroid += model.rest_position(model.tet_node(t, k)) / 4;
      if (centroid(0) > p(0)) {
        model.RetargetTet(t, c, copy);
        touched.push_back(t);
      }
    }
  }
  ASSERT_FALSE(touched.empty());
  model.SetRestPosition(copy, p + Vec3<double>(1e-4, 0, 0));
  EXPECT_EQ(model.RecomputeElements(touched), 0);
  const std::vector<int32_t> nodes = {node, copy};
  model.RecomputeNodeMasses(nodes);
  EXPECT_FALSE(model.topology_dirty());
  EXPECT_EQ(model.topology_version(), 1u);
  EXPECT_GT(model.node_mass(copy), 0);
  EXPECT_NEAR(model.TotalMass(), m0, 1e-14 * m0);
  // Element masses are frozen: the total matches the load-time ρ·V exactly.
  double elem_total = 0;
  for (int t = 0; t < model.num_tets(); ++t) elem_total += model.element_mass(t);
  EXPECT_NEAR(model.TotalMass(), elem_total, 1e-14 * m0);  // summation order only
  // Incidence: every slot of the copy points at a retargeted corner.
  for (int k = model.incidence_begin(copy); k < model.incidence_end(copy); ++k) {
    const int slot = model.incidence_slots()[k];
    EXPECT_EQ(model.tet_node(slot / 12, (slot % 12) / 3), copy);
  }
}

TEST(FemModel, DegenerateRecomputeGivesInertElement) {
  const mesh::TetMesh mesh = testing::MakeUnitTet(0.01);
  Model<double> model(mesh, std::span(&kTissue, 1));
  model.SetRestPosition(3, Vec3<double>(0.003, 0.003, 0));  // flat
  const std::vector<int32_t> t = {0};
  EXPECT_EQ(model.RecomputeElements(t), 1);
  EXPECT_EQ(model.rest_volume(0), 0);
  State<double> state(model);
  std::vector<double> f(state.x.size());
  EXPECT_EQ(ComputeInternalForces(model, state, ForceMode::kElastic, f.data()), -1);
  for (double fi : f) EXPECT_EQ(fi, 0);
  EXPECT_GT(model.TotalMass(), 0);  // mass frozen
}

TEST(FemModel, IncrementalStableStepMatchesFullRefresh) {
  const mesh::TetMesh mesh = testing::MakeBoxMesh(4, 3, 3, 0.04, 0.03, 0.03);
  Model<double> model(mesh, std::span(&kTissue, 1));
  State<double> state(model);
  RefreshStableStep(model, state, true, 1);
  const double before = StableStepBound(state);
  // A cut-like edit: move one node's rest position, shrinking its elements.
  const int node = 21;
  model.SetRestPosition(node, model.rest_position(node) + Vec3<double>(0.004, 0.003, 0.002));
  std::vector<int32_t> touched;
  for (int t = 0; t < model.num_tets(); ++t) {
    for (int c = 0; c < 4; ++c) {
      if (model.tet_node(t, c) == node) touched.push_back(t);
    }
  }
  ASSERT_EQ(model.RecomputeElements(touched), 0);
  UpdateStableStep(model, state, touched, true);
  const double incremental = StableStepBound(state);
  const int limiting = StableStepLimitingElement(state);
  RefreshStableStep(model, state, true, 1);
  EXPECT_EQ(incremental, StableStepBound(state));
  EXPECT_NE(incremental, before);
  EXPECT_EQ(state.element_dt[static_cast<size_t>(limiting)], incremental);
}

}  // namespace
}  // namespace cutsim::fem
