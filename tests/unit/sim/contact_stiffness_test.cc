// The contact stiffness functions (common/sim/contact_stiffness.h) against
// central finite differences of the FEM's internal forces at a deformed
// state: the element tangents, each node's diagonal block along a
// direction, and the patch's point stiffness 1/(fᵀK⁻¹f) on the unknowns the
// patch frees.
#include <algorithm>
#include <array>
#include <cmath>
#include <random>
#include <span>
#include <vector>

#include <Eigen/Dense>
#include <gtest/gtest.h>

#include "common/fem/forces.h"
#include "common/fem/model.h"
#include "common/fem/state.h"
#include "common/mesh/generators.h"
#include "common/sim/contact_stiffness.h"

namespace cutsim::sim {
namespace {

constexpr double kSize = 0.02;  // m, the block's edge

/// A 3×3×2-cell block of soft tissue, its base fixed if asked, stretched
/// along x by 10 % (at constant volume for the nodal-pressure element) and jittered by a tenth of a cell, so that the tangent
/// differs from the rest one.
struct Fixture {
  explicit Fixture(bool fixed_base, fem::ElementKind element = fem::ElementKind::kLinear)
      : mesh(mesh::MakeBox(Eigen::Vector3d::Zero(), Eigen::Vector3d(kSize, kSize, kSize), 3, 3, 2)),
        tissue(fem::Material::FromYoungPoisson(5e4, element == fem::ElementKind::kLinear ? 0.4 : 0.49, 1000)),
        model(mesh, std::span(&tissue, 1), fem::ModelOptions{.element = element}),
        state(model) {
    if (fixed_base) {
      for (int32_t n = 0; n < model.num_nodes(); ++n) {
        if (mesh.nodes(n, 2) == 0.0) model.SetFixed(n, true);
      }
    }
    // The nearly incompressible material contracts sideways (volume kept),
    // or the hydrostatic tension of a 10 % volume change would make the
    // patch tangent indefinite.
    const double lateral = element == fem::ElementKind::kLinear ? 1.0 : 1.0 / std::sqrt(1.1);
    std::mt19937 rng(3);
    std::uniform_real_distribution<double> jitter(-0.1 * kSize / 3, 0.1 * kSize / 3);
    for (int32_t n = 0; n < model.num_nodes(); ++n) {
      const auto i = 3 * static_cast<size_t>(n);
      if (model.fixed(n)) continue;
      state.x[i] = 1.1 * mesh.nodes(n, 0) + jitter(rng);
      state.x[i + 1] = lateral * mesh.nodes(n, 1) + jitter(rng);
      state.x[i + 2] = lateral * mesh.nodes(n, 2) + jitter(rng);
    }
  }

  /// Column (node, axis) of −∂f/∂x by central differences.  // #N·3
  Eigen::VectorXd FiniteDifferenceColumn(int32_t node, int axis) {
    const size_t i = 3 * static_cast<size_t>(node) + static_cast<size_t>(axis);
    const double h = 1e-7 * kSize, x0 = state.x[i];
    const size_t n3 = 3 * static_cast<size_t>(model.num_nodes());
    std::vector<double> plus(n3), minus(n3);
    state.x[i] = x0 + h;
    EXPECT_EQ(fem::ComputeInternalForces(model, state, fem::ForceMode::kElastic, plus.data(), 1), -1);
    state.x[i] = x0 - h;
    EXPECT_EQ(fem::ComputeInternalForces(model, state, fem::ForceMode::kElastic, minus.data(), 1), -1);
    state.x[i] = x0;
    Eigen::VectorXd column(static_cast<Eigen::Index>(n3));
    for (size_t k = 0; k < n3; ++k) column[static_cast<Eigen::Index>(k)] = -(plus[k] - minus[k]) / (2 * h);
    return column;
  }

  /// The whole tangent by finite differences.  // #N·3 × #N·3
  Eigen::MatrixXd FiniteDifferenceTangent() {
    const int n3 = 3 * model.num_nodes();
    Eigen::MatrixXd K(n3, n3);
    for (int32_t n = 0; n < model.num_nodes(); ++n) {
      for (int a = 0; a < 3; ++a) K.col(3 * n + a) = FiniteDifferenceColumn(n, a);
    }
    return K;
  }

  mesh::TetMesh mesh;
  fem::Material tissue;
  fem::Model<double> model;
  fem::State<double> state;
};

/// A facet on the block's top: a tet face whose three nodes lie at z = kSize.
std::array<int32_t, 3> TopFacet(const Fixture& f) {
  for (int32_t t = 0; t < f.mesh.num_tets(); ++t) {
    std::array<int32_t, 3> facet{};
    int count = 0;
    for (int c = 0; c < 4 && count < 3; ++c) {
      const int32_t n = f.mesh.tets(t, c);
      if (f.mesh.nodes(n, 2) == kSize) facet[static_cast<size_t>(count++)] = n;
    }
    if (count == 3) return facet;
  }
  ADD_FAILURE() << "no top facet";
  return {0, 1, 2};
}

TEST(ContactStiffness, ElementTangentsAssembleToMinusTheForceDerivative) {
  Fixture f(/*fixed_base=*/false);
  const Eigen::MatrixXd K_fd = f.FiniteDifferenceTangent();
  Eigen::MatrixXd K = Eigen::MatrixXd::Zero(K_fd.rows(), K_fd.cols());
  for (int32_t t = 0; t < f.model.num_tets(); ++t) {
    const Eigen::Matrix<double, 12, 12> Ke = ElementStiffness(f.model, f.state.x.data(), t);
    for (int ci = 0; ci < 4; ++ci) {
      for (int cj = 0; cj < 4; ++cj) {
        K.block<3, 3>(3 * f.model.tet_node(t, ci), 3 * f.model.tet_node(t, cj)) += Ke.block<3, 3>(3 * ci, 3 * cj);
      }
    }
  }
  const double scale = K_fd.cwiseAbs().maxCoeff();
  ASSERT_GT(scale, 0.0);
  EXPECT_LT((K - K_fd).cwiseAbs().maxCoeff(), 1e-5 * scale);
}

class ContactStiffnessElements : public ::testing::TestWithParam<fem::ElementKind> {};

TEST_P(ContactStiffnessElements, NodeNormalStiffnessIsTheDiagonalBlockAlongTheDirection) {
  Fixture f(/*fixed_base=*/false, GetParam());
  const Eigen::Vector3d u = Eigen::Vector3d(0.3, -0.2, 1.0).normalized();
  for (const int32_t node : {0, f.model.num_nodes() / 2, f.model.num_nodes() - 1}) {
    Eigen::Matrix3d block;
    for (int a = 0; a < 3; ++a) block.col(a) = f.FiniteDifferenceColumn(node, a).segment<3>(3 * node);
    const double expected = u.dot(block * u);
    EXPECT_NEAR(NodeNormalStiffness(f.model, f.state.x.data(), node, u), expected, 1e-5 * std::abs(expected))
        << "node " << node;
  }
}

// The patch frees the facet's nodes and two rings around them, holds the
// rest: its stiffness is 1/(fᵀK⁻¹f) with K the finite-difference tangent
// restricted to the unknowns it freed.
TEST_P(ContactStiffnessElements, PatchStiffnessIsThePointStiffnessOfTheFreedNodes) {
  Fixture f(/*fixed_base=*/true, GetParam());
  const std::array<int32_t, 3> facet = TopFacet(f);
  const Eigen::Vector3d w(0.2, 0.5, 0.3);
  const Eigen::Vector3d u = Eigen::Vector3d(0.1, 0.2, -1.0).normalized();
  PatchScratch scratch;
  const double k = PatchStiffness(f.model, f.state.x.data(), facet, w, u, scratch);
  const std::vector<int32_t> unknown = scratch.unknown;  // kept after the call
  ASSERT_GE(unknown.size(), 3u);
  for (const int32_t n : unknown) EXPECT_FALSE(f.model.fixed(n)) << "node " << n;
  EXPECT_TRUE(std::all_of(scratch.column.begin(), scratch.column.end(), [](int32_t c) { return c == -1; }))
      << "the node → unknown map must be left at −1";

  const Eigen::MatrixXd K_fd = f.FiniteDifferenceTangent();
  const int n = 3 * static_cast<int>(unknown.size());
  Eigen::MatrixXd K(n, n);
  Eigen::VectorXd load = Eigen::VectorXd::Zero(n);
  for (int i = 0; i < static_cast<int>(unknown.size()); ++i) {
    for (int j = 0; j < static_cast<int>(unknown.size()); ++j) {
      K.block<3, 3>(3 * i, 3 * j) = K_fd.block<3, 3>(3 * unknown[static_cast<size_t>(i)], 3 * unknown[static_cast<size_t>(j)]);
    }
    for (int c = 0; c < 3; ++c) {
      if (unknown[static_cast<size_t>(i)] == facet[static_cast<size_t>(c)]) load.segment<3>(3 * i) = w[c] * u;
    }
  }
  const double expected = 1.0 / load.dot(K.ldlt().solve(load));
  ASSERT_GT(expected, 0.0);
  EXPECT_NEAR(k, expected, 1e-5 * expected);

  // A second call on the warm scratch gives the same bits.
  EXPECT_EQ(PatchStiffness(f.model, f.state.x.data(), facet, w, u, scratch), k);
}

// The nodal-pressure element's tangent couples whole node patches: the
// patch solve and the diagonal estimate must include it to match the force's
// derivative.
INSTANTIATE_TEST_SUITE_P(Elements, ContactStiffnessElements,
                         ::testing::Values(fem::ElementKind::kLinear, fem::ElementKind::kNodalPressure),
                         [](const ::testing::TestParamInfo<fem::ElementKind>& param_info) {
                           return param_info.param == fem::ElementKind::kLinear ? "Linear" : "NodalPressure";
                         });

TEST(ContactStiffness, SeriesStiffnessIsSofterThanEither) {
  EXPECT_DOUBLE_EQ(SeriesStiffness(100.0, 100.0), 50.0);
  EXPECT_LT(SeriesStiffness(100.0, 1.0), 1.0);
  EXPECT_EQ(SeriesStiffness(0.0, 0.0), 0.0);
  EXPECT_EQ(SeriesStiffness(100.0, 0.0), 0.0);
}

}  // namespace
}  // namespace cutsim::sim
