// The nodal-pressure element in the explicit force pass and step: the
// vectorised forces equal the reference deviatoric + nodal terms and minus
// the energy's gradient (double and float), rigid motions give no force,
// symplectic Euler keeps the energy as it does for the plain element (its
// momentum: dynamics_test.cc), and the stable-step bound holds without being
// vacuous.
#include <gtest/gtest.h>

#include <cmath>
#include <random>
#include <vector>

#include <Eigen/Geometry>

#include "common/fem/forces.h"
#include "common/fem/integrator.h"
#include "common/fem/nodal_pressure.h"
#include "common/fem/stable_dt.h"
#include "tests/unit/fem/test_meshes.h"

namespace cutsim::fem {
namespace {

template <typename T>
Model<T> MakeBlock(double nu, ElementKind element, double psi = 0) {
  const mesh::TetMesh mesh = testing::MakeBoxMesh(3, 2, 2, 0.03, 0.02, 0.02);
  Material mat = Material::FromYoungPoisson(1e4, nu, 1000.0);
  mat.psi = psi;
  mat.phi = 8 * psi;
  ModelOptions opt;
  opt.element = element;
  return Model<T>(mesh, std::span(&mat, 1), opt);
}

template <typename T>
void Perturb(State<T>& state, int num_nodes, double amplitude, unsigned seed) {
  std::mt19937 rng(seed);
  std::uniform_real_distribution<double> u(-amplitude, amplitude);
  for (int i = 0; i < 3 * num_nodes; ++i) state.x[static_cast<size_t>(i)] += static_cast<T>(u(rng));
}

std::vector<double> BulkModuli(const Model<double>& model) {
  return {model.kappas(), model.kappas() + model.num_tets()};
}

TEST(NodalPressureExplicit, ForcesAreTheDeviatoricPlusTheNodalTerm) {
  const Model<double> anp = MakeBlock<double>(0.49, ElementKind::kNodalPressure);
  State<double> state(anp);
  Perturb(state, anp.num_nodes(), 1e-3, 1);
  std::vector<double> f(state.x.size(), 0.0);
  ASSERT_EQ(ComputeInternalForces(anp, state, ForceMode::kElastic, f.data(), 2), -1);
  // Reference: the deviatoric element (StVK with λ = −2μ/3, one element at a
  // time) plus the nodal term's reference implementation.
  std::vector<double> ref(state.x.size(), 0.0);
  NodalPressureEnergyAndForce(anp, BulkModuli(anp), state.x.data(), ref.data());
  for (int32_t t = 0; t < anp.num_tets(); ++t) {
    const Mat3<double> F = DeformationGradient(anp, state.x.data(), t);
    const Mat3<double> P = StvkFirstPiola<double>(F, anp.element_lambdas()[t], anp.mus()[t]);
    const Vec12<double> fe = ElementForceFromPiola<double>(P, anp.DmInv(t), anp.rest_volume(t));
    for (int c = 0; c < 4; ++c) {
      for (int d = 0; d < 3; ++d) ref[static_cast<size_t>(3 * anp.tet_node(t, c) + d)] += fe(3 * c + d);
    }
  }
  double worst = 0, scale = 0;
  for (size_t i = 0; i < f.size(); ++i) {
    worst = std::max(worst, std::abs(f[i] - ref[i]));
    scale = std::max(scale, std::abs(ref[i]));
  }
  ASSERT_GT(scale, 0.0);
  EXPECT_LT(worst, 1e-10 * scale);
}

TEST(NodalPressureExplicit, ForceIsMinusTheEnergyGradient) {
  const Model<double> model = MakeBlock<double>(0.49, ElementKind::kNodalPressure);
  State<double> state(model);
  Perturb(state, model.num_nodes(), 1e-3, 2);
  std::vector<double> f(state.x.size(), 0.0);
  ComputeInternalForces(model, state, ForceMode::kElastic, f.data(), 1);
  const double h = 1e-8;
  double worst = 0, scale = 0;
  for (int32_t i = 0; i < 3 * model.num_nodes(); ++i) {
    const auto k = static_cast<size_t>(i);
    const double xi = state.x[k];
    state.x[k] = xi + h;
    const double ep = StrainEnergy(model, state.x.data());
    state.x[k] = xi - h;
    const double em = StrainEnergy(model, state.x.data());
    state.x[k] = xi;
    worst = std::max(worst, std::abs(-(ep - em) / (2 * h) - f[k]));
    scale = std::max(scale, std::abs(f[k]));
  }
  EXPECT_LT(worst, 1e-5 * scale);
}

TEST(NodalPressureExplicit, FloatAgreesWithDouble) {
  const Model<double> md = MakeBlock<double>(0.49, ElementKind::kNodalPressure);
  const Model<float> mf = MakeBlock<float>(0.49, ElementKind::kNodalPressure);
  State<double> sd(md);
  State<float> sf(mf);
  Perturb(sd, md.num_nodes(), 1e-3, 3);
  for (size_t i = 0; i < sd.x.size(); ++i) sf.x[i] = static_cast<float>(sd.x[i]);
  std::vector<double> fd(sd.x.size(), 0.0);
  std::vector<float> ff(sf.x.size(), 0.0F);
  ComputeInternalForces(md, sd, ForceMode::kElastic, fd.data(), 1);
  ComputeInternalForces(mf, sf, ForceMode::kElastic, ff.data(), 1);
  double worst = 0, scale = 0;
  for (size_t i = 0; i < fd.size(); ++i) {
    worst = std::max(worst, std::abs(fd[i] - static_cast<double>(ff[i])));
    scale = std::max(scale, std::abs(fd[i]));
  }
  // Forces are differences of stresses near the rest state: float keeps
  // about 3–4 digits of them.
  EXPECT_LT(worst, 1e-3 * scale);
}

TEST(NodalPressureExplicit, RigidMotionsGiveNoForce) {
  const Model<double> model = MakeBlock<double>(0.499, ElementKind::kNodalPressure);
  State<double> state(model);
  const Eigen::Matrix3d R = Eigen::AngleAxisd(1.1, Eigen::Vector3d(-1, 2, 0.5).normalized()).toRotationMatrix();
  for (int32_t n = 0; n < model.num_nodes(); ++n) {
    Eigen::Map<Eigen::Vector3d>(state.x.data() + 3 * n) = R * model.rest_position(n) + Eigen::Vector3d(1, -2, 3);
  }
  std::vector<double> f(state.x.size(), 1.0);
  ComputeInternalForces(model, state, ForceMode::kElastic, f.data(), 2);
  for (int32_t i = 0; i < 3 * model.num_nodes(); ++i) EXPECT_NEAR(f[static_cast<size_t>(i)], 0.0, 1e-9);
  EXPECT_NEAR(StrainEnergy(model, state.x.data()), 0.0, 1e-15);
}

// Symplectic Euler at a tenth of the bound keeps the energy of an undamped
// perturbed block within the band the plain element's test allows.
TEST(NodalPressureExplicit, EnergyStaysBoundedUndamped) {
  for (const ElementKind kind : {ElementKind::kLinear, ElementKind::kNodalPressure}) {
    Model<double> model = MakeBlock<double>(0.49, kind);
    State<double> state(model);
    Perturb(state, model.num_nodes(), 5e-4, 6);
    RefreshStableStep(model, state, true, 1);
    const double dt = 0.1 * StableStepBound(state);
    const auto total = [&] { return StrainEnergy(model, state.x.data()) + KineticEnergy(model, state.v.data()); };
    const double e0 = total();
    double max_dev = 0;
    for (int s = 1; s <= 2000; ++s) {
      ASSERT_TRUE(Step(model, state, dt, {.num_threads = 1}).ok());
      if (s % 100 == 0) max_dev = std::max(max_dev, std::abs(total() - e0) / e0);
    }
    EXPECT_LT(max_dev, 2e-2) << (kind == ElementKind::kLinear ? "linear" : "nodal pressure");
  }
}

// A run at the bound's step stays stable; well past the true limit it blows
// up, so the bound is neither unsafe nor vacuous for this element.
TEST(NodalPressureExplicit, StableStepBoundHolds) {
  const auto blows_up = [](double factor) {
    Model<double> model = MakeBlock<double>(0.49, ElementKind::kNodalPressure);
    State<double> state(model);
    Perturb(state, model.num_nodes(), 1e-7, 7);
    RefreshStableStep(model, state, true, 1);
    const double bound = StableStepBound(state);
    const double e0 = StrainEnergy(model, state.x.data());
    for (int s = 0; s < 3000; ++s) {
      if (!Step(model, state, factor * bound, {.num_threads = 1}).ok()) return true;
      if (s % 50 == 0 && StrainEnergy(model, state.x.data()) + KineticEnergy(model, state.v.data()) > 100 * e0) {
        return true;
      }
    }
    return false;
  };
  EXPECT_FALSE(blows_up(1.0));
  EXPECT_TRUE(blows_up(8.0));
}

}  // namespace
}  // namespace cutsim::fem
