// The implicit step's assembled system: the closed-form blocks against the
// reference element stiffness, the assembled K and C against finite
// differences and the explicit path's forces, the clamped tangent, the
// determinism of assembly, and the linear solver with a stale factor.
#include <gtest/gtest.h>

#include <algorithm>
#include <cmath>
#include <numbers>
#include <random>
#include <vector>

#include <Eigen/Eigenvalues>

#include "common/fem/forces.h"
#include "common/fem/implicit.h"
#include "common/fem/linear_solver.h"
#include "common/fem/sparse_system.h"
#include "common/fem/tangent.h"
#include "tests/unit/fem/implicit_fixtures.h"

namespace cutsim::fem {
namespace {

using Mat12 = Eigen::Matrix<double, 12, 12>;

Mat12 BlocksToMatrix(const ElementBlocks& b) {
  Mat12 m;
  for (int i = 0; i < 4; ++i) {
    for (int j = 0; j < 4; ++j) m.block<3, 3>(3 * i, 3 * j) = b[4 * i + j];
  }
  return m;
}

/// y = A x for a full symmetric matrix on `system`'s pattern.
std::vector<double> Multiply(const SparseSystem& system, const std::vector<double>& values,
                             const std::vector<double>& x) {
  std::vector<double> y(static_cast<size_t>(system.num_dofs()));
  system.MultiplyTeam(values.data(), x.data(), y.data());
  return y;
}

double MaxAbs(const std::vector<double>& a) {
  double m = 0;
  for (const double v : a) m = std::max(m, std::abs(v));
  return m;
}

TEST(ImplicitTangent, ClosedFormBlocksEqualReferenceStiffness) {
  std::mt19937 rng(7);
  std::uniform_real_distribution<double> u(-0.3, 0.3);
  const Mat34<double> rest = (Mat34<double>() << 0, 1, 0, 0, 0, 0, 1, 0, 0, 0, 0, 1).finished() * 0.01;
  const Mat3<double> dm_inv = EdgeMatrix(rest).inverse();
  for (int trial = 0; trial < 5; ++trial) {
    Mat34<double> x = rest;
    for (int k = 0; k < 12; ++k) x(k % 3, k / 3) += 0.01 * u(rng);
    const Mat3<double> F = EdgeMatrix(x) * dm_inv;
    const Mat3<double> S = StvkSecondPiola(GreenStrain(F), 2e5, 1e4);
    ElementBlocks blocks;
    ElementTangentBlocks(F, S, ShapeGradients(dm_inv), 1e-6 / 6, 2e5, 1e4, blocks);
    const Mat12 ref = StvkElementStiffness<double>(x, dm_inv, 1e-6 / 6, 2e5, 1e4);
    EXPECT_LE((BlocksToMatrix(blocks) - ref).norm(), 1e-12 * ref.norm()) << "trial " << trial;
    Mat3<double> S2;
    Mat34<double> f;
    StvkEnergyAndForce(F, ShapeGradients(dm_inv), 1e-6 / 6, 2e5, 1e4, &S2, &f);
    const Vec12<double> fref = StvkElementForce<double>(x, dm_inv, 1e-6 / 6, 2e5, 1e4);
    EXPECT_LE((Eigen::Map<const Vec12<double>>(f.data()) - fref).norm(), 1e-12 * fref.norm());
  }
}

TEST(ImplicitTangent, ClampedTangentIsPsdAndExactWithoutCompression) {
  const Mat34<double> rest = (Mat34<double>() << 0, 1, 0, 0, 0, 0, 1, 0, 0, 0, 0, 1).finished() * 0.01;
  const Mat3<double> dm_inv = EdgeMatrix(rest).inverse();
  const auto tangents = [&](const Mat3<double>& F, Mat12* exact, Mat12* clamped) {
    const Mat3<double> S = StvkSecondPiola(GreenStrain(F), 2e5, 1e4);
    ElementBlocks b;
    ElementTangentBlocks(F, S, ShapeGradients(dm_inv), 1e-6, 2e5, 1e4, b);
    *exact = BlocksToMatrix(b);
    ElementTangentBlocks(F, PositivePart(S), ShapeGradients(dm_inv), 1e-6, 2e5, 1e4, b);
    *clamped = BlocksToMatrix(b);
  };
  Mat12 k, kp;
  // Strong axial compression: the geometric term makes K indefinite.
  tangents(Eigen::Vector3d(0.5, 1.0, 1.0).asDiagonal(), &k, &kp);
  Eigen::SelfAdjointEigenSolver<Mat12> es_k(k), es_kp(kp);
  EXPECT_LT(es_k.eigenvalues()(0), -1e-6 * es_k.eigenvalues()(11));
  EXPECT_GE(es_kp.eigenvalues()(0), -1e-10 * es_kp.eigenvalues()(11));
  // Pure stretch (S ⪰ 0): the clamp changes nothing.
  tangents(Eigen::Vector3d(1.2, 1.1, 1.05).asDiagonal(), &k, &kp);
  EXPECT_EQ(k, kp);
}

class ImplicitAssembly : public ::testing::Test {
 protected:
  Model<double> model_ = testing::MakeCantilever(4, 0.04, 3e4, true, 2.0, 10.0);
};

// K = −∂f/∂x: central differences of the assembled internal force along
// random directions, at a random state, a stretched one and a compressed one.
TEST_F(ImplicitAssembly, StiffnessMatchesFiniteDifferencesOfTheForce) {
  ImplicitIntegrator integ;
  std::mt19937 rng(3);
  std::normal_distribution<double> normal;
  for (const double sx : {1.0, 1.15, 0.8}) {
    const std::vector<double> x = testing::DeformedPositions(model_, 1e-3, sx, sx);
    std::vector<double> k;
    integ.AssembleStiffness(model_, x.data(), false, k);
    const SparseSystem& sys = integ.system();
    std::vector<double> dir(static_cast<size_t>(sys.num_dofs()));
    for (double& d : dir) d = normal(rng);
    const double eps = 1e-7;
    std::vector<double> xp = x, xm = x, fp(dir.size()), fm(dir.size()), fd(dir.size());
    for (size_t i = 0; i < dir.size(); ++i) {
      xp[i] += eps * dir[i];
      xm[i] -= eps * dir[i];
    }
    integ.InternalForce(model_, xp.data(), fp.data());
    integ.InternalForce(model_, xm.data(), fm.data());
    for (size_t i = 0; i < dir.size(); ++i) fd[i] = -(fp[i] - fm[i]) / (2 * eps);
    const std::vector<double> kd = Multiply(sys, k, dir);
    std::vector<double> diff(dir.size());
    for (size_t i = 0; i < dir.size(); ++i) diff[i] = kd[i] - fd[i];
    EXPECT_LE(MaxAbs(diff), 1e-6 * MaxAbs(kd)) << "sx " << sx;
  }
}

// The implicit force is the explicit path's elastic force (no element is
// near inversion here), and C·v is minus its viscous force.
TEST_F(ImplicitAssembly, ForcesAndDampingMatchTheExplicitPath) {
  ImplicitIntegrator integ;
  State<double> state(model_);
  state.x = testing::DeformedPositions(model_, 1e-3, 0.9);
  for (size_t i = 0; i < state.v.size(); ++i) state.v[i] = 0.01 * std::cos(0.37 * static_cast<double>(i));
  const auto nd = static_cast<size_t>(3 * model_.num_nodes());
  std::vector<double> f_exp(state.x.size()), f_imp(nd), f_visc(state.x.size());
  ASSERT_EQ(ComputeInternalForces(model_, state, ForceMode::kElastic, f_exp.data(), 1), -1);
  integ.InternalForce(model_, state.x.data(), f_imp.data());
  std::vector<double> diff(nd);
  for (size_t i = 0; i < nd; ++i) diff[i] = f_imp[i] - f_exp[i];
  EXPECT_LE(MaxAbs(diff), 1e-12 * MaxAbs(f_imp));

  ASSERT_EQ(ComputeInternalForces(model_, state, ForceMode::kViscousOnly, f_visc.data(), 1), -1);
  std::vector<double> c;
  integ.AssembleDamping(model_, state.x.data(), c);
  const std::vector<double> v(state.v.begin(), state.v.begin() + static_cast<long>(nd));
  const std::vector<double> cv = Multiply(integ.system(), c, v);
  for (size_t i = 0; i < nd; ++i) diff[i] = cv[i] + f_visc[i];
  EXPECT_LE(MaxAbs(diff), 1e-12 * MaxAbs(cv));
  EXPECT_GT(MaxAbs(cv), 0.0);

  // Mass-proportional damping adds α·M on the diagonal.
  ImplicitIntegrator with_alpha({.mass_damping = 3.0});
  std::vector<double> ca;
  with_alpha.AssembleDamping(model_, state.x.data(), ca);
  const std::vector<double> cav = Multiply(with_alpha.system(), ca, v);
  for (int32_t n = 0; n < model_.num_nodes(); ++n) {
    for (int d = 0; d < 3; ++d) {
      const auto i = static_cast<size_t>(3 * n + d);
      EXPECT_NEAR(cav[i] - cv[i], 3.0 * model_.node_mass(n) * v[i], 1e-12 * MaxAbs(cv));
    }
  }
}

TEST_F(ImplicitAssembly, OneThreadEqualsTwoThreads) {
  // Enough chunks that a colour holds several (sparse_system.h).
  model_ = testing::MakeCantilever(24, 0.24, 3e4, true, 2.0, 10.0);
  const std::vector<double> x = testing::DeformedPositions(model_, 2e-3, 0.85);
  ImplicitIntegrator one({.num_threads = 1}), two({.num_threads = 2});
  std::vector<double> k1, k2, c1, c2;
  one.AssembleStiffness(model_, x.data(), false, k1);
  two.AssembleStiffness(model_, x.data(), false, k2);
  one.AssembleDamping(model_, x.data(), c1);
  two.AssembleDamping(model_, x.data(), c2);
  EXPECT_EQ(k1, k2);
  EXPECT_EQ(c1, c2);
  EXPECT_GT(one.system().num_colors(), 1);
  EXPECT_GE(one.system().color_ptr()[1], 2);  // the first colour has chunks to share
}

TEST(SparseSystemPattern, BlocksAreSymmetricAndColoursDisjoint) {
  const Model<double> model = testing::MakeCantilever(16, 0.16, 3e4);
  SparseSystem sys;
  sys.Build(model);
  for (int32_t t = 0; t < model.num_tets(); ++t) {
    for (int i = 0; i < 4; ++i) {
      for (int j = 0; j < 4; ++j) {
        const int32_t a = model.tet_node(t, i), b = model.tet_node(t, j);
        EXPECT_EQ(sys.tet_blocks(t)[4 * i + j], sys.FindBlock(a, b));
        EXPECT_GE(sys.FindBlock(b, a), 0);
      }
    }
  }
  // Chunks of one colour share no node; every tet is in exactly one chunk.
  std::vector<int32_t> owner(static_cast<size_t>(model.num_nodes()));
  std::vector<int> tet_seen(static_cast<size_t>(model.num_tets()), 0);
  for (int32_t c = 0; c < sys.num_colors(); ++c) {
    std::fill(owner.begin(), owner.end(), -1);
    for (int32_t k = sys.color_ptr()[c]; k < sys.color_ptr()[c + 1]; ++k) {
      const int32_t chunk = sys.color_chunks()[k];
      for (int32_t t = sys.chunk_begin(chunk); t < sys.chunk_end(chunk); ++t) {
        ++tet_seen[static_cast<size_t>(t)];
        for (int i = 0; i < 4; ++i) {
          int32_t& o = owner[static_cast<size_t>(model.tet_node(t, i))];
          EXPECT_TRUE(o == -1 || o == chunk) << "colour " << c << " tet " << t;
          o = chunk;
        }
      }
    }
  }
  for (const int n : tet_seen) EXPECT_EQ(n, 1);
}

/// Every node's column as an independent reference: the node itself and
/// every node it shares a tet with, ascending.
std::vector<std::vector<int32_t>> ReferenceColumns(const Model<double>& model) {
  std::vector<std::vector<int32_t>> cols(static_cast<size_t>(model.num_nodes()));
  for (int32_t n = 0; n < model.num_nodes(); ++n) cols[static_cast<size_t>(n)].push_back(n);
  for (int32_t t = 0; t < model.num_tets(); ++t) {
    for (int i = 0; i < 4; ++i) {
      for (int j = 0; j < 4; ++j) cols[static_cast<size_t>(model.tet_node(t, j))].push_back(model.tet_node(t, i));
    }
  }
  for (auto& c : cols) {
    std::sort(c.begin(), c.end());
    c.erase(std::unique(c.begin(), c.end()), c.end());
  }
  return cols;
}

void ExpectPatternOf(const SparseSystem& sys, const Model<double>& model) {
  const auto cols = ReferenceColumns(model);
  ASSERT_EQ(sys.num_nodes(), model.num_nodes());
  for (int32_t b = 0; b < model.num_nodes(); ++b) {
    const auto& ref = cols[static_cast<size_t>(b)];
    for (int c = 0; c < 3; ++c) {
      const int32_t begin = sys.col_ptr()[3 * b + c], end = sys.col_ptr()[3 * b + c + 1];
      ASSERT_EQ(end - begin, 3 * static_cast<int32_t>(ref.size())) << "node " << b;
      for (size_t k = 0; k < ref.size(); ++k) {
        for (int r = 0; r < 3; ++r) EXPECT_EQ(sys.row_index()[begin + 3 * static_cast<int32_t>(k) + r], 3 * ref[k] + r);
      }
    }
    EXPECT_EQ(sys.diagonal_block(b), sys.FindBlock(b, b));
  }
  for (int32_t t = 0; t < model.num_tets(); ++t) {
    for (int i = 0; i < 4; ++i) {
      for (int j = 0; j < 4; ++j) {
        EXPECT_EQ(sys.tet_blocks(t)[4 * i + j], sys.FindBlock(model.tet_node(t, i), model.tet_node(t, j)));
      }
    }
  }
}

// The pattern is built from the model's incidence, which a cut edits in
// place (a retargeted tet's slot moves to the end of the slot array): after
// cuts, the rebuilt pattern is still exactly the tets' node pairs.
TEST(SparseSystemPattern, EqualsTheTetPairsAfterCuts) {
  Model<double> model = testing::MakeCantilever(16, 0.16, 3e4, true, 0, 0, 8);
  State<double> state(model);
  SparseSystem sys;
  sys.Build(model);
  ExpectPatternOf(sys, model);
  for (const int32_t node : {20, 31, 40, 47}) {
    const double x0 = model.rest_position(node)(0);
    ASSERT_GT(testing::SplitNodeAsACut(model, state, node, [&](const Vec3<double>& c) { return c(0) > x0; }), 0);
    ASSERT_TRUE(sys.Stale(model));
    sys.Build(model);
    ExpectPatternOf(sys, model);
  }
}

// A node shared by more chunks than one 64-bit word of colours holds (a
// fan of 5 000 tets around one hub: every chunk needs its own colour):
// the colouring widens its sets and stays disjoint.
TEST(SparseSystemPattern, ColoursBeyondSixtyFour) {
  constexpr int kFan = 5000;
  mesh::TetMesh fan;
  fan.nodes.resize(1 + 2 * kFan, 3);
  fan.nodes.row(0) << 0, 0, 0;
  for (int i = 0; i < kFan; ++i) {
    const double a = 2 * std::numbers::pi * i / kFan;
    fan.nodes.row(1 + i) << std::cos(a), std::sin(a), 0;
    fan.nodes.row(1 + kFan + i) << 0.5 * std::cos(a), 0.5 * std::sin(a), 1;
  }
  fan.tets.resize(kFan, 4);
  for (int i = 0; i < kFan; ++i) fan.tets.row(i) << 0, 1 + i, 1 + (i + 1) % kFan, 1 + kFan + i;
  const Material mat = Material::FromYoungPoisson(3e4, 0.45, 1000.0);
  const Model<double> model(fan, std::span(&mat, 1), ModelOptions{});
  SparseSystem sys;
  sys.Build(model);
  const int32_t chunks = (kFan + SparseSystem::kChunk - 1) / SparseSystem::kChunk;
  EXPECT_EQ(sys.num_colors(), chunks);
  EXPECT_GT(sys.num_colors(), 64);
  ExpectPatternOf(sys, model);
}

/// SPD test matrix on a model's pattern: M/h² + K at rest, identity rows on
/// fixed nodes.
std::vector<double> TestMatrix(ImplicitIntegrator& integ, const Model<double>& model) {
  std::vector<double> k;
  const std::vector<double> x = testing::DeformedPositions(model, 0, 1.0);
  integ.AssembleStiffness(model, x.data(), false, k);
  const SparseSystem& sys = integ.system();
  for (int32_t n = 0; n < model.num_nodes(); ++n) {
    Eigen::Matrix3d d = 1e4 * model.node_mass(n) * Eigen::Matrix3d::Identity();
    sys.AddBlock(k.data(), sys.diagonal_block(n), n, d);
  }
  return k;
}

// A factor of the matrix before a cut preconditions the cut model's matrix
// on the old DOFs (block Jacobi on the new node) and PCG still converges.
TEST(ImplicitLinearSolver, StaleFactorOfTheOldPatternStillConverges) {
  Model<double> model = testing::MakeCantilever(4, 0.04, 3e4, true, 0, 0, 4);
  State<double> state(model);
  ImplicitIntegrator old_integ;
  const std::vector<double> a_old = TestMatrix(old_integ, model);
  LinearSolver solver(false);
  ASSERT_TRUE(solver.RequestFactor(old_integ.system(), a_old.data()));
  EXPECT_EQ(solver.factor_dofs(), old_integ.system().num_dofs());

  // Split a middle node: tets on its +x side move to a copy.
  const int32_t node = 2 * 1 + 1;
  const int32_t mid = [&] {
    for (int32_t n = 0; n < model.num_nodes(); ++n) {
      const Vec3<double> p = model.rest_position(n);
      if (std::abs(p(0) - 0.02) < 1e-9 && std::abs(p(1) - 0.01) < 1e-9 && std::abs(p(2) - 0.01) < 1e-9) return n;
    }
    return node;
  }();
  const Vec3<double> p = model.rest_position(mid);
  ASSERT_GT(testing::SplitNodeAsACut(model, state, mid,
                                     [&](const Vec3<double>& c) { return c(0) > p(0); }),
            0);

  ImplicitIntegrator new_integ;
  const std::vector<double> a_new = TestMatrix(new_integ, model);
  const SparseSystem& sys = new_integ.system();
  ASSERT_GT(sys.num_dofs(), solver.factor_dofs());
  solver.Resize(sys);
  // Every node active: the test matrix does not eliminate the fixed ones.
  const std::vector<uint8_t> active(static_cast<size_t>(sys.num_nodes()), 1);
  std::vector<double> b(static_cast<size_t>(sys.num_dofs())), x(b.size());
  for (size_t i = 0; i < b.size(); ++i) b[i] = std::sin(0.3 * static_cast<double>(i));
  const PcgResult r = solver.Solve(sys, a_new.data(), active.data(), b.data(), x.data(), 1e-10 * MaxAbs(b),
                                   500, 1);
  EXPECT_TRUE(r.converged) << r.iterations << " iterations, residual " << r.residual;
  std::vector<double> ax = Multiply(sys, a_new, x);
  for (int32_t n = 0; n < sys.num_nodes(); ++n) {
    for (int d = 0; d < 3; ++d) {
      const auto i = static_cast<size_t>(3 * n + d);
      EXPECT_NEAR(ax[i], b[i], 1e-8);
    }
  }
  // A fresh factor of the new pattern needs far fewer iterations.
  ASSERT_TRUE(solver.RequestFactor(sys, a_new.data()));
  const PcgResult fresh = solver.Solve(sys, a_new.data(), active.data(), b.data(), x.data(),
                                       1e-10 * MaxAbs(b), 500, 1);
  EXPECT_TRUE(fresh.converged);
  EXPECT_EQ(solver.factor_dofs(), sys.num_dofs());
  EXPECT_EQ(solver.stats().shifted, 0);
  EXPECT_EQ(solver.stats().failed, 0);
  EXPECT_LE(fresh.iterations, 2);
  EXPECT_GT(r.iterations, fresh.iterations);
}

}  // namespace
}  // namespace cutsim::fem
