// The matrix-free element tangent against the assembled one (both
// elements, unclamped and clamped, after cuts) and against finite
// differences of the force.
#include <gtest/gtest.h>

#include <cmath>
#include <vector>

#include "common/fem/implicit.h"
#include "common/fem/tangent_product.h"
#include "tests/unit/fem/implicit_fixtures.h"

namespace cutsim::fem {
namespace {

/// A cantilever of either element, cut through two nodes of its middle
/// section (a copy takes the tets on the x > 0.04 m side), stretched 20 %
/// along x and shaken, so compressed and stretched elements both occur.
struct CutCantilever {
  Model<double> model;
  State<double> state;
  std::vector<double> x;
  int32_t tets_moved = 0;  // by the cuts

  explicit CutCantilever(ElementKind element)
      : model(Make(element)), state(model) {
    for (const double y : {0.0, 0.01}) {
      tets_moved += testing::SplitNodeAsACut(model, state, testing::FindNode(model, 0.04, y, 0.01),
                                             [](const Vec3<double>& c) { return c(0) > 0.04; });
    }
    x = testing::DeformedPositions(model, 2e-3, 1.2);
  }
  static Model<double> Make(ElementKind element) {
    const mesh::TetMesh mesh = testing::MakeBoxMesh(8, 2, 2, 0.08, 0.02, 0.02);
    const Material mat = Material::FromYoungPoisson(3e4, 0.45, 1000.0, 0, 0);
    ModelOptions opt;
    opt.element = element;
    opt.node_capacity = mesh.num_nodes() + 4;
    Model<double> m(mesh, std::span(&mat, 1), opt);
    for (int32_t n = 0; n < m.num_nodes(); ++n) {
      if (m.rest_position(n)(0) < 1e-9) m.SetFixed(n, true);
    }
    return m;
  }
};

std::vector<double> Direction(int32_t dofs) {
  std::vector<double> p(static_cast<size_t>(dofs));
  for (size_t i = 0; i < p.size(); ++i) p[i] = std::cos(0.91 * static_cast<double>(i) + 0.3);
  return p;
}

class TangentProductTest : public ::testing::TestWithParam<ElementKind> {};

// K·p without the matrix equals the product with the assembled element
// tangent (the nodal-pressure element's element-local volumetric term
// included), on a cut mesh, with K or K⁺, for one and two threads.
TEST_P(TangentProductTest, EqualsTheAssembledTangentAfterCuts) {
  CutCantilever c(GetParam());
  ASSERT_GT(c.tets_moved, 0);
  for (const bool clamped : {false, true}) {
    ImplicitIntegrator integ({.num_threads = 1, .asynchronous_factorization = false});
    std::vector<double> k;
    integ.AssembleStiffness(c.model, c.x.data(), clamped, k);
    const SparseSystem& sys = integ.system();
    const std::vector<double> p = Direction(sys.num_dofs());
    std::vector<double> assembled(p.size(), 0.0);
    sys.MultiplyTeam(k.data(), p.data(), assembled.data());
    for (const int threads : {1, 2}) {
      TangentProduct op;
      op.Linearize(c.model, sys, c.x.data(), clamped, threads);
      std::vector<double> q(p.size(), 0.0);
      op.AddProduct(p.data(), 1.0, nullptr, q.data());
      EXPECT_LT(testing::RelativeDifference(q, assembled), 1e-12) << "clamped " << clamped << ", threads " << threads;
    }
  }
}

// With some nodes inactive, the pairs touching them drop out, as in the
// assembled matrix: the product equals the full one with p zero on those
// nodes and the rows of those nodes ignored.
TEST_P(TangentProductTest, InactiveNodesDropOutOfThePairs) {
  CutCantilever c(GetParam());
  ImplicitIntegrator integ({.num_threads = 1, .asynchronous_factorization = false});
  std::vector<double> k;
  integ.AssembleStiffness(c.model, c.x.data(), false, k);
  const SparseSystem& sys = integ.system();
  std::vector<uint8_t> active(static_cast<size_t>(sys.num_nodes()), 1);
  for (size_t n = 0; n < active.size(); n += 3) active[n] = 0;
  std::vector<double> p = Direction(sys.num_dofs());
  TangentProduct op;
  op.Linearize(c.model, sys, c.x.data(), false, 2);
  std::vector<double> q(p.size(), 0.0);
  op.AddProduct(p.data(), 2.0, active.data(), q.data());
  for (size_t i = 0; i < p.size(); ++i) {
    if (active[i / 3] == 0) p[i] = 0;
  }
  std::vector<double> full(p.size(), 0.0);
  sys.MultiplyTeam(k.data(), p.data(), full.data());
  double largest = 0;
  for (size_t i = 0; i < p.size(); ++i) {
    if (active[i / 3] == 0) {
      EXPECT_EQ(q[i], 0.0) << i;
      full[i] = 0;
    }
    full[i] *= 2.0;
    largest = std::max(largest, std::abs(full[i]));
  }
  EXPECT_GT(largest, 0.0);
  EXPECT_LT(testing::RelativeDifference(q, full), 1e-12);
}

INSTANTIATE_TEST_SUITE_P(BothElements, TangentProductTest,
                         ::testing::Values(ElementKind::kLinear, ElementKind::kNodalPressure),
                         [](const ::testing::TestParamInfo<ElementKind>& param_info) {
                           return param_info.param == ElementKind::kLinear ? std::string("Linear")
                                                                           : std::string("NodalPressure");
                         });

// For the plain StVK element the product is the derivative of the force:
// K·p = −(f(x + εp) − f(x − εp)) / 2ε to the central difference's O(ε²).
TEST(TangentProductFd, IsTheDerivativeOfTheForce) {
  CutCantilever c(ElementKind::kLinear);
  ImplicitIntegrator integ({.num_threads = 1, .asynchronous_factorization = false});
  std::vector<double> k;
  integ.AssembleStiffness(c.model, c.x.data(), false, k);
  const SparseSystem& sys = integ.system();
  const std::vector<double> p = Direction(sys.num_dofs());
  TangentProduct op;
  op.Linearize(c.model, sys, c.x.data(), false, 1);
  std::vector<double> q(p.size(), 0.0);
  op.AddProduct(p.data(), 1.0, nullptr, q.data());
  const double eps = 1e-7;
  std::vector<double> xp = c.x, xm = c.x, fp(p.size()), fm(p.size());
  for (size_t i = 0; i < p.size(); ++i) {
    xp[i] += eps * p[i];
    xm[i] -= eps * p[i];
  }
  integ.InternalForce(c.model, xp.data(), fp.data());
  integ.InternalForce(c.model, xm.data(), fm.data());
  std::vector<double> fd(p.size());
  for (size_t i = 0; i < p.size(); ++i) fd[i] = -(fp[i] - fm[i]) / (2 * eps);
  EXPECT_LT(testing::RelativeDifference(q, fd), 1e-6);
}

}  // namespace
}  // namespace cutsim::fem
